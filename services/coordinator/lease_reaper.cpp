#include "services/coordinator/lease_reaper.h"

#include <chrono>

#include "core/util/log.h"
#include "core/util/status.h"

namespace pbgi::farm {

Seconds wallClock() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch()).count();
}

LeaseReaper::LeaseReaper(JobStore& store, metrics::Counter& expired, Seconds leaseSeconds,
                         Seconds intervalSeconds, OnExpired onExpired)
    : store_(store),
      expired_(expired),
      onExpired_(std::move(onExpired)),
      leaseSeconds_(leaseSeconds),
      intervalSeconds_(intervalSeconds),
      started_(wallClock()),
      thread_([this] { loop(); }) {}

LeaseReaper::~LeaseReaper() { stop(); }

void LeaseReaper::stop() {
  {
    std::lock_guard lock(mutex_);
    stopping_ = true;
  }
  changed_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void LeaseReaper::loop() {
  std::unique_lock lock(mutex_);
  while (!stopping_) {
    changed_.wait_for(lock, std::chrono::duration<double>(intervalSeconds_));
    if (stopping_) break;
    lock.unlock();
    const Seconds now = wallClock();
    if (now >= started_ + leaseSeconds_) {
      std::vector<ExpiredLease> expired;
      auto n = store_.expireLeases(now, &expired);
      if (!n.ok()) {
        log::error("reclaiming expired leases: {}", n.status().message());
      } else if (*n > 0) {
        expired_.add(static_cast<uint64_t>(*n));
        for (const ExpiredLease& e : expired) {
          // The lease ran leaseSeconds_ from its last heartbeat (or from the lease itself).
          log::warn(
              "lease expired: {} ({} {}, attempt {}) on worker {}, last heard {:.1f} s ago; "
              "the {} is tried again",
              e.what, e.audit ? "audit" : "task", e.id, e.attempt, e.worker,
              std::max(0.0, now - (e.expires - leaseSeconds_)), e.audit ? "audit" : "task");
        }
        if (onExpired_) onExpired_(expired);
      }
    }
    lock.lock();
  }
}

}  // namespace pbgi::farm
