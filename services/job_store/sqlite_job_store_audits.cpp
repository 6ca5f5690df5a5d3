// The embedded job store's audits (sqlite_job_store.h).
#include <fmt/format.h>

#include "services/job_store/sqlite_job_store.h"

namespace pbgi::farm::sqlite_store {

absl::StatusOr<AuditInfo> SqliteJobStore::readAudit(const Query& q) const {
  return readAuditRow(q, path_);
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

}  // namespace pbgi::farm::sqlite_store
