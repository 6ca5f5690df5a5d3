#pragma once
// A job's status as the wire carries it (GetStatus, and /status as JSON): its state, its
// tasks counted by state, the dead tasks with their errors, and, when asked, every task and
// the frames written so far.
#include <absl/status/statusor.h>

#include "pbgi/farm/v1/farm.pb.h"
#include "services/coordinator/farm_activity.h"
#include "services/coordinator/parsed_job_cache.h"
#include "services/job_store/job_store.h"

namespace pbgi::farm {

// The workers heard from within `leaseSeconds` of `now`: by this coordinator (`activity`) or,
// through a store shared with others, by another one.
std::vector<std::string> liveWorkers(JobStore& store, const FarmActivity& activity, Seconds now,
                                     Seconds leaseSeconds);

// Whether an active job can go on: "stalled" when it has ready tasks, none leased, and every
// live worker is blocklisted for it (with the error of its task that failed most), "waiting"
// when no worker is live; empty otherwise. The blocklisted workers in any case.
struct JobStall {
  std::string word;
  std::vector<std::string> blocklisted;
  std::string error;
};
absl::StatusOr<JobStall> jobStall(JobStore& store, const JobInfo& info,
                                  const std::vector<std::string>& live);

// request.job() 0: every job. An active job that no live worker may take work from says so
// (JobStatus.stall).
absl::StatusOr<v1::GetStatusResponse> statusReport(JobStore& store, ParsedJobCache& views,
                                                   const v1::GetStatusRequest& request,
                                                   const std::vector<std::string>& live);

// One task's status: its kind and state as enums and as v1's words.
void fillTask(const TaskInfo& task, v1::TaskStatus* out);

}  // namespace pbgi::farm
