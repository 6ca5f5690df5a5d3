#pragma once
// The farm's model: what the coordinator, its job stores, the workers and the command line
// say about jobs, tasks, audits and workers. Tasks move
//   blocked -> ready -> leased -> done
//                 ^       |
//                 +-------+  fail or lease expiry: retried after a back-off, until the cap;
//                         v
//                       dead  (its last error kept; the job reports the frame as failed)
// and cancel moves every unfinished task to cancelled (services/job_store/job_store.h keeps
// them).
#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/statusor.h>

#include "core/scene/shot.h"

namespace pbgi::farm {

enum class TaskKind { kBake = 0, kTile = 1, kAssemble = 2 };
enum class TaskState {
  kBlocked = 0,
  kReady = 1,
  kLeased = 2,
  kDone = 3,
  kDead = 4,
  kCancelled = 5
};
// How many task states there are, and a value per state indexed by TaskState.
inline constexpr int kTaskStateCount = static_cast<int>(TaskState::kCancelled) + 1;
template <typename T>
using PerTaskState = std::array<T, kTaskStateCount>;
enum class JobState { kActive = 0, kDone = 1, kFailed = 2, kCancelled = 3 };

std::string toString(TaskKind kind);
std::string toString(TaskState state);
std::string toString(JobState state);

// Times are seconds since the Unix epoch as doubles, passed in by the caller (the tests drive
// a clock of their own; the coordinator passes the wall clock).
using Seconds = double;

// An accuracy audit of one frame: a few of its tiles rendered again with the path tracer at
// `spp` on a worker that found nothing else to do, and compared with the job's own tiles once
// the frame is assembled. A frame whose relMSE exceeds `threshold` is flagged.
struct AuditSpec {
  int frame = 0;
  std::vector<int> tiles;  // farm tile indices, chosen by a seeded rule (farm/job_rules.h)
  int spp = 0;
  double threshold = 0;
};

struct JobSpec {
  std::string name;               // the shot's name
  std::string shotPath;           // absolute path of the shot file, as the workers will read it
  std::string shotText;           // the shot file's bytes at submission (the job renders these)
  RenderOverrides overrides;      // of the shot's [render] settings, applied by workers
  std::string outputPattern;      // absolute; '#' runs are the frame number
  int priority = 0;               // higher first
  std::vector<int> frames;        // in order
  int tileCount = 0;              // tiles per frame (> 0)
  bool needsBake = false;         // a bake task per frame, which the frame's tiles wait on
  std::vector<AuditSpec> audits;  // at most one per frame of `frames`; none: no audit
};

//   ready -> leased -> done
//     ^        |
//     +--------+  fail or lease expiry: ready again after the back-off, until the cap;
//              v
//            failed   (an audit never fails its job: it only reports)
// and a cancelled job's unfinished audits are cancelled (retry makes them ready again).
enum class AuditState { kReady = 0, kLeased = 1, kDone = 2, kFailed = 3, kCancelled = 4 };
std::string toString(AuditState state);

struct AuditResult {
  double relMse =
      0;            // mean over the audited pixels and channels of (pbgi - ref)^2 / (ref^2 + 0.01)
  double bias = 0;  // (sum of pbgi - sum of ref) / sum of ref, over the audited pixels
  double seconds = 0;  // the worker's time for the audit
};

struct AuditInfo {
  int64_t id = 0;
  int64_t job = 0;
  AuditSpec spec;
  AuditState state = AuditState::kReady;
  int attempt = 0;
  int failures = 0;
  std::string worker;  // the current or last lease's
  std::string lastError;
  std::optional<AuditResult> result;  // once done
  bool flagged() const { return result && result->relMse > spec.threshold; }
};

struct AuditLease {
  int64_t audit = 0;
  int attempt = 0;
  int64_t job = 0;
  AuditSpec spec;
  Seconds expires = 0;
};

struct TaskRef {
  int64_t job = 0;
  TaskKind kind = TaskKind::kTile;
  int frame = 0;
  int tile = -1;                 // tiles only
  std::string toString() const;  // "job 3 frame 12 tile 7" / "job 3 frame 12 bake"
};
// A frame's audit as logs and the activity name it: "job 3 frame 12 audit".
std::string auditLabel(int64_t job, int frame);

// A frame a worker has loaded (its scene, its tree's pages): where its tiles are cheapest.
struct HeldFrame {
  int64_t job = 0;
  int frame = 0;
  bool operator==(const HeldFrame&) const = default;
};

struct Lease {
  int64_t task = 0;
  int attempt = 0;  // 1 for the first lease of the task
  TaskRef ref;
  Seconds expires = 0;
};

struct TaskInfo {
  int64_t id = 0;
  TaskRef ref;
  TaskState state = TaskState::kBlocked;
  int attempt = 0;     // leases so far
  int failures = 0;    // failed attempts (explicit failures and expired leases)
  std::string worker;  // the current or last lease's worker
  std::string lastError;
  double progress = 0.0;  // 0..1, from heartbeats of the current attempt
};

struct JobInfo {
  int64_t id = 0;
  JobSpec spec;
  JobState state = JobState::kActive;
  Seconds submitted = 0;
  // Tasks by state, indexed by TaskState.
  PerTaskState<int> tasksByState{};
  // Dead tasks with their last errors: the frames that failed and why.
  std::vector<TaskInfo> dead;
};

// What a line of a job's log records. Both stores keep it as its word (toString: "leased",
// "done", "failed", "expired") in a TEXT column, the words every version has written.
enum class TaskEventKind { kLeased = 0, kDone = 1, kFailed = 2, kExpired = 3 };
std::string toString(TaskEventKind kind);
// A stored word back; DataLoss naming the word and the words expected when it is not one of
// them (a row written by a newer coordinator sharing the database, or by hand).
absl::StatusOr<TaskEventKind> parseTaskEventKind(std::string_view word);

// One line of a job's log: a lease, a completion or failure (with what the worker printed),
// an expiry. Appended in the same transaction as the change it records.
struct TaskEvent {
  Seconds time = 0;
  int64_t task = 0;
  TaskRef ref;
  int attempt = 0;
  std::string worker;
  // The word as stored, toString(TaskEventKind) for every row this build writes; read it with
  // parseTaskEventKind. Kept as stored so that a word this build does not know is still shown.
  std::string event;
  std::string text;  // the error, or the worker's log
};

struct WorkerInfo {
  std::string id;
  std::string host;
  int cores = 0;
  uint64_t memoryBytes = 0;
  uint64_t cacheBytes = 0;
  Seconds lastSeen = 0;
};

}  // namespace pbgi::farm
