#pragma once
// The coordinator's durable state: jobs, their tasks, workers and per-(job, worker) failure
// counts, behind one interface so that a farm can swap the embedded SQLite store for
// PostgreSQL, which several coordinators can share. Every call is one transaction, committed
// before it returns: a task is leased in the database before the worker that leased it hears
// about it (ARCHITECTURE invariant 3).
//
// A job is a shot plus overrides. It becomes, per frame: bake(frame) when the integrator needs
// a tree, tile(frame, t) for every tile (each waits on its frame's bake), and assemble(frame)
// (waits on every tile of its frame); tasks move through the states of
// services/farm/farm_model.h. A lease carries an attempt number: heartbeats, completions and
// failures are accepted only from the current attempt of a leased task, so a worker that lost
// its lease can never commit a result.
#include <array>
#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "services/farm/farm_model.h"

namespace pbgi::farm {

struct RetryPolicy {
  int maxAttempts = 3;            // a task that failed this many times is dead
  Seconds backoffBase = 2.0;      // ready again after base * 2^(failures - 1) seconds...
  Seconds backoffMax = 60.0;      // ...at most this
  int blocklistAfter = 3;         // failures of one job on one worker that blocklist the worker
};

// A lease expireLeases() reclaimed: what the coordinator logs of it.
struct ExpiredLease {
  int64_t id = 0;  // the task's, or the audit's
  bool audit = false;
  std::string what;  // "job 3 frame 12 tile 7", "job 3 frame 12 audit"
  int attempt = 0;
  std::string worker;
  Seconds expires = 0;  // the lease's end: its last heartbeat (or the lease) plus the lease length
};

class JobStore {
 public:
  virtual ~JobStore() = default;

  virtual absl::StatusOr<int64_t> submit(const JobSpec& spec, Seconds now) = 0;
  virtual absl::StatusOr<JobInfo> job(int64_t job) = 0;
  virtual absl::StatusOr<std::vector<JobInfo>> jobs() = 0;
  virtual absl::StatusOr<std::vector<TaskInfo>> tasks(int64_t job) = 0;
  // One task by id; NotFound when there is none.
  virtual absl::StatusOr<TaskInfo> task(int64_t task) = 0;

  virtual absl::Status registerWorker(const WorkerInfo& worker) = 0;
  virtual absl::StatusOr<std::vector<WorkerInfo>> workers() = 0;

  // The most urgent ready task (priority, then job age, then frame, kind, tile) whose back-off
  // has passed and whose job has not blocklisted `worker`, leased until now + leaseSeconds;
  // nullopt when there is none. Within the most urgent job that has a ready task, a task of a
  // frame in `held` (frames whose scene and pages the worker has loaded) comes first: locality
  // never reorders jobs, so no job waits on another's frames.
  virtual absl::StatusOr<std::optional<Lease>> lease(const std::string& worker, Seconds now,
                                                     Seconds leaseSeconds,
                                                     std::span<const HeldFrame> held = {}) = 0;
  // Extends the lease to now + leaseSeconds and records progress. FailedPrecondition when
  // the attempt is not the task's current leased one (the lease was lost).
  virtual absl::Status heartbeat(int64_t task, int attempt, double progress, Seconds now,
                                 Seconds leaseSeconds) = 0;
  // The task is done; its dependents become ready when all they wait on is done; the job is
  // done when every task is. Returns the task. FailedPrecondition from a stale attempt
  // (nothing changes).
  virtual absl::StatusOr<TaskRef> complete(int64_t task, int attempt, Seconds now,
                                           const std::string& log = {}) = 0;
  // The attempt failed with `error`: ready again after the back-off, or dead at the cap.
  // Counts the failure against (job, worker) for the blocklist. FailedPrecondition when stale.
  virtual absl::Status fail(int64_t task, int attempt, const std::string& error, Seconds now,
                            const std::string& log = {}) = 0;
  // Leases that expired by `now` count as failures ("lease expired: worker W stopped
  // heartbeating"). Returns how many expired, and lists them in `expired` when given.
  virtual absl::StatusOr<int> expireLeases(Seconds now,
                                           std::vector<ExpiredLease>* expired = nullptr) = 0;

  virtual absl::Status cancel(int64_t job) = 0;
  // Dead and cancelled tasks of the job (of one frame, or one tile of it) become ready again
  // with their failures reset; the job becomes active; its blocklist is lifted.
  virtual absl::Status retry(int64_t job, std::optional<int> frame, std::optional<int> tile,
                             Seconds now) = 0;
  virtual absl::StatusOr<bool> blocklisted(int64_t job, const std::string& worker) = 0;
  // The workers the job has blocklisted, by name. retry() lifts the job's blocklist: what
  // failed on a worker is tried there again.
  virtual absl::StatusOr<std::vector<std::string>> blocklistedWorkers(int64_t job) = 0;
  // The job's events in order, of one frame or one tile of it when given.
  virtual absl::StatusOr<std::vector<TaskEvent>> events(int64_t job, std::optional<int> frame,
                                                        std::optional<int> tile) = 0;

  // Audits. The coordinator asks for one only when lease() found no task for the worker, so
  // an audit never delays a frame. An audit is leasable when it is ready, its back-off has
  // passed, its job is not cancelled and its frame's assemble task is done; the most urgent
  // first (priority, then job age, then frame). Heartbeats, completions and failures follow
  // the tasks' rules: FailedPrecondition from anything but the current attempt of a leased
  // audit (nothing changes), NotFound for an unknown audit. A failure makes the audit ready
  // after the policy's back-off, or failed at its attempt cap; it never touches the job.
  // expireLeases() reclaims expired audit leases too (counted with the tasks'); cancel()
  // cancels a job's unfinished audits and retry() (of the job, or of a frame) makes its
  // failed and cancelled audits ready again.
  virtual absl::StatusOr<std::optional<AuditLease>> leaseAudit(const std::string& worker,
                                                               Seconds now,
                                                               Seconds leaseSeconds) = 0;
  virtual absl::Status heartbeatAudit(int64_t audit, int attempt, Seconds now,
                                      Seconds leaseSeconds) = 0;
  virtual absl::Status completeAudit(int64_t audit, int attempt, const AuditResult& result,
                                     Seconds now) = 0;
  virtual absl::Status failAudit(int64_t audit, int attempt, const std::string& error,
                                 Seconds now) = 0;
  // The job's audits by frame.
  virtual absl::StatusOr<std::vector<AuditInfo>> audits(int64_t job) = 0;
  // One audit by id; NotFound when there is none.
  virtual absl::StatusOr<AuditInfo> audit(int64_t audit) = 0;
};

// The embedded store: one SQLite file in WAL mode (created with its schema when missing).
absl::StatusOr<std::unique_ptr<JobStore>> openSqliteJobStore(const std::string& path,
                                                            const RetryPolicy& policy);
// The shared store: a PostgreSQL database named by a libpq URI (postgresql://user@host/db),
// its tables created when missing. Several coordinators may open one database: leases are
// taken with row locks, so a task is never leased twice and a stale attempt never commits.
absl::StatusOr<std::unique_ptr<JobStore>> openPostgresJobStore(const std::string& uri,
                                                              const RetryPolicy& policy);
// The one place that picks an implementation: a postgresql:// or postgres:// URI opens
// PostgreSQL, anything else is a SQLite file's path.
absl::StatusOr<std::unique_ptr<JobStore>> openJobStore(const std::string& spec,
                                                       const RetryPolicy& policy);
bool isPostgresUri(std::string_view spec);
// The URI with its password (user:password@, password=...) cut out: what errors and logs show.
std::string redactedUri(std::string_view uri);

// The store's rules, written once for every implementation: the SQL differs, what it decides
// does not.

// Both schemas spell kinds and states as the enums' numbers (and their CHECKs keep stored
// values in range, which is why rows are cast back without a test).
static_assert(static_cast<int>(TaskKind::kBake) == 0 && static_cast<int>(TaskKind::kTile) == 1 &&
              static_cast<int>(TaskKind::kAssemble) == 2);
static_assert(static_cast<int>(TaskState::kBlocked) == 0 &&
              static_cast<int>(TaskState::kReady) == 1 &&
              static_cast<int>(TaskState::kLeased) == 2 &&
              static_cast<int>(TaskState::kDone) == 3 && static_cast<int>(TaskState::kDead) == 4 &&
              static_cast<int>(TaskState::kCancelled) == 5);
static_assert(static_cast<int>(JobState::kActive) == 0 && static_cast<int>(JobState::kDone) == 1 &&
              static_cast<int>(JobState::kFailed) == 2 &&
              static_cast<int>(JobState::kCancelled) == 3);
// One column list for every task and job query of both stores, so that a store's readTask()
// and readJob() and its SELECTs cannot drift apart.
#define PBGI_TASK_COLUMNS \
  "id, job, kind, frame, tile, state, attempt, failures, worker, last_error, progress"
#define PBGI_JOB_COLUMNS                                                                      \
  "id, name, shot_path, shot_text, overrides, output_pattern, priority, frames, tile_count, " \
  "needs_bake, state, submitted"

// Audits likewise: the states' numbers, and one column list for both stores' readAudit() and
// their SELECTs. rel_mse, bias and seconds are NULL until the audit is done.
static_assert(static_cast<int>(AuditState::kReady) == 0 &&
              static_cast<int>(AuditState::kLeased) == 1 &&
              static_cast<int>(AuditState::kDone) == 2 &&
              static_cast<int>(AuditState::kFailed) == 3 &&
              static_cast<int>(AuditState::kCancelled) == 4);
#define PBGI_AUDIT_COLUMNS                                                                \
  "id, job, frame, tiles, spp, threshold, state, attempt, failures, worker, last_error, " \
  "rel_mse, bias, seconds"

// InvalidArgument unless the policy allows an attempt and its back-offs are not negative.
absl::Status validateRetryPolicy(const RetryPolicy& policy);
// InvalidArgument for a job without tiles or frames, or with a frame listed twice, or with an
// audit that is not of one of its frames, a second audit of a frame, an audit without tiles or
// with a tile out of range, without samples, or with a threshold that is negative or not finite.
absl::Status validateJobSpec(const JobSpec& spec);

// The tasks a job becomes, in insertion order (so ids follow it): per frame its bake when the
// job needs one, its tiles, its assemble; ready when they wait on nothing.
struct PlannedTask {
  TaskKind kind = TaskKind::kTile;
  int frame = 0;
  int tile = -1;
  TaskState state = TaskState::kBlocked;
};
std::vector<PlannedTask> planTasks(const JobSpec& spec);

// Within a frame a bake waits on nothing, a tile on the bake, an assemble on the tiles. In
// promotion order: a task made ready is not done, so what waits on it stays blocked.
struct Dependency {
  TaskKind kind;
  std::optional<TaskKind> waitsOn;
};
inline constexpr std::array<Dependency, 3> kDependencies = {{
    {TaskKind::kBake, std::nullopt},
    {TaskKind::kTile, TaskKind::kBake},
    {TaskKind::kAssemble, TaskKind::kTile},
}};
// Whether promoting `d`'s blocked tasks can find any after a task of `completed` is done
// (nullopt: after something else, a retry say). A completion changes only what waits on its
// kind: the other promotions would be statements that find nothing, on every completion.
inline bool mayRelease(const Dependency& d, std::optional<TaskKind> completed) {
  return !completed || d.waitsOn == completed;
}
// The kinds of the same frame that can never run once a task of `kind` is dead.
std::vector<TaskKind> dependentKinds(TaskKind kind);
// The last error of a task that dies because `dead` did.
std::string waitsOnDeadError(const TaskRef& dead, std::string_view error);

// A job's frames as stored: the numbers in submission order, space separated.
std::string formatFrames(std::span<const int> frames);
// DataLoss, naming `where`, when the text is not a list of numbers.
absl::StatusOr<std::vector<int>> parseFrames(std::string_view text, std::string_view where);

// A job's text columns as both stores keep them: the overrides (farm_wire.h's toStoreText)
// and the frames, read into `spec`. DataLoss, naming `where`, for text they cannot be read
// from.
absl::Status readStoredJobText(std::string_view overrides, std::string_view frames,
                               std::string_view where, JobSpec* spec);

// The rows of both stores, read the same way through their row's text(i), bytes(i),
// int64(i), integer(i), real(i), realOrNan(i) (NULL as NaN) and boolean(i).
//
// A tasks row (PBGI_TASK_COLUMNS, in order).
template <typename Row>
TaskInfo readTaskRow(const Row& row) {
  TaskInfo task;
  task.id = row.int64(0);
  task.ref.job = row.int64(1);
  task.ref.kind = static_cast<TaskKind>(row.integer(2));
  task.ref.frame = row.integer(3);
  task.ref.tile = row.integer(4);
  task.state = static_cast<TaskState>(row.integer(5));
  task.attempt = row.integer(6);
  task.failures = row.integer(7);
  task.worker = row.text(8);
  task.lastError = row.bytes(9);
  task.progress = row.real(10);
  return task;
}

// An audits row (PBGI_AUDIT_COLUMNS, in order). The result's columns are NULL until done.
template <typename Row>
absl::StatusOr<AuditInfo> readAuditRow(const Row& row, std::string_view where) {
  AuditInfo info;
  info.id = row.int64(0);
  info.job = row.int64(1);
  info.spec.frame = row.integer(2);
  absl::StatusOr<std::vector<int>> tiles = parseFrames(
      row.text(3), std::string(where) + ": audit " + std::to_string(info.id) + " tiles");
  if (!tiles.ok()) return tiles.status();
  info.spec.tiles = *std::move(tiles);
  info.spec.spp = row.integer(4);
  info.spec.threshold = row.real(5);
  info.state = static_cast<AuditState>(row.integer(6));
  info.attempt = row.integer(7);
  info.failures = row.integer(8);
  info.worker = row.text(9);
  info.lastError = row.bytes(10);
  if (info.state == AuditState::kDone) {
    info.result = AuditResult{row.realOrNan(11), row.realOrNan(12), row.realOrNan(13)};
  }
  return info;
}

// An events row of `job`, joined with its task: e.time, e.task, t.kind, t.frame, t.tile,
// e.attempt, e.worker, e.event, e.text.
template <typename Row>
TaskEvent readEventRow(const Row& row, int64_t job) {
  TaskEvent e;
  e.time = row.real(0);
  e.task = row.int64(1);
  e.ref.job = job;
  e.ref.kind = static_cast<TaskKind>(row.integer(2));
  e.ref.frame = row.integer(3);
  e.ref.tile = row.integer(4);
  e.attempt = row.integer(5);
  e.worker = row.text(6);
  e.event = row.text(7);
  e.text = row.bytes(8);
  return e;
}

// A jobs row (PBGI_JOB_COLUMNS, in order).
template <typename Row>
absl::StatusOr<JobInfo> readJobRow(const Row& row, std::string_view where) {
  JobInfo info;
  info.id = row.int64(0);
  info.spec.name = row.text(1);
  info.spec.shotPath = row.text(2);
  info.spec.shotText = row.bytes(3);
  info.spec.outputPattern = row.text(5);
  info.spec.priority = row.integer(6);
  info.spec.tileCount = row.integer(8);
  info.spec.needsBake = row.boolean(9);
  info.state = static_cast<JobState>(row.integer(10));
  info.submitted = row.real(11);
  const absl::Status text =
      readStoredJobText(row.text(4), row.text(7),
                        std::string(where) + ": job " + std::to_string(info.id), &info.spec);
  if (!text.ok()) return text;
  return info;
}

// Failures of one job on one worker that blocklist the worker; no threshold means never.
int64_t blocklistThreshold(const RetryPolicy& policy);

// What a failed attempt makes of its task: ready again after the doubling back-off, or dead
// at the cap.
struct FailureOutcome {
  TaskState state = TaskState::kReady;
  int failures = 0;
  Seconds notBefore = 0;
};
FailureOutcome failureOutcome(const RetryPolicy& policy, int failuresBefore, Seconds now);
// The event text of a failure: the error, then what the worker printed.
std::string failureEventText(std::string_view error, std::string_view log);
std::string leaseExpiredError(std::string_view worker);

// FailedPrecondition, saying which attempt holds the task now, unless `attempt` is the current
// attempt of the leased task `info`.
absl::Status checkCurrentLease(const TaskInfo& info, int attempt);
// What expireLeases() lists of a task or an audit whose lease ended at `expires`.
ExpiredLease expiredLease(const TaskInfo& info, Seconds expires);
ExpiredLease expiredLease(const AuditInfo& info, Seconds expires);
// The same for an audit: FailedPrecondition unless `attempt` is the current attempt of the
// leased audit `info`.
absl::Status checkCurrentLease(const AuditInfo& info, int attempt);
// What a failed attempt (failureOutcome's) makes of an audit: ready again, or failed where a
// task would be dead.
AuditState auditStateAfter(const FailureOutcome& outcome);
// Progress comes from the network: NaN is 0, the rest is clamped to 0..1.
double clampProgress(double progress);
// Where a job settles given which task states it still has (indexed by TaskState): active
// while something can make progress, then done, failed, or cancelled again.
JobState settledJobState(JobState current, const PerTaskState<bool>& present);

// The lease walk: the jobs in lease order, and in each the worker's held frames of that job
// first (most recent first), then any frame; `pick` takes the first ready task of a job (of one
// frame when given) and says whether it found one. Returns whether any pick did.
absl::StatusOr<bool> pickInLeaseOrder(
    std::span<const int64_t> jobs, std::span<const HeldFrame> held,
    const std::function<absl::StatusOr<bool>(int64_t job, std::optional<int> frame)>& pick);

// The start of a statement, whitespace collapsed: enough to say which one failed.
std::string sqlSummary(std::string_view sql);

}  // namespace pbgi::farm
