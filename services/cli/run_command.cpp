// pbgi run SHOT [--workers N] [--state DIR] [job flags]: the embedded farm
// (services/local_farm) renders every frame of the shot. Run again after an interruption, the
// same job picks up where it stopped.

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <filesystem>
#include <thread>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <signal.h>

#include "core/util/log.h"
#include "core/util/status.h"
#include "formats/shot/shot_file.h"
#include "services/cli/cli.h"
#include "services/cli/farm_cli.h"
#include "services/cli/progress.h"
#include "services/farm/farm_client.h"
#include "services/farm/farm_json.h"
#include "services/farm/farm_wire.h"
#include "services/local_farm/local_farm.h"
#include "services/util/cli_checks.h"
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
  bool json = false;
  JobFlags job;
};

volatile std::sig_atomic_t interrupted = 0;
void onInterrupt(int) { interrupted = 1; }

// How far a job has come, counting the audits a done job's frames wait for (the workers take
// audits once no task is left): the run waits for them, so that it can say how the frames
// compare with the path tracer. Sets `finished` once nothing is left to wait for.
JobProgress runProgress(const farm::v1::JobStatus& js, bool* finished) {
  JobProgress p = jobProgress(js);
  const int audited = static_cast<int>(
      std::count_if(js.audits().begin(), js.audits().end(), [](const farm::v1::FrameAudit& a) {
        return a.state() == "done" || a.state() == "failed" || a.state() == "cancelled";
      }));
  const farm::v1::JobState state = farm::jobStateOf(js);
  *finished = state != farm::v1::JOB_STATE_ACTIVE &&
              (state != farm::v1::JOB_STATE_DONE || audited == js.audits_size());
  p.done += audited;
  p.total += js.audits_size();
  return p;
}

// Polls the job until it finishes, the run is interrupted or every worker has exited for
// good, restarting workers that die. kExitOk when the job finished (whatever its state).
int waitForJob(farm::LocalFarm& farm, farm::FarmClient& client, int64_t job,
               const std::string& name) {
  Progress progress(fmt::format("{} job {}", name, job));
  farm::v1::GetStatusRequest ask;
  ask.set_job(job);  // the counts by state are all a poll needs
  int exitCode = kExitOk;
  while (!interrupted) {
    const absl::StatusOr<farm::v1::GetStatusResponse> status = client.getStatus(ask);
    if (!status.ok()) {
      exitCode = reportError(status.status());
      break;
    }
    bool finished = false;
    const JobProgress p = runProgress(status->jobs(0), &finished);
    progress.update(static_cast<uint64_t>(p.done), static_cast<uint64_t>(p.total));
    if (finished) break;
    if (!farm.superviseWorkers()) {
      std::fprintf(stderr, "\npbgi: error: every worker exited; their logs are in %s\n",
                   farm.logDir().c_str());
      exitCode = kExitFailed;
      break;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  progress.finish();
  return exitCode;
}

// The job's final state, after the workers have reported, with every task and output.
int reportJob(farm::FarmClient& client, int64_t job, const std::string& logDir, bool json) {
  farm::v1::GetStatusRequest ask;
  ask.set_job(job);
  ask.set_with_tasks(true);
  const absl::StatusOr<farm::v1::GetStatusResponse> status = client.getStatus(ask);
  if (!status.ok()) return reportError(status.status());
  const farm::v1::JobStatus& js = status->jobs(0);
  if (json) {
    std::printf("%s\n", farm::toJson(js).c_str());
  } else {
    std::printf("%s", describeJob(js).c_str());
  }
  if (farm::jobStateOf(js) != farm::v1::JOB_STATE_DONE) {
    std::fprintf(stderr, "pbgi: error: job %lld %s; the workers' logs are in %s\n",
                 static_cast<long long>(job), farm::wireWord(farm::jobStateOf(js)).c_str(),
                 logDir.c_str());
    return kExitFailed;
  }
  return kExitOk;
}

int runEmbedded(const RunOptions& o) {
  auto shot = loadShotFile(o.shot);
  if (!shot.ok()) return reportError(shot.status());
  auto request = submitRequest(*shot, o.job);
  if (!request.ok()) return reportError(request.status());

  farm::LocalFarmOptions options;
  options.stateDir = o.state.empty() ? (fs::path(shot->dir) / ".pbgi-run").string() : o.state;
  options.outputRoot =
      o.outputRoot.empty() ? fs::path(shot->output).parent_path().string() : o.outputRoot;
  options.token = newToken();
  options.leaseSeconds = o.leaseSeconds;
  options.tileSize = o.tileSize;
  // Quiet: the progress bar speaks for the coordinator; its warnings still show.
  log::setLevel(log::Level::kWarn);
  auto farm = farm::LocalFarm::start(options);
  if (!farm.ok()) return reportError(farm.status());
  bool resumed = false;
  auto job = (*farm)->findOrSubmit(*request, &resumed);
  if (!job.ok()) return reportError(job.status());
  // With --json, stdout holds only the JSON.
  std::fprintf(o.json ? stderr : stdout, "%s job %lld of %s (state %s)\n",
               resumed ? "resuming" : "submitted", static_cast<long long>(*job), o.shot.c_str(),
               options.stateDir.c_str());
  std::fflush(stdout);

  const int hardware = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  const int threads = std::max(1, (o.threads > 0 ? o.threads : hardware) / o.workers);
  if (absl::Status s = (*farm)->startWorkers(*job, o.workers, threads); !s.ok()) {
    return reportError(s);
  }
  struct sigaction action {};
  action.sa_handler = onInterrupt;
  sigaction(SIGINT, &action, nullptr);
  sigaction(SIGTERM, &action, nullptr);

  farm::FarmClient client((*farm)->address(), options.token);
  const int exitCode = waitForJob(**farm, client, *job, shot->name);
  (*farm)->stopWorkers();
  if (interrupted) {
    std::fprintf(stderr, "pbgi: error: interrupted; run the same command again to resume job %lld\n",
                 static_cast<long long>(*job));
    return kExitFailed;
  }
  if (exitCode != kExitOk) return exitCode;
  return reportJob(client, *job, (*farm)->logDir(), o.json);
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
      ->check(positiveNumber());
  cmd->add_option("--state", options->state,
                  "State folder: the job database, bakes, tiles, worker logs (default: "
                  "<shot folder>/.pbgi-run)");
  cmd->add_option("--output-root", options->outputRoot,
                  "Frames must lie under this folder (default: the shot's output folder)");
  cmd->add_option("--tile-size", options->tileSize, "Farm tile edge in pixels (default 256)")
      ->check(CLI::Range(16, 8192));
  cmd->add_option("--lease-seconds", options->leaseSeconds, "Task lease length (default 30)")
      ->check(positiveNumber());
  cmd->add_flag("--json", options->json,
                "Print the finished job (its tasks' times, workers, cache figures, audits) as "
                "the JSON of pbgi status --json");
  addJobFlags(*cmd, options->job);
  cmd->callback([options, &action] { action = [options] { return runEmbedded(*options); }; });
}

}  // namespace pbgi::cli
