#pragma once
// The wire's closed sets (task kinds, task and job states, log events; farm.proto) against
// the store's enums, converted in this one place. A message carries the enum and, for v1
// readers from before the enums, the word ("tile", "leased", "active", "expired"); readers
// here take the enum, and the word only when the enum is unset (a message from a coordinator
// older than the enums).
#include <array>
#include <optional>
#include <string>
#include <string_view>

#include <absl/status/statusor.h>

#include "core/scene/shot.h"
#include "pbgi/farm/v1/farm.pb.h"
#include "services/farm/farm_model.h"

namespace pbgi::farm {

v1::TaskKind toWire(TaskKind kind);
v1::TaskState toWire(TaskState state);
v1::JobState toWire(JobState state);
v1::TaskEventKind toWire(TaskEventKind kind);
// nullopt for UNSPECIFIED and for numbers this build does not know (a newer sender).
std::optional<TaskKind> fromWire(v1::TaskKind kind);
std::optional<TaskState> fromWire(v1::TaskState state);
std::optional<JobState> fromWire(v1::JobState state);
std::optional<TaskEventKind> fromWire(v1::TaskEventKind kind);

// The word a v1 reader knows (the store's toString): "bake", "leased", "active"; "unknown"
// for UNSPECIFIED.
std::string wireWord(v1::TaskKind kind);
std::string wireWord(v1::TaskState state);
std::string wireWord(v1::JobState state);
std::string wireWord(v1::TaskEventKind kind);

// What a message says, from the enum, else from the word (UNSPECIFIED when neither is known).
v1::TaskKind taskKindOf(const v1::LeaseTaskResponse& task);
v1::TaskKind taskKindOf(const v1::TaskStatus& task);
v1::TaskKind taskKindOf(const v1::LogEntry& entry);
v1::TaskState taskStateOf(const v1::TaskStatus& task);
v1::JobState jobStateOf(const v1::JobStatus& job);
v1::TaskEventKind taskEventKindOf(const v1::LogEntry& entry);

// A job's tasks in each state, indexed by v1::TaskState: from task_counts, else from the
// tasks_by_state words.
std::array<int, v1::TaskState_ARRAYSIZE> taskCounts(const v1::JobStatus& job);

// Audits are not store tasks (job_store.h keeps them apart), so they have no TaskKind: their
// wire kind is TASK_KIND_AUDIT, and this its word.
inline constexpr const char* kAuditWord = "audit";

// Both forms into a message: the enum and the word.
void setKind(TaskKind kind, v1::LeaseTaskResponse* out);
void setAuditKind(v1::LeaseTaskResponse* out);
void setKind(TaskKind kind, v1::LogEntry* out);
void setEvent(TaskEventKind kind, v1::LogEntry* out);
void setKindAndState(TaskKind kind, TaskState state, v1::TaskStatus* out);
void setState(JobState state, const PerTaskState<int>& tasksByState, v1::JobStatus* out);

// A job's overrides on the wire and back. Values keep their types; fromWire checks each
// against its declaration (a declared key, its type, its range), as a value from a flag was.
v1::RenderOverrides toWire(const RenderOverrides& overrides);
absl::StatusOr<RenderOverrides> fromWire(const v1::RenderOverrides& overrides);
// A submission's overrides: `render`, or a client's from before it, its "key=value" lines.
absl::StatusOr<RenderOverrides> submittedOverrides(const v1::SubmitJobRequest& request);

// A job's overrides as the job stores keep them: the wire message in protobuf's JSON. Reading
// also takes a store's from before they were typed ("key=value" lines).
std::string toStoreText(const RenderOverrides& overrides);
absl::StatusOr<RenderOverrides> fromStoreText(std::string_view text);

}  // namespace pbgi::farm
