// pbgi run SHOT [--workers N] [--state DIR] [job flags]: the embedded farm. A coordinator in
// this process (its SQLite file in the state folder) and N pbgi-worker processes render every
// frame of the shot through the same gRPC calls, tasks and files as a farm of many machines.
// Run again after an interruption, the same job picks up where it stopped.

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <random>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <signal.h>
#include <sys/prctl.h>
#include <sys/wait.h>
#include <unistd.h>

#include "core/util/log.h"
#include "core/util/status.h"
#include "formats/shot/shot_file.h"
#include "services/cli/cli.h"
#include "services/cli/farm_cli.h"
#include "services/cli/progress.h"
#include "services/coordinator/coordinator.h"
#include "services/coordinator/farm_job.h"
#include "services/coordinator/farm_wire.h"
#include "services/util/daemon.h"

namespace pbgi::cli {

namespace {

namespace fs = std::filesystem;

struct RunOptions {
  std::string shot;
  int workers = 1;
  int threads = 0;
  std::string state;
  std::string outputRoot;
  int tileSize = 0;
  double leaseSeconds = 30.0;
  JobFlags job;
};

volatile std::sig_atomic_t interrupted = 0;
void onInterrupt(int) { interrupted = 1; }

// pbgi-worker lives beside this executable.
std::string workerExecutable() {
  std::error_code ec;
  const fs::path self = fs::read_symlink("/proc/self/exe", ec);
  return (self.parent_path() / "pbgi-worker").string();
}

struct Child {
  pid_t pid = -1;
  int index = 0;
  int restarts = 0;
};

// Starts worker `index`, its output appended to `logPath`. The worker is told to stop when
// this process dies, however it dies.
absl::StatusOr<pid_t> spawnWorker(const std::string& exe, const std::string& address,
                                  const std::string& token, int index, int threads,
                                  const std::string& logPath) {
  const std::string id = fmt::format("run-{}-{}", static_cast<long>(::getpid()), index);
  const std::string threadText = std::to_string(threads);
  const pid_t parent = ::getpid();
  const pid_t pid = ::fork();
  if (pid < 0) return absl::ResourceExhaustedError("fork failed: cannot start a worker");
  if (pid == 0) {
    ::prctl(PR_SET_PDEATHSIG, SIGTERM);
    if (::getppid() != parent) ::_exit(1);
    ::setenv("PBGI_TOKEN", token.c_str(), 1);
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

// The job this run continues: an unfinished one of the same shot bytes, overrides, frames and
// output (a run that was interrupted), else a new submission.
absl::StatusOr<int64_t> findOrSubmit(farm::Coordinator& coordinator, farm::FarmClient& client,
                                     const farm::v1::SubmitJobRequest& request, bool* resumed) {
  PBGI_ASSIGN_OR_RETURN(const std::vector<farm::JobInfo> jobs, coordinator.store().jobs());
  const std::string overrides = farm::joinOverrides(
      std::vector<std::string>(request.overrides().begin(), request.overrides().end()));
  for (const farm::JobInfo& j : jobs) {
    const bool sameFrames =
        request.frames().empty() ||
        std::equal(j.spec.frames.begin(), j.spec.frames.end(), request.frames().begin(),
                   request.frames().end());
    if (j.state == farm::JobState::kActive && j.spec.shotText == request.shot_text() &&
        j.spec.shotPath == request.shot_path() && j.spec.overrides == overrides && sameFrames) {
      *resumed = true;
      return j.id;
    }
  }
  PBGI_ASSIGN_OR_RETURN(const farm::v1::SubmitJobResponse submitted, client.submitJob(request));
  *resumed = false;
  return submitted.job();
}

int runEmbedded(const RunOptions& o) {
  auto shot = loadShotFile(o.shot);
  if (!shot.ok()) return reportError(shot.status());
  auto request = submitRequest(*shot, o.job);
  if (!request.ok()) return reportError(request.status());

  farm::CoordinatorOptions options;
  options.listen = "127.0.0.1:0";
  options.stateDir = o.state.empty() ? (fs::path(shot->dir) / ".pbgi-run").string() : o.state;
  options.outputRoot =
      o.outputRoot.empty() ? fs::path(shot->output).parent_path().string() : o.outputRoot;
  options.token = newToken();
  options.leaseSeconds = o.leaseSeconds;
  options.tileSize = o.tileSize;
  std::error_code ec;
  fs::create_directories(options.outputRoot, ec);
  // Quiet: the progress bar speaks for the coordinator; its warnings still show.
  log::setLevel(log::Level::kWarn);
  auto coordinator = farm::Coordinator::start(options);
  if (!coordinator.ok()) return reportError(coordinator.status());
  farm::FarmClient client((*coordinator)->address(), options.token);
  bool resumed = false;
  auto job = findOrSubmit(**coordinator, client, *request, &resumed);
  if (!job.ok()) return reportError(job.status());
  std::printf("%s job %lld of %s (state %s)\n", resumed ? "resuming" : "submitted",
              static_cast<long long>(*job), o.shot.c_str(), options.stateDir.c_str());
  std::fflush(stdout);

  const int hardware = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const int threads = std::max(1, (o.threads > 0 ? o.threads : hardware) / o.workers);
  const std::string exe = workerExecutable();
  const std::string logDir = farm::jobWorkDir(options.stateDir, *job);
  fs::create_directories(logDir, ec);
  const auto start = [&](int index) {
    return spawnWorker(exe, (*coordinator)->address(), options.token, index, threads,
                       (fs::path(logDir) / fmt::format("worker-{}.log", index)).string());
  };
  std::vector<Child> children(static_cast<size_t>(o.workers));
  for (int i = 0; i < o.workers; ++i) {
    children[i].index = i;
    auto pid = start(i);
    if (!pid.ok()) return reportError(pid.status());
    children[i].pid = *pid;
  }
  struct sigaction action {};
  action.sa_handler = onInterrupt;
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);

  Progress progress(fmt::format("{} job {}", shot->name, *job));
  farm::v1::GetStatusRequest ask;
  ask.set_job(*job);  // the counts by state are all a poll needs
  absl::StatusOr<farm::v1::GetStatusResponse> status;
  constexpr int kMaxRestarts = 3;
  int exitCode = kExitOk;
  while (!interrupted) {
    status = client.getStatus(ask);
    if (!status.ok()) {
      exitCode = reportError(status.status());
      break;
    }
    const farm::v1::JobStatus& js = status->jobs(0);
    const JobProgress p = jobProgress(js);
    // A done job's frames are audited next (the workers take audits once no task is left):
    // the run waits for them, so that it can say how the frames compare with the path tracer.
    const int audited = static_cast<int>(
        std::count_if(js.audits().begin(), js.audits().end(), [](const farm::v1::FrameAudit& a) {
          return a.state() == "done" || a.state() == "failed" || a.state() == "cancelled";
        }));
    progress.update(static_cast<uint64_t>(p.done + audited),
                    static_cast<uint64_t>(p.total + js.audits_size()));
    const farm::v1::JobState state = farm::jobStateOf(js);
    if (state != farm::v1::JOB_STATE_ACTIVE &&
        (state != farm::v1::JOB_STATE_DONE || audited == js.audits_size())) {
      break;
    }
    // A worker that died (a crash, the OOM killer) is started again, a few times.
    for (Child& c : children) {
      int wstatus = 0;
      if (c.pid > 0 && ::waitpid(c.pid, &wstatus, WNOHANG) == c.pid) {
        c.pid = -1;
        if (c.restarts++ < kMaxRestarts) {
          std::fprintf(stderr, "\npbgi: warning: worker %d exited (status %d); starting it again\n",
                       c.index, wstatus);
          if (auto pid = start(c.index); pid.ok()) c.pid = *pid;
        }
      }
    }
    if (std::all_of(children.begin(), children.end(), [](const Child& c) { return c.pid < 0; })) {
      std::fprintf(stderr, "\npbgi: error: every worker exited; their logs are in %s\n",
                   logDir.c_str());
      exitCode = kExitFailed;
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  progress.finish();
  // SIGTERM: a worker finishes the task in hand, reports it and exits.
  for (const Child& c : children) {
    if (c.pid > 0) ::kill(c.pid, SIGTERM);
  }
  for (const Child& c : children) {
    if (c.pid > 0) ::waitpid(c.pid, nullptr, 0);
  }
  if (interrupted) {
    (*coordinator)->shutdown();
    std::fprintf(stderr, "pbgi: error: interrupted; run the same command again to resume job %lld\n",
                 static_cast<long long>(*job));
    return kExitFailed;
  }
  if (exitCode != kExitOk || !status.ok()) {
    (*coordinator)->shutdown();
    return exitCode;
  }
  // The final state, after the workers have reported, with every task and output.
  ask.set_with_tasks(true);
  status = client.getStatus(ask);
  (*coordinator)->shutdown();
  if (!status.ok()) return reportError(status.status());
  const farm::v1::JobStatus& js = status->jobs(0);
  std::printf("%s", describeJob(js).c_str());
  if (farm::jobStateOf(js) != farm::v1::JOB_STATE_DONE) {
    std::fprintf(stderr, "pbgi: error: job %lld %s; the workers' logs are in %s\n",
                 static_cast<long long>(*job), farm::wireWord(farm::jobStateOf(js)).c_str(),
                 logDir.c_str());
    return kExitFailed;
  }
  return kExitOk;
}

}  // namespace

void registerRunCommand(CLI::App& app, CommandAction& action) {
  auto options = std::make_shared<RunOptions>();
  CLI::App* cmd = app.add_subcommand(
      "run", "The embedded farm: a coordinator and N local workers render every frame");
  cmd->add_option("SHOT", options->shot, "Shot file (TOML)")->required();
  cmd->add_option("--workers", options->workers, "Local worker processes (default 1)")
      ->check(CLI::Range(1, 256));
  cmd->add_option("--threads", options->threads,
                  "Render threads over all workers (default: all cores)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--state", options->state,
                  "State folder: the job database, bakes, tiles, worker logs (default: "
                  "<shot folder>/.pbgi-run)");
  cmd->add_option("--output-root", options->outputRoot,
                  "Frames must lie under this folder (default: the shot's output folder)");
  cmd->add_option("--tile-size", options->tileSize, "Farm tile edge in pixels (default 256)")
      ->check(CLI::Range(16, 8192));
  cmd->add_option("--lease-seconds", options->leaseSeconds, "Task lease length (default 30)")
      ->check(CLI::PositiveNumber);
  addJobFlags(*cmd, options->job);
  cmd->callback([options, &action] { action = [options] { return runEmbedded(*options); }; });
}

}  // namespace pbgi::cli
