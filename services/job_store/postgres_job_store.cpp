// The shared job store: PostgreSQL through libpqxx, so that several coordinators (and the
// operators' tools) can work on one farm's jobs. A pool of kConnections connections per store
// object (postgres_query.h), so that concurrent calls overlap on the server and share its WAL
// flushes; each public call is one transaction.
//
// Concurrency, with every write transaction at READ COMMITTED:
// - lease takes its task with SELECT ... FOR UPDATE SKIP LOCKED, re-checked under the lock, so
//   two coordinators never lease one task, and neither waits on the other's pick;
// - complete, fail, expireLeases, cancel and retry lock the job's row first (FOR NO KEY UPDATE:
//   it does not block the key-share locks that inserting events takes), then the task's row,
//   and change a task only at the attempt and state they checked. Serializing a job's changes
//   is what keeps promotion and settling right: two tiles completing at once would otherwise
//   each see the other unfinished, and the assemble would never become ready.
// - audits settle nothing, so their calls lock only the audit's row, never a job's: leaseAudit
//   takes its pick with FOR UPDATE SKIP LOCKED in the statement that leases it, heartbeats and
//   completions are one UPDATE conditional on the attempt, failures and expiry lock the row
//   and re-check it; cancel and retry reach a job's audits after its row and its tasks.
// Locks are taken job, then task, then audit, then worker, so deadlocks are rare; those and
// serialization failures are retried a bounded number of times.
#include <limits>
#include <memory>
#include <optional>
#include <string_view>
#include <utility>

#include <fmt/format.h>

#include "core/util/status.h"
#include "services/farm/farm_wire.h"
#include "services/job_store/job_store.h"
#include "services/job_store/postgres_query.h"

namespace pbgi::farm {
namespace {

// Bumped with every schema change: a database written by a newer coordinator is refused.
constexpr int kSchemaVersion = 2;
// Connections per store object: calls beyond this many at once wait for one. The locking
// below is what lets two coordinators share a database; it is also what lets these share it.
constexpr int kConnections = 8;
// Tasks a submission adds beyond which it refreshes the table's statistics.
constexpr size_t kAnalyzeAfterTasks = 10000;
// pg_advisory_xact_lock key ("pbgi") that serializes coordinators creating the schema at once.
constexpr int64_t kSchemaLockKey = 0x70626769;

// Free text from workers (errors, logs) and the shot's bytes are BYTEA: byte for byte, like
// the SQLite store, whatever their encoding.
constexpr const char* kSchema = R"sql(
CREATE TABLE IF NOT EXISTS jobs (
  id BIGSERIAL PRIMARY KEY,
  name TEXT NOT NULL,
  shot_path TEXT NOT NULL,
  shot_text BYTEA NOT NULL,
  overrides TEXT NOT NULL,
  output_pattern TEXT NOT NULL,
  priority INTEGER NOT NULL,
  frames TEXT NOT NULL,
  tile_count INTEGER NOT NULL CHECK (tile_count > 0),
  needs_bake BOOLEAN NOT NULL,
  state SMALLINT NOT NULL CHECK (state BETWEEN 0 AND 3),
  submitted DOUBLE PRECISION NOT NULL
);
CREATE TABLE IF NOT EXISTS tasks (
  id BIGSERIAL PRIMARY KEY,
  job BIGINT NOT NULL REFERENCES jobs (id),
  kind SMALLINT NOT NULL CHECK (kind BETWEEN 0 AND 2),
  frame INTEGER NOT NULL,
  tile INTEGER NOT NULL,
  state SMALLINT NOT NULL CHECK (state BETWEEN 0 AND 5),
  attempt INTEGER NOT NULL DEFAULT 0,
  failures INTEGER NOT NULL DEFAULT 0,
  worker TEXT NOT NULL DEFAULT '',
  last_error BYTEA NOT NULL DEFAULT '',
  progress DOUBLE PRECISION NOT NULL DEFAULT 0,
  expires DOUBLE PRECISION,
  not_before DOUBLE PRECISION NOT NULL DEFAULT 0,
  UNIQUE (job, frame, kind, tile)
);
-- The lease walk: active jobs in lease order, then each one's first ready task. Both indexes
-- are partial, so finished jobs and tasks never lengthen a lease's scan.
CREATE INDEX IF NOT EXISTS jobs_active ON jobs (priority DESC, submitted, id) WHERE state = 0;
CREATE INDEX IF NOT EXISTS tasks_ready ON tasks (job, frame, kind, tile) WHERE state = 1;
CREATE INDEX IF NOT EXISTS tasks_leased ON tasks (expires) WHERE state = 2;
-- Promotion asks whether a frame still has an unfinished task of a kind: a probe, rather than
-- a walk over the frame's thousands of done tiles at every completion.
CREATE INDEX IF NOT EXISTS tasks_unfinished ON tasks (job, frame, kind) WHERE state <> 3;
CREATE INDEX IF NOT EXISTS tasks_by_job_state ON tasks (job, state);
CREATE TABLE IF NOT EXISTS workers (
  id TEXT PRIMARY KEY,
  host TEXT NOT NULL,
  cores INTEGER NOT NULL,
  memory_bytes BIGINT NOT NULL,
  cache_bytes BIGINT NOT NULL,
  last_seen DOUBLE PRECISION NOT NULL
);
CREATE TABLE IF NOT EXISTS job_worker_failures (
  job BIGINT NOT NULL REFERENCES jobs (id),
  worker TEXT NOT NULL,
  failures INTEGER NOT NULL,
  PRIMARY KEY (job, worker)
);
CREATE TABLE IF NOT EXISTS task_events (
  id BIGSERIAL PRIMARY KEY,
  task BIGINT NOT NULL REFERENCES tasks (id),
  job BIGINT NOT NULL REFERENCES jobs (id),
  attempt INTEGER NOT NULL,
  worker TEXT NOT NULL,
  time DOUBLE PRECISION NOT NULL,
  event TEXT NOT NULL,
  text BYTEA NOT NULL
);
CREATE INDEX IF NOT EXISTS task_events_by_job ON task_events (job, id);
)sql";

// Version 2 added the audits; a version 1 database gets them on opening.
constexpr const char* kAuditsSchema = R"sql(
CREATE TABLE IF NOT EXISTS audits (
  id BIGSERIAL PRIMARY KEY,
  job BIGINT NOT NULL REFERENCES jobs (id),
  frame INTEGER NOT NULL,
  tiles TEXT NOT NULL,
  spp INTEGER NOT NULL CHECK (spp > 0),
  threshold DOUBLE PRECISION NOT NULL CHECK (threshold >= 0),
  state SMALLINT NOT NULL DEFAULT 0 CHECK (state BETWEEN 0 AND 4),
  attempt INTEGER NOT NULL DEFAULT 0,
  failures INTEGER NOT NULL DEFAULT 0,
  worker TEXT NOT NULL DEFAULT '',
  last_error BYTEA NOT NULL DEFAULT '',
  expires DOUBLE PRECISION,
  not_before DOUBLE PRECISION NOT NULL DEFAULT 0,
  rel_mse DOUBLE PRECISION,
  bias DOUBLE PRECISION,
  seconds DOUBLE PRECISION,
  UNIQUE (job, frame)
);
-- Partial, like the tasks': done audits never lengthen a lease's or an expiry's scan.
CREATE INDEX IF NOT EXISTS audits_ready ON audits (job, frame) WHERE state = 0;
CREATE INDEX IF NOT EXISTS audits_leased ON audits (expires) WHERE state = 1;
)sql";

int number(TaskKind kind) { return static_cast<int>(kind); }
int number(TaskState state) { return static_cast<int>(state); }
int number(JobState state) { return static_cast<int>(state); }
int number(AuditState state) { return static_cast<int>(state); }

// Reads a row selected with PBGI_TASK_COLUMNS.
TaskInfo readTask(const pqxx::row& r) { return readTaskRow(PgRow{r}); }

class PostgresJobStore final : public JobStore {
 public:
  PostgresJobStore(std::string uri, const RetryPolicy& policy)
      : sessions_(uri, kConnections), policy_(policy) {}

  absl::Status initialize();

  absl::StatusOr<int64_t> submit(const JobSpec& spec, Seconds now) override;
  absl::StatusOr<JobInfo> job(int64_t job) override;
  absl::StatusOr<std::vector<JobInfo>> jobs() override;
  absl::StatusOr<std::vector<TaskInfo>> tasks(int64_t job) override;
  absl::StatusOr<TaskInfo> task(int64_t task) override;
  absl::StatusOr<AuditInfo> audit(int64_t audit) override;
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
  absl::StatusOr<int> expireLeases(Seconds now, std::vector<ExpiredLease>* expired) override;
  absl::Status cancel(int64_t job) override;
  absl::Status retry(int64_t job, std::optional<int> frame, std::optional<int> tile,
                     Seconds now) override;
  absl::StatusOr<bool> blocklisted(int64_t job, const std::string& worker) override;
  absl::StatusOr<std::vector<std::string>> blocklistedWorkers(int64_t job) override;
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
  template <typename Body>
  auto transaction(PgAccess access, Body&& body) {
    return sessions_.transaction(access, std::forward<Body>(body));
  }
  absl::StatusOr<JobState> jobState(PgTx& tx, int64_t job, bool lock = false);
  absl::StatusOr<JobInfo> readJob(const pqxx::row& r) const;
  absl::Status addTaskSummary(PgTx& tx, JobInfo& info);
  absl::StatusOr<TaskInfo> loadTask(PgTx& tx, int64_t task, bool lock = false);
  absl::StatusOr<TaskInfo> lockCurrentLease(PgTx& tx, int64_t task, int attempt);
  void addEvent(PgTx& tx, const TaskInfo& task, int attempt, const std::string& worker,
                TaskEventKind event, std::string_view text, Seconds now);
  void touchWorker(PgTx& tx, const std::string& worker, Seconds now);
  void promoteBlocked(PgTx& tx, int64_t job, std::optional<int> frame,
                      std::optional<TaskKind> completed = std::nullopt);
  void killDependents(PgTx& tx, const TaskInfo& dead);
  absl::Status recordFailure(PgTx& tx, const TaskInfo& task, const std::string& error, Seconds now,
                             TaskEventKind event, std::string_view log);
  absl::Status settleJob(PgTx& tx, int64_t job);
  absl::StatusOr<AuditInfo> readAudit(const pqxx::row& r) const;
  absl::StatusOr<AuditInfo> loadAudit(PgTx& tx, int64_t audit, bool lock = false);
  // Why a change to the audit at `attempt` matched no row: NotFound or FailedPrecondition.
  absl::Status auditLeaseLost(PgTx& tx, int64_t audit, int attempt);
  void recordAuditFailure(PgTx& tx, const AuditInfo& audit, const std::string& error, Seconds now);

  PgPool sessions_;
  const RetryPolicy policy_;
};

absl::Status PostgresJobStore::initialize() {
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::Status {
    tx.exec("SELECT pg_advisory_xact_lock($1)", kSchemaLockKey);
    tx.script("CREATE TABLE IF NOT EXISTS pbgi_schema (version INTEGER NOT NULL)");
    const pqxx::result version = tx.exec("SELECT version FROM pbgi_schema");
    const int found = version.empty() ? 0 : version[0][0].as<int>();
    if (found == kSchemaVersion) return absl::OkStatus();
    if (found < 0 || found > kSchemaVersion) {
      return absl::FailedPreconditionError(
          fmt::format("{}: schema version {}; this coordinator reads version {}",
                      sessions_.shownUri(), found, kSchemaVersion));
    }
    // Each version's additions in turn: a new database gets them all, an older one what it
    // lacks.
    if (found < 1) tx.script(kSchema);
    tx.script(kAuditsSchema);
    if (version.empty()) {
      tx.exec("INSERT INTO pbgi_schema (version) VALUES ($1)", kSchemaVersion);
    } else {
      tx.exec("UPDATE pbgi_schema SET version = $1", kSchemaVersion);
    }
    return absl::OkStatus();
  });
}

absl::StatusOr<JobState> PostgresJobStore::jobState(PgTx& tx, int64_t job, bool lock) {
  const pqxx::result r =
      lock ? tx.exec("SELECT state FROM jobs WHERE id = $1 FOR NO KEY UPDATE", job)
           : tx.exec("SELECT state FROM jobs WHERE id = $1", job);
  if (r.empty()) return absl::NotFoundError(fmt::format("job {}: no such job", job));
  return static_cast<JobState>(r[0][0].as<int>());
}

absl::StatusOr<JobInfo> PostgresJobStore::readJob(const pqxx::row& r) const {
  return readJobRow(PgRow{r}, sessions_.shownUri());
}

absl::Status PostgresJobStore::addTaskSummary(PgTx& tx, JobInfo& info) {
  for (const auto& row :
       tx.exec("SELECT state, COUNT(*) FROM tasks WHERE job = $1 GROUP BY state", info.id)) {
    info.tasksByState[row[0].as<size_t>()] = row[1].as<int>();
  }
  for (const auto& row :
       tx.exec("SELECT " PBGI_TASK_COLUMNS " FROM tasks WHERE job = $1 AND state = 4 "
               "ORDER BY frame, kind, tile",
               info.id)) {
    info.dead.push_back(readTask(row));
  }
  return absl::OkStatus();
}

absl::StatusOr<TaskInfo> PostgresJobStore::loadTask(PgTx& tx, int64_t task, bool lock) {
  const pqxx::result r =
      lock ? tx.exec("SELECT " PBGI_TASK_COLUMNS " FROM tasks WHERE id = $1 FOR UPDATE", task)
           : tx.exec("SELECT " PBGI_TASK_COLUMNS " FROM tasks WHERE id = $1", task);
  if (r.empty()) return absl::NotFoundError(fmt::format("task {}: no such task", task));
  return readTask(r[0]);
}

// The task with its job's row and its own locked, checked to be leased at `attempt`.
absl::StatusOr<TaskInfo> PostgresJobStore::lockCurrentLease(PgTx& tx, int64_t task, int attempt) {
  PBGI_ASSIGN_OR_RETURN(const TaskInfo seen, loadTask(tx, task));
  PBGI_RETURN_IF_ERROR(jobState(tx, seen.ref.job, /*lock=*/true).status());
  // Read again under the lock: another coordinator may have moved it since.
  PBGI_ASSIGN_OR_RETURN(TaskInfo info, loadTask(tx, task, /*lock=*/true));
  PBGI_RETURN_IF_ERROR(checkCurrentLease(info, attempt));
  return info;
}

void PostgresJobStore::addEvent(PgTx& tx, const TaskInfo& task, int attempt,
                                const std::string& worker, TaskEventKind event,
                                std::string_view text, Seconds now) {
  tx.exec(
      "INSERT INTO task_events (task, job, attempt, worker, time, event, text) "
      "VALUES ($1, $2, $3, $4, $5, $6, $7)",
      task.id, task.ref.job, attempt, worker, now, toString(event),
      pqxx::binarystring(text.data(), text.size()));
}

void PostgresJobStore::touchWorker(PgTx& tx, const std::string& worker, Seconds now) {
  tx.exec("UPDATE workers SET last_seen = $2 WHERE id = $1", worker, now);
}

// kDependencies, in its order.
void PostgresJobStore::promoteBlocked(PgTx& tx, int64_t job, std::optional<int> frame,
                                      std::optional<TaskKind> completed) {
  for (const Dependency& d : kDependencies) {
    if (!mayRelease(d, completed)) continue;
    const NullableInt waitsOn = d.waitsOn ? NullableInt{false, number(*d.waitsOn)} : NullableInt{};
    tx.exec(
        "UPDATE tasks SET state = 1 WHERE job = $1 AND ($2::integer IS NULL OR "
        "frame = $2::integer) AND state = 0 AND kind = $3 AND ($4::smallint IS NULL OR NOT "
        "EXISTS (SELECT 1 FROM tasks d WHERE d.job = tasks.job AND d.frame = tasks.frame "
        "AND d.kind = $4::smallint AND d.state <> 3))",
        job, nullable(frame), number(d.kind), waitsOn);
  }
}

void PostgresJobStore::killDependents(PgTx& tx, const TaskInfo& dead) {
  const std::string error = waitsOnDeadError(dead.ref, dead.lastError);
  for (const TaskKind kind : dependentKinds(dead.ref.kind)) {
    tx.exec(
        "UPDATE tasks SET state = 4, last_error = $4 WHERE job = $1 AND frame = $2 "
        "AND state = 0 AND kind = $3",
        dead.ref.job, dead.ref.frame, number(kind), pqxx::binarystring(error));
  }
}

// The caller holds the job's and the task's rows.
absl::Status PostgresJobStore::recordFailure(PgTx& tx, const TaskInfo& task,
                                             const std::string& error, Seconds now,
                                             TaskEventKind event, std::string_view log) {
  addEvent(tx, task, task.attempt, task.worker, event, failureEventText(error, log), now);
  const FailureOutcome outcome = failureOutcome(policy_, task.failures, now);
  tx.exec(
      "UPDATE tasks SET state = $3, failures = $4, last_error = $5, not_before = $6, "
      "expires = NULL WHERE id = $1 AND attempt = $2 AND state = 2",
      task.id, task.attempt, number(outcome.state), outcome.failures, pqxx::binarystring(error),
      outcome.notBefore);
  if (!task.worker.empty()) {
    tx.exec(
        "INSERT INTO job_worker_failures (job, worker, failures) VALUES ($1, $2, 1) "
        "ON CONFLICT (job, worker) DO UPDATE SET failures = job_worker_failures.failures + 1",
        task.ref.job, task.worker);
  }
  if (outcome.state == TaskState::kDead) {
    TaskInfo dead = task;
    dead.lastError = error;
    killDependents(tx, dead);
  }
  return settleJob(tx, task.ref.job);
}

// The caller holds the job's row.
absl::Status PostgresJobStore::settleJob(PgTx& tx, int64_t job) {
  PBGI_ASSIGN_OR_RETURN(const JobState current, jobState(tx, job));
  if (current == JobState::kCancelled) return absl::OkStatus();
  // An index probe per state rather than a count of every task of the job.
  const pqxx::result r = tx.exec(
      "SELECT EXISTS (SELECT 1 FROM tasks WHERE job = $1 AND state = 0), "
      "EXISTS (SELECT 1 FROM tasks WHERE job = $1 AND state = 1), "
      "EXISTS (SELECT 1 FROM tasks WHERE job = $1 AND state = 2), "
      "EXISTS (SELECT 1 FROM tasks WHERE job = $1 AND state = 4), "
      "EXISTS (SELECT 1 FROM tasks WHERE job = $1 AND state = 5)",
      job);
  PerTaskState<bool> present{};
  present[number(TaskState::kBlocked)] = r[0][0].as<bool>();
  present[number(TaskState::kReady)] = r[0][1].as<bool>();
  present[number(TaskState::kLeased)] = r[0][2].as<bool>();
  present[number(TaskState::kDead)] = r[0][3].as<bool>();
  present[number(TaskState::kCancelled)] = r[0][4].as<bool>();
  const JobState next = settledJobState(current, present);
  if (next != current) tx.exec("UPDATE jobs SET state = $2 WHERE id = $1", job, number(next));
  return absl::OkStatus();
}

// Brace-enclosed array literals for the one-statement task and audit inserts. fmt, not
// std::to_string: a double keeps every digit (the shortest text that reads back the same).
template <typename T, typename Get>
std::string arrayLiteral(const std::vector<T>& items, Get get) {
  std::string out = "{";
  for (size_t i = 0; i < items.size(); ++i) {
    if (i > 0) out += ',';
    out += fmt::format("{}", get(items[i]));
  }
  return out + "}";
}

absl::StatusOr<int64_t> PostgresJobStore::submit(const JobSpec& spec, Seconds now) {
  PBGI_RETURN_IF_ERROR(validateJobSpec(spec));
  const std::vector<PlannedTask> planned = planTasks(spec);
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::StatusOr<int64_t> {
    const pqxx::result inserted = tx.exec(
        "INSERT INTO jobs (name, shot_path, shot_text, overrides, output_pattern, priority, "
        "frames, tile_count, needs_bake, state, submitted) "
        "VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, $11) RETURNING id",
        spec.name, spec.shotPath, pqxx::binarystring(spec.shotText), toStoreText(spec.overrides),
        spec.outputPattern, spec.priority, formatFrames(spec.frames), spec.tileCount,
        spec.needsBake, number(JobState::kActive), now);
    const int64_t job = inserted[0][0].as<int64_t>();
    // One statement for the whole graph (thousands of tiles for a long shot), ids in plan order.
    tx.exec(
        "INSERT INTO tasks (job, kind, frame, tile, state) SELECT $1, u.kind, u.frame, u.tile, "
        "u.state FROM unnest($2::smallint[], $3::integer[], $4::integer[], $5::smallint[]) "
        "WITH ORDINALITY AS u (kind, frame, tile, state, n) ORDER BY u.n",
        job, arrayLiteral(planned, [](const PlannedTask& t) { return number(t.kind); }),
        arrayLiteral(planned, [](const PlannedTask& t) { return t.frame; }),
        arrayLiteral(planned, [](const PlannedTask& t) { return t.tile; }),
        arrayLiteral(planned, [](const PlannedTask& t) { return number(t.state); }));
    // A job that grows the table by much: fresh statistics now, not at autovacuum's next
    // pass, so that the lease and completion plans keep to the indexes.
    if (planned.size() >= kAnalyzeAfterTasks) tx.script("ANALYZE tasks");
    if (!spec.audits.empty()) {
      tx.exec(
          "INSERT INTO audits (job, frame, tiles, spp, threshold) SELECT $1, u.frame, u.tiles, "
          "u.spp, u.threshold FROM unnest($2::integer[], $3::text[], $4::integer[], "
          "$5::double precision[]) AS u (frame, tiles, spp, threshold)",
          job, arrayLiteral(spec.audits, [](const AuditSpec& a) { return a.frame; }),
          // Quoted: each list of tiles is one element (digits and spaces, nothing to escape).
          arrayLiteral(spec.audits,
                       [](const AuditSpec& a) { return '"' + formatFrames(a.tiles) + '"'; }),
          arrayLiteral(spec.audits, [](const AuditSpec& a) { return a.spp; }),
          arrayLiteral(spec.audits, [](const AuditSpec& a) { return a.threshold; }));
    }
    return job;
  });
}

absl::StatusOr<JobInfo> PostgresJobStore::job(int64_t job) {
  return transaction(PgAccess::kRead, [&](PgTx& tx) -> absl::StatusOr<JobInfo> {
    const pqxx::result r = tx.exec("SELECT " PBGI_JOB_COLUMNS " FROM jobs WHERE id = $1", job);
    if (r.empty()) return absl::NotFoundError(fmt::format("job {}: no such job", job));
    PBGI_ASSIGN_OR_RETURN(JobInfo info, readJob(r[0]));
    PBGI_RETURN_IF_ERROR(addTaskSummary(tx, info));
    return info;
  });
}

absl::StatusOr<std::vector<JobInfo>> PostgresJobStore::jobs() {
  return transaction(PgAccess::kRead, [&](PgTx& tx) -> absl::StatusOr<std::vector<JobInfo>> {
    std::vector<JobInfo> out;
    for (const auto& row : tx.exec("SELECT " PBGI_JOB_COLUMNS " FROM jobs ORDER BY id DESC")) {
      PBGI_ASSIGN_OR_RETURN(JobInfo info, readJob(row));
      PBGI_RETURN_IF_ERROR(addTaskSummary(tx, info));
      out.push_back(std::move(info));
    }
    return out;
  });
}

absl::StatusOr<TaskInfo> PostgresJobStore::task(int64_t task) {
  return transaction(PgAccess::kRead, [&](PgTx& tx) { return loadTask(tx, task, false); });
}

absl::StatusOr<AuditInfo> PostgresJobStore::audit(int64_t audit) {
  return transaction(PgAccess::kRead, [&](PgTx& tx) { return loadAudit(tx, audit); });
}

absl::StatusOr<std::vector<TaskInfo>> PostgresJobStore::tasks(int64_t job) {
  return transaction(PgAccess::kRead, [&](PgTx& tx) -> absl::StatusOr<std::vector<TaskInfo>> {
    PBGI_RETURN_IF_ERROR(jobState(tx, job).status());
    std::vector<TaskInfo> out;
    for (const auto& row : tx.exec("SELECT " PBGI_TASK_COLUMNS
                                   " FROM tasks WHERE job = $1 ORDER BY frame, kind, tile",
                                   job)) {
      out.push_back(readTask(row));
    }
    return out;
  });
}

absl::Status PostgresJobStore::registerWorker(const WorkerInfo& worker) {
  if (worker.id.empty()) return absl::InvalidArgumentError("a worker needs an id");
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::Status {
    // BIGINT is signed; the bit pattern round-trips through the casts.
    tx.exec(
        "INSERT INTO workers (id, host, cores, memory_bytes, cache_bytes, last_seen) "
        "VALUES ($1, $2, $3, $4, $5, $6) ON CONFLICT (id) DO UPDATE SET host = excluded.host, "
        "cores = excluded.cores, memory_bytes = excluded.memory_bytes, "
        "cache_bytes = excluded.cache_bytes, last_seen = excluded.last_seen",
        worker.id, worker.host, worker.cores, static_cast<int64_t>(worker.memoryBytes),
        static_cast<int64_t>(worker.cacheBytes), worker.lastSeen);
    return absl::OkStatus();
  });
}

absl::StatusOr<std::vector<WorkerInfo>> PostgresJobStore::workers() {
  return transaction(PgAccess::kRead, [&](PgTx& tx) -> absl::StatusOr<std::vector<WorkerInfo>> {
    std::vector<WorkerInfo> out;
    for (const auto& row : tx.exec("SELECT id, host, cores, memory_bytes, cache_bytes, last_seen "
                                   "FROM workers ORDER BY id")) {
      WorkerInfo w;
      w.id = row[0].as<std::string>();
      w.host = row[1].as<std::string>();
      w.cores = row[2].as<int>();
      w.memoryBytes = static_cast<uint64_t>(row[3].as<int64_t>());
      w.cacheBytes = static_cast<uint64_t>(row[4].as<int64_t>());
      w.lastSeen = row[5].as<double>();
      out.push_back(std::move(w));
    }
    return out;
  });
}

absl::StatusOr<std::optional<Lease>> PostgresJobStore::lease(const std::string& worker, Seconds now,
                                                             Seconds leaseSeconds,
                                                             std::span<const HeldFrame> held) {
  if (worker.empty()) return absl::InvalidArgumentError("a lease needs a worker id");
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::StatusOr<std::optional<Lease>> {
    std::vector<int64_t> order;
    for (const auto& row :
         tx.exec("SELECT j.id FROM jobs j WHERE j.state = 0 AND NOT EXISTS (SELECT 1 FROM "
                 "job_worker_failures f WHERE f.job = j.id AND f.worker = $1 AND f.failures >= "
                 "$2::bigint) "
                 "ORDER BY j.priority DESC, j.submitted, j.id",
                 worker, blocklistThreshold(policy_))) {
      order.push_back(row[0].as<int64_t>());
    }
    Lease lease;
    // The first ready task of `job` (of `frame` when given) that no other coordinator is
    // leasing this moment; locked, and re-checked to be ready under the lock.
    const auto pickFrom = [&](int64_t job, std::optional<int> frame) -> absl::StatusOr<bool> {
      const pqxx::result r =
          frame ? tx.exec(
                      "SELECT id, kind, frame, tile FROM tasks WHERE job = $1 AND state = 1 "
                      "AND frame = $3 AND not_before <= $2 ORDER BY kind, tile LIMIT 1 "
                      "FOR UPDATE SKIP LOCKED",
                      job, now, *frame)
                : tx.exec(
                      "SELECT id, kind, frame, tile FROM tasks WHERE job = $1 AND state = 1 "
                      "AND not_before <= $2 ORDER BY frame, kind, tile LIMIT 1 "
                      "FOR UPDATE SKIP LOCKED",
                      job, now);
      if (r.empty()) return false;
      lease.task = r[0][0].as<int64_t>();
      lease.ref.job = job;
      lease.ref.kind = static_cast<TaskKind>(r[0][1].as<int>());
      lease.ref.frame = r[0][2].as<int>();
      lease.ref.tile = r[0][3].as<int>();
      return true;
    };
    PBGI_ASSIGN_OR_RETURN(const bool found, pickInLeaseOrder(order, held, pickFrom));
    if (!found) return std::optional<Lease>();
    lease.expires = now + leaseSeconds;
    const pqxx::result taken = tx.exec(
        "UPDATE tasks SET state = 2, attempt = attempt + 1, worker = $2, expires = $3, "
        "progress = 0 WHERE id = $1 AND state = 1 RETURNING attempt",
        lease.task, worker, lease.expires);
    if (taken.empty()) {
      return absl::InternalError(fmt::format("{}: {} (task {}) was ready under its lock, then not",
                                             sessions_.shownUri(), lease.ref.toString(),
                                             lease.task));
    }
    lease.attempt = taken[0][0].as<int>();
    touchWorker(tx, worker, now);
    TaskInfo leased;
    leased.id = lease.task;
    leased.ref = lease.ref;
    addEvent(tx, leased, lease.attempt, worker, TaskEventKind::kLeased, "", now);
    return std::optional<Lease>(lease);
  });
}

absl::Status PostgresJobStore::heartbeat(int64_t task, int attempt, double progress, Seconds now,
                                         Seconds leaseSeconds) {
  progress = clampProgress(progress);
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::Status {
    // Only the current attempt of a leased task extends its lease.
    const pqxx::result r = tx.exec(
        "UPDATE tasks SET expires = $3, progress = $4 WHERE id = $1 AND attempt = $2 "
        "AND state = 2 RETURNING worker",
        task, attempt, now + leaseSeconds, progress);
    if (r.empty()) {
      PBGI_ASSIGN_OR_RETURN(const TaskInfo info, loadTask(tx, task));
      return checkCurrentLease(info, attempt);
    }
    touchWorker(tx, r[0][0].as<std::string>(), now);
    return absl::OkStatus();
  });
}

absl::StatusOr<TaskRef> PostgresJobStore::complete(int64_t task, int attempt, Seconds now,
                                                   const std::string& log) {
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::StatusOr<TaskRef> {
    PBGI_ASSIGN_OR_RETURN(const TaskInfo info, lockCurrentLease(tx, task, attempt));
    addEvent(tx, info, attempt, info.worker, TaskEventKind::kDone, log, now);
    tx.exec(
        "UPDATE tasks SET state = 3, progress = 1, expires = NULL WHERE id = $1 "
        "AND attempt = $2 AND state = 2",
        task, attempt);
    promoteBlocked(tx, info.ref.job, info.ref.frame, info.ref.kind);
    touchWorker(tx, info.worker, now);
    PBGI_RETURN_IF_ERROR(settleJob(tx, info.ref.job));
    return info.ref;
  });
}

absl::Status PostgresJobStore::fail(int64_t task, int attempt, const std::string& error,
                                    Seconds now, const std::string& log) {
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const TaskInfo info, lockCurrentLease(tx, task, attempt));
    return recordFailure(tx, info, error, now, TaskEventKind::kFailed, log);
  });
}

absl::StatusOr<int> PostgresJobStore::expireLeases(Seconds now, std::vector<ExpiredLease>* listed) {
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::StatusOr<int> {
    if (listed) listed->clear();
    // The jobs first, in id order (the order every coordinator locks them in), then their
    // expired tasks, read again under the locks: another coordinator's sweep or a late
    // heartbeat may have got there first.
    std::vector<int64_t> jobs;
    for (const auto& row :
         tx.exec("SELECT id FROM jobs WHERE id IN (SELECT job FROM tasks WHERE state = 2 AND "
                 "expires <= $1) ORDER BY id FOR NO KEY UPDATE",
                 now)) {
      jobs.push_back(row[0].as<int64_t>());
    }
    int expired = 0;
    for (const int64_t job : jobs) {
      const pqxx::result r = tx.exec("SELECT " PBGI_TASK_COLUMNS
                                     ", expires FROM tasks WHERE job = $1 AND state = 2 AND "
                                     "expires <= $2 ORDER BY id FOR UPDATE",
                                     job, now);
      for (const auto& row : r) {
        const TaskInfo info = readTask(row);
        PBGI_RETURN_IF_ERROR(recordFailure(tx, info, leaseExpiredError(info.worker), now,
                                           TaskEventKind::kExpired, ""));
        if (listed) {
          listed->push_back(expiredLease(info, row[row.size() - 1].as<double>()));
        }
        ++expired;
      }
    }
    // Audits lock no job (they never settle one): their rows only, in id order, each read
    // again under its lock (a late heartbeat may have extended it).
    for (const auto& row : tx.exec("SELECT " PBGI_AUDIT_COLUMNS
                                   ", expires FROM audits WHERE state = 1 AND expires <= $1 "
                                   "ORDER BY id "
                                   "FOR UPDATE",
                                   now)) {
      PBGI_ASSIGN_OR_RETURN(const AuditInfo info, readAudit(row));
      recordAuditFailure(tx, info, leaseExpiredError(info.worker), now);
      if (listed) listed->push_back(expiredLease(info, row[row.size() - 1].as<double>()));
      ++expired;
    }
    return expired;
  });
}

absl::Status PostgresJobStore::cancel(int64_t job) {
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const JobState state, jobState(tx, job, /*lock=*/true));
    if (state == JobState::kDone) {
      return absl::FailedPreconditionError(
          fmt::format("job {}: done; there is nothing left to cancel", job));
    }
    // Dead tasks stay dead: their errors are the record of why the job failed.
    tx.exec("UPDATE tasks SET state = 5, expires = NULL WHERE job = $1 AND state IN (0, 1, 2)",
            job);
    tx.exec("UPDATE audits SET state = 4, expires = NULL WHERE job = $1 AND state IN (0, 1)", job);
    tx.exec("UPDATE jobs SET state = 3 WHERE id = $1", job);
    return absl::OkStatus();
  });
}

absl::Status PostgresJobStore::retry(int64_t job, std::optional<int> frame, std::optional<int> tile,
                                     Seconds now) {
  if (tile && !frame) {
    return absl::InvalidArgumentError(
        fmt::format("job {}: retrying tile {} needs its frame", job, *tile));
  }
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::Status {
    PBGI_RETURN_IF_ERROR(jobState(tx, job, /*lock=*/true).status());
    // As in the SQLite store: a tile's dead bake and assemble are revived with it, and
    // attempts keep counting so that a worker from before the retry holds a stale one.
    tx.exec(
        "UPDATE tasks SET state = 0, failures = 0, last_error = '', progress = 0, "
        "not_before = 0, expires = NULL WHERE job = $1 AND state IN (4, 5) "
        "AND ($2::integer IS NULL OR frame = $2::integer) "
        "AND ($3::integer IS NULL OR kind <> 1 OR tile = $3::integer)",
        job, nullable(frame), nullable(tile));
    // An audit covers its whole frame: a tile's retry revives its frame's audit.
    tx.exec(
        "UPDATE audits SET state = 0, failures = 0, last_error = '', not_before = 0, "
        "expires = NULL WHERE job = $1 AND state IN (3, 4) "
        "AND ($2::integer IS NULL OR frame = $2::integer)",
        job, nullable(frame));
    tx.exec("UPDATE jobs SET state = 0 WHERE id = $1", job);
    tx.exec("DELETE FROM job_worker_failures WHERE job = $1", job);
    promoteBlocked(tx, job, frame);
    // What was revived may still wait on a task left dead (another tile of the frame, say).
    for (const auto& row : tx.exec("SELECT " PBGI_TASK_COLUMNS
                                   " FROM tasks WHERE job = $1 AND ($2::integer IS NULL OR "
                                   "frame = $2::integer) AND state = 4 AND kind <> 2 "
                                   "ORDER BY frame, kind, tile",
                                   job, nullable(frame))) {
      killDependents(tx, readTask(row));
    }
    return settleJob(tx, job);
  });
}

absl::StatusOr<std::vector<std::string>> PostgresJobStore::blocklistedWorkers(int64_t job) {
  return transaction(PgAccess::kRead, [&](PgTx& tx) -> absl::StatusOr<std::vector<std::string>> {
    PBGI_RETURN_IF_ERROR(jobState(tx, job).status());
    std::vector<std::string> workers;
    for (const auto& row : tx.exec("SELECT worker FROM job_worker_failures WHERE job = $1 AND "
                                   "failures >= $2 ORDER BY worker",
                                   job, blocklistThreshold(policy_))) {
      workers.push_back(row[0].as<std::string>());
    }
    return workers;
  });
}

absl::StatusOr<bool> PostgresJobStore::blocklisted(int64_t job, const std::string& worker) {
  return transaction(PgAccess::kRead, [&](PgTx& tx) -> absl::StatusOr<bool> {
    PBGI_RETURN_IF_ERROR(jobState(tx, job).status());
    const pqxx::result r = tx.exec(
        "SELECT failures FROM job_worker_failures WHERE job = $1 AND worker = $2", job, worker);
    return !r.empty() && r[0][0].as<int64_t>() >= blocklistThreshold(policy_);
  });
}

absl::StatusOr<std::vector<TaskEvent>> PostgresJobStore::events(int64_t job,
                                                                std::optional<int> frame,
                                                                std::optional<int> tile) {
  return transaction(PgAccess::kRead, [&](PgTx& tx) -> absl::StatusOr<std::vector<TaskEvent>> {
    PBGI_RETURN_IF_ERROR(jobState(tx, job).status());
    std::vector<TaskEvent> out;
    for (const auto& row :
         tx.exec("SELECT e.time, e.task, t.kind, t.frame, t.tile, e.attempt, e.worker, e.event, "
                 "e.text FROM task_events e JOIN tasks t ON t.id = e.task WHERE e.job = $1 "
                 "AND ($2::integer IS NULL OR t.frame = $2::integer) "
                 "AND ($3::integer IS NULL OR t.tile = $3::integer) ORDER BY e.id",
                 job, nullable(frame), nullable(tile))) {
      out.push_back(readEventRow(PgRow{row}, job));
    }
    return out;
  });
}

absl::StatusOr<AuditInfo> PostgresJobStore::readAudit(const pqxx::row& r) const {
  return readAuditRow(PgRow{r}, sessions_.shownUri());
}

absl::StatusOr<AuditInfo> PostgresJobStore::loadAudit(PgTx& tx, int64_t audit, bool lock) {
  const pqxx::result r =
      lock ? tx.exec("SELECT " PBGI_AUDIT_COLUMNS " FROM audits WHERE id = $1 FOR UPDATE", audit)
           : tx.exec("SELECT " PBGI_AUDIT_COLUMNS " FROM audits WHERE id = $1", audit);
  if (r.empty()) return absl::NotFoundError(fmt::format("audit {}: no such audit", audit));
  return readAudit(r[0]);
}

absl::Status PostgresJobStore::auditLeaseLost(PgTx& tx, int64_t audit, int attempt) {
  PBGI_ASSIGN_OR_RETURN(const AuditInfo info, loadAudit(tx, audit));
  PBGI_RETURN_IF_ERROR(checkCurrentLease(info, attempt));
  // Current now, but not when the update ran: a lease of that attempt committed in between,
  // so the caller named an attempt before it was handed out.
  return absl::FailedPreconditionError(
      fmt::format("job {} frame {} audit (audit {}): attempt {} did not hold the lease yet",
                  info.job, info.spec.frame, audit, attempt));
}

// The caller holds the audit's row. Unlike a task's failure, nothing else moves: not the job,
// not the worker's blocklist.
void PostgresJobStore::recordAuditFailure(PgTx& tx, const AuditInfo& audit,
                                          const std::string& error, Seconds now) {
  const FailureOutcome outcome = failureOutcome(policy_, audit.failures, now);
  tx.exec(
      "UPDATE audits SET state = $3, failures = $4, last_error = $5, not_before = $6, "
      "expires = NULL WHERE id = $1 AND attempt = $2 AND state = 1",
      audit.id, audit.attempt, number(auditStateAfter(outcome)), outcome.failures,
      pqxx::binarystring(error), outcome.notBefore);
}

absl::StatusOr<std::optional<AuditLease>> PostgresJobStore::leaseAudit(const std::string& worker,
                                                                       Seconds now,
                                                                       Seconds leaseSeconds) {
  if (worker.empty()) return absl::InvalidArgumentError("an audit's lease needs a worker id");
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::StatusOr<std::optional<AuditLease>> {
    // The most urgent leasable audit that no other coordinator is leasing this moment, taken
    // in one statement: the pick locks its row (SKIP LOCKED passes over a row another
    // transaction holds) and the update re-checks that it is still ready.
    const Seconds expires = now + leaseSeconds;
    const pqxx::result taken = tx.exec(
        "UPDATE audits SET state = 1, attempt = attempt + 1, worker = $2, expires = $3 "
        "WHERE state = 0 AND id = (SELECT a.id FROM audits a JOIN jobs j ON j.id = a.job "
        "WHERE a.state = 0 AND a.not_before <= $1 AND j.state <> 3 AND EXISTS (SELECT 1 FROM "
        "tasks t WHERE t.job = a.job AND t.frame = a.frame AND t.kind = 2 AND t.state = 3) "
        "ORDER BY j.priority DESC, j.submitted, j.id, a.frame LIMIT 1 "
        "FOR UPDATE OF a SKIP LOCKED) RETURNING " PBGI_AUDIT_COLUMNS,
        now, worker, expires);
    if (taken.empty()) return std::optional<AuditLease>();
    PBGI_ASSIGN_OR_RETURN(const AuditInfo info, readAudit(taken[0]));
    touchWorker(tx, worker, now);
    return std::optional<AuditLease>(
        AuditLease{info.id, info.attempt, info.job, info.spec, expires});
  });
}

absl::Status PostgresJobStore::heartbeatAudit(int64_t audit, int attempt, Seconds now,
                                              Seconds leaseSeconds) {
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::Status {
    // Only the current attempt of a leased audit extends its lease.
    const pqxx::result r = tx.exec(
        "UPDATE audits SET expires = $3 WHERE id = $1 AND attempt = $2 AND state = 1 "
        "RETURNING worker",
        audit, attempt, now + leaseSeconds);
    if (r.empty()) return auditLeaseLost(tx, audit, attempt);
    touchWorker(tx, r[0][0].as<std::string>(), now);
    return absl::OkStatus();
  });
}

absl::Status PostgresJobStore::completeAudit(int64_t audit, int attempt, const AuditResult& result,
                                             Seconds now) {
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::Status {
    // One statement: at READ COMMITTED it waits for a concurrent change to the row and
    // re-checks the attempt and state against what that change left.
    const pqxx::result r = tx.exec(
        "UPDATE audits SET state = 2, expires = NULL, rel_mse = $3, bias = $4, seconds = $5 "
        "WHERE id = $1 AND attempt = $2 AND state = 1 RETURNING worker",
        audit, attempt, result.relMse, result.bias, result.seconds);
    if (r.empty()) return auditLeaseLost(tx, audit, attempt);
    touchWorker(tx, r[0][0].as<std::string>(), now);
    return absl::OkStatus();
  });
}

absl::Status PostgresJobStore::failAudit(int64_t audit, int attempt, const std::string& error,
                                         Seconds now) {
  return transaction(PgAccess::kWrite, [&](PgTx& tx) -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const AuditInfo info, loadAudit(tx, audit, /*lock=*/true));
    PBGI_RETURN_IF_ERROR(checkCurrentLease(info, attempt));
    recordAuditFailure(tx, info, error, now);
    return absl::OkStatus();
  });
}

absl::StatusOr<std::vector<AuditInfo>> PostgresJobStore::audits(int64_t job) {
  return transaction(PgAccess::kRead, [&](PgTx& tx) -> absl::StatusOr<std::vector<AuditInfo>> {
    PBGI_RETURN_IF_ERROR(jobState(tx, job).status());
    std::vector<AuditInfo> out;
    for (const auto& row :
         tx.exec("SELECT " PBGI_AUDIT_COLUMNS " FROM audits WHERE job = $1 ORDER BY frame", job)) {
      PBGI_ASSIGN_OR_RETURN(AuditInfo info, readAudit(row));
      out.push_back(std::move(info));
    }
    return out;
  });
}

}  // namespace

absl::StatusOr<std::unique_ptr<JobStore>> openPostgresJobStore(const std::string& uri,
                                                               const RetryPolicy& policy) {
  PBGI_RETURN_IF_ERROR(validateRetryPolicy(policy));
  auto store = std::make_unique<PostgresJobStore>(uri, policy);
  PBGI_RETURN_IF_ERROR(store->initialize());
  return std::unique_ptr<JobStore>(std::move(store));
}

}  // namespace pbgi::farm
