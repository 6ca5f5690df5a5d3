// The embedded job store: one SQLite file in WAL mode, one connection behind a mutex. Each
// public call is one transaction, so a crash between two calls loses nothing a caller heard
// about, and a crash inside one loses the whole call and nothing else.
//
// Group commit: writes that arrive while another batch commits wait, then commit together,
// each inside a savepoint of one transaction (one fsync for all of them instead of one each).
// A call still returns only after its changes are durable; a call that fails rolls back to its
// savepoint, undoing only itself; a commit that fails fails every call of its batch.
#include <absl/strings/ascii.h>
#include <fmt/format.h>

#include "services/farm/farm_wire.h"
#include "services/job_store/sqlite_job_store.h"

namespace pbgi::farm {
namespace sqlite_store {

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
        lost->committed = absl::AbortedError(
            fmt::format("job store {}: rolled back with another call of its group commit: {}",
                        path_, ran.ToString()));
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

absl::StatusOr<JobInfo> SqliteJobStore::readJob(const Query& q) { return readJobRow(q, path_); }

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
    Query q = frame ? query(
                          "UPDATE tasks SET state = 1 WHERE job = ?1 AND state = 0 AND "
                          "frame = ?2 AND kind = ?3 AND (?4 IS NULL OR NOT EXISTS (SELECT 1 "
                          "FROM tasks d WHERE d.job = tasks.job AND d.frame = tasks.frame AND "
                          "d.kind = ?4 AND d.state IN (0, 1, 2, 4, 5)))")
                    : query(
                          "UPDATE tasks SET state = 1 WHERE job = ?1 AND state = 0 AND "
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
    if (present[static_cast<size_t>(s)] && (s == TaskState::kReady || s == TaskState::kLeased)) {
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
          .bind(4, toStoreText(spec.overrides))
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

absl::StatusOr<AuditInfo> SqliteJobStore::audit(int64_t audit) {
  return transaction(Access::kRead, [&]() { return loadAudit(audit); });
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

}  // namespace sqlite_store

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
  auto store = std::make_unique<sqlite_store::SqliteJobStore>(path, policy, std::move(db));
  PBGI_RETURN_IF_ERROR(store->initialize());
  return std::unique_ptr<JobStore>(std::move(store));
}

}  // namespace pbgi::farm
