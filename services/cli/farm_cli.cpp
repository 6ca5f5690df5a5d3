#include "services/cli/farm_cli.h"

#include <cstdlib>
#include <filesystem>
#include <map>

#include <absl/strings/numbers.h>
#include <absl/strings/str_split.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <CLI/CLI.hpp>

#include "core/render/integrators.h"
#include "core/util/status.h"
#include "services/cli/cli.h"
#include "services/farm/farm_wire.h"
#include "services/farm/job_rules.h"
#include "services/util/cli_checks.h"

namespace pbgi::cli {

void addJobFlags(CLI::App& cmd, JobFlags& flags) {
  cmd.add_option("--frames", flags.frames, "Frames to render, e.g. 1-3,7 (default: every frame)");
  cmd.add_option("--integrator", flags.integrator, "Integrator (default: the shot's)");
  cmd.add_option("--spp", flags.spp, "Camera samples per pixel (default: the shot's)")
      ->check(positiveNumber());
  addIntegratorParamFlags(cmd, flags.set, flags.gather, flags.quality);
  cmd.add_option("--cache-mb", flags.cacheMb, "PBGI: tree page cache budget in MiB");
  cmd.add_option("--priority", flags.priority, "Higher runs first (default 0)");
  cmd.add_option("--audit-tiles", flags.auditTiles,
                 "Accuracy audit: tiles per frame path traced on idle workers and compared with "
                 "the job's (default: 2 for PBGI, 0 for the path tracer; 0: no audit)")
      ->check(nonNegativeNumber());
  cmd.add_option("--audit-spp", flags.auditSpp,
                 "Accuracy audit: the path tracer's spp (default 256)")
      ->check(positiveNumber());
  cmd.add_option("--audit-threshold", flags.auditThreshold,
                 "Accuracy audit: the relMSE beyond which a frame is flagged (default 0.05)")
      ->check(positiveNumber());
  addImageFlags(cmd, flags.image);
}

absl::StatusOr<farm::v1::SubmitJobRequest> submitRequest(const ShotDesc& shot,
                                                         const JobFlags& flags) {
  farm::v1::SubmitJobRequest request;
  request.set_shot_path(std::filesystem::absolute(shot.path).lexically_normal().string());
  request.set_shot_text(shot.source);
  request.set_priority(flags.priority);
  if (flags.auditTiles) request.set_audit_tiles(*flags.auditTiles);
  request.set_audit_spp(flags.auditSpp);
  request.set_audit_threshold(flags.auditThreshold);
  // The flags parsed once, here, and sent typed.
  RenderOverrides overrides;
  overrides.integrator = flags.integrator;
  overrides.integratorWhere = {"--integrator"};
  overrides.spp = flags.spp;
  PBGI_RETURN_IF_ERROR(integratorParamFlags(
      flags.set,
      {{"gather", flags.gather}, {"quality", flags.quality}, {"cache_mb", flags.cacheMb}},
      &overrides.params));
  PBGI_RETURN_IF_ERROR(imageOverrides(flags.image, shot, &overrides));
  // The coordinator checks the same, but bad input is better caught before anything starts.
  ShotDesc overridden = shot;
  PBGI_RETURN_IF_ERROR(applyShotOverrides(overridden, overrides));
  *request.mutable_render() = farm::toWire(overrides);
  if (!flags.frames.empty()) {
    PBGI_ASSIGN_OR_RETURN(const std::vector<int> frames, parseFrameList(flags.frames));
    for (int f : frames) {
      PBGI_RETURN_IF_ERROR(checkShotFrame(shot, f));
      request.add_frames(f);
    }
  }
  return request;
}

void addConnectionFlags(CLI::App& cmd, ConnectionFlags& flags) {
  const char* env = std::getenv("PBGI_COORDINATOR");
  flags.coordinator = env != nullptr && *env != '\0' ? env : farm::kDefaultCoordinatorAddress;
  cmd.add_option("--coordinator", flags.coordinator,
                 "Coordinator host:port (default: $PBGI_COORDINATOR, else 127.0.0.1:7411)");
  cmd.add_option("--token-file", flags.tokenFile,
                 "The farm token (default: $PBGI_TOKEN; the coordinator writes <state>/token)");
  cmd.add_option("--tls-ca", flags.tls.ca,
                 "TLS: the CA that signed the coordinator's certificate (default: $PBGI_TLS_CA, "
                 "else plaintext)")
      ->envname("PBGI_TLS_CA");
  cmd.add_option("--tls-cert", flags.tls.cert,
                 "TLS: this client's certificate, for a coordinator that asks for one (default: "
                 "$PBGI_TLS_CERT)")
      ->envname("PBGI_TLS_CERT");
  cmd.add_option("--tls-key", flags.tls.key, "TLS: the key of --tls-cert (default: $PBGI_TLS_KEY)")
      ->envname("PBGI_TLS_KEY");
}

absl::StatusOr<std::unique_ptr<farm::FarmClient>> connect(const ConnectionFlags& flags,
                                                          bool readsOnly) {
  absl::StatusOr<std::string> token = farm::loadClientToken(flags.tokenFile);
  // A coordinator's reads are open by default (--read-access): no token, no refusal here.
  if (!token.ok() && !(readsOnly && token.status().code() == absl::StatusCode::kNotFound &&
                       flags.tokenFile.empty())) {
    return token.status();
  }
  PBGI_ASSIGN_OR_RETURN(std::optional<farm::TlsPem> tls, farm::readClientTls(flags.tls));
  return std::make_unique<farm::FarmClient>(
      flags.coordinator, token.ok() ? *std::move(token) : std::string(), 30.0, std::move(tls));
}

JobProgress jobProgress(const farm::v1::JobStatus& job) {
  const auto counts = farm::taskCounts(job);
  JobProgress p;
  for (const int count : counts) p.total += count;
  p.done = counts[farm::v1::TASK_STATE_DONE];
  return p;
}

std::string describeJob(const farm::v1::JobStatus& job) {
  const JobProgress p = jobProgress(job);
  std::string out = fmt::format("job {} {} {}: {} of {} tasks done, {} frames x {} tiles\n",
                                job.job(), job.name(), jobStateWord(job), p.done, p.total,
                                job.frames_size(), job.tiles_per_frame());
  struct FrameLine {
    std::string bake = "-";
    int tilesDone = 0;
    int tilesLeased = 0;
    int tilesDead = 0;
    double tileProgress = 0.0;
    std::string assemble;
  };
  std::map<int, FrameLine> frames;
  for (const auto& t : job.tasks()) {
    FrameLine& f = frames[t.frame()];
    const farm::v1::TaskState state = farm::taskStateOf(t);
    switch (farm::taskKindOf(t)) {
      case farm::v1::TASK_KIND_BAKE:
        f.bake = state == farm::v1::TASK_STATE_LEASED
                     ? fmt::format("leased ({:.0f} %)", 100 * t.progress())
                     : farm::wireWord(state);
        break;
      case farm::v1::TASK_KIND_ASSEMBLE:
        f.assemble = farm::wireWord(state);
        break;
      case farm::v1::TASK_KIND_TILE:
        f.tilesDone += state == farm::v1::TASK_STATE_DONE;
        f.tilesDead += state == farm::v1::TASK_STATE_DEAD;
        if (state == farm::v1::TASK_STATE_LEASED) {
          ++f.tilesLeased;
          f.tileProgress += t.progress();
        }
        break;
      default:  // a kind newer than this client
        break;
    }
  }
  for (const auto& [frame, f] : frames) {
    out += fmt::format("  frame {:>4}: bake {}, tiles {}/{} done", frame, f.bake, f.tilesDone,
                       job.tiles_per_frame());
    if (f.tilesLeased > 0) {
      out += fmt::format(", {} running ({:.0f} % on average)", f.tilesLeased,
                         100 * f.tileProgress / f.tilesLeased);
    }
    if (f.tilesDead > 0) out += fmt::format(", {} dead", f.tilesDead);
    out += fmt::format(", assemble {}\n", f.assemble);
  }
  for (const auto& d : job.dead()) {
    const farm::v1::TaskKind kind = farm::taskKindOf(d);
    out += fmt::format("  dead: frame {} {}{} after {} attempt(s): {}\n", d.frame(),
                       farm::wireWord(kind),
                       kind == farm::v1::TASK_KIND_TILE ? fmt::format(" {}", d.tile()) : "",
                       d.attempt(), d.last_error());
  }
  if (job.stall() == "stalled") {
    out += fmt::format(
        "  STALLED: no live worker may take its ready tasks; blocklisted: {}{}\n  (pbgi retry "
        "{} lifts the blocklist)\n",
        fmt::join(job.blocklisted_workers(), ", "),
        job.stall_error().empty() ? "" : fmt::format("; last error: {}", job.stall_error()),
        job.job());
  } else if (job.stall() == "waiting") {
    out += "  waiting: no worker is live\n";
  } else if (!job.blocklisted_workers().empty()) {
    out += fmt::format("  blocklisted: {}\n", fmt::join(job.blocklisted_workers(), ", "));
  }
  out += describeAudits(job);
  for (const auto& o : job.outputs()) out += fmt::format("  wrote {}\n", o);
  return out;
}

std::string jobStateWord(const farm::v1::JobStatus& job) {
  return job.stall().empty() ? farm::wireWord(farm::jobStateOf(job)) : job.stall();
}

std::string stallSummary(const farm::v1::JobStatus& job) {
  if (job.stall() == "stalled") {
    return fmt::format(", no live worker may take its tasks (blocklisted: {})",
                       fmt::join(job.blocklisted_workers(), ", "));
  }
  return job.stall() == "waiting" ? ", no worker is live" : "";
}

std::string describeAudits(const farm::v1::JobStatus& job) {
  std::string out;
  for (const farm::v1::FrameAudit& a : job.audits()) {
    out += fmt::format("  audit frame {:>4}: ", a.frame());
    if (a.has_result()) {
      out += fmt::format("relMSE {:.4g}, bias {:+.2f} % against the path tracer at {} spp on {} "
                         "tile(s){}\n",
                         a.rel_mse(), 100.0 * a.bias(), a.spp(), a.tiles_size(),
                         a.flagged() ? fmt::format("  FLAGGED (above {})", a.threshold()) : "");
    } else {
      out += a.state() + (a.last_error().empty() ? "" : ": " + a.last_error()) + "\n";
    }
  }
  return out;
}

std::string auditSummary(const farm::v1::JobStatus& job) {
  if (job.audits().empty()) return "";
  int done = 0, flagged = 0;
  for (const farm::v1::FrameAudit& a : job.audits()) {
    done += a.has_result();
    flagged += a.flagged();
  }
  return fmt::format(", audited {}/{} frames{}", done, job.audits_size(),
                     flagged > 0 ? fmt::format(", {} FLAGGED", flagged) : "");
}

}  // namespace pbgi::cli
