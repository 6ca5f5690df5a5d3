// Workers as a Slurm job array (deploy/slurm/pbgi-worker.sbatch) on a one-node cluster this
// test starts itself (tests/support/slurm_cluster.h): a 2-frame job renders to completion while
// one array task is killed mid-tile with scancel; its tile is retried by the other worker, no
// tile completes twice, and both frames are bit-identical to the frames rendered whole.
// Needs root and slurm-wlm + munge: it skips anywhere else and says why, except where
// PBGI_REQUIRE_SLURM=1 (CI) turns the skip into a failure.
#include <gtest/gtest.h>

#include <cstdlib>
#include <map>
#include <regex>

#include "tests/support/slurm_cluster.h"
#include "tests/support/worker_farm.h"

namespace pbgi::testing {
namespace {

using SlurmWorkerTest = WorkerFarmTest;

TEST_F(SlurmWorkerTest, AWorkerArrayRendersAJobAndAScancelledWorkersTileIsRetried) {
  if (auto why = SlurmCluster::unavailable()) {
    const char* require = std::getenv("PBGI_REQUIRE_SLURM");
    if (require != nullptr && std::string(require) == "1") {
      FAIL() << "PBGI_REQUIRE_SLURM=1 but no Slurm cluster can be started: " << *why;
    }
    GTEST_SKIP() << "no Slurm cluster can be started here: " << *why;
  }
  SlurmCluster slurm;
  ASSERT_TRUE(slurm.error().empty()) << slurm.error();

  // Tiles of a second or so each on one thread, so that a worker is caught mid-tile.
  options_.tileSize = 64;
  start();
  SmallShot shot;
  shot.width = 128;
  shot.height = 64;
  shot.spp = 1024;
  const int64_t job = submit(shot, {1, 2});
  const std::string tokenFile = (dir_ / "token").string();
  std::ofstream(tokenFile) << options_.token;
  const ShellResult submitted = shell(slurm.command(
      "PBGI_COORDINATOR=" + coordinator_->address() + " PBGI_TOKEN_FILE=" + tokenFile +
      " PBGI_WORKER=" + binary("pbgi-worker").string() + " PBGI_CACHE_ROOT=" + dir_.string() +
      " PBGI_WORKER_ARGS='--poll-seconds 0.05' sbatch --parsable --array=0-1 --cpus-per-task=1" +
      " --output=" + (dir_ / "slurm-%A_%a.log").string() + " " +
      (sourceDir() / "deploy/slurm/pbgi-worker.sbatch").string() + " 2>&1"));
  ASSERT_EQ(submitted.status, 0) << submitted.out << slurm.log("slurmctld.log");
  const std::string arrayJob = submitted.out.substr(0, submitted.out.find_first_of(";\n"));
  auto slurmLogs = [&] {
    return shell("cat " + (dir_ / "slurm-*.log").string() + " 2>&1").out +
           slurm.log("slurmd.log");
  };

  // Array task 1's worker, caught holding a tile.
  const std::string doomed = "slurm-" + arrayJob + "_1@";
  ASSERT_TRUE(waitFor(
      [&] {
        auto s = jobStatus(job);
        if (!s.ok()) return false;
        for (const auto& t : s->tasks()) {
          if (t.kind() == "tile" && t.state() == "leased" && t.worker().starts_with(doomed)) {
            return true;
          }
        }
        return false;
      },
      60.0))
      << slurmLogs();
  const ShellResult cancelled =
      shell(slurm.command("scancel --batch --signal=KILL " + arrayJob + "_1 2>&1"));
  ASSERT_EQ(cancelled.status, 0) << cancelled.out;

  std::string state;
  ASSERT_TRUE(waitFor([&] { return settled(job, &state); }, 240.0)) << slurmLogs();
  ASSERT_EQ(state, "done") << slurmLogs();

  // The killed worker's lease expired and its tile was done by the other array task; no tile
  // was completed twice.
  auto events = coordinator_->store().events(job, std::nullopt, std::nullopt);
  ASSERT_TRUE(events.ok()) << events.status();
  int expired = 0;
  int64_t lost = -1;  // the task the killed worker held (not necessarily the tile seen above:
                      // it may have finished that one before the kill)
  std::map<int64_t, int> doneByTask;
  std::map<int64_t, std::string> doneBy;
  for (const farm::TaskEvent& e : *events) {
    if (e.event == "expired" && e.worker.starts_with(doomed)) {
      ++expired;
      lost = e.task;
    }
    if (e.event == "done") {
      ++doneByTask[e.task];
      doneBy[e.task] = e.worker;
    }
  }
  EXPECT_EQ(expired, 1) << slurmLogs();
  EXPECT_TRUE(doneBy[lost].starts_with("slurm-" + arrayJob + "_0@"))
      << "task " << lost << " done by " << doneBy[lost];
  for (const auto& [task, done] : doneByTask) EXPECT_EQ(done, 1) << "task " << task;
  expectFrameEqualsWholeRender(1);
  expectFrameEqualsWholeRender(2);
}

}  // namespace
}  // namespace pbgi::testing
