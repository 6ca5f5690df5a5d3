// The numerical-stability suite's hostile scenes (tests/support/stress_scenes.h) as farm jobs:
// an in-process coordinator and one real pbgi-worker process render each with PBGI (a bake
// task, four tiles, an assemble) through both gathers. Every job of a scene that renders ends
// done, its frame bit for bit the frame `pbgi render` makes in this process with no NaN or Inf
// pixel, the loader's drops and the tiles' discards in the task logs, and its accuracy audit
// done with a finite relMSE. A scene that must be refused fails with its bake dead, the error
// naming the file. The one worker process survives every job, and then renders a plain room.

#include <gtest/gtest.h>

#include <cmath>
#include <fstream>
#include <map>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "formats/image/image_io.h"
#include "formats/shot/shot_file.h"
#include "services/farm/job_rules.h"
#include "tests/support/stress_scenes.h"
#include "tests/support/worker_farm.h"

namespace pbgi::farm {
namespace {

namespace fs = std::filesystem;
using pbgi::testing::StressCase;
using pbgi::testing::waitFor;

class StabilityFarmTest : public pbgi::testing::WorkerFarmTest {
 protected:
  struct Submitted {
    std::string what;  // the case and the gather, for messages
    fs::path shot;
    int64_t job = 0;
  };

  // Writes the case into a folder of its own under the farm's output root and submits it with
  // one audited tile at 16 spp (a few hundred milliseconds of path tracing). A case whose
  // geometry the coordinator refuses at submission is submitted with a plain room, and its
  // geometry written after: a file edited under a job, which the worker meets instead.
  Submitted submitCase(const StressCase& c, const std::string& gather,
                       bool geometryAfterSubmission = false) {
    Submitted s;
    s.what = c.name + " / " + gather;
    const fs::path dir = dir_ / fmt::format("case-{}", submitted_++);
    fs::create_directories(dir);
    StressCase submitted = c;
    if (geometryAfterSubmission) submitted.obj = pbgi::testing::roomObj(1.0);
    s.shot = pbgi::testing::writeStressShot(dir, submitted, "pbgi", gather);
    // The case's name in its shot's bytes: the rooms of scale 1 have the same shot text and
    // differ only in their OBJ, which a bake's hash does not cover, so that the renders in this
    // process (all baked into one folder) would take one case's tree for another's.
    std::ofstream(s.shot, std::ios::app) << fmt::format("# {}\n", s.what);
    v1::SubmitJobRequest request;
    request.set_shot_path(s.shot.string());
    request.set_shot_text(pbgi::testing::slurpFile(s.shot));
    request.set_audit_tiles(1);
    request.set_audit_spp(16);
    auto id = client_->submitJob(request);
    EXPECT_TRUE(id.ok()) << s.what << ": " << id.status();
    s.job = id.ok() ? id->job() : 0;
    if (geometryAfterSubmission) {
      std::ofstream(dir / "scene.obj", std::ios::trunc) << c.obj;
      // Submitted as it is now, the coordinator refuses it, naming the file.
      auto refused = client_->submitJob(request);
      EXPECT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument)
          << s.what << ": " << refused.status();
      EXPECT_NE(refused.status().message().find((dir / "scene.obj").string()), std::string::npos)
          << refused.status();
    }
    return s;
  }

  // Settled, and its audit too when it is done.
  bool finished(int64_t job) {
    auto s = jobStatus(job);
    if (!s.ok() || s->state() == "active") return false;
    if (s->state() != "done") return true;
    for (const v1::FrameAudit& a : s->audits()) {
      if (!a.has_result() && a.state() != "failed") return false;
    }
    return true;
  }

  // Done, the same frame as `pbgi render` makes, no non-finite pixel, every tile's discards
  // in its log, the audit a finite measurement; the task logs, joined.
  std::string expectRendered(const Submitted& s) {
    SCOPED_TRACE(s.what);
    auto status = jobStatus(s.job);
    EXPECT_TRUE(status.ok()) << status.status();
    if (!status.ok()) return {};
    EXPECT_EQ(status->state(), "done") << status->DebugString() << workerLogs();
    if (status->state() != "done") return {};
    shotPath_ = s.shot;
    expectFrameEqualsWholeRender(1);
    auto shot = loadShotFile(s.shot.string());
    EXPECT_TRUE(shot.ok()) << shot.status();
    if (!shot.ok()) return {};
    auto image = readImage(outputPathForFrame(shot->output, 1, false));
    EXPECT_TRUE(image.ok()) << image.status();
    if (image.ok()) {
      int nonFinite = 0;
      for (const float v : image->pixels()) nonFinite += !std::isfinite(v);
      EXPECT_EQ(nonFinite, 0);
    }
    EXPECT_EQ(status->audits_size(), 1);
    for (const v1::FrameAudit& a : status->audits()) {
      EXPECT_EQ(a.state(), "done") << a.DebugString();
      EXPECT_TRUE(a.has_result() && std::isfinite(a.rel_mse()) && std::isfinite(a.bias()))
          << a.DebugString();
    }
    auto events = coordinator_->store().events(s.job, std::nullopt, std::nullopt);
    EXPECT_TRUE(events.ok()) << events.status();
    if (!events.ok()) return {};
    std::string logs;
    int tiles = 0, counted = 0;
    for (const TaskEvent& e : *events) {
      if (e.event != "done") continue;
      logs += e.text;
      if (e.ref.kind == TaskKind::kTile) {
        ++tiles;
        counted += e.text.find("discarded (NaN/Inf) ") != std::string::npos;
      }
    }
    EXPECT_EQ(tiles, status->tiles_per_frame());
    EXPECT_EQ(counted, tiles) << logs;
    return logs;
  }

  // Failed, its bake dead with an error that names the geometry file; the frame never written.
  void expectRefused(const Submitted& s) {
    SCOPED_TRACE(s.what);
    auto status = jobStatus(s.job);
    ASSERT_TRUE(status.ok()) << status.status();
    EXPECT_EQ(status->state(), "failed") << status->DebugString();
    ASSERT_GE(status->dead_size(), 1) << status->DebugString();
    EXPECT_EQ(status->dead(0).kind(), "bake");
    const std::string obj = (s.shot.parent_path() / "scene.obj").string();
    EXPECT_NE(status->dead(0).last_error().find(obj), std::string::npos)
        << status->dead(0).last_error();
    auto shot = loadShotFile(s.shot.string());
    ASSERT_TRUE(shot.ok()) << shot.status();
    EXPECT_FALSE(fs::exists(outputPathForFrame(shot->output, 1, false)));
  }

  int submitted_ = 0;
};

TEST_F(StabilityFarmTest, HostileScenesRenderAsInProcessOrAreRefusedByNameAndTheWorkerSurvives) {
  options_.tileSize = 16;  // four tiles of a 32 x 32 frame
  options_.retry.maxAttempts = 2;
  start();
  // Fewer surfels and samples than the in-process suite: what is compared here is the farm's
  // frame against the same render in this process, not PBGI against the path tracer.
  // Fewer surfels and samples than the in-process suite: what is compared here is the farm's
  // frame with the same render in this process, not PBGI with the path tracer.
  const auto scene = [](const std::string& name, const std::string& obj, double scale = 1.0,
                        const std::string& lights = {}) {
    return StressCase{
        .name = name, .scale = scale, .obj = obj, .lights = lights, .bakePoints = 2000, .spp = 4};
  };
  using pbgi::testing::kHostileTriangles;
  using pbgi::testing::roomObj;
  std::vector<Submitted> good, bad;
  for (const StressCase& c : {
           scene("hostile triangles", roomObj(1.0, kHostileTriangles)),
           scene("room at scale 1e-06", roomObj(1e-6), 1e-6),
           scene("room at scale 1e+06", roomObj(1e6), 1e6),
           scene("a million times brighter", roomObj(1.0), 1.0,
                 pbgi::testing::millionTimesBrighterLights()),
       }) {
    for (const char* gather : {"bidirectional", "per-pixel"}) good.push_back(submitCase(c, gather));
  }
  // What the hostile triangles leave by themselves: the sliver and the triangle of NaN
  // normals, a few surfels' worth of area under the room's light.
  good.push_back(submitCase(
      scene("hostile triangles alone", std::string("mtllib none.mtl\n") + kHostileTriangles),
      "bidirectional"));
  // Nothing to render: no faces at all; NaN, Inf, collinear and one-point triangles only.
  const std::string unusable =
      "mtllib none.mtl\nusemtl white\n"
      "v nan 0 0\nv 0 1 0\nv 0 0 1\nf -3 -2 -1\n"
      "v inf 0 0\nv 0 -inf 0\nv 0 0 1\nf -3 -2 -1\n"
      "v 0 0 0\nv 0.5 0.5 0.5\nv 1 1 1\nf -3 -2 -1\n"
      "v 0.2 0.2 0.2\nf -1 -1 -1\n";
  bad.push_back(submitCase(scene("empty scene", "# vertices, no faces\nv 0 0 0\nv 1 0 0\n"),
                           "bidirectional", true));
  bad.push_back(submitCase(scene("no usable triangle", unusable), "bidirectional", true));
  pbgi::testing::Process& worker = startWorker("w1");
  const auto all = [&] {
    for (const auto* list : {&good, &bad}) {
      for (const Submitted& s : *list) {
        if (!finished(s.job)) return false;
      }
    }
    return true;
  };
  ASSERT_TRUE(waitFor(all, 120.0)) << workerLogs();
  for (const Submitted& s : good) {
    const std::string logs = expectRendered(s);
    if (s.what.starts_with("hostile triangles")) {
      // The bake's scene load said what it dropped.
      EXPECT_NE(logs.find(pbgi::testing::kHostileTrianglesDropped), std::string::npos) << logs;
    }
  }
  for (const Submitted& s : bad) expectRefused(s);
  EXPECT_EQ(worker.wait(0.0), -1) << "the worker exited:\n" << worker.log();

  // The same worker process, after every bad job: a plain room still renders.
  const Submitted plain = submitCase(scene("plain room", roomObj(1.0)), "bidirectional");
  ASSERT_TRUE(waitFor([&] { return finished(plain.job); }, 60.0)) << workerLogs();
  expectRendered(plain);
  auto status = jobStatus(plain.job);
  ASSERT_TRUE(status.ok());
  for (const v1::TaskStatus& t : status->tasks()) EXPECT_EQ(t.worker(), "w1");
  EXPECT_EQ(worker.wait(0.0), -1) << "the worker exited:\n" << worker.log();
}

}  // namespace
}  // namespace pbgi::farm
