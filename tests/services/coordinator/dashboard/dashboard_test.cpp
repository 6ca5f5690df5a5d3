// The dashboard's HTTP API on a real coordinator (dashboard_browser.test.mjs,
// beside this file, drives the page itself in Chromium): what it says about jobs and
// tasks, who may change a job, how bad requests are answered, and that its event stream
// speaks as soon as something changes.

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <httplib.h>

#include <chrono>
#include <future>
#include <optional>
#include <thread>

#include "services/coordinator/dashboard/dashboard.h"
#include "services/farm/job_rules.h"
#include "tests/support/coordinator_fixture.h"

namespace pbgi::farm {
namespace {

using pbgi::testing::CoordinatorTest;

class DashboardTest : public CoordinatorTest {
 protected:
  httplib::Client http() { return httplib::Client("http://" + coordinator_->httpAddress()); }
  int64_t submitSmall() {
    auto id = client_->submitJob(shotRequest({}));
    EXPECT_TRUE(id.ok()) << id.status();
    return id.ok() ? id->job() : 0;
  }
};

TEST_F(DashboardTest, ThePageAndItsFilesAreServedFromTheBinary) {
  start();
  auto c = http();
  auto page = c.Get("/");
  ASSERT_TRUE(page);
  EXPECT_EQ(page->status, 200);
  EXPECT_NE(page->get_header_value("Content-Type").find("text/html"), std::string::npos);
  EXPECT_NE(page->body.find("<title>pbgi farm</title>"), std::string::npos);
  for (const char* file : {"/dashboard.js", "/dashboard.css"}) {
    auto res = c.Get(file);
    ASSERT_TRUE(res) << file;
    EXPECT_EQ(res->status, 200) << file;
    EXPECT_GT(res->body.size(), 1000u) << file;
  }
}

TEST_F(DashboardTest, AJobsFramesAreOneStateStringEachWithTheirTilesPlaces) {
  start();
  const int64_t job = submitSmall();  // 64x64 in tiles of 32: 4 tiles, frames 1 and 2
  auto c = http();
  auto list = c.Get("/api/jobs");
  ASSERT_TRUE(list);
  EXPECT_EQ(list->status, 200);
  // Active in the store; no worker has called, so the list says it waits for one.
  EXPECT_NE(
      list->body.find(fmt::format("\"id\":{},\"name\":\"cornell\",\"state\":\"waiting\"", job)),
      std::string::npos)
      << list->body;
  auto detail = c.Get(fmt::format("/api/jobs/{}", job));
  ASSERT_TRUE(detail);
  ASSERT_EQ(detail->status, 200) << detail->body;
  EXPECT_NE(detail->body.find("\"cols\":2,\"rows\":2,\"cells\":[0,0,1,0,0,1,1,1]"),
            std::string::npos)
      << detail->body;
  // Every tile ready ('1'); no bake (path tracing); the assemble waits (blocked, '0').
  EXPECT_NE(detail->body.find("{\"frame\":1,\"bake\":null,\"assemble\":\"0\",\"tiles\":\"1111\""),
            std::string::npos)
      << detail->body;

  // A lease shows as the tile's state and in the leased list, and its history.
  v1::LeaseTaskRequest lease;
  lease.set_worker("w-test");
  auto leased = client_->leaseTask(lease);
  ASSERT_TRUE(leased.ok() && leased->has_task()) << leased.status();
  detail = c.Get(fmt::format("/api/jobs/{}", job));
  ASSERT_TRUE(detail);
  EXPECT_NE(detail->body.find("\"tiles\":\"2111\""), std::string::npos) << detail->body;
  EXPECT_NE(detail->body.find("\"worker\":\"w-test\""), std::string::npos) << detail->body;
  auto task = c.Get(fmt::format("/api/jobs/{}/task?frame={}&tile={}", job, leased->frame(),
                                leased->tile()));
  ASSERT_TRUE(task);
  EXPECT_EQ(task->status, 200) << task->body;
  EXPECT_NE(task->body.find("\"event\":\"leased\""), std::string::npos) << task->body;

  // What a worker says comes back as JSON whatever it holds: quotes, backslashes, line breaks,
  // control characters.
  const std::string error = std::string("a \"quoted\" \\ path\nnext\ttab\x01 caf\xc3\xa9");
  v1::FailTaskRequest fail;
  fail.set_worker("w-test");
  fail.set_task(leased->task());
  fail.set_attempt(leased->attempt());
  fail.set_error(error);
  ASSERT_TRUE(client_->failTask(fail).ok());
  task = c.Get(
      fmt::format("/api/jobs/{}/task?frame={}&tile={}", job, leased->frame(), leased->tile()));
  ASSERT_TRUE(task);
  ASSERT_EQ(task->status, 200) << task->body;
  const nlohmann::json parsed = nlohmann::json::parse(task->body);
  EXPECT_EQ(parsed.at("task").at("error").get<std::string>(), error) << task->body;
}

// The ETA comes from the finished tasks' durations, not from the time since submission: a job
// of uniform tiles (each reported at 2 s) keeps its predicted end, elapsed plus ETA, within 20 %
// from its first finished tile to its last, whatever the clock says in between.
TEST_F(DashboardTest, TheEtaOfAJobOfUniformTilesHoldsItsPredictedEnd) {
  start();
  v1::SubmitJobRequest request = shotRequest({});
  request.add_frames(1);  // 4 tiles and an assemble
  ASSERT_TRUE(client_->submitJob(request).ok());
  auto c = http();
  const auto eta = [&]() -> std::optional<double> {
    auto list = c.Get("/api/jobs");
    if (!list || list->status != 200) return std::nullopt;
    const auto jobs = nlohmann::json::parse(list->body);
    const auto& e = jobs["jobs"][0]["eta"];
    return e.is_null() ? std::nullopt : std::optional<double>(e.get<double>());
  };
  EXPECT_FALSE(eta()) << "no task has finished: nothing to go on";
  v1::LeaseTaskRequest lease;
  lease.set_worker("w");
  std::vector<double> predicted;
  double elapsed = 0;
  for (int t = 0; t < 4; ++t) {
    auto leased = client_->leaseTask(lease);
    ASSERT_TRUE(leased.ok() && leased->has_task()) << leased.status();
    // The coordinator's clock runs a few milliseconds; the tiles "took" 2 s each.
    v1::CompleteTaskRequest done;
    done.set_worker("w");
    done.set_task(leased->task());
    done.set_attempt(leased->attempt());
    done.set_seconds(2.0);
    ASSERT_TRUE(client_->completeTask(done).ok());
    elapsed += 2.0;
    const std::optional<double> left = eta();
    ASSERT_TRUE(left) << "after tile " << t;
    predicted.push_back(elapsed + *left);
  }
  for (const double p : predicted) {
    EXPECT_NEAR(p, predicted.front(), 0.2 * predicted.front())
        << "predicted ends: " << ::testing::PrintToString(predicted);
  }
  EXPECT_NEAR(predicted.front(), 10.0, 1e-9) << "4 tiles and an assemble at 2 s each";
}

TEST_F(DashboardTest, PbgiJobsAreAuditedByDefaultPathTracedOnesAreNotAndBadAuditsAreRefused) {
  start();
  pbgi::testing::SmallShot pbgi;
  pbgi.integrator = "pbgi";
  const int64_t audited = client_->submitJob(shotRequest(pbgi))->job();
  const int64_t plain = submitSmall();  // the path tracer: its own reference
  auto a = coordinator_->store().audits(audited);
  ASSERT_TRUE(a.ok()) << a.status();
  ASSERT_EQ(a->size(), 2u);  // frames 1 and 2
  EXPECT_EQ((*a)[0].spec.tiles, chooseAuditTiles("cornell", 1, 4, 2));
  EXPECT_EQ((*a)[0].spec.spp, kDefaultAuditSpp);
  EXPECT_EQ(coordinator_->store().audits(plain)->size(), 0u);
  auto detail = http().Get(fmt::format("/api/jobs/{}", audited));
  ASSERT_TRUE(detail);
  EXPECT_NE(detail->body.find("\"audit\":{\"state\":\"ready\""), std::string::npos)
      << detail->body;
  v1::SubmitJobRequest bad = shotRequest(pbgi);
  bad.set_audit_threshold(-1);
  EXPECT_EQ(client_->submitJob(bad).status().code(), absl::StatusCode::kInvalidArgument);
  bad = shotRequest({});
  bad.set_audit_tiles(1);
  bad.set_audit_spp(-4);
  EXPECT_EQ(client_->submitJob(bad).status().code(), absl::StatusCode::kInvalidArgument);
}

TEST_F(DashboardTest, ChangingAJobNeedsTheFarmTokenAndRefusalsAreCounted) {
  start();
  const int64_t job = submitSmall();
  auto c = http();
  const std::string cancel = fmt::format("/api/jobs/{}/cancel", job);
  auto refused = c.Post(cancel, "", "text/plain");
  ASSERT_TRUE(refused);
  EXPECT_EQ(refused->status, 401);
  EXPECT_NE(refused->body.find("farm token"), std::string::npos) << refused->body;
  auto wrong = c.Post(cancel, {{"Authorization", "Bearer not-it"}}, "", "text/plain");
  ASSERT_TRUE(wrong);
  EXPECT_EQ(wrong->status, 401);
  EXPECT_NE(metrics().find("pbgi_rpc_refused_total 2"), std::string::npos) << metrics();
  auto status = coordinator_->store().job(job);
  ASSERT_TRUE(status.ok());
  EXPECT_EQ(status->state, JobState::kActive);

  const httplib::Headers bearer = {{"Authorization", "Bearer " + options_.token}};
  auto done = c.Post(cancel, bearer, "", "text/plain");
  ASSERT_TRUE(done);
  EXPECT_EQ(done->status, 200) << done->body;
  EXPECT_EQ(coordinator_->store().job(job)->state, JobState::kCancelled);
  auto retried = c.Post(fmt::format("/api/jobs/{}/retry?frame=1&tile=2", job), bearer, "",
                        "text/plain");
  ASSERT_TRUE(retried);
  EXPECT_EQ(retried->status, 200) << retried->body;
  EXPECT_EQ(coordinator_->store().job(job)->state, JobState::kActive);
}

TEST_F(DashboardTest, BadRequestsGetAReasonNotACrash) {
  start();
  const int64_t job = submitSmall();
  auto c = http();
  const httplib::Headers bearer = {{"Authorization", "Bearer " + options_.token}};
  struct Case {
    std::string path;
    int status;
    std::string says;
  };
  for (const Case& k : std::vector<Case>{
           {"/api/jobs/999", 404, "999"},
           {fmt::format("/api/jobs/{}/task?frame=1&tile=99", job), 404, "no tile task"},
           {fmt::format("/api/jobs/{}/task?tile=1", job), 400, "needs its frame"},
           {fmt::format("/api/jobs/{}/task?frame=one", job), 400, "frame=one"},
           {fmt::format("/api/jobs/{}/frames/1/preview.png", job), 404, "no tile"},
           {fmt::format("/api/jobs/{}/frames/1/tiles/0.png", job), 404, "tile.0000.exr"},
       }) {
    auto res = c.Get(k.path);
    ASSERT_TRUE(res) << k.path;
    EXPECT_EQ(res->status, k.status) << k.path << ": " << res->body;
    EXPECT_NE(res->body.find(k.says), std::string::npos) << k.path << ": " << res->body;
  }
  auto bad = c.Post(fmt::format("/api/jobs/{}/retry?tile=3", job), bearer, "", "text/plain");
  ASSERT_TRUE(bad);
  EXPECT_EQ(bad->status, 400) << bad->body;
  auto unknown = c.Post("/api/jobs/999/cancel", bearer, "", "text/plain");
  ASSERT_TRUE(unknown);
  EXPECT_EQ(unknown->status, 404) << unknown->body;
  // Still serving.
  auto list = c.Get("/api/jobs");
  ASSERT_TRUE(list);
  EXPECT_EQ(list->status, 200);
}

TEST_F(DashboardTest, TheEventStreamSpeaksWhenAJobChanges) {
  start();
  // A stream, read on a thread: its first event at once, the next after the submission.
  std::promise<void> first, second;
  std::atomic<int> events{0};
  std::atomic<bool> stop{false};
  std::thread reader([&] {
    auto c = http();
    c.set_read_timeout(10, 0);
    c.Get("/api/events", [&](const char* data, size_t size) {
      const std::string chunk(data, size);
      for (size_t at = chunk.find("data: "); at != std::string::npos;
           at = chunk.find("data: ", at + 1)) {
        const int n = ++events;
        if (n == 1) first.set_value();
        if (n == 2) second.set_value();
      }
      return !stop.load();
    });
  });
  ASSERT_EQ(first.get_future().wait_for(std::chrono::seconds(10)), std::future_status::ready);
  const auto before = std::chrono::steady_clock::now();
  submitSmall();
  const bool heard =
      second.get_future().wait_for(std::chrono::seconds(10)) == std::future_status::ready;
  const double ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() -
                                                              before).count();
  stop = true;
  coordinator_->shutdown();  // ends the stream
  reader.join();
  EXPECT_TRUE(heard) << "no event within 10 s of a submission";
  RecordProperty("event_after_submit_ms", std::to_string(ms));
}

}  // namespace
}  // namespace pbgi::farm
