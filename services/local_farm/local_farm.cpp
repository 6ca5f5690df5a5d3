#include "services/local_farm/local_farm.h"

#include <algorithm>
#include <cstdio>
#include <filesystem>

#include <fmt/format.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include "core/util/status.h"
#include "services/coordinator/coordinator.h"
#include "services/farm/farm_client.h"
#include "services/farm/farm_wire.h"
#include "services/farm/job_rules.h"

namespace pbgi::farm {

namespace {

namespace fs = std::filesystem;

// pbgi-worker lives beside this executable.
std::string workerExecutable() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  return (self.parent_path() / "pbgi-worker").string();
}

}  // namespace

LocalFarm::LocalFarm(LocalFarmOptions options, std::unique_ptr<Coordinator> coordinator)
    : options_(std::move(options)), coordinator_(std::move(coordinator)) {}

LocalFarm::~LocalFarm() { shutdown(); }

absl::StatusOr<std::unique_ptr<LocalFarm>> LocalFarm::start(const LocalFarmOptions& options) {
  CoordinatorOptions coordinator;
  coordinator.listen = "127.0.0.1:0";
  coordinator.stateDir = options.stateDir;
  coordinator.outputRoot = options.outputRoot;
  coordinator.token = options.token;
  coordinator.leaseSeconds = options.leaseSeconds;
  coordinator.tileSize = options.tileSize;
  std::error_code ec;
  fs::create_directories(options.outputRoot, ec);
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Coordinator> started, Coordinator::start(coordinator));
  return std::unique_ptr<LocalFarm>(new LocalFarm(options, std::move(started)));
}

const std::string& LocalFarm::address() const { return coordinator_->address(); }

absl::StatusOr<int64_t> LocalFarm::findOrSubmit(const v1::SubmitJobRequest& request,
                                                bool* resumed) {
  PBGI_ASSIGN_OR_RETURN(const std::vector<JobInfo> jobs, coordinator_->store().jobs());
  PBGI_ASSIGN_OR_RETURN(const RenderOverrides overrides, submittedOverrides(request));
  for (const JobInfo& j : jobs) {
    const bool sameFrames =
        request.frames().empty() || std::equal(j.spec.frames.begin(), j.spec.frames.end(),
                                               request.frames().begin(), request.frames().end());
    if (j.state == JobState::kActive && j.spec.shotText == request.shot_text() &&
        j.spec.shotPath == request.shot_path() && j.spec.overrides == overrides && sameFrames) {
      *resumed = true;
      return j.id;
    }
  }
  FarmClient client(coordinator_->address(), options_.token);
  PBGI_ASSIGN_OR_RETURN(const v1::SubmitJobResponse submitted, client.submitJob(request));
  *resumed = false;
  return submitted.job();
}

absl::StatusOr<pid_t> LocalFarm::spawn(int index) const {
  const std::string exe = workerExecutable();
  const std::string logPath = (fs::path(logDir_) / fmt::format("worker-{}.log", index)).string();
  const std::string id = fmt::format("run-{}-{}", static_cast<long>(::getpid()), index);
  const std::string threadText = std::to_string(threads_);
  const std::string& address = coordinator_->address();
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid < 0) return absl::ResourceExhaustedError("fork failed: cannot start a worker");
  if (pid == 0) {
    ::prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (::getppid() != parent) ::_exit(1);
    ::setenv("PBGI_TOKEN", options_.token.c_str(), 1);
    std::FILE* log = std::fopen(logPath.c_str(), "a");
    if (log != nullptr) {
      ::dup2(::fileno(log), 1);
      ::dup2(::fileno(log), 2);
    }
    ::execl(exe.c_str(), exe.c_str(), "--coordinator", address.c_str(), "--id", id.c_str(),
            "--threads", threadText.c_str(), "--poll-seconds", "0.1", static_cast<char*>(nullptr));
    std::fprintf(stderr, "pbgi run: cannot start %s\n", exe.c_str());
    ::_exit(127);
  }
  return pid;
}

absl::Status LocalFarm::startWorkers(int64_t job, int count, int threads) {
  logDir_ = jobWorkDir(options_.stateDir, job);
  threads_ = std::max(1, threads);
  std::error_code ec;
  fs::create_directories(logDir_, ec);
  for (int i = 0; i < count; ++i) {
    PBGI_ASSIGN_OR_RETURN(const pid_t pid, spawn(i));
    workers_.push_back({.pid = pid, .index = i});
  }
  return absl::OkStatus();
}

bool LocalFarm::superviseWorkers() {
  for (Worker& w : workers_) {
    int wstatus = 0;
    if (w.pid > 0 && ::waitpid(w.pid, &wstatus, WNOHANG) == w.pid) {
      w.pid = -1;
      if (w.restarts++ < kMaxRestarts) {
        std::fprintf(stderr, "\npbgi: warning: worker %d exited (status %d); starting it again\n",
                     w.index, wstatus);
        if (auto pid = spawn(w.index); pid.ok()) w.pid = *pid;
      }
    }
  }
  return std::any_of(workers_.begin(), workers_.end(), [](const Worker& w) { return w.pid > 0; });
}

void LocalFarm::stopWorkers() {
  for (const Worker& w : workers_) {
    if (w.pid > 0) ::kill(w.pid, SIGTERM);
  }
  for (Worker& w : workers_) {
    if (w.pid > 0) ::waitpid(w.pid, nullptr, 0);
    w.pid = -1;
  }
}

void LocalFarm::shutdown() {
  stopWorkers();
  if (coordinator_) coordinator_->shutdown();
}

}  // namespace pbgi::farm
