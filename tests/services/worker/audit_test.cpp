// The accuracy audit through a real worker: a PBGI job's frames are audited by the worker once
// nothing else is ready (never before a frame's own task), against the path tracer, and the
// job reports relMSE and bias per frame.

#include <gtest/gtest.h>

#include <cmath>
#include <regex>

#include "tests/support/worker_farm.h"

namespace pbgi::farm {
namespace {

using pbgi::testing::WorkerFarmTest;

class AuditTest : public WorkerFarmTest {};

TEST_F(AuditTest, IdleWorkersAuditEachFrameAfterEveryFramesTasksAndReportRelMseAndBias) {
  start();
  pbgi::testing::SmallShot shot;  // 64x64 in tiles of 32: 4 tiles a frame
  shot.integrator = "pbgi";
  shot.lastFrame = 2;
  shot.spp = 16;
  shot.extraRender = "bake_points = 8000\nbake_bounces = 1\n";
  shotPath_ = pbgi::testing::writeSmallShot(dir_, shot);
  v1::SubmitJobRequest request;
  request.set_shot_path(shotPath_.string());
  request.set_shot_text(pbgi::testing::slurpFile(shotPath_));
  request.set_audit_tiles(2);
  request.set_audit_spp(64);
  request.set_audit_threshold(0.5);
  auto submitted = client_->submitJob(request);
  ASSERT_TRUE(submitted.ok()) << submitted.status();
  const int64_t job = submitted->job();
  // One worker: when frame 1 is assembled, frame 2's tasks are still to do, and come first.
  startWorker("w1");
  const auto audited = [&] {
    auto s = jobStatus(job);
    if (!s.ok() || s->audits_size() != 2) return false;
    for (const v1::FrameAudit& a : s->audits()) {
      if (!a.has_result() && a.state() != "failed") return false;
    }
    return true;
  };
  ASSERT_TRUE(pbgi::testing::waitFor(audited, 180.0)) << workerLogs();
  auto s = jobStatus(job);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->state(), "done");
  for (const v1::FrameAudit& a : s->audits()) {
    SCOPED_TRACE(a.DebugString());
    ASSERT_TRUE(a.has_result());
    EXPECT_EQ(a.state(), "done");
    EXPECT_EQ(a.tiles_size(), 2);
    EXPECT_EQ(a.spp(), 64);
    // A 16-spp PBGI frame against 64-spp path tracing: near, and not exactly equal.
    EXPECT_TRUE(std::isfinite(a.rel_mse()) && a.rel_mse() > 0.0 && a.rel_mse() < 0.5);
    EXPECT_LT(std::abs(a.bias()), 0.25);
    EXPECT_FALSE(a.flagged());
  }
  // The worker's order of work: no audit before the last of the job's own tasks.
  const std::string log = workerLogs();
  const size_t firstAudit = log.find(" audit task=");
  const size_t lastTask = std::max(log.rfind(" assemble task="), log.rfind(" tile=3 task="));
  ASSERT_NE(firstAudit, std::string::npos) << log;
  ASSERT_NE(lastTask, std::string::npos) << log;
  EXPECT_GT(firstAudit, lastTask) << log;
}

}  // namespace
}  // namespace pbgi::farm
