// The farm client commands: pbgi submit, status, cancel, retry, logs, workers. Each talks to
// a running coordinator (--coordinator, --token-file).

#include <chrono>
#include <cstdio>
#include <ctime>
#include <map>
#include <thread>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <CLI/CLI.hpp>

#include "core/util/status.h"
#include "formats/shot/shot_file.h"
#include "services/cli/cli.h"
#include "services/cli/farm_cli.h"
#include "services/cli/progress.h"
#include "services/farm/farm_json.h"
#include "services/farm/farm_wire.h"

namespace pbgi::cli {

namespace {

namespace v1 = farm::v1;

std::string timeText(double seconds) {
  const std::time_t t = static_cast<std::time_t>(seconds);
  std::tm tm{};
  localtime_r(&t, &tm);
  char text[32];
  std::strftime(text, sizeof text, "%Y-%m-%d %H:%M:%S", &tm);
  return text;
}

struct SubmitOptions {
  ConnectionFlags connection;
  std::string shot;
  std::string outputDir;
  JobFlags job;
};

int runSubmit(const SubmitOptions& o) {
  auto shot = loadShotFile(o.shot);
  if (!shot.ok()) return reportError(shot.status());
  auto request = submitRequest(*shot, o.job);
  if (!request.ok()) return reportError(request.status());
  request->set_output_dir(o.outputDir);
  auto client = connect(o.connection);
  if (!client.ok()) return reportError(client.status());
  auto response = (*client)->submitJob(*request);
  if (!response.ok()) return reportError(response.status());
  std::printf("%lld\n", static_cast<long long>(response->job()));
  return kExitOk;
}

struct StatusOptions {
  ConnectionFlags connection;
  int64_t job = 0;
  bool json = false;
};

int runStatus(const StatusOptions& o) {
  auto client = connect(o.connection, /*readsOnly=*/true);
  if (!client.ok()) return reportError(client.status());
  v1::GetStatusRequest request;
  request.set_job(o.job);
  request.set_with_tasks(o.job != 0);
  auto response = (*client)->getStatus(request);
  if (!response.ok()) return reportError(response.status());
  if (o.json) {
    std::printf("%s\n", farm::toJson(*response).c_str());
    return kExitOk;
  }
  if (response->jobs().empty()) std::printf("no jobs\n");
  for (const v1::JobStatus& job : response->jobs()) {
    if (o.job != 0) {
      // One job: its frames x tiles, with a bar on a terminal.
      const JobProgress p = jobProgress(job);
      Progress bar(fmt::format("job {}", job.job()));
      bar.update(static_cast<uint64_t>(p.done), static_cast<uint64_t>(p.total));
      bar.finish();
      std::printf("%s", describeJob(job).c_str());
    } else {
      const JobProgress p = jobProgress(job);
      std::printf("%6lld  %-20s %-9s %3d%%  %d/%d tasks  %d frames x %d tiles%s%s%s\n",
                  static_cast<long long>(job.job()), job.name().c_str(), jobStateWord(job).c_str(),
                  p.total > 0 ? 100 * p.done / p.total : 0, p.done, p.total, job.frames_size(),
                  job.tiles_per_frame(),
                  job.dead().empty() ? "" : fmt::format(", {} dead", job.dead_size()).c_str(),
                  auditSummary(job).c_str(), stallSummary(job).c_str());
    }
  }
  return kExitOk;
}

struct JobOptions {
  ConnectionFlags connection;
  int64_t job = 0;
  std::optional<int> frame;
  std::optional<int> tile;
  bool json = false;    // logs
  bool follow = false;  // logs
  bool full = false;    // logs
};

struct WorkersOptions {
  ConnectionFlags connection;
  bool json = false;
};

int runCancel(const JobOptions& o) {
  auto client = connect(o.connection);
  if (!client.ok()) return reportError(client.status());
  v1::CancelJobRequest request;
  request.set_job(o.job);
  if (auto r = (*client)->cancelJob(request); !r.ok()) return reportError(r.status());
  std::printf("cancelled job %lld\n", static_cast<long long>(o.job));
  return kExitOk;
}

int runRetry(const JobOptions& o) {
  auto client = connect(o.connection);
  if (!client.ok()) return reportError(client.status());
  v1::RetryJobRequest request;
  request.set_job(o.job);
  if (o.frame) request.set_frame(*o.frame);
  if (o.tile) request.set_tile(*o.tile);
  auto r = (*client)->retryJob(request);
  if (!r.ok()) return reportError(r.status());
  const std::string what =
      fmt::format("job {}{}{}", o.job, o.frame ? fmt::format(" frame {}", *o.frame) : "",
                  o.tile ? fmt::format(" tile {}", *o.tile) : "");
  if (r->tasks() == 0 && r->audits() == 0 && r->unblocked_workers().empty()) {
    std::fprintf(stderr,
                 "pbgi: %s: nothing to retry (no dead or cancelled task or audit, no worker "
                 "blocklisted)\n",
                 what.c_str());
    return kExitFailed;
  }
  std::printf("retrying %s: %d task(s) and %d audit(s) ready again%s\n", what.c_str(), r->tasks(),
              r->audits(),
              r->unblocked_workers().empty() ? ""
                                             : fmt::format("; blocklist lifted for {}",
                                                           fmt::join(r->unblocked_workers(), ", "))
                                                   .c_str());
  return kExitOk;
}

// A job's log as attempts: one line each, "frame 2 tile 1 attempt 1 on w1: done in 3.2 s"
// with the task's own log beneath it (--full), or its error's first line when it failed.
class AttemptPrinter {
 public:
  explicit AttemptPrinter(bool full) : full_(full) {}

  // `follow`: a lease is said when it starts, not only when it ends.
  void add(const v1::LogEntry& e, bool follow) {
    const std::pair<int64_t, int> key{e.task(), e.attempt()};
    if (farm::taskEventKindOf(e) == v1::TASK_EVENT_KIND_LEASED) {
      running_[key] = e;
      if (follow) std::printf("%s started\n", head(e).c_str());
      return;
    }
    const auto started = running_.find(key);
    std::string took;
    if (started != running_.end()) {
      took = fmt::format(" {} {:.1f} s",
                         farm::taskEventKindOf(e) == v1::TASK_EVENT_KIND_DONE ? "in" : "after",
                         std::max(0.0, e.time() - started->second.time()));
      running_.erase(started);
    }
    const std::string firstLine = e.text().substr(0, e.text().find('\n'));
    std::printf("%s %s%s%s\n", head(e).c_str(), eventWord(e).c_str(), took.c_str(),
                farm::taskEventKindOf(e) == v1::TASK_EVENT_KIND_DONE || firstLine.empty()
                    ? ""
                    : (": " + firstLine).c_str());
    if (full_ && !e.text().empty()) {
      std::string text = e.text();
      if (text.back() != '\n') text += '\n';
      for (size_t start = 0; start < text.size();) {
        const size_t end = text.find('\n', start);
        std::printf("    %s\n", text.substr(start, end - start).c_str());
        start = end + 1;
      }
    }
  }
  // The attempts leased and not ended, as of `now`.
  void running(double now) const {
    for (const auto& [key, e] : running_) {
      std::printf("%s running for %.1f s\n", head(e).c_str(), std::max(0.0, now - e.time()));
    }
  }

 private:
  static std::string head(const v1::LogEntry& e) {
    const v1::TaskKind kind = farm::taskKindOf(e);
    return fmt::format(
        "{} frame {} {}{} attempt {} on {}:", timeText(e.time()), e.frame(), farm::wireWord(kind),
        kind == v1::TASK_KIND_TILE ? fmt::format(" {}", e.tile()) : "", e.attempt(), e.worker());
  }
  // An event this build does not know (a newer coordinator's) shows the word it came with.
  static std::string eventWord(const v1::LogEntry& e) {
    const v1::TaskEventKind event = farm::taskEventKindOf(e);
    return farm::fromWire(event) || e.event().empty() ? farm::wireWord(event) : e.event();
  }

  const bool full_;
  std::map<std::pair<int64_t, int>, v1::LogEntry> running_;
};

double nowSeconds() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

int runLogs(const JobOptions& o) {
  auto client = connect(o.connection, /*readsOnly=*/true);
  if (!client.ok()) return reportError(client.status());
  v1::GetLogsRequest request;
  request.set_job(o.job);
  if (o.frame) request.set_frame(*o.frame);
  if (o.tile) request.set_tile(*o.tile);
  auto response = (*client)->getLogs(request);
  if (!response.ok()) return reportError(response.status());
  if (o.json) {
    std::printf("%s\n", farm::toJson(*response).c_str());
    return kExitOk;
  }
  AttemptPrinter printer(o.full);
  for (const v1::LogEntry& e : response->entries()) printer.add(e, false);
  if (!o.follow) {
    printer.running(nowSeconds());
    return kExitOk;
  }
  printer.running(nowSeconds());
  std::fflush(stdout);
  // Follow: poll for the events after those printed until the job is no longer active.
  int seen = response->entries_size();
  v1::GetStatusRequest ask;
  ask.set_job(o.job);
  for (;;) {
    auto status = (*client)->getStatus(ask);
    if (!status.ok()) return reportError(status.status());
    const bool active = farm::jobStateOf(status->jobs(0)) == v1::JOB_STATE_ACTIVE;
    response = (*client)->getLogs(request);
    if (!response.ok()) return reportError(response.status());
    for (int i = seen; i < response->entries_size(); ++i) printer.add(response->entries(i), true);
    seen = response->entries_size();
    std::fflush(stdout);
    if (!active) {
      std::printf("job %lld %s\n", static_cast<long long>(o.job),
                  jobStateWord(status->jobs(0)).c_str());
      return kExitOk;
    }
    std::this_thread::sleep_for(std::chrono::milliseconds(500));
  }
}

int runWorkers(const WorkersOptions& o) {
  auto client = connect(o.connection, /*readsOnly=*/true);
  if (!client.ok()) return reportError(client.status());
  auto response = (*client)->listWorkers(v1::ListWorkersRequest());
  if (!response.ok()) return reportError(response.status());
  if (o.json) {
    std::printf("%s\n", farm::toJson(*response).c_str());
    return kExitOk;
  }
  if (response->workers().empty()) std::printf("no workers\n");
  const double now =
      std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
  for (const v1::WorkerStatus& w : response->workers()) {
    // A cache of 0: the worker was given no budget, so each job's cache_mb sets it.
    const std::string cache = w.cache_bytes() > 0
                                  ? fmt::format("{:.0f} MiB", double(w.cache_bytes()) / (1 << 20))
                                  : std::string("job's cache_mb");
    std::printf(
        "%-28s %-7s %-16s %3d cores %6.1f GiB  cache %s  heard %.0f s ago%s\n", w.worker().c_str(),
        w.state().c_str(), w.host().c_str(), w.cores(), double(w.memory_bytes()) / (1 << 30),
        cache.c_str(), std::max(0.0, now - std::max(w.last_heard(), w.last_seen())),
        w.current().empty()
            ? ""
            : fmt::format(", {} {}", w.state() == "lost" ? "was on" : "on", w.current()).c_str());
  }
  return kExitOk;
}

}  // namespace

void registerFarmCommands(CLI::App& app, CommandAction& action) {
  {
    auto o = std::make_shared<SubmitOptions>();
    CLI::App* cmd = app.add_subcommand("submit", "Submit a shot job to a coordinator; prints the job id");
    cmd->add_option("SHOT", o->shot, "Shot file (TOML), at a path the workers can read")->required();
    cmd->add_option("--output-dir", o->outputDir,
                    "Write the frames here, under the coordinator's output root (default: the "
                    "shot's output pattern)");
    addJobFlags(*cmd, o->job);
    addConnectionFlags(*cmd, o->connection);
    cmd->callback([o, &action] { action = [o] { return runSubmit(*o); }; });
  }
  {
    auto o = std::make_shared<StatusOptions>();
    CLI::App* cmd = app.add_subcommand("status", "Jobs and their progress (one job: frames x tiles)");
    cmd->add_option("JOB", o->job, "A job id (default: every job)");
    cmd->add_flag("--json", o->json,
                  "Print the status as JSON (every field present, ids and counts as numbers)");
    addConnectionFlags(*cmd, o->connection);
    cmd->callback([o, &action] { action = [o] { return runStatus(*o); }; });
  }
  const auto jobCommand = [&](const char* name, const char* help, bool parts,
                              int (*run)(const JobOptions&)) {
    auto o = std::make_shared<JobOptions>();
    CLI::App* cmd = app.add_subcommand(name, help);
    cmd->add_option("JOB", o->job, "The job id")->required();
    if (parts) {
      cmd->add_option("--frame", o->frame, "Only this frame");
      cmd->add_option("--tile", o->tile, "Only this tile of the frame");
    }
    if (std::string_view(name) == "logs") {
      cmd->add_flag("--json", o->json, "Print the entries as JSON (as status --json)");
      cmd->add_flag("--follow,-f", o->follow,
                    "Print attempts as they start and end until the job is no longer active");
      cmd->add_flag("--full", o->full, "Print each attempt's own log (stages, counters) too");
    }
    addConnectionFlags(*cmd, o->connection);
    cmd->callback([o, run, &action] { action = [o, run] { return run(*o); }; });
  };
  jobCommand("cancel", "Cancel a job's unfinished tasks", false, runCancel);
  jobCommand("retry", "Run a job's dead or cancelled tasks again (a frame, a tile)", true, runRetry);
  jobCommand("logs", "A job's task history: a line per attempt (worker, outcome, time)", true,
             runLogs);
  {
    auto o = std::make_shared<WorkersOptions>();
    CLI::App* cmd = app.add_subcommand("workers", "The workers a coordinator knows");
    cmd->add_flag("--json", o->json, "Print the workers as JSON (as status --json)");
    addConnectionFlags(*cmd, o->connection);
    cmd->callback([o, &action] { action = [o] { return runWorkers(*o); }; });
  }
}

}  // namespace pbgi::cli
