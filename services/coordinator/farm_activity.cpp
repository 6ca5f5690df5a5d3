#include "services/coordinator/farm_activity.h"

#include <cmath>

namespace pbgi::farm {

void FarmActivity::changed() {
  {
    std::lock_guard lock(mutex_);
    ++version_;
  }
  cv_.notify_all();
}

uint64_t FarmActivity::version() const {
  std::lock_guard lock(mutex_);
  return version_;
}

uint64_t FarmActivity::waitForChange(uint64_t seen, std::chrono::milliseconds timeout) {
  std::unique_lock lock(mutex_);
  cv_.wait_for(lock, timeout, [&] { return version_ != seen || stopped_; });
  return version_;
}

void FarmActivity::stop() {
  {
    std::lock_guard lock(mutex_);
    stopped_ = true;
  }
  cv_.notify_all();
}

bool FarmActivity::stopped() const {
  std::lock_guard lock(mutex_);
  return stopped_;
}

void FarmActivity::leaseAsked(const std::string& worker, std::vector<HeldFrame> held,
                              std::optional<std::string> leased, Seconds now) {
  {
    std::lock_guard lock(mutex_);
    WorkerActivity& w = workers_[worker];
    w.held = std::move(held);
    w.lastHeard = now;
    w.expired.clear();
    if (!leased) return;
    w.current = *std::move(leased);
    w.progress = 0;
    ++version_;
  }
  cv_.notify_all();
}

void FarmActivity::heartbeat(const std::string& worker, double progress, Seconds now) {
  {
    std::lock_guard lock(mutex_);
    WorkerActivity& w = workers_[worker];
    w.lastHeard = now;
    w.progress = progress;
  }
  // No new version: a farm's heartbeats come many a second, and each would send every page
  // back to the store for the whole job. Progress shows at the next change of state.
}

void FarmActivity::leaseExpired(const std::string& worker, const std::string& what) {
  std::lock_guard lock(mutex_);
  const auto it = workers_.find(worker);
  if (it == workers_.end() || it->second.current != what) return;
  it->second.current.clear();
  it->second.progress = 0;
  it->second.expired = what;
}

void FarmActivity::taskFinished(const std::string& worker, bool done, uint64_t cacheHits,
                                uint64_t cacheMisses, uint64_t treeBytes, Seconds now) {
  {
    std::lock_guard lock(mutex_);
    WorkerActivity& w = workers_[worker];
    (done ? w.tasksDone : w.tasksFailed) += 1;
    w.cacheHits += cacheHits;
    w.cacheMisses += cacheMisses;
    w.treeBytesStreamed += treeBytes;
    w.lastHeard = now;
    w.current.clear();
    ++version_;
  }
  cv_.notify_all();
}

std::string workerState(const WorkerActivity& activity, Seconds lastSeen, Seconds now,
                        Seconds leaseSeconds) {
  const bool heard = now - std::max(activity.lastHeard, lastSeen) <= leaseSeconds;
  if (heard) return activity.current.empty() ? "online" : "busy";
  return activity.current.empty() && activity.expired.empty() ? "offline" : "lost";
}

void FarmActivity::taskTook(int64_t job, TaskKind kind, double seconds) {
  const auto k = static_cast<size_t>(kind);
  if (k >= 3 || !std::isfinite(seconds) || seconds < 0) return;
  std::lock_guard lock(mutex_);
  TaskDurations& d = durations_[job];
  d.seconds[k] += seconds;
  d.count[k] += 1;
}

TaskDurations FarmActivity::durations(int64_t job) const {
  std::lock_guard lock(mutex_);
  const auto it = durations_.find(job);
  return it == durations_.end() ? TaskDurations{} : it->second;
}

std::optional<double> estimatedSecondsLeft(const TaskDurations& d,
                                           const std::array<int, 3>& remaining, int running) {
  double allSeconds = 0;
  int allCount = 0;
  for (size_t k = 0; k < 3; ++k) {
    allSeconds += d.seconds[k];
    allCount += d.count[k];
  }
  if (allCount == 0) return std::nullopt;
  double work = 0;
  for (size_t k = 0; k < 3; ++k) {
    const double mean = d.count[k] > 0 ? d.seconds[k] / d.count[k] : allSeconds / allCount;
    work += remaining[k] * mean;
  }
  return work / std::max(1, running);
}

std::map<std::string, WorkerActivity> FarmActivity::workers() const {
  std::lock_guard lock(mutex_);
  return workers_;
}

}  // namespace pbgi::farm
