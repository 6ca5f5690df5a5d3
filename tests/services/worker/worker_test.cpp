// Real pbgi-worker processes (and a real pbgi-coordinator where it is the one killed) on
// loopback: killed workers, a killed coordinator, a tile that always fails, a worker that keeps
// failing a job, trees streamed from the page service. Every frame that completes is compared
// bit for bit with the frame rendered whole in this process.

#include <gtest/gtest.h>

#include <fmt/format.h>

#include <fstream>
#include <iterator>
#include <limits>
#include <map>
#include <regex>

#include "formats/image/image_io.h"
#include "formats/pbgi/tree_file.h"
#include "formats/shot/shot_file.h"
#include "services/coordinator/coordinator.h"
#include "services/farm/farm_client.h"
#include "services/farm/job_rules.h"
#include "services/render/frame_render.h"
#include "tests/support/worker_farm.h"

namespace pbgi::farm {
namespace {

namespace fs = std::filesystem;
using pbgi::testing::Process;
using pbgi::testing::waitFor;

// A counter's value in Prometheus text; 0 when it is not there.
uint64_t metricValue(const std::string& text, const std::string& name) {
  const size_t at = text.find("\n" + name + " ");
  return at == std::string::npos ? 0 : std::stoull(text.substr(at + name.size() + 2));
}

// Every page in a worker's disk cache is a page of one of `trees`, intact; returns how many.
int expectPagesIntact(const fs::path& dir, const std::vector<std::unique_ptr<TreeFile>>& trees) {
  int held = 0;
  for (const auto& e : fs::directory_iterator(dir)) {
    const std::string name = e.path().filename().string();
    if (name == "lock") continue;
    EXPECT_EQ(e.path().extension(), ".page") << name << ": not a page (a temporary left over?)";
    const PageFileReader* file = nullptr;
    for (const auto& t : trees) {
      if (name.starts_with(fmt::format("{:016x}.", t->container().head().treeId()))) {
        file = &t->container();
      }
    }
    if (file == nullptr) {
      ADD_FAILURE() << name << ": a page of no tree of the job";
      continue;
    }
    const uint32_t id = static_cast<uint32_t>(std::stoul(name.substr(17, 8), nullptr, 16));
    std::ifstream in(e.path(), std::ios::binary);
    const std::vector<uint8_t> bytes((std::istreambuf_iterator<char>(in)), {});
    EXPECT_TRUE(checkStoredPage(id, file->directory().at(id), bytes).ok()) << name;
    ++held;
  }
  return held;
}

class WorkerTest : public pbgi::testing::WorkerFarmTest {
 protected:
  // Cancels the job and waits for `worker` to say it stopped its task; the seconds between
  // (infinity when it never did within 30 s).
  double cancelAndTimeTheStop(int64_t job, const Process& worker) {
    v1::CancelJobRequest cancel;
    cancel.set_job(job);
    const auto cancelled = std::chrono::steady_clock::now();
    EXPECT_TRUE(client_->cancelJob(cancel).ok());
    if (!waitFor([&] { return worker.log().find("stopped job=") != std::string::npos; }, 30.0)) {
      ADD_FAILURE() << "the worker never stopped its task:\n" << worker.log();
      return std::numeric_limits<double>::infinity();
    }
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - cancelled).count();
  }
  // Waits up to 30 s for a task of `kind` (bake, tile) of the job to be leased.
  bool waitForLeased(int64_t job, const std::string& kind) {
    return waitFor(
        [&] {
          auto s = jobStatus(job);
          if (!s.ok()) return false;
          for (const auto& t : s->tasks()) {
            if (t.kind() == kind && t.state() == "leased") return true;
          }
          return false;
        },
        30.0);
  }
};

TEST_F(WorkerTest, AWorkerKilledMidTileLosesItsLeaseAndTheFrameIsUnchanged) {
  // Two 64 x 64 tiles of a second or two each on one thread.
  options_.tileSize = 64;
  start();
  pbgi::testing::SmallShot slow;
  slow.width = 128;
  slow.height = 64;
  slow.spp = 1024;
  const int64_t job = submit(slow, {1});
  Process& doomed = startWorker("doomed");
  int tile = -1;
  ASSERT_TRUE(waitFor(
      [&] {
        auto s = jobStatus(job);
        if (!s.ok()) return false;
        for (const auto& t : s->tasks()) {
          if (t.kind() == "tile" && t.state() == "leased" && t.worker() == "doomed") {
            tile = t.tile();
            return true;
          }
        }
        return false;
      },
      30.0))
      << workerLogs();
  std::this_thread::sleep_for(std::chrono::milliseconds(200));
  // Mid-tile: the tile's file is not there yet.
  const std::string tilePath = farmTilePath(jobWorkDir(options_.stateDir, job), 1, tile);
  EXPECT_FALSE(fs::exists(tilePath));
  doomed.signal(SIGKILL);
  EXPECT_EQ(doomed.wait(5.0), 128 + SIGKILL);
  startWorker("rescuer");
  std::string state;
  ASSERT_TRUE(waitFor([&] { return settled(job, &state); }, 90.0)) << workerLogs();
  ASSERT_EQ(state, "done") << workerLogs();
  // The killed attempt expired and was taken over; nothing it left behind was used.
  v1::GetLogsRequest logs;
  logs.set_job(job);
  auto entries = client_->getLogs(logs);
  ASSERT_TRUE(entries.ok());
  int expired = 0;
  for (const auto& e : entries->entries()) expired += e.event() == "expired" && e.worker() == "doomed";
  EXPECT_EQ(expired, 1);
  expectFrameEqualsWholeRender(1);
}

TEST_F(WorkerTest, ACancelStopsTheRunningTileWithinASecond) {
  // A lease of 30 s, as a farm runs: its heartbeats come 7.5 s apart, so only the polls
  // between them can bring the cancel sooner. The one tile would take a minute.
  options_.leaseSeconds = 30.0;
  options_.tileSize = 64;
  start();
  pbgi::testing::SmallShot slow;
  slow.width = 64;
  slow.height = 64;
  slow.spp = 16384;
  slow.extraRender = "tile_size = 4";  // render units of 4 x 4 pixels: 260,000 samples each
  const int64_t job = submit(slow, {1});
  Process& worker = startWorker("busy");
  ASSERT_TRUE(waitForLeased(job, "tile")) << workerLogs();
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  const double seconds = cancelAndTimeTheStop(job, worker);
  std::printf("the cancel stopped the running tile %.2f s after CancelJob\n", seconds);
  // Within a second, with room for a loaded test machine; without the polls it is up to the
  // 7.5 s between beats, and without the render's cancel flag the rest of the tile.
  EXPECT_LT(seconds, 2.0) << worker.log();
  EXPECT_NE(worker.log().find("the lease is lost"), std::string::npos) << worker.log();
  EXPECT_FALSE(fs::exists(farmTilePath(jobWorkDir(options_.stateDir, job), 1, 0)));
  // The worker goes on: it takes the next job's work.
  pbgi::testing::SmallShot quick;
  const int64_t next = submit(quick, {1});
  std::string state;
  ASSERT_TRUE(waitFor([&] { return settled(next, &state); }, 60.0)) << worker.log();
  EXPECT_EQ(state, "done") << worker.log();
}

// The same for a bake: its stages look at the flag between chunks of surfels, so a cancelled
// job's bake stops within about a second, whatever stage it is in, and leaves no tree.
TEST_F(WorkerTest, ACancelStopsARunningBake) {
  options_.leaseSeconds = 30.0;
  start();
  pbgi::testing::SmallShot heavy;
  heavy.integrator = "pbgi";
  heavy.extraRender = "bake_points = 4000000\nbake_bounces = 3\n";  // a minute or more of work
  const int64_t job = submit(heavy, {1});
  Process& worker = startWorker("baker");
  ASSERT_TRUE(waitForLeased(job, "bake")) << workerLogs();
  // In its sample-and-shade stage. Measured later in the bake too (one thread): cancelled 12 s
  // in (merge and build) it stopped 1.46 s after CancelJob, 24 s in (the first bounce) 0.86 s.
  std::this_thread::sleep_for(std::chrono::milliseconds(1500));
  const double seconds = cancelAndTimeTheStop(job, worker);
  std::printf("the cancel stopped the running bake %.2f s after CancelJob\n", seconds);
  EXPECT_LT(seconds, 5.0) << worker.log();
  EXPECT_NE(worker.log().find("bake task="), std::string::npos) << worker.log();
  for (const auto& e : fs::recursive_directory_iterator(jobWorkDir(options_.stateDir, job))) {
    EXPECT_NE(e.path().extension(), ".pbgi") << e.path() << ": a cancelled bake left a tree";
  }
}

TEST_F(WorkerTest, SigtermFinishesAndReportsTheTaskInHandThenExits) {
  options_.tileSize = 64;
  start();
  pbgi::testing::SmallShot slow;
  slow.width = 128;
  slow.height = 64;
  slow.spp = 512;
  const int64_t job = submit(slow, {1});
  Process& polite = startWorker("polite");
  ASSERT_TRUE(waitFor(
      [&] {
        auto s = jobStatus(job);
        return s.ok() && s->tasks_by_state().count("leased") && s->tasks_by_state().at("leased") == 1;
      },
      30.0))
      << workerLogs();
  polite.signal(SIGTERM);
  EXPECT_EQ(polite.wait(60.0), 0) << polite.log();
  // It finished the tile it held and took no other.
  auto s = jobStatus(job);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->tasks_by_state().at("done"), 1) << s->DebugString();
  EXPECT_EQ(s->tasks_by_state().count("leased") ? s->tasks_by_state().at("leased") : 0, 0);
  EXPECT_NE(polite.log().find("stopping"), std::string::npos) << polite.log();
}

TEST_F(WorkerTest, AKilledCoordinatorAndAWorkerKilledMidTileLoseNothingAndNoTaskCompletesTwice) {
  // The coordinator is a process here, so that kill -9 is real.
  const fs::path state = dir_ / "daemon-state";
  auto startDaemon = [&](const std::string& listen) {
    return Process({pbgi::testing::binary("pbgi-coordinator").string(), "--state", state.string(),
                    "--listen", listen, "--output-root", dir_.string(), "--tile-size", "32",
                    "--lease-seconds", "2", "--expiry-interval", "0.1", "--backoff-base", "0"},
                   dir_ / "coordinator.log");
  };
  Process daemon = startDaemon("127.0.0.1:0");
  const fs::path addressFile = state / "coordinator.addr";
  ASSERT_TRUE(waitFor([&] { return fs::exists(addressFile); }, 20.0)) << daemon.log();
  std::string address = pbgi::testing::slurpFile(addressFile);
  address = address.substr(0, address.find('\n'));
  const std::string token = [&] {
    std::string t = pbgi::testing::slurpFile(state / "token");
    return t.substr(0, t.find('\n'));
  }();
  client_ = std::make_unique<FarmClient>(address, token, 5.0);
  // PBGI tiles that read their trees a page at a time from the page service (this process's).
  pbgi::testing::SmallShot shot;
  shot.integrator = "pbgi";
  shot.spp = 8;
  shot.extraRender = "bake_points = 20000\nbake_bounces = 1\nquality = \"draft\"\n";
  const int64_t job = submit(shot);
  ASSERT_NE(job, 0);
  options_.token = token;
  startWorker("steady", {"--tree-source", "stream"}, address);
  Process& victim = startWorker("victim", {"--tree-source", "stream"}, address);
  // Kill a worker in the middle of a tile, and the coordinator (the page service) once some
  // tiles are done and some are not.
  ASSERT_TRUE(waitFor(
      [&] {
        auto s = jobStatus(job);
        if (!s.ok()) return false;
        for (const auto& t : s->tasks()) {
          if (t.kind() == "tile" && t.worker() == "victim" && t.state() == "leased") return true;
        }
        return false;
      },
      60.0))
      << workerLogs() << daemon.log();
  victim.signal(SIGKILL);
  ASSERT_TRUE(waitFor(
      [&] {
        auto s = jobStatus(job);
        return s.ok() && s->tasks_by_state().count("done") && s->tasks_by_state().at("done") >= 4;
      },
      60.0))
      << workerLogs() << daemon.log();
  daemon.signal(SIGKILL);
  EXPECT_EQ(daemon.wait(5.0), 128 + SIGKILL);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  Process restarted = startDaemon(address);
  // The killed worker comes back on its disk cache (what it left half written is removed).
  startWorker("victim-again", {"--tree-source", "stream", "--cache-dir",
                               (dir_ / "cache-victim").string()},
              address);
  std::string final;
  ASSERT_TRUE(waitFor([&] { return settled(job, &final); }, 120.0))
      << workerLogs() << restarted.log();
  ASSERT_EQ(final, "done") << workerLogs() << restarted.log();
  v1::GetLogsRequest logs;
  logs.set_job(job);
  auto entries = client_->getLogs(logs);
  ASSERT_TRUE(entries.ok());
  std::map<int64_t, int> completions;
  for (const auto& e : entries->entries()) {
    if (e.event() == "done") ++completions[e.task()];
  }
  EXPECT_EQ(completions.size(), 12u);  // 2 frames x (bake + 4 tiles + assemble)
  for (const auto& [task, n] : completions) EXPECT_EQ(n, 1) << "task " << task;
  // Nothing damaged in either disk cache.
  auto loaded = loadShotFile(shotPath_.string());
  ASSERT_TRUE(loaded.ok());
  std::vector<std::unique_ptr<TreeFile>> trees;
  for (int frame : {1, 2}) {
    auto tree = TreeFile::open(*jobTreePath(*loaded, jobWorkDir(state.string(), job), frame));
    ASSERT_TRUE(tree.ok()) << tree.status();
    trees.push_back(*std::move(tree));
  }
  EXPECT_GT(expectPagesIntact(dir_ / "cache-steady" / "pages", trees), 0);
  expectPagesIntact(dir_ / "cache-victim" / "pages", trees);
  expectFrameEqualsWholeRender(1);
  expectFrameEqualsWholeRender(2);
}

TEST_F(WorkerTest, ATileThatAlwaysFailsIsDeadAndTheJobSaysWhichAndWhy) {
  options_.retry.maxAttempts = 2;
  start();
  const int64_t job = submit({}, {1});
  // Tile 2's file cannot be written: a folder of its name stands where the file would go.
  const std::string blocked = farmTilePath(jobWorkDir(options_.stateDir, job), 1, 2);
  fs::create_directories(blocked);
  fs::create_directories(fs::path(blocked) / "keep");
  startWorker("w1");
  std::string state;
  ASSERT_TRUE(waitFor([&] { return settled(job, &state); }, 60.0)) << workerLogs();
  EXPECT_EQ(state, "failed");
  auto s = jobStatus(job);
  ASSERT_TRUE(s.ok());
  ASSERT_EQ(s->dead_size(), 2) << s->DebugString();  // the tile, and the assemble waiting on it
  EXPECT_EQ(s->dead(0).kind(), "tile");
  EXPECT_EQ(s->dead(0).tile(), 2);
  EXPECT_EQ(s->dead(0).attempt(), 2);
  EXPECT_NE(s->dead(0).last_error().find("tile.0002.exr"), std::string::npos)
      << s->dead(0).last_error();
  EXPECT_EQ(s->dead(1).kind(), "assemble");
  EXPECT_NE(s->dead(1).last_error().find("waits on job"), std::string::npos);
  // The other tiles are done; the frame was never written.
  EXPECT_EQ(s->tasks_by_state().at("done"), 3);
  EXPECT_FALSE(fs::exists(dir_ / "out/small.0001.exr"));
}

TEST_F(WorkerTest, AWorkerOnAFullDiskIsBlocklistedAndAGoodOneStreamsSinglePages) {
  options_.retry.maxAttempts = 5;
  options_.retry.blocklistAfter = 2;
  start();
  pbgi::testing::SmallShot pbgiShot;
  pbgiShot.integrator = "pbgi";
  pbgiShot.extraRender = "bake_points = 4000\nbake_bounces = 1\nquality = \"draft\"\n";
  const int64_t job = submit(pbgiShot, {1});
  // This worker bakes fine, but its disk cache is on a full disk (a 4 KiB tmpfs mounted in a
  // mount namespace of its own, as root can): every tile fails, saying so. Where no mount
  // namespace can be made, a cache folder that cannot be created fails them instead.
  const fs::path smallDisk = dir_ / "small-disk";
  fs::create_directories(smallDisk);
  const bool canMount = std::system("unshare -m true >/dev/null 2>&1") == 0;
  std::vector<std::string> launcher;
  if (canMount) {
    launcher = {"/usr/bin/unshare", "-m", "/bin/sh", "-c",
                "mount -t tmpfs -o size=4k pbgi-full-disk \"$1\" && shift && exec \"$@\"", "sh",
                smallDisk.string()};
  } else {
    std::printf("[ note ] unshare -m fails here: the bad worker's cache cannot be created instead "
                "of being on a full disk\n");
  }
  Process& bad = startWorker(
      "bad",
      {"--tree-source", "stream", "--cache-dir", canMount ? smallDisk.string() : "/proc/pbgi-no"},
      {}, launcher);
  ASSERT_TRUE(waitFor(
      [&] {
        auto b = coordinator_->store().blocklisted(job, "bad");
        return b.ok() && *b;
      },
      60.0))
      << workerLogs();
  bad.signal(SIGTERM);
  EXPECT_EQ(bad.wait(30.0), 0) << bad.log();
  // A worker that must stream (it does not read the shared folder) finishes the job.
  startWorker("good", {"--tree-source", "stream"});
  std::string state;
  ASSERT_TRUE(waitFor([&] { return settled(job, &state); }, 90.0)) << workerLogs();
  ASSERT_EQ(state, "done") << workerLogs();
  auto s = jobStatus(job);
  ASSERT_TRUE(s.ok());
  for (const auto& t : s->tasks()) {
    if (t.kind() == "tile") {
      EXPECT_EQ(t.worker(), "good");
    }
  }
  auto events = coordinator_->store().events(job, std::nullopt, std::nullopt);
  ASSERT_TRUE(events.ok()) << events.status();
  int fullDisk = 0;
  uint64_t fetchedByGood = 0;  // pages over the network, as the good worker's tiles logged them
  int keptOpen = 0;
  const std::regex fetched("pages over the network ([0-9]+) ");
  for (const TaskEvent& e : *events) {
    fullDisk += e.event == "failed" && e.text.find("the disk is full") != std::string::npos &&
                e.text.find("page disk cache " + smallDisk.string()) != std::string::npos;
    std::smatch m;
    if (e.event == "done" && e.worker == "good" && std::regex_search(e.text, m, fetched)) {
      fetchedByGood += std::stoull(m[1]);
      keptOpen += e.text.find("open from an earlier tile") != std::string::npos;
    }
  }
  EXPECT_EQ(keptOpen, 3) << "the frame's tree is opened for its first tile and kept";
  if (canMount) {
    EXPECT_GE(fullDisk, 2) << workerLogs();
  }
  // No whole-tree copy: single pages, each fetched once for the frame's four tiles (the disk
  // cache keeps them between tasks), every one held intact.
  auto tree = TreeFile::open(*jobTreePath(*loadShotFile(shotPath_.string()),
                                          jobWorkDir(options_.stateDir, job), 1));
  ASSERT_TRUE(tree.ok()) << tree.status();
  const PageFileReader& file = (*tree)->container();
  EXPECT_GT(fetchedByGood, 0u);
  EXPECT_LE(fetchedByGood, file.info().pageCount);
  const std::string metrics = coordinator_->metricsText();
  EXPECT_GE(metricValue(metrics, "pbgi_tree_pages_served_total"), fetchedByGood) << metrics;
  std::vector<std::unique_ptr<TreeFile>> trees;
  trees.push_back(*std::move(tree));
  EXPECT_EQ(static_cast<uint64_t>(expectPagesIntact(dir_ / "cache-good" / "pages", trees)),
            fetchedByGood);
  expectFrameEqualsWholeRender(1);
}

// A worker keeps the scene it loaded for the frame's bake and uses it for the frame's tiles;
// the frame is the same as `pbgi render` makes it.
TEST_F(WorkerTest, AWorkerKeepsTheFramesSceneForItsTiles) {
  start();
  pbgi::testing::SmallShot pbgiShot;
  pbgiShot.integrator = "pbgi";
  pbgiShot.extraRender = "bake_points = 4000\nbake_bounces = 1\nquality = \"draft\"\n";
  const int64_t job = submit(pbgiShot, {1});
  startWorker("keeper");
  std::string state;
  ASSERT_TRUE(waitFor([&] { return settled(job, &state); }, 90.0)) << workerLogs();
  ASSERT_EQ(state, "done") << workerLogs();
  auto events = coordinator_->store().events(job, std::nullopt, std::nullopt);
  ASSERT_TRUE(events.ok()) << events.status();
  int loaded = 0, kept = 0;
  for (const TaskEvent& e : *events) {
    if (e.event != "done") continue;
    loaded += e.text.find("scene: loaded") != std::string::npos;
    kept += e.text.find("scene: kept from an earlier task") != std::string::npos;
  }
  EXPECT_EQ(loaded, 1);  // the bake
  EXPECT_EQ(kept, 4);    // the 64^2 frame's four 32^2 tiles
  expectFrameEqualsWholeRender(1);
}

}  // namespace
}  // namespace pbgi::farm
