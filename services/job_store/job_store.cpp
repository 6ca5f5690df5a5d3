#include "services/job_store/job_store.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <set>
#include <utility>

#include <absl/strings/ascii.h>
#include <absl/strings/escaping.h>
#include <absl/strings/match.h>
#include <absl/strings/numbers.h>
#include <absl/strings/str_join.h>
#include <absl/strings/str_split.h>
#include <fmt/format.h>
#include <fmt/ranges.h>

#include "core/util/status.h"
#include "services/farm/farm_wire.h"

namespace pbgi::farm {

bool isPostgresUri(std::string_view spec) {
  return spec.starts_with("postgresql://") || spec.starts_with("postgres://");
}

absl::StatusOr<std::unique_ptr<JobStore>> openJobStore(const std::string& spec,
                                                       const RetryPolicy& policy) {
  if (isPostgresUri(spec)) return openPostgresJobStore(spec, policy);
  return openSqliteJobStore(spec, policy);
}

std::string redactedUri(std::string_view uri) {
  std::string out(uri);
  // user:password@ in the authority.
  if (const size_t scheme = out.find("://"); scheme != std::string::npos) {
    const size_t start = scheme + 3;
    const size_t end = std::min(out.find_first_of("/?", start), out.size());
    const size_t at = out.rfind('@', end);
    if (at != std::string::npos && at >= start) {
      const size_t colon = out.find(':', start);
      if (colon != std::string::npos && colon < at) out.erase(colon, at - colon);
    }
  }
  // password=... among the query's parameters.
  const size_t query = out.find('?');
  if (query == std::string::npos) return out;
  std::vector<std::string> kept;
  for (const auto param : absl::StrSplit(out.substr(query + 1), '&')) {
    if (!absl::StartsWithIgnoreCase(param, "password=")) {
      kept.emplace_back(param.data(), param.size());
    }
  }
  out.resize(query);
  if (!kept.empty()) {
    out += '?';
    out += absl::StrJoin(kept, "&");
  }
  return out;
}

absl::Status validateRetryPolicy(const RetryPolicy& policy) {
  if (policy.maxAttempts >= 1 && policy.backoffBase >= 0 && policy.backoffMax >= 0) {
    return absl::OkStatus();
  }
  return absl::InvalidArgumentError(fmt::format(
      "retry policy: max attempts {}, back-off base {} s, max {} s: expected at least one "
      "attempt and non-negative back-offs",
      policy.maxAttempts, policy.backoffBase, policy.backoffMax));
}

namespace {

// One audit on its own; validateJobSpec() checks it against the job's other audits.
absl::Status validateAuditSpec(const JobSpec& spec, const AuditSpec& audit) {
  const auto invalid = [&](std::string_view what) {
    return absl::InvalidArgumentError(
        fmt::format("job '{}': audit of frame {}: {}", spec.name, audit.frame, what));
  };
  if (audit.tiles.empty()) return invalid("no tiles; expected at least one");
  for (int tile : audit.tiles) {
    if (tile < 0 || tile >= spec.tileCount) {
      return invalid(fmt::format("tile {}: expected 0..{} (the job has {} tiles a frame)", tile,
                                 spec.tileCount - 1, spec.tileCount));
    }
  }
  if (audit.spp <= 0) return invalid(fmt::format("spp {}: expected at least 1", audit.spp));
  if (!std::isfinite(audit.threshold) || audit.threshold < 0) {
    return invalid(
        fmt::format("threshold {}: expected a finite relMSE of at least 0", audit.threshold));
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status validateJobSpec(const JobSpec& spec) {
  if (spec.tileCount <= 0) {
    return absl::InvalidArgumentError(
        fmt::format("job '{}': tile count {}: expected at least 1", spec.name, spec.tileCount));
  }
  if (spec.frames.empty()) {
    return absl::InvalidArgumentError(fmt::format("job '{}': no frames", spec.name));
  }
  std::set<int> seen;
  for (int frame : spec.frames) {
    if (!seen.insert(frame).second) {
      return absl::InvalidArgumentError(
          fmt::format("job '{}': frame {} is listed twice", spec.name, frame));
    }
  }
  std::set<int> audited;
  for (const AuditSpec& audit : spec.audits) {
    PBGI_RETURN_IF_ERROR(validateAuditSpec(spec, audit));
    if (!seen.contains(audit.frame)) {
      return absl::InvalidArgumentError(
          fmt::format("job '{}': audit of frame {}: the job has no such frame (its frames: {})",
                      spec.name, audit.frame, formatFrames(spec.frames)));
    }
    if (!audited.insert(audit.frame).second) {
      return absl::InvalidArgumentError(
          fmt::format("job '{}': frame {} has two audits; expected at most one a frame", spec.name,
                      audit.frame));
    }
  }
  return absl::OkStatus();
}

std::vector<PlannedTask> planTasks(const JobSpec& spec) {
  std::vector<PlannedTask> out;
  out.reserve(spec.frames.size() * (static_cast<size_t>(std::max(spec.tileCount, 0)) + 2));
  const TaskState tileState = spec.needsBake ? TaskState::kBlocked : TaskState::kReady;
  for (int frame : spec.frames) {
    if (spec.needsBake) out.push_back({TaskKind::kBake, frame, -1, TaskState::kReady});
    for (int tile = 0; tile < spec.tileCount; ++tile) {
      out.push_back({TaskKind::kTile, frame, tile, tileState});
    }
    out.push_back({TaskKind::kAssemble, frame, -1, TaskState::kBlocked});
  }
  return out;
}

std::vector<TaskKind> dependentKinds(TaskKind kind) {
  std::vector<TaskKind> out;
  const auto dies = [&](TaskKind k) {
    return k == kind || std::find(out.begin(), out.end(), k) != out.end();
  };
  // kDependencies is in promotion order, so one pass follows the whole chain.
  for (const Dependency& d : kDependencies) {
    if (d.waitsOn && dies(*d.waitsOn)) out.push_back(d.kind);
  }
  return out;
}

std::string waitsOnDeadError(const TaskRef& dead, std::string_view error) {
  return fmt::format("waits on {}: {}", dead.toString(), error);
}

std::string formatFrames(std::span<const int> frames) {
  return fmt::format("{}", fmt::join(frames, " "));
}

absl::Status readStoredJobText(std::string_view overrides, std::string_view frames,
                               std::string_view where, JobSpec* spec) {
  absl::StatusOr<RenderOverrides> read = fromStoreText(overrides);
  if (!read.ok()) {
    return absl::DataLossError(fmt::format("{}: overrides: {}", where, read.status().message()));
  }
  spec->overrides = *std::move(read);
  PBGI_ASSIGN_OR_RETURN(spec->frames, parseFrames(frames, where));
  return absl::OkStatus();
}

absl::StatusOr<std::vector<int>> parseFrames(std::string_view text, std::string_view where) {
  std::vector<int> frames;
  for (const auto word :
       absl::StrSplit(absl::string_view(text.data(), text.size()), ' ', absl::SkipEmpty())) {
    int frame = 0;
    if (!absl::SimpleAtoi(word, &frame)) {
      return absl::DataLossError(fmt::format("{}: frames '{}': expected numbers", where, text));
    }
    frames.push_back(frame);
  }
  return frames;
}

int64_t blocklistThreshold(const RetryPolicy& policy) {
  // No threshold means no blocklist, rather than every worker blocklisted from the start.
  return policy.blocklistAfter > 0 ? policy.blocklistAfter : std::numeric_limits<int64_t>::max();
}

FailureOutcome failureOutcome(const RetryPolicy& policy, int failuresBefore, Seconds now) {
  FailureOutcome out;
  out.failures = failuresBefore + 1;
  out.state = out.failures >= policy.maxAttempts ? TaskState::kDead : TaskState::kReady;
  // ldexp saturates to infinity long before the exponent could overflow; min() caps it.
  out.notBefore =
      out.state == TaskState::kReady
          ? now + std::min(policy.backoffMax, std::ldexp(policy.backoffBase, out.failures - 1))
          : now;
  return out;
}

std::string failureEventText(std::string_view error, std::string_view log) {
  return log.empty() ? std::string(error) : fmt::format("{}\n{}", error, log);
}

std::string leaseExpiredError(std::string_view worker) {
  return fmt::format("lease expired: worker {} stopped heartbeating", worker);
}

absl::Status checkCurrentLease(const TaskInfo& info, int attempt) {
  if (info.state == TaskState::kLeased && info.attempt == attempt) return absl::OkStatus();
  return absl::FailedPreconditionError(fmt::format(
      "{} (task {}): attempt {} no longer holds the lease; the task is {} at attempt {}",
      info.ref.toString(), info.id, attempt, toString(info.state), info.attempt));
}

ExpiredLease expiredLease(const TaskInfo& info, Seconds expires) {
  return {.id = info.id,
          .audit = false,
          .what = info.ref.toString(),
          .attempt = info.attempt,
          .worker = info.worker,
          .expires = expires};
}

ExpiredLease expiredLease(const AuditInfo& info, Seconds expires) {
  return {.id = info.id,
          .audit = true,
          .what = auditLabel(info.job, info.spec.frame),
          .attempt = info.attempt,
          .worker = info.worker,
          .expires = expires};
}

absl::Status checkCurrentLease(const AuditInfo& info, int attempt) {
  if (info.state == AuditState::kLeased && info.attempt == attempt) return absl::OkStatus();
  return absl::FailedPreconditionError(fmt::format(
      "{} (audit {}): attempt {} no longer holds the lease; the audit is {} at attempt {}",
      auditLabel(info.job, info.spec.frame), info.id, attempt, toString(info.state), info.attempt));
}

AuditState auditStateAfter(const FailureOutcome& outcome) {
  return outcome.state == TaskState::kDead ? AuditState::kFailed : AuditState::kReady;
}

double clampProgress(double progress) {
  return std::isnan(progress) ? 0.0 : std::clamp(progress, 0.0, 1.0);
}

JobState settledJobState(JobState current, const PerTaskState<bool>& present) {
  if (current == JobState::kCancelled) return current;
  const auto has = [&](TaskState s) { return present[static_cast<size_t>(s)]; };
  if (has(TaskState::kReady) || has(TaskState::kLeased)) return JobState::kActive;
  if (!has(TaskState::kBlocked) && !has(TaskState::kDead) && !has(TaskState::kCancelled)) {
    return JobState::kDone;
  }
  // Only blocked, dead or cancelled tasks are left: nothing can move without a retry.
  if (has(TaskState::kDead)) return JobState::kFailed;
  if (has(TaskState::kCancelled)) return JobState::kCancelled;
  return JobState::kActive;
}

absl::StatusOr<bool> pickInLeaseOrder(
    std::span<const int64_t> jobs, std::span<const HeldFrame> held,
    const std::function<absl::StatusOr<bool>(int64_t job, std::optional<int> frame)>& pick) {
  for (const int64_t job : jobs) {
    for (const HeldFrame& h : held) {
      if (h.job != job) continue;
      PBGI_ASSIGN_OR_RETURN(const bool found, pick(job, h.frame));
      if (found) return true;
    }
    PBGI_ASSIGN_OR_RETURN(const bool found, pick(job, std::nullopt));
    if (found) return true;
  }
  return false;
}

std::string sqlSummary(std::string_view sql) {
  constexpr size_t kMaxChars = 60;
  std::string out;
  for (char c : sql) {
    const bool space = absl::ascii_isspace(static_cast<unsigned char>(c));
    if (space && (out.empty() || out.back() == ' ')) continue;
    out += space ? ' ' : c;
    if (out.size() >= kMaxChars) return out + "...";
  }
  while (!out.empty() && out.back() == ' ') out.pop_back();
  return out;
}

}  // namespace pbgi::farm
