// The embedded job store: one SQLite file in WAL mode, one connection behind a mutex. Each
// public call is one transaction, so a crash between two calls loses nothing a caller heard
// about, and a crash inside one loses the whole call and nothing else.
//
// Group commit: writes that arrive while another batch commits wait, then commit together,
// each inside a savepoint of one transaction (one fsync for all of them instead of one each).
// A call still returns only after its changes are durable; a call that fails rolls back to its
// savepoint, undoing only itself; a commit that fails fails every call of its batch.
#include <condition_variable>
#include <functional>
#include <limits>
#include <mutex>
#include <optional>
#include <type_traits>
#include <vector>
#include <string_view>
#include <unordered_map>
#include <utility>

#include <absl/strings/ascii.h>
#include <fmt/format.h>

#include "services/job_store/job_store.h"
#include "services/job_store/sqlite_query.h"

namespace pbgi::farm {
namespace {

// Bumped with every schema change: a file written by a newer coordinator is refused rather
// than misread.
constexpr int kSchemaVersion = 3;
// An operator's sqlite3 shell or a backup may hold the write lock for a moment; waiting that
// long beats failing a lease.
constexpr int kBusyTimeoutMs = 5000;

// Schema 2 added the events table; a version 1 file gets it on opening.
constexpr const char* kEventsSchema = R"sql(
CREATE TABLE task_events (
  id INTEGER PRIMARY KEY AUTOINCREMENT,
  task INTEGER NOT NULL REFERENCES tasks (id),
  job INTEGER NOT NULL REFERENCES jobs (id),
  attempt INTEGER NOT NULL,
  worker TEXT NOT NULL,
  time REAL NOT NULL,
  event TEXT NOT NULL,
  text TEXT NOT NULL
);
CREATE INDEX task_events_by_job ON task_events (job, id);
-- A lease walks the active jobs in order and takes each one's first ready task from here.
CREATE INDEX tasks_by_job_state ON tasks (job, state, frame, kind, tile);
)sql";

// Schema 3 added the audits; a version 1 or 2 file gets them on opening. AUTOINCREMENT, as
// for tasks: a worker holding an audit's id from before some clean-up addresses no other.
constexpr const char* kAuditsSchema = R"sql(
CREATE TABLE audits (
  id INTEGER PRIMARY KEY AUTOINCREMENT,
  job INTEGER NOT NULL REFERENCES jobs (id),
  frame INTEGER NOT NULL,
  tiles TEXT NOT NULL,  -- farm tile indices, space separated
  spp INTEGER NOT NULL CHECK (spp > 0),
  threshold REAL NOT NULL CHECK (threshold >= 0),
  state INTEGER NOT NULL DEFAULT 0 CHECK (state BETWEEN 0 AND 4),
  attempt INTEGER NOT NULL DEFAULT 0,
  failures INTEGER NOT NULL DEFAULT 0,
  worker TEXT NOT NULL DEFAULT '',
  last_error TEXT NOT NULL DEFAULT '',
  expires REAL,                        -- while leased
  not_before REAL NOT NULL DEFAULT 0,  -- the back-off
  rel_mse REAL,                        -- the result, once done (SQLite stores NaN as NULL)
  bias REAL,
  seconds REAL,
  UNIQUE (job, frame)
);
CREATE INDEX audits_by_state ON audits (state, not_before);
)sql";

// AUTOINCREMENT so that ids are never reused: a worker still holding a task id from before
// some clean-up must never address a different task.
constexpr const char* kSchema = R"sql(
CREATE TABLE jobs (
  id INTEGER PRIMARY KEY AUTOINCREMENT,
  name TEXT NOT NULL,
  shot_path TEXT NOT NULL,
  shot_text BLOB NOT NULL,
  overrides TEXT NOT NULL,
  output_pattern TEXT NOT NULL,
  priority INTEGER NOT NULL,
  frames TEXT NOT NULL,  -- frame numbers in submission order, space separated
  tile_count INTEGER NOT NULL CHECK (tile_count > 0),
  needs_bake INTEGER NOT NULL CHECK (needs_bake IN (0, 1)),
  state INTEGER NOT NULL CHECK (state BETWEEN 0 AND 3),
  submitted REAL NOT NULL
);
CREATE TABLE tasks (
  id INTEGER PRIMARY KEY AUTOINCREMENT,
  job INTEGER NOT NULL REFERENCES jobs (id),
  kind INTEGER NOT NULL CHECK (kind BETWEEN 0 AND 2),
  frame INTEGER NOT NULL,
  tile INTEGER NOT NULL,  -- -1 for bakes and assembles
  state INTEGER NOT NULL CHECK (state BETWEEN 0 AND 5),
  attempt INTEGER NOT NULL DEFAULT 0,
  failures INTEGER NOT NULL DEFAULT 0,
  worker TEXT NOT NULL DEFAULT '',
  last_error TEXT NOT NULL DEFAULT '',
  progress REAL NOT NULL DEFAULT 0,
  expires REAL,                        -- while leased
  not_before REAL NOT NULL DEFAULT 0,  -- the back-off: not leased before this
  UNIQUE (job, frame, kind, tile)
);
CREATE INDEX tasks_by_state ON tasks (state, not_before);
CREATE TABLE workers (
  id TEXT PRIMARY KEY,
  host TEXT NOT NULL,
  cores INTEGER NOT NULL,
  memory_bytes INTEGER NOT NULL,
  cache_bytes INTEGER NOT NULL,
  last_seen REAL NOT NULL
);
CREATE TABLE job_worker_failures (
  job INTEGER NOT NULL REFERENCES jobs (id),
  worker TEXT NOT NULL,
  failures INTEGER NOT NULL,
  PRIMARY KEY (job, worker)
);
)sql";

// A result column: NULL is how SQLite stored a NaN.
double realOrNan(const Query& q, int column) {
  return q.isNull(column) ? std::numeric_limits<double>::quiet_NaN() : q.real(column);
}

// Reads a row selected with PBGI_TASK_COLUMNS.
TaskInfo readTask(const Query& q) {
  TaskInfo task;
  task.id = q.int64(0);
  task.ref.job = q.int64(1);
  task.ref.kind = static_cast<TaskKind>(q.integer(2));
  task.ref.frame = q.integer(3);
  task.ref.tile = q.integer(4);
  task.state = static_cast<TaskState>(q.integer(5));
  task.attempt = q.integer(6);
  task.failures = q.integer(7);
  task.worker = q.text(8);
  task.lastError = q.text(9);
  task.progress = q.real(10);
  return task;
}

enum class Access { kRead, kWrite };

class SqliteJobStore final : public JobStore {
 public:
  SqliteJobStore(std::string path, const RetryPolicy& policy, DatabasePtr db)
      : path_(std::move(path)), policy_(policy), db_(std::move(db)) {}

  absl::Status initialize();

  absl::StatusOr<int64_t> submit(const JobSpec& spec, Seconds now) override;
  absl::StatusOr<JobInfo> job(int64_t job) override;
  absl::StatusOr<std::vector<JobInfo>> jobs() override;
  absl::StatusOr<std::vector<TaskInfo>> tasks(int64_t job) override;
  absl::StatusOr<TaskInfo> task(int64_t task) override;
  absl::Status registerWorker(const WorkerInfo& worker) override;
  absl::StatusOr<std::vector<WorkerInfo>> workers() override;
  absl::StatusOr<std::optional<Lease>> lease(const std::string& worker, Seconds now,
                                             Seconds leaseSeconds,
                                             std::span<const HeldFrame> held) override;
  absl::Status heartbeat(int64_t task, int attempt, double progress, Seconds now,
                         Seconds leaseSeconds) override;
  absl::StatusOr<TaskRef> complete(int64_t task, int attempt, Seconds now,
                                   const std::string& log) override;
  absl::Status fail(int64_t task, int attempt, const std::string& error, Seconds now,
                    const std::string& log) override;
  absl::StatusOr<int> expireLeases(Seconds now) override;
  absl::Status cancel(int64_t job) override;
  absl::Status retry(int64_t job, std::optional<int> frame, std::optional<int> tile,
                     Seconds now) override;
  absl::StatusOr<bool> blocklisted(int64_t job, const std::string& worker) override;
  absl::StatusOr<std::vector<TaskEvent>> events(int64_t job, std::optional<int> frame,
                                                std::optional<int> tile) override;
  absl::StatusOr<std::optional<AuditLease>> leaseAudit(const std::string& worker, Seconds now,
                                                       Seconds leaseSeconds) override;
  absl::Status heartbeatAudit(int64_t audit, int attempt, Seconds now,
                              Seconds leaseSeconds) override;
  absl::Status completeAudit(int64_t audit, int attempt, const AuditResult& result,
                             Seconds now) override;
  absl::Status failAudit(int64_t audit, int attempt, const std::string& error,
                         Seconds now) override;
  absl::StatusOr<std::vector<AuditInfo>> audits(int64_t job) override;

 private:
  absl::Status addEvent(const TaskInfo& task, int attempt, const std::string& worker,
                        TaskEventKind event, std::string_view text, Seconds now);
  absl::Status exec(const char* sql);
  Query query(const char* sql);
  template <typename Body>
  auto transaction(Access access, Body&& body) -> decltype(body());

  // One write call waiting for its group commit.
  struct GroupedCall {
    std::function<absl::Status()> run;  // the call's body; its status
    absl::Status committed;             // how its batch's commit went (ok: durable)
    bool done = false;
  };
  // Queues the call and returns once a batch holding it committed (or failed).
  absl::Status commitGrouped(GroupedCall* call);
  // Runs a batch in one transaction, each call in a savepoint, and commits it.
  void runBatch(std::span<GroupedCall* const> batch);

  absl::StatusOr<JobState> jobState(int64_t job);
  absl::StatusOr<JobInfo> readJob(const Query& q);
  absl::Status addTaskSummary(JobInfo& info);
  absl::StatusOr<PerTaskState<int>> countTasksByState(int64_t job);
  absl::StatusOr<TaskInfo> loadTask(int64_t task);
  absl::StatusOr<TaskInfo> currentLease(int64_t task, int attempt);
  absl::Status touchWorker(const std::string& worker, Seconds now);
  absl::Status promoteBlocked(int64_t job, std::optional<int> frame,
                              std::optional<TaskKind> completed = std::nullopt);
  absl::Status killDependents(const TaskInfo& dead);
  absl::Status recordFailure(const TaskInfo& task, const std::string& error, Seconds now,
                             TaskEventKind event, std::string_view log);
  absl::Status settleJob(int64_t job);
  absl::StatusOr<AuditInfo> readAudit(const Query& q) const;
  absl::StatusOr<AuditInfo> loadAudit(int64_t audit);
  absl::StatusOr<AuditInfo> currentAuditLease(int64_t audit, int attempt);
  absl::Status recordAuditFailure(const AuditInfo& audit, const std::string& error, Seconds now);

  const std::string path_;
  const RetryPolicy policy_;
  std::mutex mutex_;  // the connection
  std::mutex groupMutex_;  // the queue below
  std::condition_variable groupDone_;
  std::vector<GroupedCall*> pending_;
  bool committing_ = false;  // a batch is being committed (its leader holds mutex_)
  DatabasePtr db_;
  // Prepared once per SQL text; declared after db_ so that they are finalized before it closes.
  std::unordered_map<std::string, StatementPtr> statements_;
};

absl::Status SqliteJobStore::exec(const char* sql) {
  char* message = nullptr;
  const int rc = sqlite3_exec(db_.get(), sql, nullptr, nullptr, &message);
  if (rc == SQLITE_OK) return absl::OkStatus();
  const std::string text = message != nullptr ? message : sqlite3_errstr(rc);
  sqlite3_free(message);
  return sqliteStatus(rc, text, path_, sqlSummary(sql));
}

Query SqliteJobStore::query(const char* sql) {
  auto it = statements_.find(sql);
  if (it == statements_.end()) {
    sqlite3_stmt* stmt = nullptr;
    const int rc =
        sqlite3_prepare_v3(db_.get(), sql, -1, SQLITE_PREPARE_PERSISTENT, &stmt, nullptr);
    if (rc != SQLITE_OK) {
      sqlite3_finalize(stmt);
      return Query(
          db_.get(), nullptr,
          sqliteStatus(rc, sqlite3_errmsg(db_.get()), path_, "preparing " + sqlSummary(sql)),
          path_);
    }
    it = statements_.emplace(sql, StatementPtr(stmt)).first;
  }
  return Query(db_.get(), it->second.get(), absl::OkStatus(), path_);
}

template <typename Body>
auto SqliteJobStore::transaction(Access access, Body&& body) -> decltype(body()) {
  using Result = decltype(body());
  if (access == Access::kRead) {
    // Readers stay deferred so that status queries never hold up a lease.
    std::lock_guard lock(mutex_);
    PBGI_RETURN_IF_ERROR(exec("BEGIN"));
    Result result = body();
    absl::Status committed = result.ok() ? exec("COMMIT") : absl::OkStatus();
    if (result.ok() && committed.ok()) return result;
    if (sqlite3_get_autocommit(db_.get()) == 0) (void)exec("ROLLBACK");
    if (!committed.ok()) return committed;
    return result;
  }
  std::optional<Result> result;
  GroupedCall call;
  call.run = [&]() -> absl::Status {
    result.emplace(body());
    if constexpr (std::is_same_v<Result, absl::Status>) {
      return *result;
    } else {
      return result->status();
    }
  };
  const absl::Status committed = commitGrouped(&call);
  if (!committed.ok()) return committed;
  return std::move(*result);
}

absl::Status SqliteJobStore::commitGrouped(GroupedCall* call) {
  std::unique_lock lock(groupMutex_);
  pending_.push_back(call);
  while (!call->done) {
    if (committing_) {
      groupDone_.wait(lock);
      continue;
    }
    // This call leads the next batch: everything queued so far, its own call among them.
    committing_ = true;
    std::vector<GroupedCall*> batch;
    batch.swap(pending_);
    lock.unlock();
    runBatch(batch);
    lock.lock();
    for (GroupedCall* c : batch) c->done = true;
    committing_ = false;
    groupDone_.notify_all();
  }
  return call->committed;
}

void SqliteJobStore::runBatch(std::span<GroupedCall* const> batch) {
  std::lock_guard lock(mutex_);
  std::vector<GroupedCall*> open;  // calls whose changes wait for the commit
  auto inTransaction = [&] { return sqlite3_get_autocommit(db_.get()) == 0; };
  for (GroupedCall* call : batch) {
    // Writers take the write lock up front: a deferred transaction that meets a lock at its
    // first write can only fail, since busy_timeout cannot wait out a reader's upgrade.
    if (!inTransaction()) {
      if (absl::Status begun = exec("BEGIN IMMEDIATE"); !begun.ok()) {
        call->committed = begun;
        continue;
      }
    }
    if (absl::Status saved = exec("SAVEPOINT pbgi_call"); !saved.ok()) {
      call->committed = saved;
      continue;
    }
    const absl::Status ran = call->run();
    if (!inTransaction()) {
      // SQLite rolled the whole transaction back (a full disk, an I/O error): the calls
      // before this one in it are lost with it; this one returns its own error.
      for (GroupedCall* lost : open) {
        lost->committed = absl::AbortedError(fmt::format(
            "job store {}: rolled back with another call of its group commit: {}", path_,
            ran.ToString()));
      }
      open.clear();
      if (ran.ok()) call->committed = absl::InternalError("job store: transaction lost");
      continue;
    }
    if (ran.ok()) {
      call->committed = exec("RELEASE pbgi_call");
      if (call->committed.ok()) open.push_back(call);
    } else {
      // A failed call changes nothing: back to its savepoint; its result is its error.
      (void)exec("ROLLBACK TO pbgi_call");
      (void)exec("RELEASE pbgi_call");
    }
  }
  if (!inTransaction()) return;
  const absl::Status committed = exec("COMMIT");
  if (committed.ok()) return;
  if (inTransaction()) (void)exec("ROLLBACK");
  for (GroupedCall* c : open) c->committed = committed;
}

absl::Status SqliteJobStore::initialize() {
  {
    std::lock_guard lock(mutex_);
    sqlite3_extended_result_codes(db_.get(), 1);
    sqlite3_busy_timeout(db_.get(), kBusyTimeoutMs);
    // WAL: status readers never block the lease path, and a commit is one append.
    std::string chosen;
    {
      Query mode = query("PRAGMA journal_mode = WAL");
      PBGI_ASSIGN_OR_RETURN(const bool row, mode.step());
      if (row) chosen = absl::AsciiStrToLower(mode.text(0));
    }
    if (chosen != "wal") {
      return absl::FailedPreconditionError(fmt::format(
          "{}: the job store needs WAL journaling; SQLite chose '{}' (a network file system?)",
          path_, chosen));
    }
    // FULL, not NORMAL: a lease that a worker has heard of must survive a power cut, or the
    // same attempt number could be handed to a second worker after the restart.
    PBGI_RETURN_IF_ERROR(exec("PRAGMA synchronous = FULL"));
    PBGI_RETURN_IF_ERROR(exec("PRAGMA foreign_keys = ON"));
    // 64 MiB of pages (the default is 2): a farm's million-task table keeps its indexes'
    // upper levels in memory, so a lease costs the same at 10 k tasks as at 1 M.
    PBGI_RETURN_IF_ERROR(exec("PRAGMA cache_size = -65536"));
  }
  // Inside a write transaction, so that two coordinators creating one file cannot both see
  // version 0.
  return transaction(Access::kWrite, [&]() -> absl::Status {
    int found = 0;
    {
      Query version = query("PRAGMA user_version");
      PBGI_ASSIGN_OR_RETURN(const bool row, version.step());
      if (row) found = version.integer(0);
    }
    if (found == kSchemaVersion) return absl::OkStatus();
    if (found < 0 || found > kSchemaVersion) {
      return absl::FailedPreconditionError(
          fmt::format("{}: schema version {}; this coordinator reads version {}", path_, found,
                      kSchemaVersion));
    }
    // Each version's additions in turn: a new file gets them all, an older one what it lacks.
    if (found < 1) PBGI_RETURN_IF_ERROR(exec(kSchema));
    if (found < 2) PBGI_RETURN_IF_ERROR(exec(kEventsSchema));
    PBGI_RETURN_IF_ERROR(exec(kAuditsSchema));
    // PRAGMA takes no parameters; the value is our own constant.
    return exec(fmt::format("PRAGMA user_version = {}", kSchemaVersion).c_str());
  });
}

absl::StatusOr<JobState> SqliteJobStore::jobState(int64_t job) {
  Query q = query("SELECT state FROM jobs WHERE id = ?1");
  q.bind(1, job);
  PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
  if (!row) return absl::NotFoundError(fmt::format("job {}: no such job", job));
  return static_cast<JobState>(q.integer(0));
}

absl::StatusOr<JobInfo> SqliteJobStore::readJob(const Query& q) {
  JobInfo info;
  info.id = q.int64(0);
  info.spec.name = q.text(1);
  info.spec.shotPath = q.text(2);
  info.spec.shotText = q.text(3);
  info.spec.overrides = q.text(4);
  info.spec.outputPattern = q.text(5);
  info.spec.priority = q.integer(6);
  PBGI_ASSIGN_OR_RETURN(info.spec.frames,
                        parseFrames(q.text(7), fmt::format("{}: job {}", path_, info.id)));
  info.spec.tileCount = q.integer(8);
  info.spec.needsBake = q.integer(9) != 0;
  info.state = static_cast<JobState>(q.integer(10));
  info.submitted = q.real(11);
  return info;
}

// Indexed by TaskState.
absl::StatusOr<PerTaskState<int>> SqliteJobStore::countTasksByState(int64_t job) {
  PerTaskState<int> counts{};
  Query q = query("SELECT state, COUNT(*) FROM tasks WHERE job = ?1 GROUP BY state");
  q.bind(1, job);
  for (;;) {
    PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
    if (!row) return counts;
    counts[static_cast<size_t>(q.integer(0))] = q.integer(1);
  }
}

absl::Status SqliteJobStore::addTaskSummary(JobInfo& info) {
  PBGI_ASSIGN_OR_RETURN(info.tasksByState, countTasksByState(info.id));
  Query dead = query("SELECT " PBGI_TASK_COLUMNS
                     " FROM tasks WHERE job = ?1 AND state = 4 ORDER BY frame, kind, tile");
  dead.bind(1, info.id);
  for (;;) {
    PBGI_ASSIGN_OR_RETURN(const bool row, dead.step());
    if (!row) return absl::OkStatus();
    info.dead.push_back(readTask(dead));
  }
}

absl::StatusOr<TaskInfo> SqliteJobStore::loadTask(int64_t task) {
  Query q = query("SELECT " PBGI_TASK_COLUMNS " FROM tasks WHERE id = ?1");
  q.bind(1, task);
  PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
  if (!row) return absl::NotFoundError(fmt::format("task {}: no such task", task));
  return readTask(q);
}

absl::StatusOr<TaskInfo> SqliteJobStore::currentLease(int64_t task, int attempt) {
  PBGI_ASSIGN_OR_RETURN(TaskInfo info, loadTask(task));
  PBGI_RETURN_IF_ERROR(checkCurrentLease(info, attempt));
  return info;
}

absl::Status SqliteJobStore::addEvent(const TaskInfo& task, int attempt, const std::string& worker,
                                      TaskEventKind event, std::string_view text, Seconds now) {
  Query q = query(
      "INSERT INTO task_events (task, job, attempt, worker, time, event, text) "
      "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)");
  q.bind(1, task.id)
      .bind(2, task.ref.job)
      .bind(3, attempt)
      .bind(4, worker)
      .bind(5, now)
      .bind(6, toString(event))
      .bind(7, text);
  return q.run();
}

absl::Status SqliteJobStore::touchWorker(const std::string& worker, Seconds now) {
  Query q = query("UPDATE workers SET last_seen = ?2 WHERE id = ?1");
  q.bind(1, worker).bind(2, now);
  return q.run();
}

// kDependencies, in its order.
absl::Status SqliteJobStore::promoteBlocked(int64_t job, std::optional<int> frame,
                                            std::optional<TaskKind> completed) {
  for (const Dependency& d : kDependencies) {
    if (!mayRelease(d, completed)) continue;
    // Two statements, not `(?2 IS NULL OR frame = ?2)`: with the OR, SQLite's plan walks every
    // blocked task of the job (a frame's assemble each: thousands in a long shot) per call.
    // The unfinished states listed, not `state != 3`: with `!=` the probe for an unfinished
    // tile walks the frame's tiles in tile order through every done one (thousands, on every
    // tile's completion); with the list it is one probe of tasks_by_job_state per state.
    Query q = frame ? query("UPDATE tasks SET state = 1 WHERE job = ?1 AND state = 0 AND "
                            "frame = ?2 AND kind = ?3 AND (?4 IS NULL OR NOT EXISTS (SELECT 1 "
                            "FROM tasks d WHERE d.job = tasks.job AND d.frame = tasks.frame AND "
                            "d.kind = ?4 AND d.state IN (0, 1, 2, 4, 5)))")
                    : query("UPDATE tasks SET state = 1 WHERE job = ?1 AND state = 0 AND "
                            "kind = ?3 AND (?4 IS NULL OR NOT EXISTS (SELECT 1 FROM tasks d "
                            "WHERE d.job = tasks.job AND d.frame = tasks.frame AND d.kind = ?4 "
                            "AND d.state IN (0, 1, 2, 4, 5)))");
    q.bind(1, job).bind(3, d.kind).bind(4, d.waitsOn);
    if (frame) q.bind(2, *frame);
    PBGI_RETURN_IF_ERROR(q.run());
  }
  return absl::OkStatus();
}

// A blocked task that waits on a dead one can never run: it dies too, with the reason, so that
// the job's failure names every frame that cannot finish and why.
absl::Status SqliteJobStore::killDependents(const TaskInfo& dead) {
  const std::string error = waitsOnDeadError(dead.ref, dead.lastError);
  for (const TaskKind kind : dependentKinds(dead.ref.kind)) {
    Query q = query(
        "UPDATE tasks SET state = 4, last_error = ?4 WHERE job = ?1 AND frame = ?2 AND state = 0 "
        "AND kind = ?3");
    q.bind(1, dead.ref.job).bind(2, dead.ref.frame).bind(3, kind).bind(4, error);
    PBGI_RETURN_IF_ERROR(q.run());
  }
  return absl::OkStatus();
}

absl::Status SqliteJobStore::recordFailure(const TaskInfo& task, const std::string& error,
                                           Seconds now, TaskEventKind event, std::string_view log) {
  PBGI_RETURN_IF_ERROR(
      addEvent(task, task.attempt, task.worker, event, failureEventText(error, log), now));
  const FailureOutcome outcome = failureOutcome(policy_, task.failures, now);
  TaskInfo failed = task;
  failed.failures = outcome.failures;
  failed.lastError = error;
  failed.state = outcome.state;
  {
    Query q = query(
        "UPDATE tasks SET state = ?2, failures = ?3, last_error = ?4, not_before = ?5, "
        "expires = NULL WHERE id = ?1");
    q.bind(1, task.id)
        .bind(2, failed.state)
        .bind(3, failed.failures)
        .bind(4, error)
        .bind(5, outcome.notBefore);
    PBGI_RETURN_IF_ERROR(q.run());
  }
  if (!task.worker.empty()) {
    Query q = query(
        "INSERT INTO job_worker_failures (job, worker, failures) VALUES (?1, ?2, 1) "
        "ON CONFLICT (job, worker) DO UPDATE SET failures = failures + 1");
    q.bind(1, task.ref.job).bind(2, task.worker);
    PBGI_RETURN_IF_ERROR(q.run());
  }
  if (failed.state == TaskState::kDead) PBGI_RETURN_IF_ERROR(killDependents(failed));
  return settleJob(task.ref.job);
}

absl::Status SqliteJobStore::settleJob(int64_t job) {
  PBGI_ASSIGN_OR_RETURN(const JobState current, jobState(job));
  if (current == JobState::kCancelled) return absl::OkStatus();
  // Every completion settles its job: an index probe per state, not a count of every task
  // of the job (4096 a frame for a big one). A ready or leased task decides it alone (the job
  // is active), so those are probed first and, on a busy farm, are the only probes.
  PerTaskState<bool> present{};
  for (const TaskState s : {TaskState::kReady, TaskState::kLeased, TaskState::kBlocked,
                            TaskState::kDead, TaskState::kCancelled}) {
    Query q = query("SELECT 1 FROM tasks WHERE job = ?1 AND state = ?2 LIMIT 1");
    q.bind(1, job).bind(2, static_cast<int>(s));
    PBGI_ASSIGN_OR_RETURN(present[static_cast<size_t>(s)], q.step());
    if (present[static_cast<size_t>(s)] &&
        (s == TaskState::kReady || s == TaskState::kLeased)) {
      break;
    }
  }
  const JobState next = settledJobState(current, present);
  if (next == current) return absl::OkStatus();
  Query q = query("UPDATE jobs SET state = ?2 WHERE id = ?1");
  q.bind(1, job).bind(2, next);
  return q.run();
}

absl::StatusOr<int64_t> SqliteJobStore::submit(const JobSpec& spec, Seconds now) {
  PBGI_RETURN_IF_ERROR(validateJobSpec(spec));
  return transaction(Access::kWrite, [&]() -> absl::StatusOr<int64_t> {
    {
      Query q = query(
          "INSERT INTO jobs (name, shot_path, shot_text, overrides, output_pattern, priority, "
          "frames, tile_count, needs_bake, state, submitted) "
          "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11)");
      q.bind(1, spec.name)
          .bind(2, spec.shotPath)
          .bindBlob(3, spec.shotText)
          .bind(4, spec.overrides)
          .bind(5, spec.outputPattern)
          .bind(6, spec.priority)
          .bind(7, formatFrames(spec.frames))
          .bind(8, spec.tileCount)
          .bind(9, spec.needsBake ? 1 : 0)
          .bind(10, JobState::kActive)
          .bind(11, now);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    const int64_t job = sqlite3_last_insert_rowid(db_.get());
    for (const PlannedTask& t : planTasks(spec)) {
      Query q =
          query("INSERT INTO tasks (job, kind, frame, tile, state) VALUES (?1, ?2, ?3, ?4, ?5)");
      q.bind(1, job).bind(2, t.kind).bind(3, t.frame).bind(4, t.tile).bind(5, t.state);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    for (const AuditSpec& a : spec.audits) {
      Query q = query(
          "INSERT INTO audits (job, frame, tiles, spp, threshold) VALUES (?1, ?2, ?3, ?4, ?5)");
      q.bind(1, job)
          .bind(2, a.frame)
          .bind(3, formatFrames(a.tiles))
          .bind(4, a.spp)
          .bind(5, a.threshold);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    return job;
  });
}

absl::StatusOr<JobInfo> SqliteJobStore::job(int64_t job) {
  return transaction(Access::kRead, [&]() -> absl::StatusOr<JobInfo> {
    JobInfo info;
    {
      Query q = query("SELECT " PBGI_JOB_COLUMNS " FROM jobs WHERE id = ?1");
      q.bind(1, job);
      PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
      if (!row) return absl::NotFoundError(fmt::format("job {}: no such job", job));
      PBGI_ASSIGN_OR_RETURN(info, readJob(q));
    }
    PBGI_RETURN_IF_ERROR(addTaskSummary(info));
    return info;
  });
}

absl::StatusOr<std::vector<JobInfo>> SqliteJobStore::jobs() {
  return transaction(Access::kRead, [&]() -> absl::StatusOr<std::vector<JobInfo>> {
    std::vector<JobInfo> out;
    {
      Query q = query("SELECT " PBGI_JOB_COLUMNS " FROM jobs ORDER BY id DESC");
      for (;;) {
        PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
        if (!row) break;
        PBGI_ASSIGN_OR_RETURN(JobInfo info, readJob(q));
        out.push_back(std::move(info));
      }
    }
    for (JobInfo& info : out) PBGI_RETURN_IF_ERROR(addTaskSummary(info));
    return out;
  });
}

absl::StatusOr<TaskInfo> SqliteJobStore::task(int64_t task) {
  return transaction(Access::kRead, [&]() { return loadTask(task); });
}

absl::StatusOr<std::vector<TaskInfo>> SqliteJobStore::tasks(int64_t job) {
  return transaction(Access::kRead, [&]() -> absl::StatusOr<std::vector<TaskInfo>> {
    PBGI_RETURN_IF_ERROR(jobState(job).status());
    Query q =
        query("SELECT " PBGI_TASK_COLUMNS " FROM tasks WHERE job = ?1 ORDER BY frame, kind, tile");
    q.bind(1, job);
    std::vector<TaskInfo> out;
    for (;;) {
      PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
      if (!row) return out;
      out.push_back(readTask(q));
    }
  });
}

absl::Status SqliteJobStore::registerWorker(const WorkerInfo& worker) {
  if (worker.id.empty()) return absl::InvalidArgumentError("a worker needs an id");
  return transaction(Access::kWrite, [&]() -> absl::Status {
    Query q = query(
        "INSERT INTO workers (id, host, cores, memory_bytes, cache_bytes, last_seen) "
        "VALUES (?1, ?2, ?3, ?4, ?5, ?6) ON CONFLICT (id) DO UPDATE SET host = excluded.host, "
        "cores = excluded.cores, memory_bytes = excluded.memory_bytes, "
        "cache_bytes = excluded.cache_bytes, last_seen = excluded.last_seen");
    // SQLite integers are signed; the bit pattern round-trips through the casts.
    q.bind(1, worker.id)
        .bind(2, worker.host)
        .bind(3, worker.cores)
        .bind(4, static_cast<int64_t>(worker.memoryBytes))
        .bind(5, static_cast<int64_t>(worker.cacheBytes))
        .bind(6, worker.lastSeen);
    return q.run();
  });
}

absl::StatusOr<std::vector<WorkerInfo>> SqliteJobStore::workers() {
  return transaction(Access::kRead, [&]() -> absl::StatusOr<std::vector<WorkerInfo>> {
    Query q = query(
        "SELECT id, host, cores, memory_bytes, cache_bytes, last_seen FROM workers ORDER BY id");
    std::vector<WorkerInfo> out;
    for (;;) {
      PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
      if (!row) return out;
      WorkerInfo w;
      w.id = q.text(0);
      w.host = q.text(1);
      w.cores = q.integer(2);
      w.memoryBytes = static_cast<uint64_t>(q.int64(3));
      w.cacheBytes = static_cast<uint64_t>(q.int64(4));
      w.lastSeen = q.real(5);
      out.push_back(std::move(w));
    }
  });
}

absl::StatusOr<std::optional<Lease>> SqliteJobStore::lease(const std::string& worker, Seconds now,
                                                           Seconds leaseSeconds,
                                                           std::span<const HeldFrame> held) {
  if (worker.empty()) return absl::InvalidArgumentError("a lease needs a worker id");
  return transaction(Access::kWrite, [&]() -> absl::StatusOr<std::optional<Lease>> {
    Lease lease;
    // The active jobs in lease order, then each one's first ready task (an index walk each),
    // rather than one sort of every ready task of every job per lease.
    std::vector<int64_t> order;
    {
      Query jobs = query(
          "SELECT j.id FROM jobs j WHERE j.state = 0 AND NOT EXISTS (SELECT 1 FROM "
          "job_worker_failures f WHERE f.job = j.id AND f.worker = ?1 AND f.failures >= ?2) "
          "ORDER BY j.priority DESC, j.submitted, j.id");
      jobs.bind(1, worker).bind(2, blocklistThreshold(policy_));
      for (;;) {
        PBGI_ASSIGN_OR_RETURN(const bool row, jobs.step());
        if (!row) break;
        order.push_back(jobs.int64(0));
      }
    }
    // The first ready task of `job`, of `frame` only when one is given.
    auto pickFrom = [&](int64_t job, std::optional<int> frame) -> absl::StatusOr<bool> {
      Query pick = query(
          frame ? "SELECT id, job, kind, frame, tile, attempt FROM tasks INDEXED BY "
                  "tasks_by_job_state WHERE job = ?1 AND state = 1 AND frame = ?3 AND "
                  "not_before <= ?2 ORDER BY kind, tile LIMIT 1"
                : "SELECT id, job, kind, frame, tile, attempt FROM tasks INDEXED BY "
                  "tasks_by_job_state WHERE job = ?1 AND state = 1 AND not_before <= ?2 ORDER "
                  "BY frame, kind, tile LIMIT 1");
      pick.bind(1, job).bind(2, now);
      if (frame) pick.bind(3, *frame);
      PBGI_ASSIGN_OR_RETURN(const bool row, pick.step());
      if (!row) return false;
      lease.task = pick.int64(0);
      lease.ref.job = pick.int64(1);
      lease.ref.kind = static_cast<TaskKind>(pick.integer(2));
      lease.ref.frame = pick.integer(3);
      lease.ref.tile = pick.integer(4);
      lease.attempt = pick.integer(5) + 1;
      lease.expires = now + leaseSeconds;
      return true;
    };
    PBGI_ASSIGN_OR_RETURN(const bool found, pickInLeaseOrder(order, held, pickFrom));
    if (!found) return std::optional<Lease>();
    {
      Query take = query(
          "UPDATE tasks SET state = 2, attempt = ?2, worker = ?3, expires = ?4, progress = 0 "
          "WHERE id = ?1");
      take.bind(1, lease.task).bind(2, lease.attempt).bind(3, worker).bind(4, lease.expires);
      PBGI_RETURN_IF_ERROR(take.run());
    }
    PBGI_RETURN_IF_ERROR(touchWorker(worker, now));
    TaskInfo leased;
    leased.id = lease.task;
    leased.ref = lease.ref;
    PBGI_RETURN_IF_ERROR(addEvent(leased, lease.attempt, worker, TaskEventKind::kLeased, "", now));
    return std::optional<Lease>(lease);
  });
}

absl::Status SqliteJobStore::heartbeat(int64_t task, int attempt, double progress, Seconds now,
                                       Seconds leaseSeconds) {
  progress = clampProgress(progress);
  return transaction(Access::kWrite, [&]() -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const TaskInfo info, currentLease(task, attempt));
    Query q = query("UPDATE tasks SET expires = ?2, progress = ?3 WHERE id = ?1");
    q.bind(1, task).bind(2, now + leaseSeconds).bind(3, progress);
    PBGI_RETURN_IF_ERROR(q.run());
    return touchWorker(info.worker, now);
  });
}

absl::StatusOr<TaskRef> SqliteJobStore::complete(int64_t task, int attempt, Seconds now,
                                                 const std::string& log) {
  return transaction(Access::kWrite, [&]() -> absl::StatusOr<TaskRef> {
    PBGI_ASSIGN_OR_RETURN(const TaskInfo info, currentLease(task, attempt));
    PBGI_RETURN_IF_ERROR(addEvent(info, attempt, info.worker, TaskEventKind::kDone, log, now));
    {
      Query q = query("UPDATE tasks SET state = 3, progress = 1, expires = NULL WHERE id = ?1");
      q.bind(1, task);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    PBGI_RETURN_IF_ERROR(promoteBlocked(info.ref.job, info.ref.frame, info.ref.kind));
    PBGI_RETURN_IF_ERROR(touchWorker(info.worker, now));
    PBGI_RETURN_IF_ERROR(settleJob(info.ref.job));
    return info.ref;
  });
}

absl::Status SqliteJobStore::fail(int64_t task, int attempt, const std::string& error,
                                  Seconds now, const std::string& log) {
  return transaction(Access::kWrite, [&]() -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const TaskInfo info, currentLease(task, attempt));
    return recordFailure(info, error, now, TaskEventKind::kFailed, log);
  });
}

absl::StatusOr<int> SqliteJobStore::expireLeases(Seconds now) {
  return transaction(Access::kWrite, [&]() -> absl::StatusOr<int> {
    // Collected first: recordFailure() runs statements of its own on the same table.
    std::vector<int64_t> expired;
    {
      Query q = query("SELECT id FROM tasks WHERE state = 2 AND expires <= ?1 ORDER BY id");
      q.bind(1, now);
      for (;;) {
        PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
        if (!row) break;
        expired.push_back(q.int64(0));
      }
    }
    for (int64_t id : expired) {
      PBGI_ASSIGN_OR_RETURN(const TaskInfo info, loadTask(id));
      PBGI_RETURN_IF_ERROR(
          recordFailure(info, leaseExpiredError(info.worker), now, TaskEventKind::kExpired, ""));
    }
    std::vector<AuditInfo> expiredAudits;
    {
      Query q = query("SELECT " PBGI_AUDIT_COLUMNS
                      " FROM audits WHERE state = 1 AND expires <= ?1 ORDER BY id");
      q.bind(1, now);
      for (;;) {
        PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
        if (!row) break;
        PBGI_ASSIGN_OR_RETURN(AuditInfo info, readAudit(q));
        expiredAudits.push_back(std::move(info));
      }
    }
    for (const AuditInfo& info : expiredAudits) {
      PBGI_RETURN_IF_ERROR(recordAuditFailure(info, leaseExpiredError(info.worker), now));
    }
    return static_cast<int>(expired.size() + expiredAudits.size());
  });
}

absl::Status SqliteJobStore::cancel(int64_t job) {
  return transaction(Access::kWrite, [&]() -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const JobState state, jobState(job));
    if (state == JobState::kDone) {
      return absl::FailedPreconditionError(
          fmt::format("job {}: done; there is nothing left to cancel", job));
    }
    // Dead tasks stay dead: their errors are the record of why the job failed, and retry
    // revives dead and cancelled tasks alike.
    {
      Query q =
          query("UPDATE tasks SET state = 5, expires = NULL WHERE job = ?1 AND state IN (0, 1, 2)");
      q.bind(1, job);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    {
      Query q =
          query("UPDATE audits SET state = 4, expires = NULL WHERE job = ?1 AND state IN (0, 1)");
      q.bind(1, job);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    Query q = query("UPDATE jobs SET state = 3 WHERE id = ?1");
    q.bind(1, job);
    return q.run();
  });
}

absl::Status SqliteJobStore::retry(int64_t job, std::optional<int> frame, std::optional<int> tile,
                                   Seconds now) {
  if (tile && !frame) {
    return absl::InvalidArgumentError(
        fmt::format("job {}: retrying tile {} needs its frame", job, *tile));
  }
  return transaction(Access::kWrite, [&]() -> absl::Status {
    PBGI_RETURN_IF_ERROR(jobState(job).status());
    // A tile is retried with its frame's bake and assemble when those are dead or cancelled
    // too: the tile cannot run without the one, and its result is lost without the other.
    // Attempts keep counting, so a worker from before the retry still holds a stale attempt.
    {
      Query q = query(
          "UPDATE tasks SET state = 0, failures = 0, last_error = '', progress = 0, "
          "not_before = 0, expires = NULL WHERE job = ?1 AND state IN (4, 5) "
          "AND (?2 IS NULL OR frame = ?2) AND (?3 IS NULL OR kind != 1 OR tile = ?3)");
      q.bind(1, job).bind(2, frame).bind(3, tile);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    {
      // An audit covers its whole frame: a tile's retry revives its frame's audit.
      Query q = query(
          "UPDATE audits SET state = 0, failures = 0, last_error = '', not_before = 0, "
          "expires = NULL WHERE job = ?1 AND state IN (3, 4) AND (?2 IS NULL OR frame = ?2)");
      q.bind(1, job).bind(2, frame);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    {
      Query q = query("UPDATE jobs SET state = 0 WHERE id = ?1");
      q.bind(1, job);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    PBGI_RETURN_IF_ERROR(promoteBlocked(job, frame));
    // What was revived may still wait on a task left dead (another tile of the frame, say).
    std::vector<TaskInfo> dead;
    {
      Query q = query("SELECT " PBGI_TASK_COLUMNS
                      " FROM tasks WHERE job = ?1 AND (?2 IS NULL OR frame = ?2) AND state = 4 "
                      "AND kind != 2 ORDER BY frame, kind, tile");
      q.bind(1, job).bind(2, frame);
      for (;;) {
        PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
        if (!row) break;
        dead.push_back(readTask(q));
      }
    }
    for (const TaskInfo& task : dead) PBGI_RETURN_IF_ERROR(killDependents(task));
    return settleJob(job);
  });
}

absl::StatusOr<bool> SqliteJobStore::blocklisted(int64_t job, const std::string& worker) {
  return transaction(Access::kRead, [&]() -> absl::StatusOr<bool> {
    PBGI_RETURN_IF_ERROR(jobState(job).status());
    Query q = query("SELECT failures FROM job_worker_failures WHERE job = ?1 AND worker = ?2");
    q.bind(1, job).bind(2, worker);
    PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
    return row && q.int64(0) >= blocklistThreshold(policy_);
  });
}

absl::StatusOr<std::vector<TaskEvent>> SqliteJobStore::events(int64_t job,
                                                              std::optional<int> frame,
                                                              std::optional<int> tile) {
  return transaction(Access::kRead, [&]() -> absl::StatusOr<std::vector<TaskEvent>> {
    PBGI_RETURN_IF_ERROR(jobState(job).status());
    Query q = query(
        "SELECT e.time, e.task, t.kind, t.frame, t.tile, e.attempt, e.worker, e.event, e.text "
        "FROM task_events e JOIN tasks t ON t.id = e.task WHERE e.job = ?1 "
        "AND (?2 IS NULL OR t.frame = ?2) AND (?3 IS NULL OR t.tile = ?3) ORDER BY e.id");
    q.bind(1, job).bind(2, frame).bind(3, tile);
    std::vector<TaskEvent> out;
    for (;;) {
      PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
      if (!row) return out;
      TaskEvent e;
      e.time = q.real(0);
      e.task = q.int64(1);
      e.ref.job = job;
      e.ref.kind = static_cast<TaskKind>(q.integer(2));
      e.ref.frame = q.integer(3);
      e.ref.tile = q.integer(4);
      e.attempt = q.integer(5);
      e.worker = q.text(6);
      e.event = q.text(7);
      e.text = q.text(8);
      out.push_back(std::move(e));
    }
  });
}

absl::StatusOr<AuditInfo> SqliteJobStore::readAudit(const Query& q) const {
  AuditInfo info;
  info.id = q.int64(0);
  info.job = q.int64(1);
  info.spec.frame = q.integer(2);
  PBGI_ASSIGN_OR_RETURN(info.spec.tiles,
                        parseFrames(q.text(3), fmt::format("{}: audit {} tiles", path_, info.id)));
  info.spec.spp = q.integer(4);
  info.spec.threshold = q.real(5);
  info.state = static_cast<AuditState>(q.integer(6));
  info.attempt = q.integer(7);
  info.failures = q.integer(8);
  info.worker = q.text(9);
  info.lastError = q.text(10);
  if (info.state == AuditState::kDone) {
    info.result = AuditResult{realOrNan(q, 11), realOrNan(q, 12), realOrNan(q, 13)};
  }
  return info;
}

absl::StatusOr<AuditInfo> SqliteJobStore::loadAudit(int64_t audit) {
  Query q = query("SELECT " PBGI_AUDIT_COLUMNS " FROM audits WHERE id = ?1");
  q.bind(1, audit);
  PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
  if (!row) return absl::NotFoundError(fmt::format("audit {}: no such audit", audit));
  return readAudit(q);
}

absl::StatusOr<AuditInfo> SqliteJobStore::currentAuditLease(int64_t audit, int attempt) {
  PBGI_ASSIGN_OR_RETURN(AuditInfo info, loadAudit(audit));
  PBGI_RETURN_IF_ERROR(checkCurrentLease(info, attempt));
  return info;
}

// Unlike a task's failure, nothing else moves: not the job, not the worker's blocklist.
absl::Status SqliteJobStore::recordAuditFailure(const AuditInfo& audit, const std::string& error,
                                                Seconds now) {
  const FailureOutcome outcome = failureOutcome(policy_, audit.failures, now);
  Query q = query(
      "UPDATE audits SET state = ?2, failures = ?3, last_error = ?4, not_before = ?5, "
      "expires = NULL WHERE id = ?1");
  q.bind(1, audit.id)
      .bind(2, auditStateAfter(outcome))
      .bind(3, outcome.failures)
      .bind(4, error)
      .bind(5, outcome.notBefore);
  return q.run();
}

absl::StatusOr<std::optional<AuditLease>> SqliteJobStore::leaseAudit(const std::string& worker,
                                                                     Seconds now,
                                                                     Seconds leaseSeconds) {
  if (worker.empty()) return absl::InvalidArgumentError("an audit's lease needs a worker id");
  return transaction(Access::kWrite, [&]() -> absl::StatusOr<std::optional<AuditLease>> {
    AuditInfo picked;
    {
      // One sort of the ready audits: a job has at most one a frame, and this runs only for a
      // worker that found no task.
      Query q = query(
          "SELECT " PBGI_AUDIT_COLUMNS
          " FROM audits WHERE id = (SELECT a.id FROM audits a "
          "JOIN jobs j ON j.id = a.job WHERE a.state = 0 AND a.not_before <= ?1 AND j.state != 3 "
          "AND EXISTS (SELECT 1 FROM tasks t WHERE t.job = a.job AND t.frame = a.frame AND "
          "t.kind = 2 AND t.state = 3) "
          "ORDER BY j.priority DESC, j.submitted, j.id, a.frame LIMIT 1)");
      q.bind(1, now);
      PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
      if (!row) return std::optional<AuditLease>();
      PBGI_ASSIGN_OR_RETURN(picked, readAudit(q));
    }
    AuditLease lease{picked.id, picked.attempt + 1, picked.job, picked.spec, now + leaseSeconds};
    {
      Query take = query(
          "UPDATE audits SET state = 1, attempt = ?2, worker = ?3, expires = ?4 WHERE id = ?1");
      take.bind(1, lease.audit).bind(2, lease.attempt).bind(3, worker).bind(4, lease.expires);
      PBGI_RETURN_IF_ERROR(take.run());
    }
    PBGI_RETURN_IF_ERROR(touchWorker(worker, now));
    return std::optional<AuditLease>(std::move(lease));
  });
}

absl::Status SqliteJobStore::heartbeatAudit(int64_t audit, int attempt, Seconds now,
                                            Seconds leaseSeconds) {
  return transaction(Access::kWrite, [&]() -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const AuditInfo info, currentAuditLease(audit, attempt));
    Query q = query("UPDATE audits SET expires = ?2 WHERE id = ?1");
    q.bind(1, audit).bind(2, now + leaseSeconds);
    PBGI_RETURN_IF_ERROR(q.run());
    return touchWorker(info.worker, now);
  });
}

absl::Status SqliteJobStore::completeAudit(int64_t audit, int attempt, const AuditResult& result,
                                           Seconds now) {
  return transaction(Access::kWrite, [&]() -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const AuditInfo info, currentAuditLease(audit, attempt));
    {
      Query q = query(
          "UPDATE audits SET state = 2, expires = NULL, rel_mse = ?2, bias = ?3, seconds = ?4 "
          "WHERE id = ?1");
      q.bind(1, audit).bind(2, result.relMse).bind(3, result.bias).bind(4, result.seconds);
      PBGI_RETURN_IF_ERROR(q.run());
    }
    return touchWorker(info.worker, now);
  });
}

absl::Status SqliteJobStore::failAudit(int64_t audit, int attempt, const std::string& error,
                                       Seconds now) {
  return transaction(Access::kWrite, [&]() -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const AuditInfo info, currentAuditLease(audit, attempt));
    return recordAuditFailure(info, error, now);
  });
}

absl::StatusOr<std::vector<AuditInfo>> SqliteJobStore::audits(int64_t job) {
  return transaction(Access::kRead, [&]() -> absl::StatusOr<std::vector<AuditInfo>> {
    PBGI_RETURN_IF_ERROR(jobState(job).status());
    Query q = query("SELECT " PBGI_AUDIT_COLUMNS " FROM audits WHERE job = ?1 ORDER BY frame");
    q.bind(1, job);
    std::vector<AuditInfo> out;
    for (;;) {
      PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
      if (!row) return out;
      PBGI_ASSIGN_OR_RETURN(AuditInfo info, readAudit(q));
      out.push_back(std::move(info));
    }
  });
}

}  // namespace

absl::StatusOr<std::unique_ptr<JobStore>> openSqliteJobStore(const std::string& path,
                                                             const RetryPolicy& policy) {
  PBGI_RETURN_IF_ERROR(validateRetryPolicy(policy));
  sqlite3* raw = nullptr;
  // NOMUTEX: the store's own mutex already serializes every use of the connection.
  const int rc =
      sqlite3_open_v2(path.c_str(), &raw,
                      SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_NOMUTEX, nullptr);
  DatabasePtr db(raw);
  if (rc != SQLITE_OK) {
    return sqliteStatus(rc, raw != nullptr ? sqlite3_errmsg(raw) : sqlite3_errstr(rc), path,
                        "opening the job store");
  }
  auto store = std::make_unique<SqliteJobStore>(path, policy, std::move(db));
  PBGI_RETURN_IF_ERROR(store->initialize());
  return std::unique_ptr<JobStore>(std::move(store));
}

}  // namespace pbgi::farm
