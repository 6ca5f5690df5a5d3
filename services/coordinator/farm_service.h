#pragma once
// The RPCs of pbgi.farm.v1.Coordinator (coordinator.cpp), made for a caller that runs them
// in-process without a server: tests/fuzz/coordinator_fuzz.cpp. Each handler turns a request
// into job store calls and reads nothing from its ServerContext (the token check runs before
// any handler, farm_auth.h), so a null one will do; FetchPages writes to its stream, so call
// PageService::fetchPages for it instead.
#include <memory>

#include "pbgi/farm/v1/farm.grpc.pb.h"
#include "services/coordinator/coordinator_metrics.h"
#include "services/coordinator/coordinator_options.h"
#include "services/coordinator/farm_activity.h"
#include "services/coordinator/page_service.h"
#include "services/coordinator/parsed_job_cache.h"
#include "services/job_store/job_store.h"

namespace pbgi::farm {

// Every argument must outlive the service.
std::unique_ptr<v1::Coordinator::Service> makeFarmService(const CoordinatorOptions& options,
                                                          JobStore& store, ParsedJobCache& jobs,
                                                          PageService& pages,
                                                          CoordinatorMetrics& metrics,
                                                          FarmActivity& activity);

}  // namespace pbgi::farm
