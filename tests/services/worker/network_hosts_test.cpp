// The farm across real network hosts: three worker hosts, each a network namespace on a veth
// link of its own (tests/support/network_hosts.h), and the coordinator (a pbgi-coordinator
// process) on this one, reached over those links, not loopback. During a 4-frame job one
// host's worker is killed (SIGKILL) every few seconds and started again; another host's link
// goes down while its worker holds a tile; the coordinator is killed (SIGKILL) and restarted on
// the same port; the link comes back after the lease expired, and the late result is refused
// as stale. Every frame completes bit-identical to the frame rendered whole, and no task
// completes twice. Needs root and `ip netns`: it skips elsewhere, saying why.
//
// Each worker host also has a filesystem of its own: in its mount namespace an empty tmpfs
// lies over the test folder (the coordinator's job folder and output root), so its tiles reach
// the coordinator over its link (PutFile) and an assembling worker fetches them (GetFile).
// One more worker's disk is full: its tiles fail, saying so, and are done elsewhere.
#include <gtest/gtest.h>

#include <httplib.h>

#include <atomic>
#include <map>
#include <thread>

#include "tests/support/network_hosts.h"
#include "tests/support/worker_farm.h"

namespace pbgi::testing {
namespace {

namespace fs = std::filesystem;
using NetworkHostsTest = WorkerFarmTest;

uint64_t metric(const std::string& text, const std::string& name) {
  const size_t at = text.find("\n" + name + " ");
  return at == std::string::npos ? 0 : std::stoull(text.substr(at + name.size() + 2));
}

TEST_F(NetworkHostsTest,
       KilledWorkersALostLinkAndAKilledCoordinatorLoseNothingAndCommitNothingTwice) {
  if (auto why = NetworkHosts::unavailable()) GTEST_SKIP() << *why;
  // Each host's disk is a tmpfs in a mount namespace of its own, made private so that it stays
  // there. Where / is not a mount point (a chroot) that cannot be done: said, not failed.
  if (const ShellResult r = shell("/usr/bin/unshare --mount --propagation private true 2>&1");
      r.status != 0) {
    GTEST_SKIP() << "the hosts' disks need a private mount namespace, and `unshare --mount "
                    "--propagation private` fails here (/ is not a mount point in a chroot): "
                 << r.out;
  }
  NetworkHosts hosts(3);
  ASSERT_TRUE(hosts.error().empty()) << hosts.error();

  // The coordinator is a process here, so that kill -9 is real. Killed every 2 s, a worker
  // expires a lease each time: more attempts than the default 3, or a tile it keeps drawing
  // dies of it (as it should on a real farm).
  const fs::path state = dir_ / "daemon-state";
  const fs::path addressFile = state / "coordinator.addr";
  const fs::path httpFile = state / "coordinator.http";
  const auto startDaemon = [&](const std::string& listen, const std::string& http,
                               const std::string& log) {
    fs::remove(addressFile);
    fs::remove(httpFile);
    return Process({binary("pbgi-coordinator").string(), "--state", state.string(), "--listen",
                    listen, "--http", http, "--output-root", dir_.string(), "--tile-size", "64",
                    "--lease-seconds", "1", "--expiry-interval", "0.1", "--backoff-base", "0",
                    "--max-attempts", "20"},
                   dir_ / log);
  };
  Process daemon = startDaemon("0.0.0.0:0", "127.0.0.1:0", "coordinator.log");
  const auto firstLine = [](const fs::path& file) {
    const std::string text = slurpFile(file);
    return text.substr(0, text.find('\n'));
  };
  ASSERT_TRUE(waitFor([&] { return fs::exists(addressFile) && fs::exists(httpFile); }, 20.0))
      << daemon.log();
  const std::string address = firstLine(addressFile);
  const std::string port = address.substr(address.rfind(':') + 1);
  const std::string httpAddress = firstLine(httpFile);
  options_.token = [&] {
    const std::string t = slurpFile(state / "token");
    return t.substr(0, t.find('\n'));
  }();
  client_ = std::make_unique<FarmClient>("127.0.0.1:" + port, options_.token, 5.0);
  const auto metricsText = [&] {
    httplib::Client http("http://" + httpAddress);
    auto res = http.Get("/metrics");
    return res ? res->body : std::string();
  };
  const auto events = [&](int64_t job) {
    v1::GetLogsRequest request;
    request.set_job(job);
    auto logs = client_->getLogs(request);
    return logs.ok() ? std::vector<v1::LogEntry>(logs->entries().begin(), logs->entries().end())
                     : std::vector<v1::LogEntry>();
  };
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
  ASSERT_NE(job, 0) << daemon.log();

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
      << workerLogs() << daemon.log();
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
  // The coordinator dies once some tasks are done and others are not (tiles in flight, uploads
  // half sent), and comes back on the same port; every worker carries on with it.
  const auto doneTasks = [&] {
    auto s = jobStatus(job);
    return s.ok() && s->tasks_by_state().count("done") ? s->tasks_by_state().at("done") : 0;
  };
  ASSERT_TRUE(waitFor([&] { return doneTasks() >= 2; }, 120.0)) << workerLogs() << daemon.log();
  ASSERT_LT(doneTasks(), 12) << "the job ended before the coordinator could be killed";
  daemon.signal(SIGKILL);
  EXPECT_EQ(daemon.wait(5.0), 128 + SIGKILL);
  std::this_thread::sleep_for(std::chrono::milliseconds(500));
  Process restarted =
      startDaemon("0.0.0.0:" + port, httpAddress, "coordinator-restarted.log");
  ASSERT_TRUE(waitFor([&] { return fs::exists(addressFile) && fs::exists(httpFile); }, 20.0))
      << restarted.log();
  // The cut-off worker's lease expires (of the tile it held when the link went: not
  // necessarily the one seen above, which it may have finished first), before the kill or
  // after the restart; then its link comes back.
  int64_t lost = -1;
  int lostAttempt = 0;
  ASSERT_TRUE(waitFor(
      [&] {
        for (const v1::LogEntry& e : events(job)) {
          if (e.event() == "expired" && e.worker() == "cut-off") {
            lost = e.task();
            lostAttempt = e.attempt();
          }
        }
        return lost >= 0;
      },
      30.0))
      << restarted.log();
  ASSERT_TRUE(hosts.setLink(1, true));

  std::string final;
  const bool settled = waitFor([&] { return this->settled(job, &final); }, 300.0);
  stop.store(true);
  killer.join();
  ASSERT_TRUE(settled) << workerLogs() << restarted.log();
  ASSERT_EQ(final, "done") << workerLogs() << restarted.log();
  EXPECT_GE(kills.load(), 1);

  // The cut-off worker's result, late, was refused as stale by the restarted coordinator (it
  // comes back within a heartbeat or two of the link).
  EXPECT_TRUE(waitFor([&] { return metric(metricsText(), "pbgi_stale_completions_total") >= 1; },
                      30.0))
      << workerLogs() << restarted.log();
  const std::vector<v1::LogEntry> log = events(job);
  ASSERT_FALSE(log.empty());
  std::map<int64_t, int> done;
  int lostDoneAttempt = 0;
  for (const v1::LogEntry& e : log) {
    if (e.event() != "done") continue;
    ++done[e.task()];
    if (e.task() == lost) lostDoneAttempt = e.attempt();
  }
  EXPECT_EQ(done.size(), 12u) << "8 tiles and 4 assembles";
  for (const auto& [task, count] : done) EXPECT_EQ(count, 1) << "task " << task;
  EXPECT_GT(lostDoneAttempt, lostAttempt) << "the tile whose lease expired was done by a later "
                                             "attempt (another worker's, or the cut-off one's anew)";
  // The full disk's failures said why, and cost nothing but retries.
  int fullDiskFailures = 0;
  for (const v1::LogEntry& e : log) {
    if (e.worker() != "full-disk" || e.event() != "failed") continue;
    ++fullDiskFailures;
    EXPECT_NE(e.text().find("the disk is full"), std::string::npos) << e.text();
  }
  EXPECT_GE(fullDiskFailures, 1) << workerLogs();
  // Every tile and frame came over the links: each completion's log says what it sent.
  int sent = 0;
  for (const v1::LogEntry& e : log) {
    sent += e.event() == "done" && e.text().find("to the coordinator") != std::string::npos;
  }
  EXPECT_EQ(sent, 12) << "8 tiles and 4 frames, each sent by the worker that made it";
  for (int frame = 1; frame <= 4; ++frame) expectFrameEqualsWholeRender(frame);
}

}  // namespace
}  // namespace pbgi::testing
