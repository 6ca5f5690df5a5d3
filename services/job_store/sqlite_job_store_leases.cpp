// The embedded job store's leases and what ends them: complete, fail, expiry, cancel and
// retry (sqlite_job_store.h).
#include <fmt/format.h>

#include "services/job_store/sqlite_job_store.h"

namespace pbgi::farm::sqlite_store {

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

absl::Status SqliteJobStore::fail(int64_t task, int attempt, const std::string& error, Seconds now,
                                  const std::string& log) {
  return transaction(Access::kWrite, [&]() -> absl::Status {
    PBGI_ASSIGN_OR_RETURN(const TaskInfo info, currentLease(task, attempt));
    return recordFailure(info, error, now, TaskEventKind::kFailed, log);
  });
}

absl::StatusOr<int> SqliteJobStore::expireLeases(Seconds now, std::vector<ExpiredLease>* listed) {
  return transaction(Access::kWrite, [&]() -> absl::StatusOr<int> {
    if (listed) listed->clear();
    // Collected first: recordFailure() runs statements of its own on the same table.
    std::vector<std::pair<int64_t, Seconds>> expired;
    {
      Query q =
          query("SELECT id, expires FROM tasks WHERE state = 2 AND expires <= ?1 ORDER BY id");
      q.bind(1, now);
      for (;;) {
        PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
        if (!row) break;
        expired.emplace_back(q.int64(0), q.real(1));
      }
    }
    for (const auto& [id, expires] : expired) {
      PBGI_ASSIGN_OR_RETURN(const TaskInfo info, loadTask(id));
      PBGI_RETURN_IF_ERROR(
          recordFailure(info, leaseExpiredError(info.worker), now, TaskEventKind::kExpired, ""));
      if (listed) listed->push_back(expiredLease(info, expires));
    }
    std::vector<std::pair<AuditInfo, Seconds>> expiredAudits;
    {
      Query q = query("SELECT " PBGI_AUDIT_COLUMNS
                      ", expires FROM audits WHERE state = 1 AND expires <= ?1 ORDER BY id");
      q.bind(1, now);
      for (;;) {
        PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
        if (!row) break;
        PBGI_ASSIGN_OR_RETURN(AuditInfo info, readAudit(q));
        expiredAudits.emplace_back(std::move(info), q.real(q.columns() - 1));
      }
    }
    for (const auto& [info, expires] : expiredAudits) {
      PBGI_RETURN_IF_ERROR(recordAuditFailure(info, leaseExpiredError(info.worker), now));
      if (listed) listed->push_back(expiredLease(info, expires));
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
    {
      Query q = query("DELETE FROM job_worker_failures WHERE job = ?1");
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

absl::StatusOr<std::vector<std::string>> SqliteJobStore::blocklistedWorkers(int64_t job) {
  return transaction(Access::kRead, [&]() -> absl::StatusOr<std::vector<std::string>> {
    PBGI_RETURN_IF_ERROR(jobState(job).status());
    Query q = query(
        "SELECT worker FROM job_worker_failures WHERE job = ?1 AND failures >= ?2 "
        "ORDER BY worker");
    q.bind(1, job).bind(2, blocklistThreshold(policy_));
    std::vector<std::string> workers;
    for (;;) {
      PBGI_ASSIGN_OR_RETURN(const bool row, q.step());
      if (!row) break;
      workers.push_back(q.text(0));
    }
    return workers;
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

absl::StatusOr<std::vector<TaskEvent>> SqliteJobStore::events(int64_t job, std::optional<int> frame,
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
      out.push_back(readEventRow(q, job));
    }
  });
}

}  // namespace pbgi::farm::sqlite_store
