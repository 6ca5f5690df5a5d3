// The coordinator over real gRPC on loopback (port 0): the token, the output root, bad jobs,
// stale completions, the metrics endpoint. Workers here are this test speaking the worker's
// calls, so that each rule is exercised exactly; tests/services/worker/ runs real workers.

#include <gtest/gtest.h>

#include <httplib.h>

#include <sqlite3.h>

#include <fstream>
#include <memory>
#include <regex>
#include <thread>

#include "formats/pbgi/remote_page_file.h"
#include "services/bake/frame_bake.h"
#include "services/farm/job_rules.h"

#include "services/coordinator/coordinator.h"
#include "services/farm/farm_client.h"
#include "services/farm/farm_wire.h"
#include "tests/support/coordinator_fixture.h"
#include "tests/support/farm_fixtures.h"

namespace pbgi::farm {
namespace {

namespace fs = std::filesystem;

using pbgi::testing::CoordinatorTest;

TEST_F(CoordinatorTest, EveryCallWithoutTheTokenIsRefusedAndCounted) {
  options_.readsNeedToken = true;  // --read-access token; open reads are below
  start();
  FarmClient wrong(coordinator_->address(), "not-the-token", 10.0);
  FarmClient none(coordinator_->address(), "", 10.0);
  const auto submitted = wrong.submitJob(shotRequest({}));
  EXPECT_EQ(submitted.status().code(), absl::StatusCode::kUnauthenticated) << submitted.status();
  v1::LeaseTaskRequest lease;
  lease.set_worker("w");
  EXPECT_EQ(none.leaseTask(lease).status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(wrong.getStatus(v1::GetStatusRequest()).status().code(),
            absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(wrong.openTree(1, 1).status().code(), absl::StatusCode::kUnauthenticated);
  const uint32_t page[1] = {0};
  EXPECT_EQ(wrong.fetchPages(1, 1, 0, page).status().code(), absl::StatusCode::kUnauthenticated);
  // Nothing was submitted by the refused call; the right token works.
  auto status = client_->getStatus(v1::GetStatusRequest());
  ASSERT_TRUE(status.ok()) << status.status();
  EXPECT_EQ(status->jobs_size(), 0);
  EXPECT_NE(metrics().find("pbgi_rpc_refused_total 5"), std::string::npos) << metrics();
}

// By default reads are open, as the dashboard's are (--read-access open); anything else still
// needs the token.
TEST_F(CoordinatorTest, ReadsAreOpenByDefaultAndNothingElseIs) {
  start();
  FarmClient none(coordinator_->address(), "", 10.0);
  EXPECT_TRUE(none.getStatus(v1::GetStatusRequest()).ok());
  EXPECT_TRUE(none.listWorkers(v1::ListWorkersRequest()).ok());
  EXPECT_EQ(none.submitJob(shotRequest({})).status().code(), absl::StatusCode::kUnauthenticated);
  v1::CancelJobRequest cancel;
  cancel.set_job(1);
  EXPECT_EQ(none.cancelJob(cancel).status().code(), absl::StatusCode::kUnauthenticated);
  EXPECT_EQ(none.openTree(1, 1).status().code(), absl::StatusCode::kUnauthenticated);
}

TEST_F(CoordinatorTest, OutputsOutsideTheOutputRootAreRejected) {
  start();
  pbgi::testing::SmallShot escaping;
  escaping.output = "../../escaped/small.####.exr";
  const auto refused = client_->submitJob(shotRequest(escaping));
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kPermissionDenied) << refused.status();
  EXPECT_NE(refused.status().message().find("outside the coordinator's output root"),
            std::string::npos)
      << refused.status();
  v1::SubmitJobRequest elsewhere = shotRequest({});
  elsewhere.set_output_dir("/tmp");
  EXPECT_EQ(client_->submitJob(elsewhere).status().code(), absl::StatusCode::kPermissionDenied);
  v1::SubmitJobRequest dotdot = shotRequest({});
  dotdot.set_output_dir("sub/../../..");
  EXPECT_EQ(client_->submitJob(dotdot).status().code(), absl::StatusCode::kPermissionDenied);
  // Inside the root, relative to it: accepted.
  v1::SubmitJobRequest inside = shotRequest({});
  inside.set_output_dir("renders/v1");
  auto id = client_->submitJob(inside);
  ASSERT_TRUE(id.ok()) << id.status();
  auto job = coordinator_->store().job(id->job());
  ASSERT_TRUE(job.ok());
  EXPECT_EQ(job->spec.outputPattern,
            (fs::path(options_.outputRoot) / "renders/v1/small.####.exr").string());
}

// A job's output format is checked at submission: an unknown extension is refused, and an
// 8-bit frame cannot be audited (an audit compares linear light).
TEST_F(CoordinatorTest, AnOutputsFormatIsCheckedAtSubmission) {
  start();
  pbgi::testing::SmallShot unknown;
  unknown.output = "out/small.####.bmp";
  const auto refused = client_->submitJob(shotRequest(unknown));
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument) << refused.status();
  EXPECT_NE(refused.status().message().find("unknown image format '.bmp'"), std::string::npos)
      << refused.status();

  pbgi::testing::SmallShot png;
  png.output = "out/small.####.png";
  png.integrator = "pbgi";
  v1::SubmitJobRequest audited = shotRequest(png);
  audited.set_audit_tiles(1);
  const auto noAudit = client_->submitJob(audited);
  EXPECT_EQ(noAudit.status().code(), absl::StatusCode::kInvalidArgument) << noAudit.status();
  EXPECT_NE(noAudit.status().message().find("--audit-tiles 0"), std::string::npos)
      << noAudit.status();
  const auto accepted = client_->submitJob(shotRequest(png));
  ASSERT_TRUE(accepted.ok()) << accepted.status();
  auto audits = coordinator_->store().audits(accepted->job());
  ASSERT_TRUE(audits.ok()) << audits.status();
  EXPECT_TRUE(audits->empty());
}

TEST_F(CoordinatorTest, ABadShotIsRefusedWithItsLineAndTheCoordinatorCarriesOn) {
  start();
  v1::SubmitJobRequest bad = shotRequest({});
  bad.set_shot_text("version = 1\n[shot]\nname = \"x\"\nframes = [1, 1]\nbogus = 3\n");
  const auto refused = client_->submitJob(bad);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument) << refused.status();
  EXPECT_NE(refused.status().message().find("small.shot.toml:"), std::string::npos)
      << refused.status();
  v1::SubmitJobRequest badOverride = shotRequest({});
  badOverride.add_overrides("spp=many");
  EXPECT_EQ(client_->submitJob(badOverride).status().code(), absl::StatusCode::kInvalidArgument);
  // The integrator registry decides at submission, not the worker at render time.
  v1::SubmitJobRequest unknownIntegrator = shotRequest({});
  unknownIntegrator.add_overrides("integrator=photon");
  const auto noIntegrator = client_->submitJob(unknownIntegrator);
  EXPECT_EQ(noIntegrator.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(noIntegrator.status().message().find("photon"), std::string::npos)
      << noIntegrator.status();
  EXPECT_NE(noIntegrator.status().message().find("pbgi"), std::string::npos)
      << noIntegrator.status();  // names what was expected
  v1::SubmitJobRequest unknownParam = shotRequest({});
  unknownParam.add_overrides("integrator=pbgi");
  unknownParam.add_overrides("light_solid_angel=0.1");
  const auto noParam = client_->submitJob(unknownParam);
  EXPECT_EQ(noParam.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(noParam.status().message().find("light_solid_angel"), std::string::npos)
      << noParam.status();
  v1::SubmitJobRequest outOfRange = shotRequest({});
  outOfRange.add_overrides("integrator=pbgi");
  outOfRange.add_overrides("gather=sideways");
  EXPECT_EQ(client_->submitJob(outOfRange).status().code(), absl::StatusCode::kInvalidArgument);
  v1::SubmitJobRequest badFrame = shotRequest({});
  badFrame.add_frames(7);
  EXPECT_EQ(client_->submitJob(badFrame).status().code(), absl::StatusCode::kOutOfRange);
  auto good = client_->submitJob(shotRequest({}));
  ASSERT_TRUE(good.ok()) << good.status();
  auto job = coordinator_->store().job(good->job());
  ASSERT_TRUE(job.ok());
  EXPECT_EQ(job->spec.frames, (std::vector<int>{1, 2}));
  EXPECT_EQ(job->spec.tileCount, 4);  // 64 x 64 in 32-pixel tiles
  EXPECT_FALSE(job->spec.needsBake);
}

// Overrides arrive typed, are checked once at submission, and reach the worker as the
// same typed values (and as text for workers from before them).
TEST_F(CoordinatorTest, TypedOverridesAreCheckedAtSubmissionAndLeasedAsSent) {
  start();
  v1::SubmitJobRequest wrongType = shotRequest({});
  (*wrongType.mutable_render()->mutable_params())["gather"].set_float_value(1.0);
  const auto refused = client_->submitJob(wrongType);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument) << refused.status();
  EXPECT_NE(refused.status().message().find("gather"), std::string::npos) << refused.status();

  v1::SubmitJobRequest request = shotRequest({});
  request.add_frames(1);
  request.mutable_render()->set_spp(3);
  (*request.mutable_render()->mutable_params())["gather"].set_choice("per-pixel");
  ASSERT_TRUE(client_->submitJob(request).ok());
  v1::LeaseTaskRequest lease;
  lease.set_worker("w");
  auto leased = client_->leaseTask(lease);
  ASSERT_TRUE(leased.ok()) << leased.status();
  ASSERT_TRUE(leased->has_task());
  EXPECT_EQ(leased->render().spp(), 3);
  EXPECT_EQ(leased->render().params().at("gather").choice(), "per-pixel");
  EXPECT_EQ(std::vector<std::string>(leased->overrides().begin(), leased->overrides().end()),
            (std::vector<std::string>{"spp=3", "gather=per-pixel"}));
}

// A job whose only live worker is blocklisted says so, with the failing task's error, and a
// retry lifts the blocklist and says what it changed; with no live worker it is waiting.
TEST_F(CoordinatorTest, AJobNoLiveWorkerMayTakeIsStalledAndRetryLiftsTheBlocklist) {
  start();
  v1::SubmitJobRequest request = shotRequest({});
  request.add_frames(1);
  auto submitted = client_->submitJob(request);
  ASSERT_TRUE(submitted.ok()) << submitted.status();
  const int64_t job = submitted->job();
  const auto status = [&] {
    v1::GetStatusRequest r;
    r.set_job(job);
    auto s = client_->getStatus(r);
    EXPECT_TRUE(s.ok()) << s.status();
    return s.ok() ? s->jobs(0) : v1::JobStatus();
  };
  EXPECT_EQ(status().stall(), "waiting");  // no worker has called

  v1::LeaseTaskRequest lease;
  lease.set_worker("w1");
  for (int i = 0; i < 3; ++i) {  // the default blocklist: three failures of the job
    auto leased = client_->leaseTask(lease);
    ASSERT_TRUE(leased.ok()) << leased.status();
    ASSERT_TRUE(leased->has_task());
    v1::FailTaskRequest fail;
    fail.set_worker("w1");
    fail.set_task(leased->task());
    fail.set_attempt(leased->attempt());
    fail.set_error("small.obj:3: expected a vertex");
    ASSERT_TRUE(client_->failTask(fail).ok());
  }
  auto none = client_->leaseTask(lease);
  ASSERT_TRUE(none.ok()) << none.status();
  EXPECT_FALSE(none->has_task());
  v1::JobStatus stalled = status();
  EXPECT_EQ(stalled.stall(), "stalled");
  ASSERT_EQ(stalled.blocklisted_workers_size(), 1);
  EXPECT_EQ(stalled.blocklisted_workers(0), "w1");
  EXPECT_NE(stalled.stall_error().find("expected a vertex"), std::string::npos)
      << stalled.stall_error();

  v1::RetryJobRequest retry;
  retry.set_job(job);
  auto retried = client_->retryJob(retry);
  ASSERT_TRUE(retried.ok()) << retried.status();
  // The tile that failed all three times (dead at its attempt cap) and the frame's assemble,
  // which died waiting on it.
  EXPECT_EQ(retried->tasks(), 2);
  ASSERT_EQ(retried->unblocked_workers_size(), 1);
  EXPECT_EQ(retried->unblocked_workers(0), "w1");
  const v1::JobStatus lifted = status();
  EXPECT_EQ(lifted.stall(), "");
  EXPECT_EQ(lifted.blocklisted_workers_size(), 0);
  auto again = client_->leaseTask(lease);
  ASSERT_TRUE(again.ok()) << again.status();
  EXPECT_TRUE(again->has_task());
  // Nothing left to retry: an empty answer (the CLI exits 1 on it).
  auto empty = client_->retryJob(retry);
  ASSERT_TRUE(empty.ok()) << empty.status();
  EXPECT_EQ(empty->tasks() + empty->audits() + empty->unblocked_workers_size(), 0);
}

// Workers have a state from when they were last heard against a lease: busy with a task,
// online when idle, lost when they went silent holding a task, offline when they stopped idle.
TEST_F(CoordinatorTest, WorkersAreBusyOnlineLostOrOfflineFromWhenTheyWereLastHeard) {
  options_.leaseSeconds = 0.5;
  options_.expiryIntervalSeconds = 60;  // the lost worker's lease stays while this looks
  start();
  v1::SubmitJobRequest request = shotRequest({});
  request.add_frames(1);
  ASSERT_TRUE(client_->submitJob(request).ok());
  for (const char* id : {"busy-w", "idle-w"}) {
    v1::RegisterWorkerRequest r;
    r.set_worker(id);
    r.set_host("h");
    ASSERT_TRUE(client_->registerWorker(r).ok());
  }
  v1::LeaseTaskRequest lease;
  lease.set_worker("busy-w");
  auto leased = client_->leaseTask(lease);
  ASSERT_TRUE(leased.ok() && leased->has_task());
  const auto states = [&] {
    std::map<std::string, std::pair<std::string, std::string>> out;
    auto list = client_->listWorkers(v1::ListWorkersRequest());
    EXPECT_TRUE(list.ok()) << list.status();
    if (list.ok()) {
      for (const auto& w : list->workers()) out[w.worker()] = {w.state(), w.current()};
    }
    return out;
  };
  auto now = states();
  EXPECT_EQ(now["busy-w"].first, "busy");
  EXPECT_EQ(now["busy-w"].second, "job 1 frame 1 tile 0");
  EXPECT_EQ(now["idle-w"].first, "online");
  std::this_thread::sleep_for(std::chrono::milliseconds(800));  // past a lease, both silent
  now = states();
  EXPECT_EQ(now["busy-w"].first, "lost");
  EXPECT_EQ(now["idle-w"].first, "offline");
}

// When the lost worker's lease expires, the coordinator logs the task, the worker and when it
// was last heard, and the worker no longer shows the task: it went back to the queue.
TEST_F(CoordinatorTest, AnExpiredLeaseIsLoggedWithItsWorkerAndTaskAndLeavesTheLostWorker) {
  options_.leaseSeconds = 0.5;
  options_.expiryIntervalSeconds = 0.05;
  start();
  v1::SubmitJobRequest request = shotRequest({});
  request.add_frames(1);
  ASSERT_TRUE(client_->submitJob(request).ok());
  v1::RegisterWorkerRequest r;
  r.set_worker("gone-w");
  r.set_host("h");
  ASSERT_TRUE(client_->registerWorker(r).ok());
  v1::LeaseTaskRequest lease;
  lease.set_worker("gone-w");
  ::testing::internal::CaptureStdout();
  auto leased = client_->leaseTask(lease);
  ASSERT_TRUE(leased.ok() && leased->has_task());
  std::string state, current = "unset";
  const bool cleared = pbgi::testing::waitFor(
      [&] {
        auto list = client_->listWorkers(v1::ListWorkersRequest());
        if (!list.ok() || list->workers_size() != 1) return false;
        state = list->workers(0).state();
        current = list->workers(0).current();
        return current.empty();
      },
      10.0);
  std::this_thread::sleep_for(std::chrono::milliseconds(100));
  const std::string log = ::testing::internal::GetCapturedStdout();
  ASSERT_TRUE(cleared) << state << " " << current << "\n" << log;
  EXPECT_EQ(state, "lost");
  EXPECT_NE(log.find(fmt::format("lease expired: job 1 frame 1 tile 0 (task {}, attempt 1) on "
                                 "worker gone-w, last heard ",
                                 leased->task())),
            std::string::npos)
      << log;
  // Heard again, it is online (or busy, with the task back after its back-off).
  ASSERT_TRUE(client_->leaseTask(lease).ok());
  auto list = client_->listWorkers(v1::ListWorkersRequest());
  ASSERT_TRUE(list.ok() && list->workers_size() == 1);
  EXPECT_EQ(list->workers(0).state(), list->workers(0).current().empty() ? "online" : "busy");
}

// A shot whose geometry file exists but does not parse is refused at submission, naming the
// file, instead of failing on every worker until the job stalls.
TEST_F(CoordinatorTest, AShotWhoseGeometryCannotLoadIsRefusedAtSubmission) {
  start();
  v1::SubmitJobRequest request = shotRequest({});
  std::string text = request.shot_text();
  const std::string bad = (pbgi::testing::testDataDir() / "meshes/bad_face_index.obj").string();
  const size_t at = text.find("cornell_box.obj\"");
  ASSERT_NE(at, std::string::npos) << text;
  const size_t start = text.rfind('"', at) + 1;
  text.replace(start, at + std::string("cornell_box.obj").size() - start, bad);
  request.set_shot_text(text);
  const auto refused = client_->submitJob(request);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument) << refused.status();
  EXPECT_NE(refused.status().message().find("bad_face_index.obj"), std::string::npos)
      << refused.status();
  EXPECT_NE(refused.status().message().find("Invalid face index"), std::string::npos)
      << refused.status();
  auto jobs = coordinator_->store().jobs();
  ASSERT_TRUE(jobs.ok());
  EXPECT_TRUE(jobs->empty());
}

TEST_F(CoordinatorTest, AStaleAttemptCannotCompleteItsTask) {
  options_.leaseSeconds = 0.4;
  options_.expiryIntervalSeconds = 0.05;
  start();
  v1::SubmitJobRequest request = shotRequest({});
  request.add_frames(1);
  ASSERT_TRUE(client_->submitJob(request).ok());
  v1::LeaseTaskRequest asA;
  asA.set_worker("worker-a");
  auto first = client_->leaseTask(asA);
  ASSERT_TRUE(first.ok() && first->has_task()) << first.status();
  EXPECT_EQ(first->attempt(), 1);
  EXPECT_EQ(first->kind(), "tile");  // for v1 workers from before the enums
  EXPECT_EQ(first->task_kind(), v1::TASK_KIND_TILE);
  EXPECT_EQ(first->tile_size(), 32);
  EXPECT_EQ(first->tiles_per_frame(), 4);
  // worker-a goes silent; its lease expires and the tile goes to worker-b.
  v1::LeaseTaskRequest asB;
  asB.set_worker("worker-b");
  absl::StatusOr<v1::LeaseTaskResponse> second;
  ASSERT_TRUE(pbgi::testing::waitFor(
      [&] {
        second = client_->leaseTask(asB);
        return second.ok() && second->has_task() && second->task() == first->task();
      },
      10.0));
  EXPECT_EQ(second->attempt(), 2);
  v1::CompleteTaskRequest late;
  late.set_worker("worker-a");
  late.set_task(first->task());
  late.set_attempt(first->attempt());
  const auto rejected = client_->completeTask(late);
  EXPECT_EQ(rejected.status().code(), absl::StatusCode::kFailedPrecondition) << rejected.status();
  v1::HeartbeatRequest beat;
  beat.set_task(first->task());
  beat.set_attempt(first->attempt());
  auto lost = client_->heartbeat(beat);
  ASSERT_TRUE(lost.ok());
  EXPECT_FALSE(lost->keep_going());
  v1::CompleteTaskRequest current = late;
  current.set_worker("worker-b");
  current.set_attempt(second->attempt());
  current.set_seconds(1.5);
  EXPECT_TRUE(client_->completeTask(current).ok());
  const std::string text = metrics();
  EXPECT_NE(text.find("pbgi_stale_completions_total 1"), std::string::npos) << text;
  // worker-b's polling leased (and let expire) other tiles too: at least worker-a's expired.
  EXPECT_TRUE(std::regex_search(text, std::regex("pbgi_leases_expired_total [1-9]"))) << text;
  EXPECT_NE(text.find("pbgi_task_seconds_count{kind=\"tile\"} 1"), std::string::npos) << text;
  // The log says what happened, in order.
  v1::GetLogsRequest logs;
  logs.set_job(first->job());
  logs.set_tile(first->tile());
  auto entries = client_->getLogs(logs);
  ASSERT_TRUE(entries.ok());
  std::vector<std::string> events;
  for (const auto& e : entries->entries()) {
    events.push_back(wireWord(e.event_kind()) + "/" + e.worker());
    EXPECT_EQ(e.event(), wireWord(e.event_kind()));  // for v1 readers from before the enum
    EXPECT_EQ(e.task_kind(), v1::TASK_KIND_TILE);
    EXPECT_EQ(e.kind(), "tile");
  }
  EXPECT_EQ(events, (std::vector<std::string>{"leased/worker-a", "expired/worker-a",
                                              "leased/worker-b", "done/worker-b"}));
  ASSERT_EQ(entries->entries_size(), 4);
  EXPECT_EQ(entries->entries(1).event_kind(), v1::TASK_EVENT_KIND_EXPIRED);
}

// A stored event word this coordinator does not know (a newer coordinator's, sharing the
// database) reaches the reader as that word without an enum; the call still answers.
TEST_F(CoordinatorTest, ALogEventOfAKindThisCoordinatorDoesNotKnowIsSentAsItsWord) {
  start();
  v1::SubmitJobRequest request = shotRequest({});
  request.add_frames(1);
  auto id = client_->submitJob(request);
  ASSERT_TRUE(id.ok()) << id.status();
  v1::LeaseTaskRequest asA;
  asA.set_worker("worker-a");
  auto first = client_->leaseTask(asA);
  ASSERT_TRUE(first.ok() && first->has_task()) << first.status();
  {
    sqlite3* raw = nullptr;
    const std::string path = (fs::path(options_.stateDir) / "jobs.db").string();
    ASSERT_EQ(sqlite3_open(path.c_str(), &raw), SQLITE_OK) << path;
    std::unique_ptr<sqlite3, decltype(&sqlite3_close)> db(raw, &sqlite3_close);
    sqlite3_busy_timeout(db.get(), 10'000);
    ASSERT_EQ(sqlite3_exec(db.get(), "UPDATE task_events SET event = 'paused'", nullptr, nullptr,
                           nullptr),
              SQLITE_OK)
        << sqlite3_errmsg(db.get());
  }
  auto second = client_->leaseTask(asA);
  ASSERT_TRUE(second.ok() && second->has_task()) << second.status();

  v1::GetLogsRequest logs;
  logs.set_job(id->job());
  auto entries = client_->getLogs(logs);
  ASSERT_TRUE(entries.ok()) << entries.status();
  ASSERT_EQ(entries->entries_size(), 2);
  const v1::LogEntry& unknown = entries->entries(0);
  EXPECT_EQ(unknown.event(), "paused");
  EXPECT_EQ(unknown.event_kind(), v1::TASK_EVENT_KIND_UNSPECIFIED);
  EXPECT_EQ(taskEventKindOf(unknown), v1::TASK_EVENT_KIND_UNSPECIFIED);
  EXPECT_EQ(unknown.worker(), "worker-a");
  const v1::LogEntry& known = entries->entries(1);
  EXPECT_EQ(known.event_kind(), v1::TASK_EVENT_KIND_LEASED);
  EXPECT_EQ(known.event(), "leased");
}

TEST_F(CoordinatorTest, ACompletionThatAsksForTheNextTaskGetsItInTheSameCallUnlessRefused) {
  start();
  v1::SubmitJobRequest request = shotRequest({});
  request.add_frames(1);  // 4 tiles and the assemble
  ASSERT_TRUE(client_->submitJob(request).ok());
  v1::LeaseTaskRequest ask;
  ask.set_worker("worker-a");
  auto lease = client_->leaseTask(ask);
  ASSERT_TRUE(lease.ok() && lease->has_task()) << lease.status();
  std::vector<int> tiles{lease->tile()};
  // Each completion brings the next tile, then the assemble the last tile released, then an
  // answer that there is nothing left.
  for (int step = 0; step < 5; ++step) {
    v1::CompleteTaskRequest done;
    done.set_worker(ask.worker());
    done.set_task(lease->task());
    done.set_attempt(lease->attempt());
    *done.mutable_next() = ask;
    auto answer = client_->completeTask(done);
    ASSERT_TRUE(answer.ok()) << answer.status();
    ASSERT_TRUE(answer->has_next());
    if (step == 4) {
      EXPECT_FALSE(answer->next().has_task());
      break;
    }
    ASSERT_TRUE(answer->next().has_task()) << step;
    EXPECT_EQ(answer->next().attempt(), 1);
    if (step < 3) {
      EXPECT_EQ(answer->next().task_kind(), v1::TASK_KIND_TILE);
      tiles.push_back(answer->next().tile());
    } else {
      EXPECT_EQ(answer->next().task_kind(), v1::TASK_KIND_ASSEMBLE);
    }
    lease = answer->next();
  }
  EXPECT_EQ(tiles, (std::vector<int>{0, 1, 2, 3}));
  // A completion that is refused (here, of a task already done) leases nothing: the worker asks
  // again with LeaseTask, and no task is left leased to it in the meantime.
  v1::CompleteTaskRequest again;
  again.set_worker(ask.worker());
  again.set_task(lease->task());
  again.set_attempt(lease->attempt());
  *again.mutable_next() = ask;
  EXPECT_EQ(client_->completeTask(again).status().code(), absl::StatusCode::kFailedPrecondition);
  auto status = client_->getStatus(v1::GetStatusRequest());
  ASSERT_TRUE(status.ok());
  ASSERT_EQ(status->jobs_size(), 1);
  EXPECT_EQ(status->jobs(0).state(), "done");
  // 4 tiles and the assemble: the refused completion leased nothing.
  EXPECT_NE(metrics().find("pbgi_leases_total 5"), std::string::npos) << metrics();
}

TEST_F(CoordinatorTest, StatusJsonAndMetricsAreServedOverHttp) {
  start();
  ASSERT_TRUE(client_->submitJob(shotRequest({})).ok());
  httplib::Client http("http://" + coordinator_->httpAddress());
  auto status = http.Get("/status");
  ASSERT_TRUE(status);
  EXPECT_EQ(status->status, 200);
  EXPECT_NE(status->body.find("\"tilesPerFrame\":4"), std::string::npos) << status->body;
  // States both ways: the enum, and v1's word.
  EXPECT_NE(status->body.find("\"jobState\":\"JOB_STATE_ACTIVE\""), std::string::npos)
      << status->body;
  EXPECT_NE(status->body.find("\"state\":\"active\""), std::string::npos) << status->body;
  EXPECT_NE(status->body.find("{\"state\":\"TASK_STATE_READY\",\"count\":8}"), std::string::npos)
      << status->body;
  const std::string text = metrics();
  EXPECT_NE(text.find("pbgi_tasks{state=\"ready\"} 8"), std::string::npos) << text;
  EXPECT_NE(text.find("pbgi_tasks{state=\"blocked\"} 2"), std::string::npos) << text;
  EXPECT_NE(text.find("pbgi_jobs{state=\"active\"} 1"), std::string::npos) << text;
  EXPECT_NE(text.find("# TYPE pbgi_task_seconds histogram"), std::string::npos) << text;
  // Every metric the README and dashboards name, each declared once with its type.
  for (const char* counter :
       {"pbgi_leases_total", "pbgi_task_failures_total", "pbgi_leases_expired_total",
        "pbgi_stale_completions_total", "pbgi_rpc_refused_total",
        "pbgi_tls_handshake_failures_total", "pbgi_page_cache_hits_total",
        "pbgi_page_cache_misses_total", "pbgi_trees_opened_total", "pbgi_tree_pages_served_total",
        "pbgi_tree_bytes_served_total", "pbgi_tree_bytes_streamed_total"}) {
    EXPECT_NE(text.find(fmt::format("# TYPE {} counter\n{} ", counter, counter)), std::string::npos)
        << counter << "\n"
        << text;
  }
  for (const char* gauge : {"pbgi_tasks", "pbgi_jobs", "pbgi_page_cache_hit_rate"}) {
    EXPECT_NE(text.find(fmt::format("# TYPE {} gauge\n", gauge)), std::string::npos) << gauge;
  }
}

// The page service: a frame's tree opened, single pages sent as stored; a page damaged on the
// coordinator's disk named as such; a worker holding an older tree of the frame refused.
TEST_F(CoordinatorTest, ThePageServiceSendsSinglePagesAndNamesDamage) {
  start();
  pbgi::testing::SmallShot pbgiShot;
  pbgiShot.integrator = "pbgi";
  pbgiShot.extraRender = "bake_points = 4000\nbake_bounces = 0\n";
  v1::SubmitJobRequest request = shotRequest(pbgiShot);
  request.add_frames(1);
  auto job = client_->submitJob(request);
  ASSERT_TRUE(job.ok()) << job.status();
  // The bake task's work, done here: the tree lands where the page service looks.
  auto shot = jobShot(request.shot_text(), request.shot_path(), {});
  ASSERT_TRUE(shot.ok()) << shot.status();
  auto bake = shotBakeRequest(*shot, 1);
  ASSERT_TRUE(bake.ok());
  bake->outDir = jobBakeDir(jobWorkDir(options_.stateDir, job->job()));
  auto baked = bakeShotFrame(*shot, *bake);
  ASSERT_TRUE(baked.ok()) << baked.status();
  auto local = PageFileReader::open(baked->treePath);
  ASSERT_TRUE(local.ok()) << local.status();
  const uint32_t pages = (*local)->info().pageCount;
  ASSERT_GE(pages, 2u);

  auto fetcher = std::make_shared<FarmPageFetcher>(*client_, job->job(), 1);
  auto stats = std::make_shared<RemoteFetchStats>();
  auto head = fetcher->head();
  ASSERT_TRUE(head.ok()) << head.status();
  EXPECT_EQ(head->treeId(), (*local)->head().treeId());
  auto remote = PageFileReader::open(openRemotePageFile(*head, fetcher, nullptr, stats));
  ASSERT_TRUE(remote.ok()) << remote.status();
  for (uint32_t id = 0; id < pages; ++id) {
    auto page = (*remote)->readPage(id);
    ASSERT_TRUE(page.ok()) << page.status();
    EXPECT_EQ(*page, *(*local)->readPage(id)) << "page " << id;
  }
  EXPECT_EQ(stats->pagesFetched.load(), pages);
  EXPECT_NE(metrics().find(fmt::format("pbgi_tree_pages_served_total {}", pages)),
            std::string::npos);

  // A byte of page 1 damaged on the coordinator's disk.
  {
    std::fstream f(baked->treePath, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(static_cast<std::streamoff>((*local)->directory()[1].offset + 3));
    f.put('\x77');
  }
  auto again = PageFileReader::open(openRemotePageFile(*head, fetcher, nullptr, nullptr));
  ASSERT_TRUE(again.ok());
  auto damaged = (*again)->readPage(1);
  ASSERT_FALSE(damaged.ok());
  EXPECT_TRUE(absl::IsDataLoss(damaged.status())) << damaged.status();
  for (const char* part : {"page service of job", "page 1", "checksum mismatch"}) {
    EXPECT_NE(damaged.status().message().find(part), std::string::npos) << damaged.status();
  }
  // The frame's tree replaced (baked again): pages of the old one are refused.
  {
    auto writer = PageFileWriter::create(baked->treePath);
    ASSERT_TRUE(writer.ok());
    ASSERT_TRUE(writer->appendPage(std::vector<uint8_t>(100, 1)).ok());
    ASSERT_TRUE(writer->finish({}).ok());
  }
  const uint32_t first[1] = {0};
  auto stale = client_->fetchPages(job->job(), 1, head->treeId(), first);
  EXPECT_TRUE(absl::IsFailedPrecondition(stale.status())) << stale.status();
  EXPECT_NE(stale.status().message().find("baked again"), std::string::npos) << stale.status();
}

}  // namespace
}  // namespace pbgi::farm
