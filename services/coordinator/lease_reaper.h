#pragma once
// Reclaims expired leases: a thread that asks the store to expire them every interval, so
// that a task whose worker died or hung is retried (after its back-off) or dead. After a
// start it waits one lease period first: leases from before it belong to workers that may
// only have lost sight of this coordinator and will heartbeat again.
#include <condition_variable>
#include <functional>
#include <mutex>
#include <thread>

#include "services/coordinator/metrics.h"
#include "services/job_store/job_store.h"

namespace pbgi::farm {

class LeaseReaper {
 public:
  // Starts the thread. `expired` counts the leases reclaimed; `onExpired` runs after a sweep
  // that reclaimed any, with them. Each is logged: its task, worker and when it was last heard.
  using OnExpired = std::function<void(const std::vector<ExpiredLease>&)>;
  LeaseReaper(JobStore& store, metrics::Counter& expired, Seconds leaseSeconds,
              Seconds intervalSeconds, OnExpired onExpired = {});
  ~LeaseReaper();  // stop()
  LeaseReaper(const LeaseReaper&) = delete;
  LeaseReaper& operator=(const LeaseReaper&) = delete;

  // Stops the thread after the sweep in progress, if any. Idempotent.
  void stop();

 private:
  void loop();

  JobStore& store_;
  metrics::Counter& expired_;
  const OnExpired onExpired_;
  const Seconds leaseSeconds_;
  const Seconds intervalSeconds_;
  const Seconds started_;
  std::mutex mutex_;
  std::condition_variable changed_;
  bool stopping_ = false;
  std::thread thread_;
};

// Seconds since the Unix epoch: the store's clock.
Seconds wallClock();

}  // namespace pbgi::farm
