#pragma once
// A job's status as the wire carries it (GetStatus, and /status as JSON): its state, its
// tasks counted by state, the dead tasks with their errors, and, when asked, every task and
// the frames written so far.
#include <absl/status/statusor.h>

#include "pbgi/farm/v1/farm.pb.h"
#include "services/coordinator/parsed_job_cache.h"
#include "services/job_store/job_store.h"

namespace pbgi::farm {

// request.job() 0: every job.
absl::StatusOr<v1::GetStatusResponse> statusReport(JobStore& store, ParsedJobCache& views,
                                                   const v1::GetStatusRequest& request);

// One task's status: its kind and state as enums and as v1's words.
void fillTask(const TaskInfo& task, v1::TaskStatus* out);

}  // namespace pbgi::farm
