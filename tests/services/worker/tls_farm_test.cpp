// TLS on the farm's channels, with certificates made by deploy/tls/make-certs.sh in a temporary
// folder: a real pbgi-worker renders a PBGI job over TLS with client certificates (its tree
// streamed from the page service), and each way a connection is refused is said clearly on the
// client's side (`pbgi` and pbgi-worker processes) and counted on the coordinator.

#include <gtest/gtest.h>

#include <fmt/format.h>

#include <cstdlib>
#include <fstream>

#include "services/farm/farm_tls.h"
#include "tests/support/worker_farm.h"

namespace pbgi::farm {
namespace {

namespace fs = std::filesystem;
using pbgi::testing::Process;
using pbgi::testing::runPbgi;
using pbgi::testing::shellQuote;
using pbgi::testing::waitFor;

uint64_t metricValue(const std::string& text, const std::string& name) {
  const size_t at = text.find("\n" + name + " ");
  return at == std::string::npos ? 0 : std::stoull(text.substr(at + name.size() + 2));
}

class TlsFarmTest : public pbgi::testing::WorkerFarmTest {
 protected:
  void SetUp() override {
    WorkerFarmTest::SetUp();
    certs_ = dir_ / "certs";
    other_ = dir_ / "other-farm";
    for (const fs::path& d : {certs_, other_}) {
      const std::string command =
          shellQuote((pbgi::testing::sourceDir() / "deploy/tls/make-certs.sh").string()) + " " +
          shellQuote(d.string()) + " farm-head >" + shellQuote((dir_ / "make-certs.log").string()) +
          " 2>&1";
      ASSERT_EQ(std::system(command.c_str()), 0)
          << pbgi::testing::slurpFile(dir_ / "make-certs.log");
    }
  }
  std::string cert(const std::string& name) const { return (certs_ / name).string(); }
  std::string otherCert(const std::string& name) const { return (other_ / name).string(); }

  // The fixture's coordinator, its client over TLS with the worker certificate.
  void startTls(TlsFiles server) {
    options_.tls = std::move(server);
    start();
    auto tls = readClientTls({cert("worker.crt"), cert("worker.key"), cert("ca.crt")});
    ASSERT_TRUE(tls.ok()) << tls.status();
    client_ = std::make_unique<FarmClient>(coordinator_->address(), options_.token, 10.0, *tls);
    std::ofstream(dir_ / "token") << options_.token << "\n";
  }
  uint64_t handshakeFailures() {
    return metricValue(coordinator_->metricsText(), "pbgi_tls_handshake_failures_total");
  }
  // `pbgi status` with `flags` is refused, saying each of `parts`, and the coordinator counts
  // a failed handshake (the client's, and the one it diagnoses the failure with).
  void expectRefused(const std::string& flags, const std::vector<std::string>& parts) {
    const uint64_t before = handshakeFailures();
    const auto r = runPbgi("status --coordinator " + coordinator_->address() + " --token-file " +
                           shellQuote((dir_ / "token").string()) + flags);
    EXPECT_EQ(r.exitCode, 1) << flags << ": " << r.output();
    for (const std::string& part : parts) {
      EXPECT_NE(r.err.find(part), std::string::npos) << flags << ": " << r.err;
    }
    EXPECT_TRUE(waitFor([&] { return handshakeFailures() > before; }, 10.0))
        << flags << ": not counted";
  }

  fs::path certs_;
  fs::path other_;
};

TEST_F(TlsFarmTest, AWorkerRendersAJobOverTlsWithClientCertificates) {
  startTls({cert("server.crt"), cert("server.key"), cert("ca.crt")});
  pbgi::testing::SmallShot shot;
  shot.integrator = "pbgi";
  shot.extraRender = "bake_points = 4000\nbake_bounces = 1\nquality = \"draft\"\n";
  const int64_t job = submit(shot, {1});
  ASSERT_NE(job, 0);
  // The worker's TLS files from its TOML config, like its other long flags; its tiles stream
  // the tree from the page service, over TLS too.
  const fs::path config = dir_ / "worker.toml";
  std::ofstream(config) << fmt::format("tls-ca = \"{}\"\ntls-cert = \"{}\"\ntls-key = \"{}\"\n",
                                       cert("ca.crt"), cert("worker.crt"), cert("worker.key"));
  Process& worker =
      startWorker("tls-worker", {"--config", config.string(), "--tree-source", "stream"});
  std::string state;
  ASSERT_TRUE(waitFor([&] { return settled(job, &state); }, 120.0)) << workerLogs();
  ASSERT_EQ(state, "done") << workerLogs();
  EXPECT_NE(worker.log().find("over TLS with a client certificate"), std::string::npos)
      << worker.log();
  const std::string metrics = coordinator_->metricsText();
  EXPECT_GT(metricValue(metrics, "pbgi_tree_pages_served_total"), 0u) << metrics;
  EXPECT_EQ(metricValue(metrics, "pbgi_rpc_refused_total"), 0u) << metrics;
  expectFrameEqualsWholeRender(1);
}

TEST_F(TlsFarmTest, RefusedConnectionsSayWhyAndAreCounted) {
  startTls({cert("server.crt"), cert("server.key"), cert("ca.crt")});
  // A plaintext client.
  expectRefused("", {"speaks TLS", "--tls-ca"});
  // A client that trusts another farm's CA.
  expectRefused(" --tls-ca " + otherCert("ca.crt") + " --tls-cert " + otherCert("worker.crt") +
                    " --tls-key " + otherCert("worker.key"),
                {"not trusted", "does not verify against the CA of --tls-ca"});
  // No client certificate, where the coordinator asks for one.
  expectRefused(" --tls-ca " + cert("ca.crt"),
                {"asks every client for a certificate", "--tls-cert"});
  // A client certificate of another farm.
  expectRefused(" --tls-ca " + cert("ca.crt") + " --tls-cert " + otherCert("worker.crt") +
                    " --tls-key " + otherCert("worker.key"),
                {"refused this client's certificate", "--tls-client-ca"});
  // A real worker without a client certificate gives up at once, saying why.
  const uint64_t before = handshakeFailures();
  Process& worker = startWorker("no-cert", {"--tls-ca", cert("ca.crt")});
  EXPECT_EQ(worker.wait(30.0), 1) << worker.log();
  EXPECT_NE(worker.log().find("asks every client for a certificate"), std::string::npos)
      << worker.log();
  EXPECT_GT(handshakeFailures(), before);
  // None of these reached the token check; over TLS the token is still required.
  const std::string tls = " --tls-ca " + cert("ca.crt") + " --tls-cert " + cert("worker.crt") +
                          " --tls-key " + cert("worker.key");
  std::ofstream(dir_ / "wrong-token") << "not-the-token\n";
  const auto wrong = runPbgi("cancel 1 --coordinator " + coordinator_->address() +
                             " --token-file " + shellQuote((dir_ / "wrong-token").string()) + tls);
  EXPECT_EQ(wrong.exitCode, 1) << wrong.output();
  EXPECT_NE(wrong.err.find("farm token"), std::string::npos) << wrong.err;
  EXPECT_EQ(metricValue(coordinator_->metricsText(), "pbgi_rpc_refused_total"), 1u);
  const auto good = runPbgi("status --coordinator " + coordinator_->address() + " --token-file " +
                            shellQuote((dir_ / "token").string()) + tls);
  EXPECT_EQ(good.exitCode, 0) << good.output();
  EXPECT_EQ(good.out, "no jobs\n");
}

TEST_F(TlsFarmTest, AnExpiredServerCertificateIsRefusedByItsClients) {
  // Signed by the farm's CA for one day in 2020 (`openssl ca -startdate -enddate`: Debian 12's
  // OpenSSL 3.0 `x509` has no way to date a certificate in the past).
  const std::string command = fmt::format(
      "cd {} && mkdir -p expired && : >expired/index.txt && echo 01 >expired/serial && "
      "printf '[ca]\\ndefault_ca = farm\\n[farm]\\ndatabase = expired/index.txt\\n"
      "new_certs_dir = expired\\nserial = expired/serial\\ndefault_md = sha256\\npolicy = any\\n"
      "copy_extensions = copy\\n[any]\\ncommonName = supplied\\n' >expired/ca.cnf && "
      "openssl req -new -key server.key -subj /CN=pbgi-coordinator "
      "-addext subjectAltName=IP:127.0.0.1 -out expired/server.csr && "
      "openssl ca -config expired/ca.cnf -batch -notext -startdate 20200101000000Z "
      "-enddate 20200102000000Z -in expired/server.csr -cert ca.crt -keyfile ca.key "
      "-out expired.crt >expired/log 2>&1",
      shellQuote(certs_.string()));
  ASSERT_EQ(std::system(command.c_str()), 0) << pbgi::testing::slurpFile(certs_ / "expired/log");
  startTls({cert("expired.crt"), cert("server.key"), ""});
  expectRefused(" --tls-ca " + cert("ca.crt"), {"not trusted", "expired on", "2020"});
}

TEST_F(TlsFarmTest, ATlsClientOfAPlaintextCoordinatorIsToldSo) {
  start();
  std::ofstream(dir_ / "token") << options_.token << "\n";
  const auto r = runPbgi("status --coordinator " + coordinator_->address() + " --token-file " +
                         shellQuote((dir_ / "token").string()) + " --tls-ca " + cert("ca.crt"));
  EXPECT_EQ(r.exitCode, 1) << r.output();
  EXPECT_NE(r.err.find("does not answer TLS"), std::string::npos) << r.err;
}

// pbgi-coordinator reads its TLS files from its TOML config, and refuses files that do not fit
// before it listens.
TEST_F(TlsFarmTest, TheCoordinatorDaemonReadsTlsFromItsConfig) {
  const fs::path state = dir_ / "daemon-state";
  const auto daemon = [&](const std::string& name, const std::string& key) {
    const fs::path config = dir_ / (name + ".toml");
    std::ofstream(config) << fmt::format(
        "tls-cert = \"{}\"\ntls-key = \"{}\"\ntls-client-ca = \"{}\"\n", cert("server.crt"), key,
        cert("ca.crt"));
    return Process({pbgi::testing::binary("pbgi-coordinator").string(), "--config", config.string(),
                    "--state", state.string(), "--listen", "127.0.0.1:0"},
                   dir_ / (name + ".log"));
  };
  Process mismatched = daemon("mismatched", otherCert("server.key"));
  EXPECT_EQ(mismatched.wait(20.0), 2) << mismatched.log();
  EXPECT_NE(mismatched.log().find("is not the key of --tls-cert"), std::string::npos)
      << mismatched.log();
  Process good = daemon("good", cert("server.key"));
  ASSERT_TRUE(waitFor([&] { return fs::exists(state / "coordinator.addr"); }, 20.0)) << good.log();
  std::string address = pbgi::testing::slurpFile(state / "coordinator.addr");
  address = address.substr(0, address.find('\n'));
  const auto r = runPbgi("workers --coordinator " + address + " --token-file " +
                         shellQuote((state / "token").string()) + " --tls-ca " + cert("ca.crt") +
                         " --tls-cert " + cert("worker.crt") + " --tls-key " + cert("worker.key"));
  EXPECT_EQ(r.exitCode, 0) << r.output() << good.log();
  EXPECT_EQ(r.out, "no workers\n");
  EXPECT_NE(good.log().find("TLS, client certificates required"), std::string::npos) << good.log();
  good.signal(SIGTERM);
  EXPECT_EQ(good.wait(20.0), 0) << good.log();
}

}  // namespace
}  // namespace pbgi::farm
