#include "services/coordinator/status_report.h"

#include <algorithm>
#include <set>

#include <fmt/format.h>

#include "core/util/status.h"
#include "services/farm/farm_wire.h"

namespace pbgi::farm {

void fillTask(const TaskInfo& t, v1::TaskStatus* out) {
  out->set_task(t.id);
  setKindAndState(t.ref.kind, t.state, out);
  out->set_frame(t.ref.frame);
  out->set_tile(t.ref.tile);
  out->set_attempt(t.attempt);
  out->set_failures(t.failures);
  out->set_worker(t.worker);
  out->set_last_error(t.lastError);
  out->set_progress(t.progress);
}

void fillAudit(const AuditInfo& a, v1::FrameAudit* out) {
  out->set_frame(a.spec.frame);
  out->set_state(toString(a.state));
  for (const int t : a.spec.tiles) out->add_tiles(t);
  out->set_spp(a.spec.spp);
  out->set_threshold(a.spec.threshold);
  out->set_has_result(a.result.has_value());
  if (a.result) {
    out->set_rel_mse(a.result->relMse);
    out->set_bias(a.result->bias);
  }
  out->set_flagged(a.flagged());
  out->set_worker(a.worker);
  out->set_last_error(a.lastError);
  out->set_attempt(a.attempt);
}

std::vector<std::string> liveWorkers(JobStore& store, const FarmActivity& activity, Seconds now,
                                     Seconds leaseSeconds) {
  std::set<std::string> live;
  for (const auto& [id, a] : activity.workers()) {
    if (now - a.lastHeard <= leaseSeconds) live.insert(id);
  }
  if (absl::StatusOr<std::vector<WorkerInfo>> registered = store.workers(); registered.ok()) {
    for (const WorkerInfo& w : *registered) {
      if (now - w.lastSeen <= leaseSeconds) live.insert(w.id);
    }
  }
  return {live.begin(), live.end()};
}

absl::StatusOr<JobStall> jobStall(JobStore& store, const JobInfo& info,
                                  const std::vector<std::string>& live) {
  JobStall stall;
  if (info.state != JobState::kActive) return stall;
  const auto count = [&](TaskState s) { return info.tasksByState[static_cast<int>(s)]; };
  PBGI_ASSIGN_OR_RETURN(stall.blocklisted, store.blocklistedWorkers(info.id));
  if (count(TaskState::kReady) == 0 || count(TaskState::kLeased) > 0) return stall;
  if (live.empty()) {
    stall.word = "waiting";
    return stall;
  }
  for (const std::string& w : live) {
    if (std::find(stall.blocklisted.begin(), stall.blocklisted.end(), w) ==
        stall.blocklisted.end()) {
      return stall;
    }
  }
  stall.word = "stalled";
  PBGI_ASSIGN_OR_RETURN(const std::vector<TaskInfo> tasks, store.tasks(info.id));
  // The error of the task that failed most (a task dead at its attempt cap, or one ready
  // again), not of a task that died only because another did.
  int latest = -1;
  for (const TaskInfo& t : tasks) {
    const bool failed = t.state == TaskState::kReady || t.state == TaskState::kDead;
    if (failed && !t.lastError.empty() && t.attempt > latest) {
      latest = t.attempt;
      stall.error = fmt::format("{}: {}", t.ref.toString(), t.lastError);
    }
  }
  return stall;
}

absl::StatusOr<v1::GetStatusResponse> statusReport(JobStore& store, ParsedJobCache& views,
                                                   const v1::GetStatusRequest& request,
                                                   const std::vector<std::string>& live) {
  std::vector<JobInfo> infos;
  if (request.job() != 0) {
    PBGI_ASSIGN_OR_RETURN(JobInfo one, store.job(request.job()));
    infos.push_back(std::move(one));
  } else {
    PBGI_ASSIGN_OR_RETURN(infos, store.jobs());
  }
  v1::GetStatusResponse response;
  for (const JobInfo& info : infos) {
    v1::JobStatus* job = response.add_jobs();
    job->set_job(info.id);
    job->set_name(info.spec.name);
    setState(info.state, info.tasksByState, job);
    job->set_priority(info.spec.priority);
    for (int f : info.spec.frames) job->add_frames(f);
    job->set_tiles_per_frame(info.spec.tileCount);
    for (const TaskInfo& t : info.dead) fillTask(t, job->add_dead());
    PBGI_ASSIGN_OR_RETURN(const std::vector<AuditInfo> audits, store.audits(info.id));
    for (const AuditInfo& a : audits) fillAudit(a, job->add_audits());
    PBGI_ASSIGN_OR_RETURN(const JobStall stall, jobStall(store, info, live));
    job->set_stall(stall.word);
    for (const std::string& w : stall.blocklisted) job->add_blocklisted_workers(w);
    job->set_stall_error(stall.error);
    // Every task of a job is a large read: only for callers that ask for them.
    if (!request.with_tasks()) continue;
    PBGI_ASSIGN_OR_RETURN(const std::vector<TaskInfo> tasks, store.tasks(info.id));
    auto view = views.get(info.id);
    for (const TaskInfo& t : tasks) {
      fillTask(t, job->add_tasks());
      if (view.ok() && t.ref.kind == TaskKind::kAssemble && t.state == TaskState::kDone) {
        job->add_outputs(ParsedJobCache::frameOutput(**view, t.ref.frame));
      }
    }
  }
  return response;
}

}  // namespace pbgi::farm
