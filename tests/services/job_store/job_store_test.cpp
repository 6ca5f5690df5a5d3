// Both job stores against the contract in job_store.h, every case on SQLite and on PostgreSQL
// (a throwaway cluster, tests/support/postgres_cluster.h): the task graph, lease order, stale
// attempts, retries and their back-off, dead tasks, blocklists, cancel and retry, the event
// log, a database that outlives the store object that wrote it, and two store objects (two
// coordinators) leasing from one database at once. The tests drive a clock of their own.

#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <mutex>
#include <set>
#include <thread>

#include <sqlite3.h>

#include <fmt/format.h>

#include "core/render/integrators.h"
#include "services/job_store/job_store.h"
#include "tests/support/postgres_cluster.h"
#include "tests/support/test_paths.h"

namespace pbgi::farm {

// So that a failed EXPECT_EQ prints "ready", not "1".
void PrintTo(TaskKind kind, std::ostream* os) { *os << toString(kind); }
void PrintTo(TaskState state, std::ostream* os) { *os << toString(state); }
void PrintTo(JobState state, std::ostream* os) { *os << toString(state); }
void PrintTo(AuditState state, std::ostream* os) { *os << toString(state); }

namespace {

namespace fs = std::filesystem;

constexpr Seconds kLease = 30;

JobSpec makeSpec(std::vector<int> frames, int tiles, bool bake, int priority = 0) {
  JobSpec spec;
  spec.name = "shot";
  spec.shotPath = "/shots/shot.toml";
  spec.shotText = "[camera]\nfov = 40\n";
  spec.overrides.spp = 16;
  EXPECT_TRUE(setParamText(spec.overrides.params, "gather", "per-pixel", {"test"}).ok());
  spec.outputPattern = "/renders/shot.####.exr";
  spec.priority = priority;
  spec.frames = std::move(frames);
  spec.tileCount = tiles;
  spec.needsBake = bake;
  return spec;
}

AuditSpec makeAudit(int frame, std::vector<int> tiles, int spp = 64, double threshold = 0.05) {
  return AuditSpec{frame, std::move(tiles), spp, threshold};
}

int count(const JobInfo& info, TaskState state) {
  return info.tasksByState[static_cast<size_t>(state)];
}

enum class Backend { kSqlite, kPostgres };
void PrintTo(Backend backend, std::ostream* os) {
  *os << (backend == Backend::kSqlite ? "sqlite" : "postgres");
}

class JobStoreFixture : public ::testing::Test {
 protected:
  virtual Backend backend() const = 0;

  void SetUp() override {
    dir_ = testing::makeTempDir("job-store");
    if (backend() == Backend::kSqlite) {
      spec_ = (dir_ / "farm.db").string();
    } else {
      PBGI_POSTGRES_CLUSTER(cluster);
      auto database = cluster->createDatabase();
      ASSERT_TRUE(database.ok()) << database.status();
      cluster_ = cluster;
      database_ = *database;
      spec_ = cluster->uri(database_);
    }
    open();
  }
  void TearDown() override {
    store_.reset();
    fs::remove_all(dir_);
  }

  // Closes the store first, so that reopening reads only what was committed. Through
  // openJobStore, the one place that picks the implementation from the spec.
  void open(const RetryPolicy& policy = {}) {
    store_.reset();
    auto store = openJobStore(spec_, policy);
    ASSERT_TRUE(store.ok()) << store.status();
    store_ = std::move(*store);
  }

  // A second store object on the same database: a second coordinator.
  std::unique_ptr<JobStore> openAnother(const RetryPolicy& policy = {}) {
    auto store = openJobStore(spec_, policy);
    EXPECT_TRUE(store.ok()) << store.status();
    return store.ok() ? std::move(*store) : nullptr;
  }

  int64_t submit(const JobSpec& spec, Seconds now = 0) {
    auto job = store_->submit(spec, now);
    EXPECT_TRUE(job.ok()) << job.status();
    return job.ok() ? *job : -1;
  }

  JobInfo job(int64_t id) {
    auto info = store_->job(id);
    EXPECT_TRUE(info.ok()) << info.status();
    return info.ok() ? *info : JobInfo{};
  }

  std::optional<Lease> lease(const std::string& worker, Seconds now) {
    auto l = store_->lease(worker, now, kLease);
    EXPECT_TRUE(l.ok()) << l.status();
    return l.ok() ? *l : std::nullopt;
  }

  TaskInfo task(int64_t job, TaskKind kind, int frame, int tile = -1) {
    auto all = store_->tasks(job);
    EXPECT_TRUE(all.ok()) << all.status();
    if (all.ok()) {
      for (const TaskInfo& t : *all) {
        if (t.ref.kind == kind && t.ref.frame == frame && t.ref.tile == tile) return t;
      }
    }
    ADD_FAILURE() << "no " << toString(kind) << " for frame " << frame << " tile " << tile;
    return {};
  }

  // Leases and completes whatever is ready until nothing is; returns how many completed.
  int runReady(const std::string& worker, Seconds now) {
    int done = 0;
    while (auto l = lease(worker, now)) {
      EXPECT_TRUE(store_->complete(l->task, l->attempt, now).ok()) << l->ref.toString();
      ++done;
    }
    return done;
  }

  // Leases and completes the tasks of one frame (held, so first within the most urgent job)
  // until its assemble is done.
  void finishFrame(int64_t job, int frame, Seconds now) {
    const std::vector<HeldFrame> held = {{job, frame}};
    for (int spins = 0; spins < 1000; ++spins) {
      if (task(job, TaskKind::kAssemble, frame).state == TaskState::kDone) return;
      auto l = store_->lease("finisher", now, kLease, held);
      ASSERT_TRUE(l.ok()) << l.status();
      ASSERT_TRUE(l->has_value()) << "job " << job << " frame " << frame << ": nothing ready";
      ASSERT_EQ((*l)->ref.job, job) << (*l)->ref.toString();
      ASSERT_EQ((*l)->ref.frame, frame) << (*l)->ref.toString();
      ASSERT_TRUE(store_->complete((*l)->task, (*l)->attempt, now).ok()) << (*l)->ref.toString();
    }
    FAIL() << "job " << job << " frame " << frame << " never assembled";
  }

  // After a migration: a job with an audit submits, and its audit leases once its frame is
  // assembled (times from 9 on).
  void expectAnAuditedJobRuns() {
    JobSpec audited = makeSpec({1}, 1, false, 9);
    audited.audits = {makeAudit(1, {0})};
    const int64_t withAudit = submit(audited, 10);
    finishFrame(withAudit, 1, 11);
    auto a = leaseAudit("w2", 12);
    ASSERT_TRUE(a.has_value());
    EXPECT_EQ(a->job, withAudit);
  }
  std::optional<AuditLease> leaseAudit(const std::string& worker, Seconds now) {
    auto l = store_->leaseAudit(worker, now, kLease);
    EXPECT_TRUE(l.ok()) << l.status();
    return l.ok() ? *l : std::nullopt;
  }

  std::vector<AuditInfo> audits(int64_t job) {
    auto all = store_->audits(job);
    EXPECT_TRUE(all.ok()) << all.status();
    return all.ok() ? *all : std::vector<AuditInfo>{};
  }

  AuditInfo audit(int64_t job, int frame) {
    for (const AuditInfo& a : audits(job)) {
      if (a.spec.frame == frame) return a;
    }
    ADD_FAILURE() << "job " << job << ": no audit of frame " << frame;
    return {};
  }

  fs::path dir_;
  std::string spec_;  // the SQLite file or the PostgreSQL URI
  testing::PostgresCluster* cluster_ = nullptr;
  std::string database_;  // PostgreSQL's
  std::unique_ptr<JobStore> store_;
};

class JobStoreTest : public JobStoreFixture, public ::testing::WithParamInterface<Backend> {
 protected:
  Backend backend() const override { return GetParam(); }
};

INSTANTIATE_TEST_SUITE_P(Stores, JobStoreTest,
                         ::testing::Values(Backend::kSqlite, Backend::kPostgres),
                         [](const ::testing::TestParamInfo<Backend>& info) {
                           return info.param == Backend::kSqlite ? "Sqlite" : "Postgres";
                         });

class SqliteJobStoreTest : public JobStoreFixture {
 protected:
  Backend backend() const override { return Backend::kSqlite; }
};

class PostgresJobStoreTest : public JobStoreFixture {
 protected:
  Backend backend() const override { return Backend::kPostgres; }
};

TEST_P(JobStoreTest, SubmitBuildsTheTaskGraph) {
  JobSpec spec = makeSpec({10, 11}, 3, /*bake=*/true);
  spec.shotText = std::string("bytes\0with a NUL\n", 17);
  const int64_t baked = submit(spec, 100);
  const JobInfo info = job(baked);
  EXPECT_EQ(info.state, JobState::kActive);
  EXPECT_EQ(info.submitted, 100);
  EXPECT_EQ(count(info, TaskState::kReady), 2);    // the bakes
  EXPECT_EQ(count(info, TaskState::kBlocked), 8);  // 2 x (3 tiles + assemble)
  EXPECT_EQ(info.spec.shotText, spec.shotText);
  EXPECT_EQ(info.spec.frames, spec.frames);
  EXPECT_EQ(info.spec.tileCount, 3);
  EXPECT_TRUE(info.spec.needsBake);
  EXPECT_EQ(info.spec.overrides, spec.overrides);
  EXPECT_EQ(info.spec.outputPattern, spec.outputPattern);
  EXPECT_TRUE(info.dead.empty());

  auto tasks = store_->tasks(baked);
  ASSERT_TRUE(tasks.ok()) << tasks.status();
  ASSERT_EQ(tasks->size(), 10u);
  EXPECT_EQ((*tasks)[0].ref.toString(), fmt::format("job {} frame 10 bake", baked));
  EXPECT_EQ((*tasks)[1].ref.toString(), fmt::format("job {} frame 10 tile 0", baked));
  EXPECT_EQ((*tasks)[4].ref.toString(), fmt::format("job {} frame 10 assemble", baked));

  const int64_t plain = submit(makeSpec({5}, 4, /*bake=*/false), 101);
  const JobInfo plainInfo = job(plain);
  EXPECT_EQ(count(plainInfo, TaskState::kReady), 4);
  EXPECT_EQ(count(plainInfo, TaskState::kBlocked), 1);

  auto all = store_->jobs();
  ASSERT_TRUE(all.ok()) << all.status();
  ASSERT_EQ(all->size(), 2u);
  EXPECT_EQ((*all)[0].id, plain);  // newest first
  EXPECT_EQ((*all)[1].id, baked);
  EXPECT_EQ(count((*all)[1], TaskState::kReady), 2);
}

TEST_P(JobStoreTest, SubmitRejectsMalformedJobsAndUnknownIdsAreNotFound) {
  EXPECT_EQ(store_->submit(makeSpec({1}, 0, false), 0).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->submit(makeSpec({}, 2, false), 0).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->submit(makeSpec({1, 2, 1}, 2, false), 0).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->job(42).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->tasks(42).status().code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->cancel(42).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->retry(42, std::nullopt, std::nullopt, 0).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->complete(42, 1, 0).status().code(), absl::StatusCode::kNotFound);
  auto jobs = store_->jobs();
  ASSERT_TRUE(jobs.ok()) << jobs.status();
  EXPECT_TRUE(jobs->empty());
}

TEST_P(JobStoreTest, LeasesByPriorityThenJobAgeThenFrame) {
  const int64_t older = submit(makeSpec({2, 1}, 1, false, /*priority=*/0), 1);
  const int64_t urgent = submit(makeSpec({3}, 2, false, /*priority=*/5), 2);
  const int64_t newer = submit(makeSpec({0}, 1, false, /*priority=*/0), 3);
  const std::vector<std::string> expected = {
      fmt::format("job {} frame 3 tile 0", urgent), fmt::format("job {} frame 3 tile 1", urgent),
      fmt::format("job {} frame 1 tile 0", older),  fmt::format("job {} frame 2 tile 0", older),
      fmt::format("job {} frame 0 tile 0", newer),
  };
  for (const std::string& ref : expected) {
    auto l = lease("w1", 10);
    ASSERT_TRUE(l.has_value()) << "expected " << ref;
    EXPECT_EQ(l->ref.toString(), ref);
    EXPECT_EQ(l->attempt, 1);
    EXPECT_EQ(l->expires, 10 + kLease);
  }
  // Only the assembles are left, and they wait on the leased tiles.
  EXPECT_FALSE(lease("w1", 10).has_value());
  const TaskInfo leased = task(urgent, TaskKind::kTile, 3, 0);
  EXPECT_EQ(leased.state, TaskState::kLeased);
  EXPECT_EQ(leased.worker, "w1");
  EXPECT_EQ(leased.attempt, 1);
}

TEST_P(JobStoreTest, BakeUnblocksTilesWhichUnblockTheAssembleAndTheJobIsDone) {
  const int64_t id = submit(makeSpec({7}, 2, true));
  auto bake = lease("w1", 0);
  ASSERT_TRUE(bake.has_value());
  EXPECT_EQ(bake->ref.kind, TaskKind::kBake);
  EXPECT_FALSE(lease("w2", 0).has_value()) << "tiles must wait on the bake";
  const auto completed = store_->complete(bake->task, bake->attempt, 1);
  ASSERT_TRUE(completed.ok());
  EXPECT_EQ(completed->toString(), bake->ref.toString());  // the task it completed
  EXPECT_EQ(count(job(id), TaskState::kReady), 2);

  auto tile0 = lease("w1", 1);
  auto tile1 = lease("w2", 1);
  ASSERT_TRUE(tile0.has_value() && tile1.has_value());
  EXPECT_EQ(tile0->ref.kind, TaskKind::kTile);
  EXPECT_EQ(tile1->ref.kind, TaskKind::kTile);
  ASSERT_TRUE(store_->complete(tile0->task, tile0->attempt, 2).ok());
  EXPECT_FALSE(lease("w1", 2).has_value()) << "the assemble waits on every tile";
  EXPECT_EQ(task(id, TaskKind::kAssemble, 7).state, TaskState::kBlocked);
  ASSERT_TRUE(store_->complete(tile1->task, tile1->attempt, 2).ok());

  auto assemble = lease("w1", 3);
  ASSERT_TRUE(assemble.has_value());
  EXPECT_EQ(assemble->ref.toString(), fmt::format("job {} frame 7 assemble", id));
  EXPECT_EQ(job(id).state, JobState::kActive);
  ASSERT_TRUE(store_->complete(assemble->task, assemble->attempt, 4).ok());
  const JobInfo done = job(id);
  EXPECT_EQ(done.state, JobState::kDone);
  EXPECT_EQ(count(done, TaskState::kDone), 4);
  EXPECT_EQ(task(id, TaskKind::kAssemble, 7).progress, 1.0);
}

TEST_P(JobStoreTest, StaleAttemptsAreRejectedAndChangeNothing) {
  RetryPolicy policy;
  policy.backoffBase = 0;
  open(policy);
  const int64_t id = submit(makeSpec({1}, 1, false));
  auto first = lease("w1", 0);
  ASSERT_TRUE(first.has_value());
  ASSERT_EQ(store_->expireLeases(first->expires).value_or(-1), 1);
  auto second = lease("w2", first->expires);
  ASSERT_TRUE(second.has_value());
  ASSERT_EQ(second->task, first->task);
  ASSERT_EQ(second->attempt, 2);
  ASSERT_TRUE(store_->heartbeat(second->task, 2, 0.25, 31, kLease).ok());
  const TaskInfo before = task(id, TaskKind::kTile, 1, 0);

  const absl::Status completed = store_->complete(first->task, first->attempt, 32).status();
  EXPECT_EQ(completed.code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(completed.message().find(fmt::format("job {} frame 1 tile 0", id)), std::string::npos)
      << completed;
  EXPECT_NE(completed.message().find("attempt 1"), std::string::npos) << completed;
  EXPECT_NE(completed.message().find("attempt 2"), std::string::npos) << completed;
  EXPECT_EQ(store_->heartbeat(first->task, 1, 0.9, 32, kLease).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store_->fail(first->task, 1, "late", 32).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store_->complete(first->task, 3, 32).status().code(),
            absl::StatusCode::kFailedPrecondition);

  const TaskInfo after = task(id, TaskKind::kTile, 1, 0);
  EXPECT_EQ(after.state, TaskState::kLeased);
  EXPECT_EQ(after.attempt, before.attempt);
  EXPECT_EQ(after.failures, before.failures);
  EXPECT_EQ(after.worker, "w2");
  EXPECT_EQ(after.progress, 0.25);
  EXPECT_EQ(after.lastError, before.lastError);
  auto blocklisted = store_->blocklisted(id, "w1");
  ASSERT_TRUE(blocklisted.ok());
  EXPECT_FALSE(*blocklisted);

  ASSERT_TRUE(store_->complete(second->task, 2, 33).ok());
  EXPECT_EQ(store_->complete(second->task, 2, 34).status().code(),
            absl::StatusCode::kFailedPrecondition)
      << "a done task takes no second completion";
}

// Locality: a worker gets the tasks of the frames it holds first, most recent first, but only
// within the job it would be leased from anyway (no job waits on another's frames).
TEST_P(JobStoreTest, AWorkerGetsTheTasksOfFramesItHoldsWithinTheMostUrgentJob) {
  const int64_t a = submit(makeSpec({1, 2, 3}, 2, false), 0);
  auto leaseHolding = [&](const std::string& worker, std::vector<HeldFrame> held) {
    auto l = store_->lease(worker, 1, kLease, held);
    EXPECT_TRUE(l.ok() && l->has_value()) << l.status();
    return l.ok() && l->has_value() ? **l : Lease{};
  };
  // Nothing held: plain order.
  EXPECT_EQ(leaseHolding("w1", {}).ref.frame, 1);
  // Frames of another job are no reason; frame 3 then frame 2, most recent first.
  const Lease third = leaseHolding("w2", {{a + 7, 1}, {a, 3}, {a, 2}});
  EXPECT_EQ(third.ref.frame, 3);
  EXPECT_EQ(third.ref.tile, 0);
  EXPECT_EQ(leaseHolding("w2", {{a, 3}, {a, 2}}).ref.frame, 3);
  EXPECT_EQ(leaseHolding("w2", {{a, 3}, {a, 2}}).ref.frame, 2);  // frame 3's tiles are out
  // A more urgent job comes first whatever a worker holds.
  const int64_t b = submit(makeSpec({9}, 1, false, /*priority=*/5), 1);
  const Lease urgent = leaseHolding("w2", {{a, 2}});
  EXPECT_EQ(urgent.ref.job, b);
  EXPECT_EQ(urgent.ref.frame, 9);
  // Back to the held frame once the urgent job has nothing ready.
  EXPECT_EQ(leaseHolding("w2", {{a, 2}}).ref.frame, 2);
}

TEST_P(JobStoreTest, ATaskDeadAtTheCapTakesItsDependentsAndFailsTheJob) {
  RetryPolicy policy;
  policy.maxAttempts = 2;
  policy.backoffBase = 1;
  open(policy);
  const int64_t id = submit(makeSpec({1, 2}, 2, true));
  auto bake1 = lease("w1", 0);
  auto bake2 = lease("w2", 0);
  ASSERT_TRUE(bake1.has_value() && bake2.has_value());
  ASSERT_EQ(bake1->ref.frame, 1);
  ASSERT_TRUE(store_->fail(bake1->task, bake1->attempt, "out of memory", 0).ok());
  auto again = lease("w3", 1);
  ASSERT_TRUE(again.has_value());
  ASSERT_EQ(again->task, bake1->task);
  ASSERT_TRUE(store_->fail(again->task, again->attempt, "out of memory", 1).ok());

  const TaskInfo bake = task(id, TaskKind::kBake, 1);
  EXPECT_EQ(bake.state, TaskState::kDead);
  EXPECT_EQ(bake.failures, 2);
  EXPECT_EQ(bake.lastError, "out of memory");
  const std::string waits = fmt::format("waits on job {} frame 1 bake: out of memory", id);
  EXPECT_EQ(task(id, TaskKind::kTile, 1, 0).lastError, waits);
  EXPECT_EQ(task(id, TaskKind::kAssemble, 1).state, TaskState::kDead);
  EXPECT_EQ(job(id).state, JobState::kActive) << "frame 2 is still baking";

  ASSERT_TRUE(store_->complete(bake2->task, bake2->attempt, 2).ok());
  EXPECT_EQ(runReady("w1", 2), 3);  // frame 2's tiles, then its assemble
  const JobInfo failed = job(id);
  EXPECT_EQ(failed.state, JobState::kFailed);
  EXPECT_EQ(count(failed, TaskState::kDone), 4);
  EXPECT_EQ(count(failed, TaskState::kDead), 4);
  ASSERT_EQ(failed.dead.size(), 4u);
  EXPECT_EQ(failed.dead[0].ref.kind, TaskKind::kBake);
  EXPECT_EQ(failed.dead[0].lastError, "out of memory");
  EXPECT_EQ(failed.dead[3].ref.kind, TaskKind::kAssemble);
  EXPECT_EQ(failed.dead[3].lastError, waits);
}

TEST_P(JobStoreTest, AFailedTaskWaitsOutItsDoublingBackoff) {
  RetryPolicy policy;
  policy.maxAttempts = 10;
  policy.backoffBase = 2;
  policy.backoffMax = 5;
  policy.blocklistAfter = 100;  // one worker fails every attempt here
  open(policy);
  const int64_t id = submit(makeSpec({1}, 1, false));
  Seconds now = 0;
  for (Seconds wait : {2.0, 4.0, 5.0}) {
    auto l = lease("w1", now);
    ASSERT_TRUE(l.has_value()) << "at " << now;
    ASSERT_TRUE(store_->fail(l->task, l->attempt, "crashed", now).ok());
    EXPECT_FALSE(lease("w1", now + wait - 0.01).has_value()) << "back-off of " << wait << " s";
    now += wait;
  }
  auto l = lease("w1", now);
  ASSERT_TRUE(l.has_value());
  EXPECT_EQ(l->attempt, 4);
  const TaskInfo info = task(id, TaskKind::kTile, 1, 0);
  EXPECT_EQ(info.failures, 3);
  EXPECT_EQ(info.lastError, "crashed");
}

TEST_P(JobStoreTest, ExpiredLeasesCountAsFailures) {
  const int64_t id = submit(makeSpec({1}, 1, false));
  auto l = lease("w1", 0);
  ASSERT_TRUE(l.has_value());
  ASSERT_TRUE(store_->heartbeat(l->task, l->attempt, 0.5, 20, kLease).ok());
  auto none = store_->expireLeases(l->expires);
  ASSERT_TRUE(none.ok()) << none.status();
  EXPECT_EQ(*none, 0) << "the heartbeat extended the lease to 50 s";
  std::vector<ExpiredLease> listed;
  auto expired = store_->expireLeases(50, &listed);
  ASSERT_TRUE(expired.ok()) << expired.status();
  EXPECT_EQ(*expired, 1);
  // What the coordinator logs of it: the task, its attempt, the worker, the lease's end.
  ASSERT_EQ(listed.size(), 1u);
  EXPECT_EQ(listed[0].id, l->task);
  EXPECT_FALSE(listed[0].audit);
  EXPECT_EQ(listed[0].what, fmt::format("job {} frame 1 tile 0", id));
  EXPECT_EQ(listed[0].attempt, l->attempt);
  EXPECT_EQ(listed[0].worker, "w1");
  EXPECT_DOUBLE_EQ(listed[0].expires, 20 + kLease);

  const TaskInfo info = task(id, TaskKind::kTile, 1, 0);
  EXPECT_EQ(info.state, TaskState::kReady);
  EXPECT_EQ(info.failures, 1);
  EXPECT_EQ(info.lastError, "lease expired: worker w1 stopped heartbeating");
  EXPECT_EQ(store_->complete(l->task, l->attempt, 51).status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store_->expireLeases(1000).value_or(-1), 0);
}

TEST_P(JobStoreTest, AWorkerThatKeepsFailingAJobIsBlocklistedForThatJobOnlyUntilARetry) {
  RetryPolicy policy;
  policy.maxAttempts = 10;
  policy.backoffBase = 0;
  policy.blocklistAfter = 2;
  open(policy);
  const int64_t id = submit(makeSpec({1}, 3, false));
  for (int i = 0; i < 2; ++i) {
    auto l = lease("w1", 0);
    ASSERT_TRUE(l.has_value());
    ASSERT_TRUE(store_->fail(l->task, l->attempt, "segfault", 0).ok());
  }
  auto w1 = store_->blocklisted(id, "w1");
  ASSERT_TRUE(w1.ok()) << w1.status();
  EXPECT_TRUE(*w1);
  EXPECT_FALSE(lease("w1", 0).has_value());
  auto w2 = lease("w2", 0);
  ASSERT_TRUE(w2.has_value());
  EXPECT_EQ(w2->ref.tile, 0);
  EXPECT_EQ(w2->attempt, 3);
  EXPECT_FALSE(store_->blocklisted(id, "w2").value_or(true));

  const int64_t other = submit(makeSpec({1}, 1, false));
  auto w1Other = lease("w1", 0);
  ASSERT_TRUE(w1Other.has_value()) << "the blocklist is per job";
  EXPECT_EQ(w1Other->ref.job, other);

  auto listed = store_->blocklistedWorkers(id);
  ASSERT_TRUE(listed.ok()) << listed.status();
  EXPECT_EQ(*listed, std::vector<std::string>{"w1"});
  EXPECT_TRUE(store_->blocklistedWorkers(other).value_or(std::vector<std::string>{"x"}).empty());
  // A retry lifts the job's blocklist: w1 may take its tasks again.
  ASSERT_TRUE(store_->retry(id, std::nullopt, std::nullopt, 0).ok());
  EXPECT_TRUE(store_->blocklistedWorkers(id).value_or(std::vector<std::string>{"x"}).empty());
  EXPECT_FALSE(store_->blocklisted(id, "w1").value_or(true));
}

TEST_P(JobStoreTest, ABlocklistThresholdOfZeroNeverBlocklists) {
  RetryPolicy policy;
  policy.maxAttempts = 10;
  policy.backoffBase = 0;
  policy.blocklistAfter = 0;
  open(policy);
  const int64_t id = submit(makeSpec({1}, 1, false));
  for (int attempt = 1; attempt <= 4; ++attempt) {
    auto l = lease("w1", 0);
    ASSERT_TRUE(l.has_value()) << "attempt " << attempt;
    EXPECT_EQ(l->attempt, attempt);
    ASSERT_TRUE(store_->fail(l->task, l->attempt, "segfault", 0).ok());
  }
  EXPECT_FALSE(store_->blocklisted(id, "w1").value_or(true));
}

TEST_P(JobStoreTest, CancelStopsEverythingAndRetryRevivesByFrame) {
  const int64_t id = submit(makeSpec({1, 2}, 2, true));
  auto bake = lease("w1", 0);
  ASSERT_TRUE(bake.has_value());
  ASSERT_TRUE(store_->cancel(id).ok());
  JobInfo info = job(id);
  EXPECT_EQ(info.state, JobState::kCancelled);
  EXPECT_EQ(count(info, TaskState::kCancelled), 8);
  EXPECT_EQ(store_->complete(bake->task, bake->attempt, 1).status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_FALSE(lease("w1", 1).has_value());

  ASSERT_TRUE(store_->retry(id, 1, std::nullopt, 2).ok());
  info = job(id);
  EXPECT_EQ(info.state, JobState::kActive);
  EXPECT_EQ(count(info, TaskState::kReady), 1);    // frame 1's bake
  EXPECT_EQ(count(info, TaskState::kBlocked), 3);  // its tiles and assemble
  EXPECT_EQ(count(info, TaskState::kCancelled), 4);
  auto rebake = lease("w1", 2);
  ASSERT_TRUE(rebake.has_value());
  EXPECT_EQ(rebake->task, bake->task);
  EXPECT_EQ(rebake->attempt, 2) << "attempts keep counting across a retry";
  ASSERT_TRUE(store_->complete(rebake->task, rebake->attempt, 3).ok());
  EXPECT_EQ(runReady("w1", 3), 3);
  EXPECT_EQ(job(id).state, JobState::kCancelled) << "frame 2 is still cancelled";

  ASSERT_TRUE(store_->retry(id, std::nullopt, std::nullopt, 4).ok());
  EXPECT_EQ(job(id).state, JobState::kActive);
  EXPECT_EQ(runReady("w1", 4), 4);
  EXPECT_EQ(job(id).state, JobState::kDone);
  EXPECT_EQ(store_->cancel(id).code(), absl::StatusCode::kFailedPrecondition);
}

TEST_P(JobStoreTest, RetryingADeadTileRevivesTheAssembleThatWaitedOnIt) {
  RetryPolicy policy;
  policy.maxAttempts = 1;
  open(policy);
  const int64_t id = submit(makeSpec({1}, 2, false));
  auto tile0 = lease("w1", 0);
  ASSERT_TRUE(tile0.has_value());
  ASSERT_TRUE(store_->fail(tile0->task, tile0->attempt, "boom", 0).ok());
  EXPECT_EQ(task(id, TaskKind::kAssemble, 1).lastError,
            fmt::format("waits on job {} frame 1 tile 0: boom", id));
  EXPECT_EQ(job(id).state, JobState::kActive);
  EXPECT_EQ(runReady("w1", 1), 1);
  JobInfo info = job(id);
  EXPECT_EQ(info.state, JobState::kFailed);
  ASSERT_EQ(info.dead.size(), 2u);
  EXPECT_EQ(info.dead[0].ref.tile, 0);
  EXPECT_EQ(info.dead[0].lastError, "boom");

  EXPECT_EQ(store_->retry(id, std::nullopt, 0, 2).code(), absl::StatusCode::kInvalidArgument);
  ASSERT_TRUE(store_->retry(id, 1, 0, 2).ok());
  info = job(id);
  EXPECT_EQ(info.state, JobState::kActive);
  EXPECT_TRUE(info.dead.empty());
  const TaskInfo revived = task(id, TaskKind::kTile, 1, 0);
  EXPECT_EQ(revived.state, TaskState::kReady);
  EXPECT_EQ(revived.failures, 0);
  EXPECT_EQ(task(id, TaskKind::kAssemble, 1).state, TaskState::kBlocked);
  EXPECT_EQ(runReady("w1", 3), 2);  // the tile, then the assemble
  EXPECT_EQ(job(id).state, JobState::kDone);
}

// What one store object committed, a second one on the same database sees at once, and so
// does a store opened after the first is gone.
TEST_P(JobStoreTest, AReopenedStoreKeepsJobsWorkersAndLeases) {
  const JobSpec spec = makeSpec({4}, 2, true, 3);
  const int64_t id = submit(spec, 5);
  WorkerInfo worker{"w1", "render-01", 64, 256ull << 30, 100ull << 30, 5};
  ASSERT_TRUE(store_->registerWorker(worker).ok());
  worker.cores = 32;
  ASSERT_TRUE(store_->registerWorker(worker).ok()) << "registering again updates";
  auto bake = lease("w1", 6);
  ASSERT_TRUE(bake.has_value());
  if (GetParam() == Backend::kSqlite) {
    EXPECT_TRUE(fs::exists(spec_ + "-wal")) << "the store journals in WAL mode";
  }
  std::unique_ptr<JobStore> other = openAnother();
  ASSERT_NE(other, nullptr);
  auto seen = other->job(id);
  ASSERT_TRUE(seen.ok()) << seen.status();
  EXPECT_EQ(count(*seen, TaskState::kLeased), 1);
  other.reset();

  open();
  const JobInfo info = job(id);
  EXPECT_EQ(info.spec.name, spec.name);
  EXPECT_EQ(info.spec.shotText, spec.shotText);
  EXPECT_EQ(info.spec.priority, 3);
  EXPECT_EQ(info.submitted, 5);
  EXPECT_EQ(count(info, TaskState::kLeased), 1);
  EXPECT_EQ(count(info, TaskState::kBlocked), 3);
  auto workers = store_->workers();
  ASSERT_TRUE(workers.ok()) << workers.status();
  ASSERT_EQ(workers->size(), 1u);
  EXPECT_EQ((*workers)[0].host, "render-01");
  EXPECT_EQ((*workers)[0].cores, 32);
  EXPECT_EQ((*workers)[0].memoryBytes, 256ull << 30);
  EXPECT_EQ((*workers)[0].lastSeen, 6) << "a lease counts as a sign of life";

  ASSERT_TRUE(store_->heartbeat(bake->task, bake->attempt, 0.5, 7, kLease).ok());
  ASSERT_TRUE(store_->complete(bake->task, bake->attempt, 8).ok());
  EXPECT_EQ(count(job(id), TaskState::kReady), 2);
}

TEST_F(SqliteJobStoreTest, OpenRefusesWhatIsNotAJobStore) {
  store_.reset();
  const fs::path garbage = dir_ / "garbage.db";
  std::ofstream(garbage) << std::string(4096, 'x');
  auto store = openJobStore(garbage.string(), {});
  ASSERT_FALSE(store.ok());
  EXPECT_NE(store.status().message().find(garbage.string()), std::string::npos) << store.status();

  auto missing = openJobStore((dir_ / "no/such/dir/farm.db").string(), {});
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kUnavailable) << missing.status();
}

TEST_P(JobStoreTest, OpenRejectsARetryPolicyWithoutAttempts) {
  RetryPolicy policy;
  policy.maxAttempts = 0;
  EXPECT_EQ(openJobStore(spec_, policy).status().code(), absl::StatusCode::kInvalidArgument);
}

// Two stores on one database stand for two coordinators (by mistake, for SQLite), two threads
// each for the server's handlers: every task is leased and completed exactly once.
TEST_P(JobStoreTest, ConcurrentLeasesNeverHandOutATaskTwice) {
  const int64_t id = submit(makeSpec({1, 2, 3}, 12, false));
  std::unique_ptr<JobStore> second = openAnother();
  ASSERT_NE(second, nullptr);
  std::vector<JobStore*> stores = {store_.get(), second.get()};

  std::mutex mutex;
  std::multiset<int64_t> completed;
  std::vector<std::string> errors;
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      JobStore& store = *stores[t % 2];
      const std::string worker = fmt::format("w{}", t);
      for (int spins = 0; spins < 100000; ++spins) {
        auto l = store.lease(worker, 0, kLease);
        if (!l.ok()) {
          std::lock_guard lock(mutex);
          errors.push_back(std::string(l.status().message()));
          return;
        }
        if (!*l) {
          auto info = store.job(id);
          if (!info.ok() || info->state != JobState::kActive) return;
          std::this_thread::yield();  // the assembles wait on tiles another thread holds
          continue;
        }
        const absl::Status s = store.complete((*l)->task, (*l)->attempt, 0).status();
        std::lock_guard lock(mutex);
        if (!s.ok()) errors.push_back(std::string(s.message()));
        completed.insert((*l)->task);
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_TRUE(errors.empty()) << errors.front();
  EXPECT_EQ(completed.size(), 39u);
  EXPECT_EQ(std::set<int64_t>(completed.begin(), completed.end()).size(), 39u);
  EXPECT_EQ(job(id).state, JobState::kDone);
}

// Many callers at once on one store object (the SQLite store commits their writes in groups,
// each call in a savepoint): a stale completion that fails between good calls of the same
// group undoes only itself, and every good call is durable when it returns (a second store
// object sees it).
TEST_P(JobStoreTest, CallsCommittedTogetherStillSucceedOrFailAlone) {
  const int64_t id = submit(makeSpec({1, 2}, 40, false));
  std::mutex mutex;
  std::multiset<int64_t> completed;
  std::vector<std::string> errors;
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t) {
    threads.emplace_back([&, t] {
      const std::string worker = fmt::format("w{}", t);
      for (int spins = 0; spins < 100000; ++spins) {
        auto l = store_->lease(worker, 0, kLease);
        if (!l.ok() || !*l) {
          auto info = store_->job(id);
          if (!l.ok() || !info.ok() || info->state != JobState::kActive) return;
          std::this_thread::yield();
          continue;
        }
        const absl::Status stale = store_->complete((*l)->task, (*l)->attempt + 1, 0).status();
        const absl::Status good = store_->complete((*l)->task, (*l)->attempt, 0).status();
        std::lock_guard lock(mutex);
        if (stale.code() != absl::StatusCode::kFailedPrecondition) {
          errors.push_back("stale completion: " + stale.ToString());
        }
        if (!good.ok()) errors.push_back(good.ToString());
        completed.insert((*l)->task);
      }
    });
  }
  for (std::thread& t : threads) t.join();
  ASSERT_TRUE(errors.empty()) << errors.front();
  EXPECT_EQ(completed.size(), 82u);
  EXPECT_EQ(std::set<int64_t>(completed.begin(), completed.end()).size(), 82u);
  std::unique_ptr<JobStore> second = openAnother();
  ASSERT_NE(second, nullptr);
  auto seen = second->job(id);
  ASSERT_TRUE(seen.ok()) << seen.status();
  EXPECT_EQ(seen->state, JobState::kDone);
  EXPECT_EQ(count(*seen, TaskState::kDone), 82);
}

// The log keeps what workers printed byte for byte (a NUL, bytes that are not UTF-8), in order,
// and filters by frame and tile.
TEST_P(JobStoreTest, TheEventLogKeepsEveryLeaseAndOutcomeInOrder) {
  RetryPolicy policy;
  policy.backoffBase = 0;
  open(policy);
  const int64_t id = submit(makeSpec({1, 2}, 1, false));
  const std::string log("stderr: \0\xff\xfe done", 16);
  auto first = lease("w1", 0);
  ASSERT_TRUE(first.has_value());
  ASSERT_TRUE(store_->fail(first->task, first->attempt, "crashed", 1, log).ok());
  auto second = lease("w2", 2);
  ASSERT_TRUE(second.has_value());
  ASSERT_EQ(second->task, first->task);
  ASSERT_EQ(store_->expireLeases(2 + kLease).value_or(-1), 1);
  auto third = lease("w3", 40);
  ASSERT_TRUE(third.has_value());
  ASSERT_EQ(third->task, first->task);
  ASSERT_TRUE(store_->complete(third->task, third->attempt, 41, log).ok());
  auto assemble = lease("w1", 42);
  ASSERT_TRUE(assemble.has_value());
  EXPECT_EQ(assemble->ref.kind, TaskKind::kAssemble);
  auto other = lease("w1", 43);
  ASSERT_TRUE(other.has_value());
  EXPECT_EQ(other->ref.frame, 2);

  auto frame1 = store_->events(id, 1, 0);
  ASSERT_TRUE(frame1.ok()) << frame1.status();
  std::vector<std::string> seen;
  for (const TaskEvent& e : *frame1) {
    seen.push_back(fmt::format("{} {} {} {}", e.event, e.worker, e.attempt, e.time));
    EXPECT_EQ(e.ref.toString(), fmt::format("job {} frame 1 tile 0", id));
  }
  EXPECT_EQ(seen, (std::vector<std::string>{"leased w1 1 0", "failed w1 1 1", "leased w2 2 2",
                                            "expired w2 2 32", "leased w3 3 40", "done w3 3 41"}));
  ASSERT_EQ(frame1->size(), 6u);
  EXPECT_EQ((*frame1)[1].text, "crashed\n" + log);
  EXPECT_EQ((*frame1)[3].text, "lease expired: worker w2 stopped heartbeating");
  EXPECT_EQ((*frame1)[5].text, log);
  auto wholeFrame1 = store_->events(id, 1, std::nullopt);
  ASSERT_TRUE(wholeFrame1.ok()) << wholeFrame1.status();
  EXPECT_EQ(wholeFrame1->size(), 7u) << "the tile's six and the assemble's lease";
  auto all = store_->events(id, std::nullopt, std::nullopt);
  ASSERT_TRUE(all.ok()) << all.status();
  EXPECT_EQ(all->size(), 8u);
  EXPECT_EQ(all->back().ref.frame, 2);
  EXPECT_EQ(store_->events(id + 1, std::nullopt, std::nullopt).status().code(),
            absl::StatusCode::kNotFound);
}

// Audits: per-frame accuracy checks that a worker with nothing else to do takes. They wait on
// their frame's assemble, come only from leaseAudit(), and nothing they do moves a task or a job.
TEST_P(JobStoreTest, AnAuditIsLeasedOnlyOnceItsFrameIsAssembledAndOnlyWhenAskedFor) {
  JobSpec spec = makeSpec({1, 2}, 2, false);
  spec.audits = {makeAudit(2, {1}, 32, 0.1), makeAudit(1, {0, 1}, 64, 0.05)};
  const int64_t id = submit(spec, 0);
  const std::vector<AuditInfo> submitted = audits(id);
  ASSERT_EQ(submitted.size(), 2u);
  EXPECT_EQ(submitted[0].spec.frame, 1) << "by frame";
  EXPECT_EQ(submitted[0].spec.tiles, (std::vector<int>{0, 1}));
  EXPECT_EQ(submitted[0].spec.spp, 64);
  EXPECT_EQ(submitted[0].spec.threshold, 0.05);
  EXPECT_EQ(submitted[1].spec.frame, 2);
  EXPECT_EQ(submitted[1].spec.tiles, std::vector<int>{1});
  for (const AuditInfo& a : submitted) {
    EXPECT_EQ(a.job, id);
    EXPECT_EQ(a.state, AuditState::kReady);
    EXPECT_EQ(a.attempt, 0);
    EXPECT_FALSE(a.result.has_value());
    EXPECT_FALSE(a.flagged());
  }
  EXPECT_EQ(count(job(id), TaskState::kReady), 4) << "audits are not tasks";
  EXPECT_EQ(store_->audits(id + 1).status().code(), absl::StatusCode::kNotFound);

  EXPECT_FALSE(leaseAudit("w1", 0).has_value()) << "nothing is assembled";
  auto tile0 = lease("w1", 0);
  auto tile1 = lease("w1", 0);
  ASSERT_TRUE(tile0.has_value() && tile1.has_value());
  ASSERT_EQ(tile1->ref.toString(), fmt::format("job {} frame 1 tile 1", id));
  ASSERT_TRUE(store_->complete(tile0->task, tile0->attempt, 1).ok());
  ASSERT_TRUE(store_->complete(tile1->task, tile1->attempt, 1).ok());
  EXPECT_FALSE(leaseAudit("w1", 1).has_value()) << "frame 1's assemble is ready, not done";
  auto assemble = lease("w1", 1);
  ASSERT_TRUE(assemble.has_value());
  ASSERT_EQ(assemble->ref.kind, TaskKind::kAssemble);
  EXPECT_FALSE(leaseAudit("w1", 1).has_value()) << "frame 1's assemble is leased, not done";
  ASSERT_TRUE(store_->complete(assemble->task, assemble->attempt, 2).ok());

  auto first = leaseAudit("w1", 3);
  ASSERT_TRUE(first.has_value());
  EXPECT_EQ(first->audit, submitted[0].id);
  EXPECT_EQ(first->job, id);
  EXPECT_EQ(first->attempt, 1);
  EXPECT_EQ(first->spec.frame, 1);
  EXPECT_EQ(first->spec.tiles, (std::vector<int>{0, 1}));
  EXPECT_EQ(first->spec.spp, 64);
  EXPECT_EQ(first->expires, 3 + kLease);
  EXPECT_FALSE(leaseAudit("w2", 3).has_value()) << "frame 2 is not assembled";
  const AuditInfo leased = audit(id, 1);
  EXPECT_EQ(leased.state, AuditState::kLeased);
  EXPECT_EQ(leased.worker, "w1");
  EXPECT_EQ(leased.attempt, 1);

  // Frame 2's tasks, and then nothing: lease() never hands out the audit that is ready.
  EXPECT_EQ(runReady("w2", 4), 3);
  EXPECT_EQ(job(id).state, JobState::kDone) << "a job is done when its tasks are";
  EXPECT_EQ(audit(id, 2).state, AuditState::kReady);
  EXPECT_FALSE(lease("w2", 5).has_value());
  auto second = leaseAudit("w2", 5);
  ASSERT_TRUE(second.has_value());
  EXPECT_EQ(second->spec.frame, 2);
  EXPECT_EQ(job(id).state, JobState::kDone);
  EXPECT_EQ(store_->leaseAudit("", 5, kLease).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST_P(JobStoreTest, ACompletedAuditKeepsItsResultAndStaleAttemptsChangeNothing) {
  RetryPolicy policy;
  policy.backoffBase = 0;
  open(policy);
  JobSpec spec = makeSpec({1, 2}, 1, false);
  spec.audits = {makeAudit(1, {0}, 64, 0.05), makeAudit(2, {0}, 64, 0.5)};
  const int64_t id = submit(spec);
  EXPECT_EQ(runReady("w0", 0), 4);
  auto first = leaseAudit("w1", 1);
  ASSERT_TRUE(first.has_value());
  ASSERT_EQ(first->spec.frame, 1);
  ASSERT_EQ(store_->expireLeases(first->expires).value_or(-1), 1);
  auto second = leaseAudit("w2", first->expires);
  ASSERT_TRUE(second.has_value());
  ASSERT_EQ(second->audit, first->audit);
  ASSERT_EQ(second->attempt, 2);
  ASSERT_TRUE(store_->heartbeatAudit(second->audit, 2, 40, kLease).ok());
  const AuditInfo before = audit(id, 1);

  const absl::Status stale = store_->completeAudit(first->audit, 1, {0.9, 0.1, 3}, 41);
  EXPECT_EQ(stale.code(), absl::StatusCode::kFailedPrecondition) << stale;
  EXPECT_NE(stale.message().find(fmt::format("job {} frame 1 audit", id)), std::string::npos)
      << stale;
  EXPECT_NE(stale.message().find("attempt 1"), std::string::npos) << stale;
  EXPECT_NE(stale.message().find("attempt 2"), std::string::npos) << stale;
  EXPECT_EQ(store_->heartbeatAudit(first->audit, 1, 41, kLease).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store_->failAudit(first->audit, 1, "late", 41).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store_->completeAudit(first->audit, 3, {}, 41).code(),
            absl::StatusCode::kFailedPrecondition);
  const int64_t unknown = first->audit + 1000;
  EXPECT_EQ(store_->completeAudit(unknown, 1, {}, 41).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->heartbeatAudit(unknown, 1, 41, kLease).code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(store_->failAudit(unknown, 1, "?", 41).code(), absl::StatusCode::kNotFound);

  const AuditInfo after = audit(id, 1);
  EXPECT_EQ(after.state, AuditState::kLeased);
  EXPECT_EQ(after.attempt, before.attempt);
  EXPECT_EQ(after.failures, 1);
  EXPECT_EQ(after.worker, "w2");
  EXPECT_EQ(after.lastError, "lease expired: worker w1 stopped heartbeating");
  EXPECT_FALSE(after.result.has_value());
  EXPECT_EQ(store_->expireLeases(1 + 2 * kLease).value_or(-1), 0) << "the heartbeat extended it";

  ASSERT_TRUE(store_->completeAudit(second->audit, 2, {0.2, -0.0125, 12.5}, 42).ok());
  const AuditInfo done = audit(id, 1);
  EXPECT_EQ(done.state, AuditState::kDone);
  ASSERT_TRUE(done.result.has_value());
  EXPECT_EQ(done.result->relMse, 0.2);
  EXPECT_EQ(done.result->bias, -0.0125);
  EXPECT_EQ(done.result->seconds, 12.5);
  EXPECT_TRUE(done.flagged()) << "0.2 is over the threshold of 0.05";
  EXPECT_EQ(store_->completeAudit(second->audit, 2, {}, 43).code(),
            absl::StatusCode::kFailedPrecondition)
      << "a done audit takes no second completion";
  EXPECT_EQ(store_->failAudit(second->audit, 2, "late", 43).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store_->expireLeases(1e6).value_or(-1), 0);

  // Under its threshold; a result that is not a number (NaN pixels) comes back as one.
  auto other = leaseAudit("w3", 44);
  ASSERT_TRUE(other.has_value());
  ASSERT_EQ(other->spec.frame, 2);
  const double nan = std::numeric_limits<double>::quiet_NaN();
  ASSERT_TRUE(store_->completeAudit(other->audit, other->attempt, {0.25, nan, 1}, 45).ok());
  const AuditInfo under = audit(id, 2);
  ASSERT_TRUE(under.result.has_value());
  EXPECT_FALSE(under.flagged());
  EXPECT_TRUE(std::isnan(under.result->bias)) << under.result->bias;
  EXPECT_FALSE(leaseAudit("w3", 46).has_value());
  EXPECT_EQ(job(id).state, JobState::kDone);
}

TEST_P(JobStoreTest, AFailedAuditBacksOffAndFailsAtTheCapWithoutTouchingItsJob) {
  RetryPolicy policy;
  policy.maxAttempts = 3;
  policy.backoffBase = 2;
  policy.backoffMax = 3;
  policy.blocklistAfter = 1;  // were an audit's failure counted, w1 would be blocklisted
  open(policy);
  JobSpec spec = makeSpec({1, 2}, 1, false);
  spec.audits = {makeAudit(1, {0})};
  const int64_t id = submit(spec);
  finishFrame(id, 1, 0);
  Seconds now = 0;
  for (Seconds wait : {2.0, 3.0}) {
    auto l = leaseAudit("w1", now);
    ASSERT_TRUE(l.has_value()) << "at " << now;
    ASSERT_TRUE(store_->failAudit(l->audit, l->attempt, "out of memory", now).ok());
    const AuditInfo failed = audit(id, 1);
    EXPECT_EQ(failed.state, AuditState::kReady);
    EXPECT_EQ(failed.lastError, "out of memory");
    EXPECT_FALSE(leaseAudit("w1", now + wait - 0.01).has_value()) << "back-off of " << wait;
    now += wait;
  }
  auto last = leaseAudit("w1", now);
  ASSERT_TRUE(last.has_value());
  EXPECT_EQ(last->attempt, 3);
  ASSERT_TRUE(store_->failAudit(last->audit, last->attempt, "out of memory", now).ok());
  const AuditInfo failed = audit(id, 1);
  EXPECT_EQ(failed.state, AuditState::kFailed);
  EXPECT_EQ(failed.failures, 3);
  EXPECT_EQ(failed.attempt, 3);
  EXPECT_EQ(failed.lastError, "out of memory");
  EXPECT_FALSE(failed.result.has_value());
  EXPECT_FALSE(leaseAudit("w1", 1000).has_value());

  const JobInfo info = job(id);
  EXPECT_EQ(info.state, JobState::kActive);
  EXPECT_TRUE(info.dead.empty());
  EXPECT_EQ(count(info, TaskState::kDone), 2);
  EXPECT_FALSE(store_->blocklisted(id, "w1").value_or(true));
  auto events = store_->events(id, std::nullopt, std::nullopt);
  ASSERT_TRUE(events.ok()) << events.status();
  EXPECT_EQ(events->size(), 4u) << "the task log has no audits in it";
  auto tile = lease("w1", now);
  ASSERT_TRUE(tile.has_value());
  EXPECT_EQ(tile->ref.toString(), fmt::format("job {} frame 2 tile 0", id));
  EXPECT_EQ(tile->attempt, 1);
  ASSERT_TRUE(store_->complete(tile->task, tile->attempt, now).ok());
  EXPECT_EQ(runReady("w1", now), 1);
  EXPECT_EQ(job(id).state, JobState::kDone) << "a failed audit never fails its job";
}

TEST_P(JobStoreTest, ExpiredAuditLeasesAreReclaimedWithTheTasks) {
  JobSpec spec = makeSpec({1, 2}, 1, false);
  spec.audits = {makeAudit(1, {0})};
  const int64_t id = submit(spec);
  finishFrame(id, 1, 0);
  auto a = leaseAudit("w1", 0);
  auto t = lease("w2", 0);
  ASSERT_TRUE(a.has_value() && t.has_value());
  ASSERT_TRUE(store_->heartbeatAudit(a->audit, a->attempt, 20, kLease).ok());
  ASSERT_TRUE(store_->heartbeat(t->task, t->attempt, 0.5, 20, kLease).ok());
  EXPECT_EQ(store_->expireLeases(a->expires).value_or(-1), 0) << "both were extended to 50 s";
  std::vector<ExpiredLease> listed;
  EXPECT_EQ(store_->expireLeases(50, &listed).value_or(-1), 2)
      << "the audit's lease and the task's";
  ASSERT_EQ(listed.size(), 2u);
  EXPECT_FALSE(listed[0].audit);
  EXPECT_EQ(listed[0].worker, "w2");
  EXPECT_TRUE(listed[1].audit);
  EXPECT_EQ(listed[1].id, a->audit);
  EXPECT_EQ(listed[1].what, fmt::format("job {} frame 1 audit", id));
  EXPECT_EQ(listed[1].worker, "w1");
  EXPECT_DOUBLE_EQ(listed[1].expires, 20 + kLease);

  const AuditInfo expired = audit(id, 1);
  EXPECT_EQ(expired.state, AuditState::kReady);
  EXPECT_EQ(expired.failures, 1);
  EXPECT_EQ(expired.lastError, "lease expired: worker w1 stopped heartbeating");
  EXPECT_EQ(task(id, TaskKind::kTile, 2, 0).failures, 1);
  EXPECT_EQ(store_->completeAudit(a->audit, a->attempt, {}, 51).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_FALSE(leaseAudit("w3", 51.99).has_value()) << "the back-off of 2 s";
  auto again = leaseAudit("w3", 52);
  ASSERT_TRUE(again.has_value());
  EXPECT_EQ(again->audit, a->audit);
  EXPECT_EQ(again->attempt, 2);
  EXPECT_EQ(store_->expireLeases(1000).value_or(-1), 1) << "the audit's second lease";
}

TEST_P(JobStoreTest, CancelStopsAJobsAuditsAndRetryRevivesThemByFrame) {
  RetryPolicy policy;
  policy.maxAttempts = 1;
  open(policy);
  JobSpec spec = makeSpec({1, 2, 3, 4}, 1, false);
  spec.audits = {makeAudit(1, {0}), makeAudit(2, {0}), makeAudit(3, {0}), makeAudit(4, {0})};
  const int64_t id = submit(spec);
  for (int frame : {1, 2, 3}) finishFrame(id, frame, 0);
  auto a1 = leaseAudit("w1", 1);
  auto a2 = leaseAudit("w2", 1);
  auto a3 = leaseAudit("w3", 1);
  ASSERT_TRUE(a1.has_value() && a2.has_value() && a3.has_value());
  ASSERT_EQ(a3->spec.frame, 3);
  ASSERT_TRUE(store_->failAudit(a2->audit, a2->attempt, "diverged", 2).ok());
  ASSERT_TRUE(store_->completeAudit(a3->audit, a3->attempt, {0.01, 0, 5}, 2).ok());
  ASSERT_EQ(audit(id, 2).state, AuditState::kFailed);

  ASSERT_TRUE(store_->cancel(id).ok());
  EXPECT_EQ(audit(id, 1).state, AuditState::kCancelled) << "leased";
  EXPECT_EQ(audit(id, 2).state, AuditState::kFailed) << "failed stays failed";
  EXPECT_EQ(audit(id, 3).state, AuditState::kDone);
  EXPECT_EQ(audit(id, 4).state, AuditState::kCancelled) << "ready";
  EXPECT_EQ(store_->completeAudit(a1->audit, a1->attempt, {}, 3).code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store_->expireLeases(1000).value_or(-1), 0);

  // Frame 1 only; the job stays cancelled (frame 4's tasks are), so nothing is leased yet.
  ASSERT_TRUE(store_->retry(id, 1, std::nullopt, 4).ok());
  EXPECT_EQ(audit(id, 1).state, AuditState::kReady);
  EXPECT_EQ(audit(id, 2).state, AuditState::kFailed);
  EXPECT_EQ(audit(id, 4).state, AuditState::kCancelled);
  EXPECT_EQ(job(id).state, JobState::kCancelled);
  EXPECT_FALSE(leaseAudit("w1", 4).has_value()) << "the job is cancelled";
  // A tile's retry revives its frame's audit.
  ASSERT_TRUE(store_->retry(id, 2, 0, 5).ok());
  const AuditInfo revived = audit(id, 2);
  EXPECT_EQ(revived.state, AuditState::kReady);
  EXPECT_EQ(revived.failures, 0);
  EXPECT_EQ(revived.lastError, "");
  ASSERT_TRUE(store_->retry(id, std::nullopt, std::nullopt, 6).ok());
  EXPECT_EQ(job(id).state, JobState::kActive);
  EXPECT_EQ(audit(id, 4).state, AuditState::kReady);
  auto again1 = leaseAudit("w1", 6);
  auto again2 = leaseAudit("w1", 6);
  ASSERT_TRUE(again1.has_value() && again2.has_value());
  EXPECT_EQ(again1->spec.frame, 1);
  EXPECT_EQ(again1->attempt, 2) << "attempts keep counting across a retry";
  EXPECT_EQ(again2->spec.frame, 2);
  EXPECT_EQ(again2->attempt, 2);
  EXPECT_FALSE(leaseAudit("w1", 6).has_value()) << "frame 4 is not assembled";
  const AuditInfo kept = audit(id, 3);
  EXPECT_EQ(kept.state, AuditState::kDone);
  ASSERT_TRUE(kept.result.has_value());
  EXPECT_EQ(kept.result->seconds, 5);
}

TEST_P(JobStoreTest, AuditsLeaseByPriorityThenJobAgeThenFrame) {
  JobSpec olderSpec = makeSpec({2, 1}, 1, false, /*priority=*/0);
  olderSpec.audits = {makeAudit(2, {0}), makeAudit(1, {0})};
  JobSpec urgentSpec = makeSpec({3}, 1, false, /*priority=*/5);
  urgentSpec.audits = {makeAudit(3, {0})};
  JobSpec newerSpec = makeSpec({0}, 1, false, /*priority=*/0);
  newerSpec.audits = {makeAudit(0, {0})};
  const int64_t older = submit(olderSpec, 1);
  const int64_t urgent = submit(urgentSpec, 2);
  const int64_t newer = submit(newerSpec, 3);
  EXPECT_EQ(runReady("w1", 4), 8);
  const std::vector<std::pair<int64_t, int>> expected = {
      {urgent, 3}, {older, 1}, {older, 2}, {newer, 0}};
  for (const auto& [job, frame] : expected) {
    auto l = leaseAudit("w1", 5);
    ASSERT_TRUE(l.has_value()) << "expected job " << job << " frame " << frame;
    EXPECT_EQ(l->job, job);
    EXPECT_EQ(l->spec.frame, frame);
  }
  EXPECT_FALSE(leaseAudit("w1", 5).has_value());
}

TEST_P(JobStoreTest, SubmitRejectsMalformedAudits) {
  const auto rejected = [&](std::vector<AuditSpec> audits, const std::string& says) {
    JobSpec spec = makeSpec({1, 2}, 4, false);
    spec.audits = std::move(audits);
    const absl::Status status = store_->submit(spec, 0).status();
    EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << status;
    EXPECT_NE(status.message().find(says), std::string::npos)
        << status << " (expected " << says << ")";
  };
  const double inf = std::numeric_limits<double>::infinity();
  rejected({makeAudit(3, {0})}, "frame 3: the job has no such frame");
  rejected({makeAudit(1, {0}), makeAudit(2, {0}), makeAudit(1, {1})}, "frame 1 has two audits");
  rejected({makeAudit(1, {})}, "no tiles");
  rejected({makeAudit(1, {0, 4})}, "tile 4: expected 0..3");
  rejected({makeAudit(1, {-1})}, "tile -1: expected 0..3");
  rejected({makeAudit(1, {0}, 0)}, "spp 0");
  rejected({makeAudit(2, {0}, 64, -0.1)}, "threshold -0.1");
  rejected({makeAudit(2, {0}, 64, inf)}, "threshold inf");
  rejected({makeAudit(2, {0}, 64, std::numeric_limits<double>::quiet_NaN())}, "threshold nan");
  auto jobs = store_->jobs();
  ASSERT_TRUE(jobs.ok()) << jobs.status();
  EXPECT_TRUE(jobs->empty()) << "nothing of a rejected job is stored";

  JobSpec spec = makeSpec({1, 2}, 4, false);
  spec.audits = {makeAudit(2, {3, 0}, 1, 0), makeAudit(1, {2}, 4096, 1e-7)};
  const int64_t id = submit(spec);
  const std::vector<AuditInfo> stored = audits(id);
  ASSERT_EQ(stored.size(), 2u);
  EXPECT_EQ(stored[0].spec.threshold, 1e-7) << "every digit kept";
  EXPECT_EQ(stored[1].spec.tiles, (std::vector<int>{3, 0})) << "tiles in the spec's order";
  EXPECT_EQ(stored[1].spec.threshold, 0);
}

// Two store objects (two coordinators, by mistake for SQLite), two threads each, lease the
// audits of many assembled frames at once: each is leased once and completed once.
// Threads racing over stores (thread t uses stores[t % size]): each calls `take` until it says
// to stop; `take` leases and completes one item and returns its id, nullopt to go round again
// (the other store holds what this one waits on) or an error. What each took, by whom.
struct Race {
  std::multiset<int64_t> taken;
  std::vector<int> perStore;
  std::vector<std::string> errors;
};
enum class Take { kTook, kAgain, kStop };
Race race(const std::vector<JobStore*>& stores, int threads,
          const std::function<Take(JobStore& store, const std::string& worker, int64_t* id,
                                   std::string* error)>& take) {
  Race r;
  r.perStore.assign(stores.size(), 0);
  std::mutex mutex;
  std::vector<std::thread> running;
  for (int t = 0; t < threads; ++t) {
    running.emplace_back([&, t] {
      const size_t at = static_cast<size_t>(t) % stores.size();
      const std::string worker = fmt::format("coordinator{}-worker{}", at, t);
      for (int spins = 0; spins < 100000; ++spins) {
        int64_t id = 0;
        std::string error;
        const Take what = take(*stores[at], worker, &id, &error);
        std::lock_guard lock(mutex);
        if (!error.empty()) r.errors.push_back(error);
        if (what == Take::kStop) return;
        if (what == Take::kAgain) continue;
        r.taken.insert(id);
        ++r.perStore[at];
      }
    });
  }
  for (std::thread& t : running) t.join();
  return r;
}

// A race's step on job `id`: lease a task and complete it (each at its first attempt). With
// none ready, again while a task of the job is leased elsewhere (an assemble waits on it);
// otherwise stop, the job done, or left active when it should have settled (the caller checks).
auto leaseAndComplete(int64_t id) {
  return [id](JobStore& store, const std::string& worker, int64_t* task, std::string* error) {
    auto l = store.lease(worker, 0, kLease);
    if (!l.ok()) *error = std::string(l.status().message());
    if (!l.ok()) return Take::kStop;
    if (!*l) {
      auto info = store.job(id);
      if (!info.ok()) *error = std::string(info.status().message());
      if (!info.ok() || info->state != JobState::kActive) return Take::kStop;
      return info->tasksByState[static_cast<size_t>(TaskState::kLeased)] > 0 ? Take::kAgain
                                                                              : Take::kStop;
    }
    const absl::Status s = store.complete((*l)->task, (*l)->attempt, 0).status();
    if (!s.ok()) *error = std::string(s.message());
    EXPECT_EQ((*l)->attempt, 1) << (*l)->ref.toString();
    *task = (*l)->task;
    return Take::kTook;
  };
}

TEST_P(JobStoreTest, ConcurrentAuditLeasesNeverHandOutAnAuditTwice) {
  constexpr int kFrames = 60;
  std::vector<int> frames(kFrames);
  for (int f = 0; f < kFrames; ++f) frames[f] = f;
  JobSpec spec = makeSpec(frames, 1, false);
  for (int f : frames) spec.audits.push_back(makeAudit(f, {0}));
  const int64_t id = submit(spec);
  ASSERT_EQ(runReady("w0", 0), 2 * kFrames);
  std::unique_ptr<JobStore> second = openAnother();
  ASSERT_NE(second, nullptr);
  const Race r = race({store_.get(), second.get()}, 4,
                      [](JobStore& store, const std::string& worker, int64_t* id,
                         std::string* error) {
                        auto l = store.leaseAudit(worker, 1, kLease);
                        if (!l.ok()) *error = std::string(l.status().message());
                        // Every frame is assembled: none ready means none left.
                        if (!l.ok() || !*l) return Take::kStop;
                        const absl::Status s =
                            store.completeAudit((*l)->audit, (*l)->attempt, {0.01, 0, 1}, 1);
                        if (!s.ok()) *error = std::string(s.message());
                        EXPECT_EQ((*l)->attempt, 1) << "audit " << (*l)->audit;
                        *id = (*l)->audit;
                        return Take::kTook;
                      });
  const std::multiset<int64_t>& leased = r.taken;
  const std::vector<int>& perStore = r.perStore;
  EXPECT_TRUE(r.errors.empty()) << r.errors.front();
  EXPECT_EQ(leased.size(), static_cast<size_t>(kFrames));
  EXPECT_EQ(std::set<int64_t>(leased.begin(), leased.end()).size(), static_cast<size_t>(kFrames))
      << "an audit was leased twice";
  if (GetParam() == Backend::kPostgres) {
    // Both coordinators got some. Not asked of SQLite: a second connection to the file sleeps
    // in its busy handler while the first one's group commits take every audit.
    EXPECT_GT(perStore[0], 0);
    EXPECT_GT(perStore[1], 0);
  }
  for (const AuditInfo& a : audits(id)) {
    EXPECT_EQ(a.state, AuditState::kDone) << "frame " << a.spec.frame;
    EXPECT_EQ(a.attempt, 1) << "frame " << a.spec.frame;
  }
}

// Jobs whose last tasks, on different frames, complete at once on two coordinators end done,
// every task done once: a completion that settled its job without the job's row (tried, to
// let frames complete side by side) left it active, seeing the other's task still leased.
// Twenty small jobs, so that the last completions race many times.
TEST_F(PostgresJobStoreTest, JobsWhoseLastTasksCompleteAtOnceOnTwoCoordinatorsEndDone) {
  std::unique_ptr<JobStore> second = openAnother();
  ASSERT_NE(second, nullptr);
  for (int round = 0; round < 20; ++round) {
    SCOPED_TRACE(round);
    const int64_t id = submit(makeSpec({1, 2, 3, 4}, 1, false));
    const Race r = race({store_.get(), second.get()}, 4, leaseAndComplete(id));
    EXPECT_TRUE(r.errors.empty()) << r.errors.front();
    EXPECT_EQ(r.taken.size(), 8u) << "4 tiles and 4 assembles";
    EXPECT_EQ(std::set<int64_t>(r.taken.begin(), r.taken.end()).size(), 8u);
    const JobInfo done = job(id);
    EXPECT_EQ(done.state, JobState::kDone);
    EXPECT_EQ(count(done, TaskState::kDone), 8);
  }
}

// Two coordinators, one thread each, share one database: leases race on every task of a big
// job, and each is leased exactly once.
TEST_F(PostgresJobStoreTest, TwoCoordinatorsLeaseEveryTaskOfABigJobExactlyOnce) {
  constexpr int kTiles = 200;
  const int64_t id = submit(makeSpec({1}, kTiles, false));
  std::unique_ptr<JobStore> second = openAnother();
  ASSERT_NE(second, nullptr);
  const Race r = race({store_.get(), second.get()}, 2, leaseAndComplete(id));
  const std::multiset<int64_t>& leased = r.taken;
  const std::vector<int>& perStore = r.perStore;
  EXPECT_TRUE(r.errors.empty()) << r.errors.front();
  EXPECT_EQ(leased.size(), kTiles + 1u);
  EXPECT_EQ(std::set<int64_t>(leased.begin(), leased.end()).size(), kTiles + 1u)
      << "a task was leased twice";
  EXPECT_GT(perStore[0], 0);
  EXPECT_GT(perStore[1], 0);
  const JobInfo done = job(id);
  EXPECT_EQ(done.state, JobState::kDone);
  EXPECT_EQ(count(done, TaskState::kDone), kTiles + 1);
  auto events = store_->events(id, std::nullopt, std::nullopt);
  ASSERT_TRUE(events.ok()) << events.status();
  std::map<int64_t, int> leases;
  for (const TaskEvent& e : *events) leases[e.task] += e.event == "leased" ? 1 : 0;
  EXPECT_EQ(leases.size(), kTiles + 1u);
  for (const auto& [task, n] : leases) EXPECT_EQ(n, 1) << "task " << task;
}

// A coordinator that goes away mid-job (its store object destroyed, its workers' leases left
// behind): the other one's expiry sweep takes those leases back and hands the tasks out again,
// and a stale attempt from before can no longer commit.
TEST_F(PostgresJobStoreTest, LeasesOfACoordinatorThatWentAwayExpireToTheOther) {
  constexpr int kTiles = 200;
  constexpr int kLost = 10;
  RetryPolicy policy;
  policy.backoffBase = 0;  // what expires is ready again at once
  open(policy);
  const int64_t id = submit(makeSpec({1}, kTiles, false));
  std::unique_ptr<JobStore> departing = openAnother(policy);
  ASSERT_NE(departing, nullptr);
  // Leased through the departing coordinator, never finished.
  std::map<int64_t, int> lost;
  for (int i = 0; i < kLost; ++i) {
    auto l = departing->lease(fmt::format("b{}", i % 3), 0, kLease);
    ASSERT_TRUE(l.ok() && l->has_value()) << l.status();
    lost[(*l)->task] = (*l)->attempt;
  }

  std::mutex mutex;
  std::multiset<int64_t> completed;
  std::vector<std::string> errors;
  std::atomic<bool> gone = false;
  auto note = [&](const absl::Status& s) {
    std::lock_guard lock(mutex);
    if (!s.ok()) errors.push_back(std::string(s.message()));
  };
  // The departing coordinator works on for a while, then stops without a word.
  std::thread b([&] {
    for (int i = 0; i < 40; ++i) {
      auto l = departing->lease("b-busy", 1, kLease);
      if (!l.ok()) return note(l.status());
      if (!*l) break;
      note(departing->complete((*l)->task, (*l)->attempt, 1).status());
      std::lock_guard lock(mutex);
      completed.insert((*l)->task);
    }
    departing.reset();
    gone = true;
  });
  // The remaining coordinator: everything ready, then, once the other is gone, a sweep.
  std::thread a([&] {
    Seconds now = 1;
    int sweeps = 0;
    for (int spins = 0; spins < 100000; ++spins) {
      auto l = store_->lease("a", now, kLease);
      if (!l.ok()) return note(l.status());
      if (*l) {
        note(store_->complete((*l)->task, (*l)->attempt, now).status());
        std::lock_guard lock(mutex);
        completed.insert((*l)->task);
        continue;
      }
      auto info = store_->job(id);
      if (!info.ok()) return note(info.status());
      if (info->state != JobState::kActive) return;
      if (!gone || sweeps > 0) {
        std::this_thread::yield();
        continue;
      }
      now = 1 + kLease;
      auto expired = store_->expireLeases(now);
      if (!expired.ok()) return note(expired.status());
      std::lock_guard lock(mutex);
      EXPECT_EQ(*expired, kLost) << "only the departed coordinator's leases had expired";
      ++sweeps;
    }
  });
  b.join();
  a.join();
  EXPECT_TRUE(errors.empty()) << errors.front();
  EXPECT_EQ(completed.size(), kTiles + 1u);
  EXPECT_EQ(std::set<int64_t>(completed.begin(), completed.end()).size(), kTiles + 1u)
      << "a task completed twice";
  EXPECT_EQ(job(id).state, JobState::kDone);
  auto tasks = store_->tasks(id);
  ASSERT_TRUE(tasks.ok()) << tasks.status();
  for (const TaskInfo& t : *tasks) {
    if (!lost.contains(t.id)) continue;
    EXPECT_EQ(t.attempt, 2) << t.ref.toString();
    EXPECT_EQ(t.failures, 1) << t.ref.toString();
    EXPECT_EQ(t.worker, "a") << t.ref.toString();
    EXPECT_NE(t.lastError.find("lease expired: worker b"), std::string::npos) << t.lastError;
  }
  const auto [task, attempt] = *lost.begin();
  EXPECT_EQ(store_->complete(task, attempt, 100).status().code(),
            absl::StatusCode::kFailedPrecondition);
}

TEST_F(PostgresJobStoreTest, OpenRefusesAServerItCannotReachAndASchemaFromANewerCoordinator) {
  // A socket folder nobody listens in; the password must not reach the message.
  const std::string unreachable =
      fmt::format("postgresql://pbgi:hunter2@/farm?host={}&port=1", dir_.string());
  auto store = openJobStore(unreachable, {});
  EXPECT_EQ(store.status().code(), absl::StatusCode::kUnavailable) << store.status();
  EXPECT_NE(store.status().message().find(dir_.string()), std::string::npos) << store.status();
  EXPECT_EQ(store.status().message().find("hunter2"), std::string::npos) << store.status();

  store_.reset();
  ASSERT_TRUE(cluster_->execute(database_, "UPDATE pbgi_schema SET version = 99").ok());
  auto newer = openJobStore(spec_, {});
  EXPECT_EQ(newer.status().code(), absl::StatusCode::kFailedPrecondition) << newer.status();
  EXPECT_NE(newer.status().message().find("schema version 99"), std::string::npos)
      << newer.status();
}

// A file written before audits (schema 2), or before the event log too (schema 1): opening it
// adds what it lacks, and its jobs (their overrides still text), tasks and leases are as they
// were.
TEST_F(SqliteJobStoreTest, AnOlderFileGainsTheAuditsTableWithItsJobsIntact) {
  for (const int version : {2, 1}) {
    SCOPED_TRACE(fmt::format("schema version {}", version));
    open();
    const int64_t id = submit(makeSpec({4, 5}, 2, true, 3), 7);
    auto bake = lease("w1", 8);
    ASSERT_TRUE(bake.has_value());
    store_.reset();

    // Back to what that version's coordinator wrote.
    sqlite3* raw = nullptr;
    ASSERT_EQ(sqlite3_open(spec_.c_str(), &raw), SQLITE_OK);
    std::unique_ptr<sqlite3, decltype(&sqlite3_close)> db(raw, &sqlite3_close);
    const auto exec = [&](const std::string& sql) {
      char* message = nullptr;
      const int rc = sqlite3_exec(db.get(), sql.c_str(), nullptr, nullptr, &message);
      EXPECT_EQ(rc, SQLITE_OK) << sql << ": " << (message != nullptr ? message : "");
      sqlite3_free(message);
    };
    const auto userVersion = [&] {
      sqlite3_stmt* stmt = nullptr;
      EXPECT_EQ(sqlite3_prepare_v2(db.get(), "PRAGMA user_version", -1, &stmt, nullptr), SQLITE_OK);
      const int found = sqlite3_step(stmt) == SQLITE_ROW ? sqlite3_column_int(stmt, 0) : -1;
      sqlite3_finalize(stmt);
      return found;
    };
    ASSERT_EQ(userVersion(), 3);
    exec("DROP TABLE audits");
    if (version == 1) exec("DROP TABLE task_events; DROP INDEX tasks_by_job_state");
    exec(fmt::format("PRAGMA user_version = {}", version));
    // Overrides as text, as coordinators kept them before they were typed.
    exec("UPDATE jobs SET overrides = 'spp=16\ngather=per-pixel\n'");
    db.reset();

    open();
    const JobInfo info = job(id);
    EXPECT_EQ(info.spec.overrides, makeSpec({4, 5}, 2, true, 3).overrides);
    EXPECT_EQ(info.spec.priority, 3);
    EXPECT_EQ(info.submitted, 7);
    EXPECT_EQ(info.spec.frames, (std::vector<int>{4, 5}));
    EXPECT_EQ(count(info, TaskState::kLeased), 1);
    EXPECT_EQ(count(info, TaskState::kReady), 1);
    EXPECT_EQ(count(info, TaskState::kBlocked), 6);
    EXPECT_TRUE(audits(id).empty());
    auto events = store_->events(id, std::nullopt, std::nullopt);
    ASSERT_TRUE(events.ok()) << events.status();
    EXPECT_EQ(events->size(), version == 1 ? 0u : 1u);
    ASSERT_TRUE(store_->complete(bake->task, bake->attempt, 9).ok()) << "the lease survived";

    expectAnAuditedJobRuns();
    store_.reset();

    ASSERT_EQ(sqlite3_open(spec_.c_str(), &raw), SQLITE_OK);
    db.reset(raw);
    EXPECT_EQ(userVersion(), 3);
    db.reset();
    fs::remove(spec_);
    fs::remove(spec_ + "-wal");
    fs::remove(spec_ + "-shm");
  }
}

TEST_F(SqliteJobStoreTest, OpenRefusesAFileFromANewerCoordinator) {
  store_.reset();
  sqlite3* raw = nullptr;
  ASSERT_EQ(sqlite3_open(spec_.c_str(), &raw), SQLITE_OK);
  ASSERT_EQ(sqlite3_exec(raw, "PRAGMA user_version = 4", nullptr, nullptr, nullptr), SQLITE_OK);
  sqlite3_close(raw);
  auto newer = openJobStore(spec_, {});
  EXPECT_EQ(newer.status().code(), absl::StatusCode::kFailedPrecondition) << newer.status();
  EXPECT_NE(newer.status().message().find("schema version 4"), std::string::npos) << newer.status();
}

// A database written before audits (schema 1) gains them, its jobs intact.
TEST_F(PostgresJobStoreTest, AVersion1DatabaseGainsTheAuditsTableWithItsJobsIntact) {
  const int64_t id = submit(makeSpec({4, 5}, 2, true, 3), 7);
  auto bake = lease("w1", 8);
  ASSERT_TRUE(bake.has_value());
  store_.reset();
  ASSERT_TRUE(
      cluster_->execute(database_, "DROP TABLE audits; UPDATE pbgi_schema SET version = 1").ok());

  open();
  const JobInfo info = job(id);
  EXPECT_EQ(info.spec.priority, 3);
  EXPECT_EQ(info.submitted, 7);
  EXPECT_EQ(count(info, TaskState::kLeased), 1);
  EXPECT_EQ(count(info, TaskState::kBlocked), 6);
  EXPECT_TRUE(audits(id).empty());
  ASSERT_TRUE(store_->complete(bake->task, bake->attempt, 9).ok()) << "the lease survived";
  expectAnAuditedJobRuns();
  const absl::Status version = cluster_->execute(
      database_,
      "DO $$ BEGIN IF (SELECT version FROM pbgi_schema) <> 2 OR (SELECT COUNT(*) FROM "
      "pbgi_schema) <> 1 THEN RAISE EXCEPTION 'not at version 2'; END IF; END $$");
  EXPECT_TRUE(version.ok()) << version;
}

TEST(JobStoreRulesTest, AStoreSpecPicksItsImplementationAndErrorsShowNoPassword) {
  EXPECT_TRUE(isPostgresUri("postgresql://farm-db/farm"));
  EXPECT_TRUE(isPostgresUri("postgres://farm-db/farm"));
  EXPECT_FALSE(isPostgresUri("/var/lib/pbgi/jobs.db"));
  EXPECT_FALSE(isPostgresUri("postgresql.db"));
  EXPECT_EQ(redactedUri("postgresql://pbgi:s3cret@db.farm:5432/farm?sslmode=require&password=x"),
            "postgresql://pbgi@db.farm:5432/farm?sslmode=require");
  EXPECT_EQ(redactedUri("postgresql:///farm?password=x&host=/run/pg"),
            "postgresql:///farm?host=/run/pg");
  EXPECT_EQ(redactedUri("postgresql://pbgi@db/farm"), "postgresql://pbgi@db/farm");
}

// The words are what every version has stored in task_events.event: existing databases read
// unchanged only while these stay.
TEST(JobStoreRulesTest, EventKindsAreStoredAsTheirWordsAndAnUnknownWordIsDataLoss) {
  const std::pair<TaskEventKind, const char*> words[] = {{TaskEventKind::kLeased, "leased"},
                                                         {TaskEventKind::kDone, "done"},
                                                         {TaskEventKind::kFailed, "failed"},
                                                         {TaskEventKind::kExpired, "expired"}};
  for (const auto& [kind, word] : words) {
    EXPECT_EQ(toString(kind), word);
    const absl::StatusOr<TaskEventKind> back = parseTaskEventKind(word);
    ASSERT_TRUE(back.ok()) << back.status();
    EXPECT_EQ(*back, kind) << word;
  }
  for (const std::string_view word : {"paused", "", "Done", "done "}) {
    const absl::StatusOr<TaskEventKind> unknown = parseTaskEventKind(word);
    EXPECT_EQ(unknown.status().code(), absl::StatusCode::kDataLoss) << word;
    EXPECT_NE(unknown.status().message().find(fmt::format("'{}'", word)), std::string::npos)
        << unknown.status();
    EXPECT_NE(unknown.status().message().find("leased, done, failed, expired"), std::string::npos)
        << unknown.status();
  }
}

TEST(JobStoreRulesTest, ADeadTaskTakesWhatWaitsOnItInItsFrame) {
  EXPECT_EQ(dependentKinds(TaskKind::kBake),
            (std::vector<TaskKind>{TaskKind::kTile, TaskKind::kAssemble}));
  EXPECT_EQ(dependentKinds(TaskKind::kTile), std::vector<TaskKind>{TaskKind::kAssemble});
  EXPECT_TRUE(dependentKinds(TaskKind::kAssemble).empty());
}

}  // namespace
}  // namespace pbgi::farm
