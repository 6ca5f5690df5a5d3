#pragma once
// A farm in a test: an in-process coordinator on loopback with a short lease, real pbgi-worker
// processes (or a launcher that starts them, such as Slurm), jobs submitted over gRPC, and
// every completed frame compared bit for bit with the frame rendered whole in this process.
#include <gtest/gtest.h>

#include <algorithm>
#include <filesystem>
#include <memory>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "formats/image/image_io.h"
#include "formats/shot/shot_file.h"
#include "services/coordinator/coordinator.h"
#include "services/farm/farm_client.h"
#include "services/farm/job_rules.h"
#include "services/render/frame_render.h"
#include "tests/support/farm_fixtures.h"

namespace pbgi::testing {

using farm::Coordinator;
using farm::CoordinatorOptions;
using farm::FarmClient;
namespace v1 = farm::v1;

class WorkerFarmTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = pbgi::testing::makeTempDir("worker");
    options_.stateDir = (dir_ / "state").string();
    options_.outputRoot = dir_.string();
    options_.token = "worker-test-token";
    options_.tileSize = 32;
    options_.leaseSeconds = 1.0;
    options_.expiryIntervalSeconds = 0.1;
    options_.retry.backoffBase = 0.0;
  }
  void TearDown() override {
    workers_.clear();
    coordinator_.reset();
    std::filesystem::remove_all(dir_);
  }
  void start() {
    auto c = Coordinator::start(options_);
    ASSERT_TRUE(c.ok()) << c.status();
    coordinator_ = *std::move(c);
    client_ = std::make_unique<FarmClient>(coordinator_->address(), options_.token, 10.0);
  }
  // A pbgi-worker process named `id` (its log in dir_/ID.log), owned by the caller.
  Process launchWorker(const std::string& id, std::vector<std::string> extra = {},
                       const std::string& address = {}, std::vector<std::string> launcher = {}) {
    std::vector<std::string> argv = launcher;
    const std::vector<std::string> own = {pbgi::testing::binary("pbgi-worker").string(),
                                     "--coordinator",
                                     address.empty() ? coordinator_->address() : address,
                                     "--id", id, "--threads", "1", "--poll-seconds", "0.05"};
    argv.insert(argv.end(), own.begin(), own.end());
    if (std::find(extra.begin(), extra.end(), "--cache-dir") == extra.end()) {
      extra.insert(extra.end(), {"--cache-dir", (dir_ / ("cache-" + id)).string()});
    }
    argv.insert(argv.end(), extra.begin(), extra.end());
    return Process(argv, dir_ / (id + ".log"),
                   std::vector<std::string>{"PBGI_TOKEN=" + options_.token});
  }
  // The same, kept (and killed) by the fixture; `launcher`: words before the worker's own (a
  // wrapper that runs it).
  Process& startWorker(const std::string& id, std::vector<std::string> extra = {},
                       const std::string& address = {}, std::vector<std::string> launcher = {}) {
    workers_.push_back(launchWorker(id, std::move(extra), address, std::move(launcher)));
    return workers_.back();
  }

  int64_t submit(const pbgi::testing::SmallShot& shot, std::vector<int> frames = {}) {
    shotPath_ = pbgi::testing::writeSmallShot(dir_, shot);
    v1::SubmitJobRequest request;
    request.set_shot_path(shotPath_.string());
    request.set_shot_text(pbgi::testing::slurpFile(shotPath_));
    for (int f : frames) request.add_frames(f);
    auto id = client_->submitJob(request);
    EXPECT_TRUE(id.ok()) << id.status();
    return id.ok() ? id->job() : 0;
  }
  absl::StatusOr<v1::JobStatus> jobStatus(int64_t job) {
    v1::GetStatusRequest request;
    request.set_job(job);
    request.set_with_tasks(true);
    auto s = client_->getStatus(request);
    if (!s.ok()) return s.status();
    return s->jobs(0);
  }
  bool settled(int64_t job, std::string* state = nullptr) {
    auto s = jobStatus(job);
    if (state != nullptr && s.ok()) *state = s->state();
    return s.ok() && s->state() != "active";
  }
  // The frame as `pbgi render` makes it: the whole frame, in this process.
  void expectFrameEqualsWholeRender(int frame) {
    auto shot = loadShotFile(shotPath_.string());
    ASSERT_TRUE(shot.ok()) << shot.status();
    FrameRenderRequest request;
    request.frame = frame;
    request.threads = 2;
    request.preview = false;
    request.outPath = (dir_ / fmt::format("whole.{}.exr", frame)).string();
    request.bakeDir = (dir_ / "whole-bake").string();
    ASSERT_TRUE(renderShotFrame(*shot, request).ok());
    auto whole = readImage(request.outPath);
    auto farm = readImage(
        outputPathForFrame(shot->output, frame, shot->lastFrame > shot->firstFrame));
    ASSERT_TRUE(whole.ok() && farm.ok()) << whole.status() << farm.status();
    std::string why;
    EXPECT_TRUE(pbgi::testing::samePixels(*farm, *whole, &why)) << "frame " << frame << ": " << why;
  }
  std::string workerLogs() {
    std::string all;
    for (const Process& w : workers_) all += w.log();
    return all;
  }

  std::filesystem::path dir_;
  std::filesystem::path shotPath_;
  CoordinatorOptions options_;
  std::unique_ptr<Coordinator> coordinator_;
  std::unique_ptr<FarmClient> client_;
  std::vector<Process> workers_;
};

}  // namespace pbgi::testing
