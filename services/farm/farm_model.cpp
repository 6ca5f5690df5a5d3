#include "services/farm/farm_model.h"

#include <utility>

#include <absl/strings/escaping.h>
#include <fmt/format.h>
#include <fmt/ranges.h>

namespace pbgi::farm {

std::string toString(TaskKind kind) {
  switch (kind) {
    case TaskKind::kBake:
      return "bake";
    case TaskKind::kTile:
      return "tile";
    case TaskKind::kAssemble:
      return "assemble";
  }
  return fmt::format("TaskKind({})", static_cast<int>(kind));
}

std::string toString(TaskState state) {
  switch (state) {
    case TaskState::kBlocked:
      return "blocked";
    case TaskState::kReady:
      return "ready";
    case TaskState::kLeased:
      return "leased";
    case TaskState::kDone:
      return "done";
    case TaskState::kDead:
      return "dead";
    case TaskState::kCancelled:
      return "cancelled";
  }
  return fmt::format("TaskState({})", static_cast<int>(state));
}

std::string toString(JobState state) {
  switch (state) {
    case JobState::kActive:
      return "active";
    case JobState::kDone:
      return "done";
    case JobState::kFailed:
      return "failed";
    case JobState::kCancelled:
      return "cancelled";
  }
  return fmt::format("JobState({})", static_cast<int>(state));
}

std::string toString(AuditState state) {
  switch (state) {
    case AuditState::kReady:
      return "ready";
    case AuditState::kLeased:
      return "leased";
    case AuditState::kDone:
      return "done";
    case AuditState::kFailed:
      return "failed";
    case AuditState::kCancelled:
      return "cancelled";
  }
  return fmt::format("AuditState({})", static_cast<int>(state));
}

namespace {

// The stored words, each once: toString and parseTaskEventKind read this.
constexpr std::pair<TaskEventKind, std::string_view> kEventWords[] = {
    {TaskEventKind::kLeased, "leased"},
    {TaskEventKind::kDone, "done"},
    {TaskEventKind::kFailed, "failed"},
    {TaskEventKind::kExpired, "expired"},
};

}  // namespace

std::string toString(TaskEventKind kind) {
  for (const auto& [k, word] : kEventWords) {
    if (k == kind) return std::string(word);
  }
  return fmt::format("TaskEventKind({})", static_cast<int>(kind));
}

absl::StatusOr<TaskEventKind> parseTaskEventKind(std::string_view word) {
  for (const auto& [kind, known] : kEventWords) {
    if (known == word) return kind;
  }
  std::vector<std::string_view> expected;
  for (const auto& [kind, known] : kEventWords) expected.push_back(known);
  // Escaped: the word comes from a database row and goes into logs.
  const std::string escaped = absl::CEscape(absl::string_view(word.data(), word.size()));
  return absl::DataLossError(
      fmt::format("event '{}': expected one of {}", escaped, fmt::join(expected, ", ")));
}

std::string auditLabel(int64_t job, int frame) {
  return fmt::format("job {} frame {} audit", job, frame);
}

std::string TaskRef::toString() const {
  if (kind == TaskKind::kTile) return fmt::format("job {} frame {} tile {}", job, frame, tile);
  return fmt::format("job {} frame {} {}", job, frame, farm::toString(kind));
}

}  // namespace pbgi::farm
