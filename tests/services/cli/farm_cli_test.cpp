// The farm client commands (submit, status, cancel, retry, logs, workers) against a real
// pbgi-coordinator process, and the daemons' command lines.

#include <gtest/gtest.h>
#include <httplib.h>

#include <algorithm>
#include <regex>
#include <thread>

#include "services/cli/farm_cli.h"
#include "tests/support/farm_fixtures.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
using testing::runPbgi;
using testing::shellQuote;

class FarmCliTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::makeTempDir("farm-cli");
    daemon_ = testing::Process(
        {testing::binary("pbgi-coordinator").string(), "--state", (dir_ / "state").string(),
         "--listen", "127.0.0.1:0", "--output-root", dir_.string(), "--tile-size", "32"},
        dir_ / "coordinator.log");
    ASSERT_TRUE(testing::waitFor([&] { return fs::exists(dir_ / "state/coordinator.addr"); }, 20.0))
        << daemon_.log();
    std::string address = testing::slurpFile(dir_ / "state/coordinator.addr");
    connection_ = " --coordinator " + address.substr(0, address.find('\n')) + " --token-file " +
                  shellQuote((dir_ / "state/token").string());
  }
  void TearDown() override {
    daemon_.signal(SIGTERM);
    EXPECT_EQ(daemon_.wait(20.0), 0) << daemon_.log();
    fs::remove_all(dir_);
  }

  fs::path dir_;
  testing::Process daemon_;
  std::string connection_;
};

TEST_F(FarmCliTest, SubmitStatusCancelRetryLogsWorkers) {
  const fs::path shot = testing::writeSmallShot(dir_, {});
  const auto submitted = runPbgi("submit " + shellQuote(shot.string()) + " --spp 1" + connection_);
  ASSERT_EQ(submitted.exitCode, 0) << submitted.output();
  EXPECT_EQ(submitted.out, "1\n");
  const auto all = runPbgi("status" + connection_);
  ASSERT_EQ(all.exitCode, 0) << all.output();
  EXPECT_NE(all.out.find("cornell"), std::string::npos) << all.out;
  // Active in the store; no worker has called yet, so it waits for one.
  EXPECT_NE(all.out.find("waiting"), std::string::npos) << all.out;
  EXPECT_NE(all.out.find("no worker is live"), std::string::npos) << all.out;
  EXPECT_NE(all.out.find("0/10 tasks"), std::string::npos) << all.out;
  const auto one = runPbgi("status 1" + connection_);
  ASSERT_EQ(one.exitCode, 0) << one.output();
  EXPECT_NE(one.out.find("frame    2: bake -, tiles 0/4 done, assemble blocked"), std::string::npos)
      << one.out;
  const auto json = runPbgi("status 1 --json" + connection_);
  EXPECT_NE(json.out.find("\"tilesPerFrame\":4"), std::string::npos) << json.out;
  EXPECT_NE(json.out.find("{\"job\":1,"), std::string::npos) << "ids are numbers: " << json.out;
  const auto workersJson = runPbgi("workers --json" + connection_);
  EXPECT_EQ(workersJson.out, "{\"workers\":[]}\n") << workersJson.output();
  const auto logsJson = runPbgi("logs 1 --json" + connection_);
  EXPECT_EQ(logsJson.exitCode, 0) << logsJson.output();
  EXPECT_EQ(logsJson.out.rfind("{\"entries\":[", 0), 0u) << logsJson.out;
  const auto cancelled = runPbgi("cancel 1" + connection_);
  ASSERT_EQ(cancelled.exitCode, 0) << cancelled.output();
  EXPECT_NE(runPbgi("status" + connection_).out.find("cancelled"), std::string::npos);
  const auto retried = runPbgi("retry 1 --frame 2 --tile 1" + connection_);
  ASSERT_EQ(retried.exitCode, 0) << retried.output();
  // The tile and its frame's assemble were cancelled (a path-traced job has no bake).
  EXPECT_NE(retried.out.find("retrying job 1 frame 2 tile 1: 2 task(s)"), std::string::npos)
      << retried.out;
  EXPECT_NE(runPbgi("status" + connection_).out.find("waiting"), std::string::npos);
  // Nothing else of frame 2 is dead or cancelled, and frame 7 is not the job's: said, exit 1.
  const auto again = runPbgi("retry 1 --frame 7" + connection_);
  EXPECT_EQ(again.exitCode, 1) << again.output();
  EXPECT_NE(again.err.find("nothing to retry"), std::string::npos) << again.output();
  const auto workers = runPbgi("workers" + connection_);
  ASSERT_EQ(workers.exitCode, 0) << workers.output();
  EXPECT_EQ(workers.out, "no workers\n");
  // A worker runs the retried tile; logs and workers show it.
  std::string token = testing::slurpFile(dir_ / "state/token");
  token = token.substr(0, token.find('\n'));
  std::string address = testing::slurpFile(dir_ / "state/coordinator.addr");
  address = address.substr(0, address.find('\n'));
  // Followed from before the worker starts until the job is no longer active: each attempt as
  // it starts and as it ends.
  testing::Process follow({testing::pbgiBinary().string(), "logs", "1", "--follow", "--coordinator",
                           address, "--token-file", (dir_ / "state/token").string()},
                          dir_ / "follow.log");
  std::this_thread::sleep_for(std::chrono::milliseconds(300));
  testing::Process worker({testing::binary("pbgi-worker").string(), "--coordinator", address,
                           "--id", "cli-worker", "--threads", "1", "--poll-seconds", "0.05"},
                          dir_ / "worker.log", {"PBGI_TOKEN=" + token});
  EXPECT_EQ(follow.wait(60.0), 0) << follow.log() << worker.log();
  const std::string followed = follow.log();
  const std::regex done(R"(frame 2 tile 1 attempt 1 on cli-worker: done in [0-9.]+ s\n)");
  EXPECT_TRUE(std::regex_search(followed, done)) << followed;
  // The attempt in flight: "started" when the lease came after the follower's first read, or
  // "running for" when the worker (which polls every 50 ms) leased the tile before it.
  const std::regex inFlight(
      R"(frame 2 tile 1 attempt 1 on cli-worker: (started|running for [0-9.]+ s)\n)");
  EXPECT_TRUE(std::regex_search(followed, inFlight)) << followed;
  // The frame's other tiles stay cancelled, so the job settles so once the tile is done.
  EXPECT_NE(followed.find("job 1 cancelled\n"), std::string::npos) << followed;
  // Afterwards: a line per attempt, and with --full each attempt's own log beneath it.
  const auto logs = runPbgi("logs 1 --frame 2 --tile 1" + connection_);
  EXPECT_EQ(logs.exitCode, 0) << logs.output();
  EXPECT_TRUE(std::regex_search(logs.out, done)) << logs.out;
  EXPECT_EQ(std::count(logs.out.begin(), logs.out.end(), '\n'), 1) << logs.out;
  const auto full = runPbgi("logs 1 --frame 2 --tile 1 --full" + connection_);
  EXPECT_NE(full.out.find("    wrote "), std::string::npos) << full.out;  // the worker's own log
  EXPECT_EQ(runPbgi("logs 1 --frame 1" + connection_).out, "");  // nothing ran on frame 1
  EXPECT_NE(runPbgi("workers" + connection_).out.find("cli-worker"), std::string::npos);
  const auto unknown = runPbgi("status 7" + connection_);
  EXPECT_EQ(unknown.exitCode, 2) << unknown.output();
  EXPECT_NE(unknown.err.find("job 7: no such job"), std::string::npos) << unknown.err;
}

TEST_F(FarmCliTest, RefusedWithoutTheTokenAndOutsideTheOutputRoot) {
  const fs::path shot = testing::writeSmallShot(dir_, {});
  std::ofstream(dir_ / "wrong-token") << "nope\n";
  const std::string address = connection_.substr(0, connection_.find(" --token-file"));
  const auto wrong = runPbgi("cancel 1" + address + " --token-file " +
                             shellQuote((dir_ / "wrong-token").string()));
  EXPECT_EQ(wrong.exitCode, 1) << wrong.output();
  EXPECT_NE(wrong.err.find("token"), std::string::npos) << wrong.err;
  // The token itself passed where its file goes is never echoed.
  const std::string secret = "0123456789abcdef0123456789abcdef";
  const auto pasted = runPbgi("status" + address + " --token-file " + secret);
  EXPECT_EQ(pasted.exitCode, 2) << pasted.output();
  EXPECT_EQ(pasted.output().find(secret), std::string::npos) << pasted.output();
  EXPECT_NE(pasted.err.find("--token-file"), std::string::npos) << pasted.err;
  const auto none = runPbgi("submit " + shellQuote(shot.string()) + address);
  EXPECT_EQ(none.exitCode, 2) << none.output();
  EXPECT_NE(none.err.find("PBGI_TOKEN"), std::string::npos) << none.err;
  // Reads are open by default (--read-access open), as the dashboard's are: no token needed.
  for (const char* read : {"status", "workers"}) {
    const auto open = runPbgi(std::string(read) + address);
    EXPECT_EQ(open.exitCode, 0) << read << ": " << open.output();
    EXPECT_EQ(open.err.find("token"), std::string::npos) << read << ": " << open.output();
  }
  // The logs of a job that is not there: the coordinator answered (no job 1 was submitted).
  const auto logs = runPbgi("logs 1" + address);
  EXPECT_EQ(logs.exitCode, 2) << logs.output();
  EXPECT_NE(logs.err.find("job 1: no such job"), std::string::npos) << logs.output();
  const auto outside = runPbgi("submit " + shellQuote(shot.string()) + " --output-dir /tmp" + connection_);
  EXPECT_EQ(outside.exitCode, 2) << outside.output();
  EXPECT_NE(outside.err.find("outside the coordinator's output root"), std::string::npos)
      << outside.err;
  EXPECT_NE(daemon_.log().find("refused peer="), std::string::npos);
}

// --read-access token: reads need the token over gRPC and HTTP alike (one policy); the page
// takes it once in its address and keeps it in a cookie; writes still need the header.
TEST(FarmCliReadAccess, TokenOnlyReadsAreRefusedWithoutTheTokenOverGrpcAndHttp) {
  const fs::path dir = testing::makeTempDir("farm-cli-read");
  testing::Process daemon({testing::binary("pbgi-coordinator").string(), "--state",
                           (dir / "state").string(), "--listen", "127.0.0.1:0", "--http",
                           "127.0.0.1:0", "--output-root", dir.string(), "--read-access", "token"},
                          dir / "coordinator.log");
  std::string http;
  ASSERT_TRUE(testing::waitFor(
      [&] {
        const std::string log = daemon.log();
        const size_t at = log.find("dashboard on http://");
        if (at == std::string::npos || !fs::exists(dir / "state/coordinator.addr")) return false;
        const size_t start = at + std::string("dashboard on http://").size();
        http = log.substr(start, log.find('/', start) - start);
        return true;
      },
      20.0))
      << daemon.log();
  std::string address = testing::slurpFile(dir / "state/coordinator.addr");
  address = " --coordinator " + address.substr(0, address.find('\n'));
  const std::string tokenFile = " --token-file " + shellQuote((dir / "state/token").string());
  std::string token = testing::slurpFile(dir / "state/token");
  token = token.substr(0, token.find('\n'));

  const auto refused = runPbgi("status" + address);
  EXPECT_EQ(refused.exitCode, 1) << refused.output();
  EXPECT_NE(refused.err.find("--read-access token"), std::string::npos) << refused.err;
  EXPECT_EQ(runPbgi("workers" + address + tokenFile).exitCode, 0);

  httplib::Client client("http://" + http);
  for (const char* path : {"/", "/api/jobs", "/status", "/metrics"}) {
    const auto res = client.Get(path);
    ASSERT_TRUE(res) << path;
    EXPECT_EQ(res->status, 401) << path << ": " << res->body;
  }
  const httplib::Headers bearer = {{"Authorization", "Bearer " + token}};
  const auto metrics = client.Get("/metrics", bearer);
  ASSERT_TRUE(metrics);
  EXPECT_EQ(metrics->status, 200);
  // The page opened once with the token: a cookie, and the address without it.
  const auto opened = client.Get("/?token=" + token);
  ASSERT_TRUE(opened);
  EXPECT_EQ(opened->status, 302);
  const std::string cookie = opened->get_header_value("Set-Cookie");
  EXPECT_NE(cookie.find("HttpOnly"), std::string::npos) << cookie;
  const auto api = client.Get("/api/jobs", {{"Cookie", cookie.substr(0, cookie.find(';'))}});
  ASSERT_TRUE(api);
  EXPECT_EQ(api->status, 200) << api->body;
  const auto wrongQuery = client.Get("/?token=nope");
  ASSERT_TRUE(wrongQuery);
  EXPECT_EQ(wrongQuery->status, 401);
  // A cookie reads; it never changes a job.
  const auto cancel =
      client.Post("/api/jobs/1/cancel", {{"Cookie", cookie.substr(0, cookie.find(';'))}}, "", "");
  ASSERT_TRUE(cancel);
  EXPECT_EQ(cancel->status, 401);
  daemon.signal(SIGTERM);
  EXPECT_EQ(daemon.wait(20.0), 0) << daemon.log();
  fs::remove_all(dir);
}

TEST(FarmCliText, AuditsSayTheirNumbersAndFlagTheFramesBeyondTheirThreshold) {
  farm::v1::JobStatus job;
  farm::v1::FrameAudit* ok = job.add_audits();
  ok->set_frame(1);
  ok->set_state("done");
  ok->set_has_result(true);
  ok->set_rel_mse(0.0041);
  ok->set_bias(-0.012);
  ok->set_spp(256);
  ok->set_threshold(0.05);
  ok->add_tiles(3);
  ok->add_tiles(9);
  farm::v1::FrameAudit* bad = job.add_audits();
  *bad = *ok;
  bad->set_frame(2);
  bad->set_rel_mse(0.2);
  bad->set_flagged(true);
  farm::v1::FrameAudit* waiting = job.add_audits();
  waiting->set_frame(3);
  waiting->set_state("ready");
  const std::string text = cli::describeAudits(job);
  EXPECT_NE(text.find("audit frame    1: relMSE 0.0041, bias -1.20 % against the path tracer at "
                      "256 spp on 2 tile(s)\n"),
            std::string::npos)
      << text;
  EXPECT_NE(text.find("audit frame    2: relMSE 0.2, bias -1.20 %"), std::string::npos) << text;
  EXPECT_NE(text.find("FLAGGED (above 0.05)"), std::string::npos) << text;
  EXPECT_NE(text.find("audit frame    3: ready\n"), std::string::npos) << text;
  EXPECT_EQ(cli::auditSummary(job), ", audited 2/3 frames, 1 FLAGGED");
  EXPECT_EQ(cli::auditSummary(farm::v1::JobStatus()), "");
}

TEST(DaemonCliTest, ConfigFilesAreStrict) {
  const fs::path dir = testing::makeTempDir("daemon-cli");
  std::ofstream(dir / "bad.toml") << "lease-seconds = 5\nbogus-key = 3\n";
  testing::Process coordinator({testing::binary("pbgi-coordinator").string(), "--config",
                                (dir / "bad.toml").string(), "--state", (dir / "s").string()},
                               dir / "coordinator.log");
  EXPECT_EQ(coordinator.wait(20.0), 2) << coordinator.log();
  EXPECT_NE(coordinator.log().find("bogus"), std::string::npos) << coordinator.log();
  testing::Process worker({testing::binary("pbgi-worker").string(), "--config",
                           (dir / "bad.toml").string(), "--coordinator", "127.0.0.1:1"},
                          dir / "worker.log");
  EXPECT_EQ(worker.wait(20.0), 2) << worker.log();
  // A worker without a token says where it looked.
  testing::Process tokenless({testing::binary("pbgi-worker").string(), "--coordinator", "127.0.0.1:1"},
                             dir / "tokenless.log", {"PBGI_TOKEN="});
  EXPECT_EQ(tokenless.wait(20.0), 2) << tokenless.log();
  EXPECT_NE(tokenless.log().find("PBGI_TOKEN"), std::string::npos) << tokenless.log();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace pbgi
