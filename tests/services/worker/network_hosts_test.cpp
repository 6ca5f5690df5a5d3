// The farm across real network hosts: three worker hosts, each a network namespace on a veth
// link of its own (tests/support/network_hosts.h), and the coordinator on this one, reached
// over those links, not loopback. During a 4-frame job one host's worker is killed (SIGKILL)
// every few seconds and started again, and another host's link goes down while its worker
// holds a tile and comes back after the lease expired: the late completion is refused as
// stale. Every frame completes bit-identical to the frame rendered whole, and no task
// completes twice. Needs root and `ip netns`: it skips elsewhere, saying why.
//
// Each worker host also has a filesystem of its own: in its mount namespace an empty tmpfs
// lies over the test folder (the coordinator's job folder and output root), so its tiles reach
// the coordinator over its link (PutFile) and an assembling worker fetches them (GetFile).
// One more worker's disk is full: its tiles fail, saying so, and are done elsewhere.
#include <gtest/gtest.h>

#include <atomic>
#include <map>
#include <thread>

#include "tests/support/network_hosts.h"
#include "tests/support/worker_farm.h"

namespace pbgi::testing {
namespace {

using NetworkHostsTest = WorkerFarmTest;

uint64_t metric(const std::string& text, const std::string& name) {
  const size_t at = text.find("\n" + name + " ");
  return at == std::string::npos ? 0 : std::stoull(text.substr(at + name.size() + 2));
}

TEST_F(NetworkHostsTest, KilledWorkersAndALostLinkLoseNothingAndCommitNothingTwice) {
  if (auto why = NetworkHosts::unavailable()) GTEST_SKIP() << *why;
  NetworkHosts hosts(3);
  ASSERT_TRUE(hosts.error().empty()) << hosts.error();

  options_.listen = "0.0.0.0:0";
  options_.tileSize = 64;
  // A worker killed every 2 s expires a lease each time: more attempts than the default 3,
  // or a tile it keeps drawing dies of it (as it should on a real farm).
  options_.retry.maxAttempts = 20;
  start();
  const std::string port = coordinator_->address().substr(coordinator_->address().rfind(':') + 1);
  const auto coordinatorFrom = [&](int h) { return hosts.localAddress(h) + ":" + port; };
  // Host h's network, and a disk of its own where this machine has the test folder.
  const auto onHost = [&](int h, const std::string& size = "") {
    std::vector<std::string> words = hosts.launcher(h);
    for (const std::string& w :
         {std::string("/usr/bin/unshare"), std::string("--mount"), std::string("--propagation"),
          std::string("private"), std::string("/bin/sh"), std::string("-c"),
          "mount -t tmpfs " + (size.empty() ? "" : "-o size=" + size + " ") +
              "worker-host-disk \"" + dir_.string() + "\" && exec \"$0\" \"$@\""}) {
      words.push_back(w);
    }
    return words;
  };
  SmallShot shot;
  shot.width = 128;
  shot.height = 64;
  shot.spp = 512;
  shot.lastFrame = 4;
  const int64_t job = submit(shot, {1, 2, 3, 4});

  // Host 1's worker holds a tile when its link goes down.
  startWorker("cut-off", {}, coordinatorFrom(1), onHost(1));
  ASSERT_TRUE(waitFor(
      [&] {
        auto s = jobStatus(job);
        if (!s.ok()) return false;
        for (const auto& t : s->tasks()) {
          if (t.kind() == "tile" && t.state() == "leased" && t.worker() == "cut-off") return true;
        }
        return false;
      },
      60.0))
      << workerLogs();
  ASSERT_TRUE(hosts.setLink(1, false));
  // Hosts 0 and 2 work on; host 0's worker is killed every 2 s and started again.
  startWorker("steady", {}, coordinatorFrom(2), onHost(2));
  // And beside it a worker whose disk is full (16 KiB): each tile it takes fails, saying so,
  // and is done elsewhere; three failures blocklist it for the job.
  startWorker("full-disk", {}, coordinatorFrom(2), onHost(2, "16k"));
  std::atomic<bool> stop{false};
  std::atomic<int> kills{0};
  std::thread killer([&] {
    for (int generation = 0; !stop.load(); ++generation) {
      Process w = launchWorker(fmt::format("doomed-{}", generation), {}, coordinatorFrom(0),
                               onHost(0));
      for (int i = 0; i < 40 && !stop.load(); ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(50));
      }
      w.signal(SIGKILL);
      w.wait(5.0);
      ++kills;
    }
  });
  // The cut-off worker's lease expires (of the tile it held when the link went: not
  // necessarily the one seen above, which it may have finished first); then its link comes
  // back.
  int64_t lost = -1;
  int lostAttempt = 0;
  ASSERT_TRUE(waitFor(
      [&] {
        auto events = coordinator_->store().events(job, std::nullopt, std::nullopt);
        if (!events.ok()) return false;
        for (const farm::TaskEvent& e : *events) {
          if (e.event == "expired" && e.worker == "cut-off") {
            lost = e.task;
            lostAttempt = e.attempt;
          }
        }
        return lost >= 0;
      },
      30.0));
  ASSERT_TRUE(hosts.setLink(1, true));

  std::string state;
  const bool settled = waitFor([&] { return this->settled(job, &state); }, 300.0);
  stop.store(true);
  killer.join();
  ASSERT_TRUE(settled) << workerLogs();
  ASSERT_EQ(state, "done") << workerLogs();
  EXPECT_GE(kills.load(), 1);

  // The cut-off worker's completion, late, was refused as stale (it comes back within a
  // heartbeat or two of the link).
  EXPECT_TRUE(waitFor([&] { return metric(coordinator_->metricsText(),
                                          "pbgi_stale_completions_total") >= 1; },
                      30.0))
      << workerLogs();
  auto events = coordinator_->store().events(job, std::nullopt, std::nullopt);
  ASSERT_TRUE(events.ok()) << events.status();
  std::map<int64_t, int> done;
  int lostDoneAttempt = 0;
  for (const farm::TaskEvent& e : *events) {
    if (e.event != "done") continue;
    ++done[e.task];
    if (e.task == lost) lostDoneAttempt = e.attempt;
  }
  EXPECT_EQ(done.size(), 12u) << "8 tiles and 4 assembles";
  for (const auto& [task, count] : done) EXPECT_EQ(count, 1) << "task " << task;
  EXPECT_GT(lostDoneAttempt, lostAttempt) << "the tile whose lease expired was done by a later "
                                             "attempt (another worker's, or the cut-off one's anew)";
  // The full disk's failures said why, and cost nothing but retries.
  int fullDiskFailures = 0;
  for (const farm::TaskEvent& e : *events) {
    if (e.worker != "full-disk" || e.event != "failed") continue;
    ++fullDiskFailures;
    EXPECT_NE(e.text.find("the disk is full"), std::string::npos) << e.text;
  }
  EXPECT_GE(fullDiskFailures, 1) << workerLogs();
  // Every tile and frame came over the links: each completion's log says what it sent.
  int sent = 0;
  for (const farm::TaskEvent& e : *events) {
    sent += e.event == "done" && e.text.find("to the coordinator") != std::string::npos;
  }
  EXPECT_EQ(sent, 12) << "8 tiles and 4 frames, each sent by the worker that made it";
  for (int frame = 1; frame <= 4; ++frame) expectFrameEqualsWholeRender(frame);
}

}  // namespace
}  // namespace pbgi::testing
