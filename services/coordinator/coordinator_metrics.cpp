#include "services/coordinator/coordinator_metrics.h"

#include <array>

#include "services/farm/farm_tls.h"

namespace pbgi::farm {

namespace {

// Tasks (of every job) and jobs by state, from one read of the store; a store that cannot be
// read shows zeros.
struct StateCounts {
  PerTaskState<int> tasks{};
  std::array<int, 4> jobs{};
};

StateCounts stateCounts(JobStore& store) {
  StateCounts counts;
  if (auto all = store.jobs(); all.ok()) {
    for (const JobInfo& j : *all) {
      ++counts.jobs[static_cast<size_t>(j.state)];
      for (size_t s = 0; s < counts.tasks.size(); ++s) counts.tasks[s] += j.tasksByState[s];
    }
  }
  return counts;
}

template <typename State, size_t N>
metrics::Samples byState(const std::array<int, N>& counts) {
  metrics::Samples samples;
  for (size_t s = 0; s < N; ++s) {
    samples.emplace_back(toString(static_cast<State>(s)), counts[s]);
  }
  return samples;
}

}  // namespace

// In the order /metrics lists them.
CoordinatorMetrics::CoordinatorMetrics(JobStore& store) {
  metrics::Registry& r = registry;
  r.gauge("pbgi_tasks", "Tasks of every job by state.", "state",
          [&store] { return byState<TaskState>(stateCounts(store).tasks); });
  r.gauge("pbgi_jobs", "Jobs by state.", "state",
          [&store] { return byState<JobState>(stateCounts(store).jobs); });
  leases = &r.counter("pbgi_leases_total", "Tasks leased to workers.");
  failures = &r.counter("pbgi_task_failures_total",
                        "Attempts that failed on a worker (each is retried or dead).");
  expired = &r.counter("pbgi_leases_expired_total",
                       "Leases reclaimed after their worker stopped heartbeating.");
  staleCompletions = &r.counter("pbgi_stale_completions_total",
                                "Completions dropped because their attempt had lost the lease.");
  refused = &r.counter("pbgi_rpc_refused_total", "Calls refused for a missing or wrong token.");
  r.counter("pbgi_tls_handshake_failures_total",
            "Connections refused because their TLS handshake failed (over this process).",
            [] { return tlsHandshakeFailures(); });
  cacheHits = &r.counter("pbgi_page_cache_hits_total",
                         "Tree page cache hits reported with completed tasks.");
  cacheMisses = &r.counter("pbgi_page_cache_misses_total",
                           "Tree page cache misses reported with completed tasks.");
  treesOpened =
      &r.counter("pbgi_trees_opened_total", "Trees workers opened through the page service.");
  pagesServed = &r.counter("pbgi_tree_pages_served_total", "Tree pages the page service sent.");
  pageBytesServed =
      &r.counter("pbgi_tree_bytes_served_total",
                 "Bytes the page service sent: pages, and the heads of the trees opened.");
  treeBytesStreamed =
      &r.counter("pbgi_tree_bytes_streamed_total",
                 "Bytes of trees fetched from the page service, as completed tasks reported them.");
  r.gauge("pbgi_page_cache_hit_rate", "Hits over lookups, over completed tasks.", "", [this] {
    const uint64_t hits = cacheHits->value();
    const uint64_t lookups = hits + cacheMisses->value();
    return metrics::Samples{{"", lookups > 0 ? double(hits) / double(lookups) : 0.0}};
  });
  taskSeconds =
      &r.histogram("pbgi_task_seconds", "Run time of completed tasks, as the worker measured it.",
                   "kind", {0.5, 1, 2, 5, 10, 30, 60, 120, 300, 600});
}

}  // namespace pbgi::farm
