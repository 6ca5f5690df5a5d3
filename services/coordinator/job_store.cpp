#include "services/coordinator/job_store.h"

#include <fmt/format.h>

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

std::string TaskRef::toString() const {
  if (kind == TaskKind::kTile) return fmt::format("job {} frame {} tile {}", job, frame, tile);
  return fmt::format("job {} frame {} {}", job, frame, farm::toString(kind));
}

}  // namespace pbgi::farm
