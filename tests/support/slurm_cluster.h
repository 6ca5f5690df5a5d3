#pragma once
// A throwaway one-node Slurm cluster for tests: munged, slurmctld and slurmd started here, in a
// folder of their own (munge key and socket, spool, state, logs) on free ports, with the
// cgroup-free settings a container allows (proctrack/linuxproc, task/none). Needs root (slurmd
// runs jobs as their submitter) and Debian's slurm-wlm and munge; `unavailable()` says what is
// missing. Commands talk to it through SLURM_CONF (`command()` prefixes it).
#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <optional>
#include <string>
#include <thread>

#include "tests/support/run_pbgi.h"
#include "tests/support/test_paths.h"

namespace pbgi::testing {

// A TCP port nothing listens on now (the kernel's pick for port 0).
inline int freeTcpPort() {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in a{};
  a.sin_family = AF_INET;
  a.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t len = sizeof(a);
  int port = 0;
  if (::bind(fd, reinterpret_cast<sockaddr*>(&a), sizeof(a)) == 0 &&
      ::getsockname(fd, reinterpret_cast<sockaddr*>(&a), &len) == 0) {
    port = ntohs(a.sin_port);
  }
  ::close(fd);
  return port;
}

// The output of a shell command (stdout), and its exit status.
struct ShellResult {
  int status = -1;
  std::string out;
};
inline ShellResult shell(const std::string& command) {
  ShellResult r;
  std::FILE* p = ::popen(command.c_str(), "r");
  if (p == nullptr) return r;
  char buffer[4096];
  size_t n;
  while ((n = std::fread(buffer, 1, sizeof(buffer), p)) > 0) r.out.append(buffer, n);
  const int status = ::pclose(p);
  r.status = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  return r;
}

class SlurmCluster {
 public:
  // Why no cluster can be started here, or nullopt when one can.
  static std::optional<std::string> unavailable() {
    if (::geteuid() != 0) return "not root: slurmd must run as root to start jobs";
    for (const char* tool : {"/usr/sbin/munged", "/usr/sbin/slurmctld", "/usr/sbin/slurmd",
                             "/usr/bin/sbatch", "/usr/bin/scancel", "/usr/bin/squeue"}) {
      if (!std::filesystem::exists(tool)) {
        return std::string(tool) + " is missing (apt-get install slurm-wlm munge)";
      }
    }
    return std::nullopt;
  }

  // Starts the daemons and waits for the node to be idle; error() says why when it failed.
  SlurmCluster() : dir_(makeTempDir("slurm")) {
    namespace fs = std::filesystem;
    const fs::path munge = dir_ / "munge";
    fs::create_directories(munge);
    fs::create_directories(dir_ / "state");
    fs::create_directories(dir_ / "spool");
    // munged wants its folder closed to others but passable (the socket), its key owner-only.
    fs::permissions(dir_, fs::perms::owner_all | fs::perms::group_exec | fs::perms::others_exec);
    fs::permissions(munge, fs::perms::owner_all | fs::perms::group_exec | fs::perms::others_exec);
    const fs::path key = munge / "munge.key";
    if (shell("head -c 1024 /dev/urandom > " + key.string() + " && chmod 400 " + key.string())
            .status != 0) {
      error_ = "cannot write the munge key";
      return;
    }
    socket_ = (munge / "munge.sock").string();
    ShellResult m = shell(
        "/usr/sbin/munged --force --socket=" + socket_ + " --key-file=" + key.string() +
        " --log-file=" + (munge / "munged.log").string() + " --pid-file=" +
        (munge / "munged.pid").string() + " --seed-file=" + (munge / "munged.seed").string() +
        " 2>&1");
    if (m.status != 0) {
      error_ = "munged did not start: " + m.out;
      return;
    }
    mungeStarted_ = true;
    const std::string host = shell("hostname -s").out;
    host_ = host.substr(0, host.find_first_of("\r\n"));
    conf_ = (dir_ / "slurm.conf").string();
    const std::string d = dir_.string();
    std::ofstream(conf_) << "ClusterName=pbgitest\n"
                         // Addresses given: a container's hostname need not resolve.
                         << "SlurmctldHost=" << host_ << "(127.0.0.1)\n"
                         << "SlurmctldPort=" << freeTcpPort() << "\n"
                         << "SlurmdPort=" << freeTcpPort() << "\n"
                         << "SlurmUser=root\nSlurmdUser=root\n"
                         << "AuthType=auth/munge\nCredType=cred/munge\n"
                         << "AuthInfo=socket=" << socket_ << "\n"
                         << "StateSaveLocation=" << d << "/state\n"
                         << "SlurmdSpoolDir=" << d << "/spool\n"
                         << "SlurmctldPidFile=" << d << "/slurmctld.pid\n"
                         << "SlurmdPidFile=" << d << "/slurmd.pid\n"
                         << "SlurmctldLogFile=" << d << "/slurmctld.log\n"
                         << "SlurmdLogFile=" << d << "/slurmd.log\n"
                         << "ProctrackType=proctrack/linuxproc\nTaskPlugin=task/none\n"
                         << "JobAcctGatherType=jobacct_gather/none\n"
                         << "AccountingStorageType=accounting_storage/none\n"
                         << "JobCompType=jobcomp/none\nMpiDefault=none\n"
                         << "SelectType=select/cons_tres\nSelectTypeParameters=CR_CPU\n"
                         << "ReturnToService=2\nKillWait=5\n"
                         << "SlurmdParameters=config_overrides\n"
                         << "NodeName=" << host_ << " NodeAddr=127.0.0.1 CPUs=4 State=UNKNOWN\n"
                         << "PartitionName=test Nodes=" << host_
                         << " Default=YES MaxTime=INFINITE State=UP\n";
    if (ShellResult c = shell(command("/usr/sbin/slurmctld -i -f " + conf_) + " 2>&1");
        c.status != 0) {
      error_ = "slurmctld did not start: " + c.out + log("slurmctld.log");
      return;
    }
    ctldStarted_ = true;
    if (ShellResult c = shell(command("/usr/sbin/slurmd -f " + conf_) + " 2>&1"); c.status != 0) {
      error_ = "slurmd did not start: " + c.out + log("slurmd.log");
      return;
    }
    const auto until = std::chrono::steady_clock::now() + std::chrono::seconds(30);
    while (std::chrono::steady_clock::now() < until) {
      if (shell(command("sinfo -h -o %t")).out.starts_with("idle")) return;
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    error_ = "the node never came up idle: " + shell(command("sinfo") + " 2>&1").out +
             log("slurmctld.log") + log("slurmd.log");
  }
  ~SlurmCluster() {
    if (ctldStarted_) {
      shell(command("scancel --full --signal=KILL --user=root") + " >/dev/null 2>&1");
      shell(command("scontrol shutdown") + " >/dev/null 2>&1");
    }
    // Whatever did not stop by itself.
    for (const char* pid : {"slurmd.pid", "slurmctld.pid", "munge/munged.pid"}) {
      shell("test -f " + (dir_ / pid).string() + " && kill -9 $(cat " + (dir_ / pid).string() +
            ") 2>/dev/null");
    }
  }
  SlurmCluster(const SlurmCluster&) = delete;
  SlurmCluster& operator=(const SlurmCluster&) = delete;

  const std::string& error() const { return error_; }
  const std::filesystem::path& dir() const { return dir_; }
  // `cmd` with SLURM_CONF pointing at this cluster.
  std::string command(const std::string& cmd) const { return "SLURM_CONF=" + conf_ + " " + cmd; }
  // A daemon's log, for failure messages.
  std::string log(const std::string& name) const {
    return "\n--- " + name + ":\n" + slurpFile(dir_ / name);
  }

 private:
  std::filesystem::path dir_;
  std::string conf_, socket_, host_, error_;
  bool mungeStarted_ = false, ctldStarted_ = false;
};

}  // namespace pbgi::testing
