#pragma once
// What the coordinator counts, each metric declared once (coordinator_metrics.cpp). The names
// are an interface: dashboards, the tests and the README use them. /metrics serves
// registry.text(); counters reset with the process, as Prometheus expects.
#include "services/coordinator/metrics.h"
#include "services/job_store/job_store.h"

namespace pbgi::farm {

struct CoordinatorMetrics {
  // The task and job gauges read `store` at each scrape.
  explicit CoordinatorMetrics(JobStore& store);

  CoordinatorMetrics(const CoordinatorMetrics&) = delete;
  CoordinatorMetrics& operator=(const CoordinatorMetrics&) = delete;

  metrics::Registry registry;
  // Kept in `registry`.
  metrics::Counter* leases;
  metrics::Counter* failures;
  metrics::Counter* expired;
  metrics::Counter* staleCompletions;
  metrics::Counter* refused;
  metrics::Counter* cacheHits;
  metrics::Counter* cacheMisses;
  metrics::Counter* treesOpened;
  metrics::Counter* pagesServed;
  metrics::Counter* pageBytesServed;
  metrics::Counter* treeBytesStreamed;
  metrics::Histogram* taskSeconds;  // by task kind
};

}  // namespace pbgi::farm
