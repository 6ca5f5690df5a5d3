// A worker on a host that does not see the coordinator's job folder or output root: it works
// in a copy of its own, sends what its tasks make (trees, tiles, frames) and fetches what they
// read (tiles to assemble, the frame to audit); trees reach its tiles through the page service.

#include <gtest/gtest.h>

#include <unistd.h>

#include <cstdlib>

#include "tests/support/worker_farm.h"

namespace pbgi::farm {
namespace {

namespace fs = std::filesystem;
using pbgi::testing::WorkerFarmTest;

class SeparateFilesTest : public WorkerFarmTest {};

// Whether this process may make a mount namespace (root, and a kernel and container that
// allow it): then the worker's view of the test folder is an empty tmpfs.
bool canHideFolders() {
  return ::geteuid() == 0 &&
         std::system("unshare --mount --propagation private true >/dev/null 2>&1") == 0;
}

TEST_F(SeparateFilesTest, AWorkerThatSeesNoneOfTheJobsFilesRendersBakesAssemblesAndAudits) {
  start();
  pbgi::testing::SmallShot shot;  // 64x64 in tiles of 32, frames 1 and 2
  shot.integrator = "pbgi";
  shot.spp = 8;
  shot.extraRender = "bake_points = 8000\nbake_bounces = 1\n";
  const int64_t job = submit(shot);
  ASSERT_NE(job, 0);
  std::vector<std::string> launcher;
  std::vector<std::string> extra = {"--files", "copy"};
  if (canHideFolders()) {
    // The worker's mount namespace lays an empty tmpfs over the whole test folder: the state
    // (job folder), the output root and its own cache live only there, on "its own disk".
    launcher = {"/usr/bin/unshare", "--mount", "--propagation", "private", "/bin/sh", "-c",
                "mount -t tmpfs pbgi-worker-disk \"" + dir_.string() + "\" && exec \"$0\" \"$@\""};
    extra = {"--files", "auto", "--cache-dir", (dir_ / "worker-disk").string()};
  } else {
    std::fprintf(stderr, "no mount namespace here (needs root): the worker is told --files copy "
                         "instead of being unable to see the folders\n");
  }
  startWorker("remote", extra, "", launcher);
  const auto finished = [&] {
    auto s = jobStatus(job);
    if (!s.ok() || s->state() == "active") return false;
    for (const v1::FrameAudit& a : s->audits()) {
      if (a.state() == "ready" || a.state() == "leased") return false;
    }
    return true;
  };
  ASSERT_TRUE(pbgi::testing::waitFor(finished, 180.0)) << workerLogs();
  auto s = jobStatus(job);
  ASSERT_TRUE(s.ok());
  ASSERT_EQ(s->state(), "done") << s->DebugString() << workerLogs();
  // What the coordinator holds arrived over the network: the trees, the tiles, the frames.
  const std::string work = jobWorkDir(options_.stateDir, job);
  for (const int frame : {1, 2}) {
    for (int t = 0; t < 4; ++t) EXPECT_TRUE(fs::exists(farmTilePath(work, frame, t)));
  }
  // Each task's log (its completion's) says what it sent.
  auto events = coordinator_->store().events(job, std::nullopt, std::nullopt);
  ASSERT_TRUE(events.ok()) << events.status();
  int sent = 0;
  for (const TaskEvent& e : *events) sent += e.text.find("to the coordinator") != std::string::npos;
  EXPECT_EQ(sent, 2 + 8 + 2) << "2 trees, 8 tiles and 2 frames (with their previews)";
  for (const v1::FrameAudit& a : s->audits()) {
    EXPECT_EQ(a.state(), "done") << a.DebugString();
    EXPECT_TRUE(a.has_result());
  }
  expectFrameEqualsWholeRender(1);
  expectFrameEqualsWholeRender(2);
}

}  // namespace
}  // namespace pbgi::farm
