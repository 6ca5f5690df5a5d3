#pragma once
// The embedded job store's class (sqlite_job_store.cpp: the connection, group commit, the
// schema, jobs, tasks and workers; sqlite_job_store_leases.cpp: leases and what ends them;
// sqlite_job_store_audits.cpp: audits). Not an interface: job_store.h's openSqliteJobStore is.
#include <condition_variable>
#include <functional>
#include <limits>
#include <mutex>
#include <optional>
#include <string_view>
#include <type_traits>
#include <unordered_map>
#include <utility>
#include <vector>

#include "core/util/status.h"
#include "services/job_store/job_store.h"
#include "services/job_store/sqlite_query.h"

namespace pbgi::farm::sqlite_store {

// Reads a row selected with PBGI_TASK_COLUMNS.
inline TaskInfo readTask(const Query& q) { return readTaskRow(q); }

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
  std::mutex mutex_;       // the connection
  std::mutex groupMutex_;  // the queue below
  std::condition_variable groupDone_;
  std::vector<GroupedCall*> pending_;
  bool committing_ = false;  // a batch is being committed (its leader holds mutex_)
  DatabasePtr db_;
  // Prepared once per SQL text; declared after db_ so that they are finalized before it closes.
  std::unordered_map<std::string, StatementPtr> statements_;
};

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

}  // namespace pbgi::farm::sqlite_store
