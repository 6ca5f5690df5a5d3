// Workers as a Slurm job array (deploy/slurm/pbgi-worker.sbatch) on a one-node cluster this
// test starts itself (tests/support/slurm_cluster.h): a 2-frame job renders to completion while
// one array task is killed mid-tile with scancel; its tile is retried by the other worker, no
// tile completes twice, and both frames are bit-identical to the frames rendered whole. An
// array given PBGI_TLS_DIR joins a coordinator that asks for client certificates.
// Those need root and slurm-wlm + munge: they skip anywhere else and say why, except where
// PBGI_REQUIRE_SLURM=1 (CI) turns the skip into a failure.
// The script's TLS settings are tested outside Slurm too (it needs none of Slurm's variables):
// a folder or the PBGI_TLS_* variables reach a TLS coordinator with the files
// deploy/tls/make-certs.sh makes, none still reaches a plaintext one, and each setting that
// does not fit ends it with status 2 saying which.
#include <gtest/gtest.h>

#include <cstdlib>
#include <map>
#include <regex>
#include <set>

#include "tests/deploy/deploy_farm.h"
#include "tests/support/slurm_cluster.h"
#include "tests/support/worker_farm.h"

namespace pbgi::testing {
namespace {

namespace fs = std::filesystem;

fs::path script() { return sourceDir() / "deploy/slurm/pbgi-worker.sbatch"; }

// Skips (or fails, where PBGI_REQUIRE_SLURM=1) where no Slurm cluster can be started.
#define SKIP_WITHOUT_SLURM()                                                          \
  if (auto why = SlurmCluster::unavailable()) {                                       \
    const char* require = std::getenv("PBGI_REQUIRE_SLURM");                          \
    if (require != nullptr && std::string(require) == "1") {                          \
      FAIL() << "PBGI_REQUIRE_SLURM=1 but no Slurm cluster can be started: " << *why; \
    }                                                                                 \
    GTEST_SKIP() << "no Slurm cluster can be started here: " << *why;                 \
  }

// Cancels the array while the cluster runs and waits for it to leave the queue (SIGTERM: an
// idle worker exits at once); a job step still running when its slurmd is shut down stays
// behind as a stray slurmstepd.
void expectArrayStops(const SlurmCluster& slurm, const std::string& arrayJob) {
  shell(slurm.command("scancel " + arrayJob));
  EXPECT_TRUE(waitFor([&] { return shell(slurm.command("squeue -h 2>&1")).out.empty(); }, 15.0))
      << shell(slurm.command("squeue 2>&1")).out;
}

// A farm whose coordinator serves TLS and asks for client certificates, with the files of
// make-certs.sh (certs_) and a folder as a studio would share it (shared_: ca.crt, worker.crt,
// worker.key only).
class SlurmWorkerTest : public WorkerFarmTest {
 protected:
  void makeTlsFiles() {
    certs_ = dir_ / "certs";
    shared_ = dir_ / "shared";
    ASSERT_TRUE(makeCerts(certs_, {"farm-head"}));
    fs::create_directories(shared_);
    for (const char* f : {"ca.crt", "worker.crt", "worker.key"}) {
      fs::copy_file(certs_ / f, shared_ / f);
    }
    std::ofstream(dir_ / "token") << options_.token << "\n";
  }
  void startTls() {
    makeTlsFiles();
    options_.tls = {cert("server.crt"), cert("server.key"), cert("ca.crt")};
    start();
  }
  std::string cert(const std::string& name) const { return (certs_ / name).string(); }
  farm::TlsFiles clientTls() const {
    return {cert("worker.crt"), cert("worker.key"), cert("ca.crt")};
  }
  // The script run directly as array task `task` of job "local", with `env` over settings
  // of this farm; every TLS variable not in `env` is empty.
  Process runScript(int task, std::vector<std::string> env) {
    std::vector<std::string> all = {"PBGI_TLS_DIR=",
                                    "PBGI_TLS_CA=",
                                    "PBGI_TLS_CERT=",
                                    "PBGI_TLS_KEY=",
                                    "PBGI_COORDINATOR=" + coordinator_->address(),
                                    "PBGI_TOKEN_FILE=" + (dir_ / "token").string(),
                                    "PBGI_WORKER=" + binary("pbgi-worker").string(),
                                    "PBGI_CACHE_ROOT=" + dir_.string(),
                                    "PBGI_WORKER_ARGS=--poll-seconds 0.05",
                                    "SLURM_ARRAY_JOB_ID=local",
                                    "SLURM_ARRAY_TASK_ID=" + std::to_string(task)};
    all.insert(all.end(), env.begin(), env.end());  // putenv: a later one wins
    return Process({"/bin/bash", script().string()},
                   dir_ / ("script-" + std::to_string(task) + ".log"), all);
  }
  fs::path certs_;
  fs::path shared_;
};

TEST_F(SlurmWorkerTest, AWorkerArrayRendersAJobAndAScancelledWorkersTileIsRetried) {
  SKIP_WITHOUT_SLURM();
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
    return shell("cat " + (dir_ / "slurm-*.log").string() + " 2>&1").out + slurm.log("slurmd.log");
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
  expectArrayStops(slurm, arrayJob);
}

TEST_F(SlurmWorkerTest, AWorkerArrayWithPbgiTlsDirJoinsACoordinatorThatAsksForCertificates) {
  SKIP_WITHOUT_SLURM();
  SlurmCluster slurm;
  ASSERT_TRUE(slurm.error().empty()) << slurm.error();
  startTls();
  // README.md's command, with this farm's coordinator, token, binary and folders.
  const ShellResult submitted = shell(slurm.command(
      "PBGI_COORDINATOR=" + coordinator_->address() +
      " PBGI_TOKEN_FILE=" + (dir_ / "token").string() + " PBGI_TLS_DIR=" + shared_.string() +
      " PBGI_WORKER=" + binary("pbgi-worker").string() + " PBGI_CACHE_ROOT=" + dir_.string() +
      " sbatch --parsable --array=0-1 --cpus-per-task=1 --output=" +
      (dir_ / "slurm-%A_%a.log").string() + " " + script().string() + " 2>&1"));
  ASSERT_EQ(submitted.status, 0) << submitted.out << slurm.log("slurmctld.log");
  const std::string arrayJob = submitted.out.substr(0, submitted.out.find_first_of(";\n"));
  auto tls = farm::readClientTls(clientTls());
  ASSERT_TRUE(tls.ok()) << tls.status();
  FarmClient client(coordinator_->address(), options_.token, 5.0, *tls);
  std::set<std::string> seen;
  const bool joined = waitFor(
      [&] {
        auto list = client.listWorkers({});
        if (!list.ok()) return false;
        for (const auto& w : list->workers()) {
          for (const char* task : {"_0@", "_1@"}) {
            if (w.worker().starts_with("slurm-" + arrayJob + task)) seen.insert(task);
          }
        }
        return seen.size() == 2;
      },
      20.0);
  EXPECT_TRUE(joined) << "array tasks registered: " << seen.size() << " of 2\n"
                      << shell("cat " + (dir_ / "slurm-*.log").string() + " 2>&1").out
                      << slurm.log("slurmd.log");
  EXPECT_EQ(shell("cat " + (dir_ / "slurm-*.log").string()).out.find("holds ca.key"),
            std::string::npos);
  expectArrayStops(slurm, arrayJob);
}

TEST_F(SlurmWorkerTest, TheScriptJoinsATlsCoordinatorWithAFolderOrWithVariables) {
  startTls();
  {
    Process worker = runScript(1, {"PBGI_TLS_DIR=" + shared_.string()});
    EXPECT_TRUE(workerRegisters(worker, coordinator_->address(), options_.token, clientTls(),
                                "slurm-local_1@"));
    EXPECT_EQ(worker.log().find("holds ca.key"), std::string::npos) << worker.log();
  }
  {
    Process worker =
        runScript(2, {"PBGI_TLS_CA=" + cert("ca.crt"), "PBGI_TLS_CERT=" + cert("worker.crt"),
                      "PBGI_TLS_KEY=" + cert("worker.key")});
    EXPECT_TRUE(workerRegisters(worker, coordinator_->address(), options_.token, clientTls(),
                                "slurm-local_2@"));
  }
  {
    // The CA without a client certificate: the coordinator refuses it; the worker stops
    // (status 1) and says why, as README.md tells.
    Process worker = runScript(3, {"PBGI_TLS_CA=" + cert("ca.crt")});
    EXPECT_EQ(worker.wait(20.0), 1) << worker.log();
    EXPECT_NE(worker.log().find("asks every client for a certificate"), std::string::npos)
        << worker.log();
  }
  {
    // No TLS variable: plaintext, which this coordinator refuses in the same way.
    Process worker = runScript(4, {});
    EXPECT_EQ(worker.wait(20.0), 1) << worker.log();
    EXPECT_NE(worker.log().find("speaks TLS"), std::string::npos) << worker.log();
  }
}

TEST_F(SlurmWorkerTest, TheScriptWithoutTlsVariablesJoinsAPlaintextCoordinatorAsBefore) {
  start();
  std::ofstream(dir_ / "token") << options_.token << "\n";
  Process worker = runScript(0, {});
  EXPECT_TRUE(
      workerRegisters(worker, coordinator_->address(), options_.token, {}, "slurm-local_0@"));
}

TEST_F(SlurmWorkerTest, TheScriptRefusesTlsSettingsThatDoNotFitSayingWhich) {
  makeTlsFiles();
  const fs::path noKey = dir_ / "no-key";
  fs::create_directories(noKey);
  fs::copy_file(certs_ / "ca.crt", noKey / "ca.crt");
  fs::copy_file(certs_ / "worker.crt", noKey / "worker.crt");
  struct Case {
    std::string env;
    int status;
    std::string says;
  };
  const std::string missing = (dir_ / "missing.crt").string();
  const std::vector<Case> cases = {
      {"PBGI_TLS_DIR=" + (dir_ / "nowhere").string(), 2,
       "PBGI_TLS_DIR: " + (dir_ / "nowhere").string() + " is not a folder"},
      {"PBGI_TLS_DIR=" + noKey.string(), 2,
       "PBGI_TLS_DIR: " + (noKey / "worker.key").string() + ": no such file"},
      {"PBGI_TLS_CA=" + missing, 2, "PBGI_TLS_CA: " + missing + ": no such file"},
      {"PBGI_TLS_CA=" + cert("ca.crt") + " PBGI_TLS_CERT=" + cert("worker.crt"), 2,
       "PBGI_TLS_CERT needs PBGI_TLS_KEY"},
      {"PBGI_TLS_CA=" + cert("ca.crt") + " PBGI_TLS_KEY=" + cert("worker.key"), 2,
       "PBGI_TLS_KEY needs PBGI_TLS_CERT"},
      {"PBGI_TLS_CERT=" + cert("worker.crt") + " PBGI_TLS_KEY=" + cert("worker.key"), 2,
       "need PBGI_TLS_CA or PBGI_TLS_DIR"},
      {"PBGI_TLS_CA=" + cert("ca.crt") + " PBGI_TLS_CERT=" + missing +
           " PBGI_TLS_KEY=" + cert("worker.key"),
       2, "PBGI_TLS_CERT: " + missing + ": no such file"},
      // make-certs.sh's own folder works, but holds the keys no node should see.
      {"PBGI_TLS_DIR=" + certs_.string(), 0,
       "warning: PBGI_TLS_DIR: " + certs_.string() + " holds ca.key or server.key"},
  };
  for (const Case& c : cases) {
    // PBGI_WORKER=echo: what the worker would be started with, and no worker.
    const ShellResult r = shell(
        "env PBGI_TLS_DIR= PBGI_TLS_CA= PBGI_TLS_CERT= PBGI_TLS_KEY= "
        "PBGI_COORDINATOR=farm-head:7411 "
        "PBGI_TOKEN=t PBGI_WORKER=echo PBGI_CACHE_ROOT=" +
        shellQuote(dir_.string()) + " " + c.env + " bash " + shellQuote(script().string()) +
        " 2>&1");
    EXPECT_EQ(r.status, c.status) << c.env << ":\n" << r.out;
    EXPECT_NE(r.out.find(c.says), std::string::npos) << c.env << ":\n" << r.out;
  }
}

}  // namespace
}  // namespace pbgi::testing
