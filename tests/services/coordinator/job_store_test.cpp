// Both job stores against the contract in job_store.h, every case on SQLite and on PostgreSQL
// (a throwaway cluster, tests/support/postgres_cluster.h): the task graph, lease order, stale
// attempts, retries and their back-off, dead tasks, blocklists, cancel and retry, the event
// log, a database that outlives the store object that wrote it, and two store objects (two
// coordinators) leasing from one database at once. The tests drive a clock of their own.

#include <gtest/gtest.h>

#include <atomic>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <thread>

#include <fmt/format.h>

#include "services/coordinator/job_store.h"
#include "tests/support/postgres_cluster.h"
#include "tests/support/test_paths.h"

namespace pbgi::farm {

// So that a failed EXPECT_EQ prints "ready", not "1".
void PrintTo(TaskKind kind, std::ostream* os) { *os << toString(kind); }
void PrintTo(TaskState state, std::ostream* os) { *os << toString(state); }
void PrintTo(JobState state, std::ostream* os) { *os << toString(state); }

namespace {

namespace fs = std::filesystem;

constexpr Seconds kLease = 30;

JobSpec makeSpec(std::vector<int> frames, int tiles, bool bake, int priority = 0) {
  JobSpec spec;
  spec.name = "shot";
  spec.shotPath = "/shots/shot.toml";
  spec.shotText = "[camera]\nfov = 40\n";
  spec.overrides = "spp=16\n";
  spec.outputPattern = "/renders/shot.####.exr";
  spec.priority = priority;
  spec.frames = std::move(frames);
  spec.tileCount = tiles;
  spec.needsBake = bake;
  return spec;
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
  auto expired = store_->expireLeases(50);
  ASSERT_TRUE(expired.ok()) << expired.status();
  EXPECT_EQ(*expired, 1);

  const TaskInfo info = task(id, TaskKind::kTile, 1, 0);
  EXPECT_EQ(info.state, TaskState::kReady);
  EXPECT_EQ(info.failures, 1);
  EXPECT_EQ(info.lastError, "lease expired: worker w1 stopped heartbeating");
  EXPECT_EQ(store_->complete(l->task, l->attempt, 51).status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(store_->expireLeases(1000).value_or(-1), 0);
}

TEST_P(JobStoreTest, AWorkerThatKeepsFailingAJobIsBlocklistedForThatJobOnly) {
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

// Two coordinators, one thread each, share one database: leases race on every task of a big
// job, and each is leased exactly once.
TEST_F(PostgresJobStoreTest, TwoCoordinatorsLeaseEveryTaskOfABigJobExactlyOnce) {
  constexpr int kTiles = 200;
  const int64_t id = submit(makeSpec({1}, kTiles, false));
  std::unique_ptr<JobStore> second = openAnother();
  ASSERT_NE(second, nullptr);
  std::vector<JobStore*> stores = {store_.get(), second.get()};

  std::mutex mutex;
  std::multiset<int64_t> leased;
  std::vector<int> perStore(2, 0);
  std::vector<std::string> errors;
  std::vector<std::thread> threads;
  for (int t = 0; t < 2; ++t) {
    threads.emplace_back([&, t] {
      JobStore& store = *stores[t];
      const std::string worker = fmt::format("coordinator{}-worker", t);
      for (int spins = 0; spins < 100000; ++spins) {
        auto l = store.lease(worker, 0, kLease);
        if (!l.ok() || !*l) {
          auto info = store.job(id);
          std::lock_guard lock(mutex);
          if (!l.ok()) errors.push_back(std::string(l.status().message()));
          if (!l.ok() || !info.ok() || info->state != JobState::kActive) return;
          continue;  // the assemble waits on a tile the other coordinator holds
        }
        const absl::Status s = store.complete((*l)->task, (*l)->attempt, 0).status();
        std::lock_guard lock(mutex);
        if (!s.ok()) errors.push_back(std::string(s.message()));
        EXPECT_EQ((*l)->attempt, 1) << (*l)->ref.toString();
        leased.insert((*l)->task);
        ++perStore[t];
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_TRUE(errors.empty()) << errors.front();
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

TEST(JobStoreRulesTest, ADeadTaskTakesWhatWaitsOnItInItsFrame) {
  EXPECT_EQ(dependentKinds(TaskKind::kBake),
            (std::vector<TaskKind>{TaskKind::kTile, TaskKind::kAssemble}));
  EXPECT_EQ(dependentKinds(TaskKind::kTile), std::vector<TaskKind>{TaskKind::kAssemble});
  EXPECT_TRUE(dependentKinds(TaskKind::kAssemble).empty());
}

}  // namespace
}  // namespace pbgi::farm
