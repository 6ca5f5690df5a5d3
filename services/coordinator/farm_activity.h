#pragma once
// What this coordinator has seen happen, for the dashboard: a version number that moves
// whenever a job's tasks change (so a page waiting on it can refresh at once instead of
// polling), and what each worker said last: the frames it holds (scenes and pages loaded),
// its page-cache hits and misses, the tasks it finished.
//
// The store stays the truth: the version only says "look again". With a store shared by
// several coordinators (PostgreSQL), changes made through another one move no version here;
// a waiter then wakes on its timeout and looks anyway.
#include <array>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "services/job_store/job_store.h"

namespace pbgi::farm {

struct WorkerActivity {
  std::vector<HeldFrame> held;  // from its latest lease request, most recent first
  Seconds lastHeard = 0;        // its latest call of any kind
  std::string current;          // what it leased last ("job 3 frame 12 tile 7"), until done
  std::string expired;          // a task whose lease expired on it, until it is heard again
  double progress = 0;          // of the current task, from its heartbeats
  int64_t tasksDone = 0;        // completions accepted from it by this coordinator
  int64_t tasksFailed = 0;
  uint64_t cacheHits = 0, cacheMisses = 0, treeBytesStreamed = 0;
};

// A worker as operators see it, from when it was last heard (by this coordinator's activity
// or, `lastSeen`, through the store) against a lease: "busy" (heard, with a task), "online"
// (heard, idle), "lost" (silent past a lease while it held a task, or after the task's lease
// expired on it: killed, or cut off), or "offline" (silent past a lease, idle: stopped).
std::string workerState(const WorkerActivity& activity, Seconds lastSeen, Seconds now,
                        Seconds leaseSeconds);

// How long a job's finished tasks took, by kind (TaskKind), as their workers reported.
struct TaskDurations {
  std::array<double, 3> seconds{};  // summed, by kind: bake, tile, assemble
  std::array<int, 3> count{};
};

// The time a job has left: each kind's remaining tasks at that kind's mean duration (a kind
// none of whose tasks has finished: the mean over all finished tasks), over the tasks running
// at once (at least one). Null without a finished task. Depends on what finished, not on the
// time since submission: a job of uniform tiles keeps its estimate as it goes.
std::optional<double> estimatedSecondsLeft(const TaskDurations& durations,
                                           const std::array<int, 3>& remaining, int running);

class FarmActivity {
 public:
  // A job's tasks changed (submitted, leased, done, failed, expired, cancelled, retried): the
  // version moves and every waiter wakes. Heartbeats (progress) do not move it.
  void changed();
  uint64_t version() const;
  // Blocks until the version is not `seen`, `timeout` passes or stop(); returns the version.
  uint64_t waitForChange(uint64_t seen, std::chrono::milliseconds timeout);
  // Wakes every waiter for good (the coordinator is shutting down).
  void stop();
  bool stopped() const;

  // A lease request (`leased`: what it got, if anything, as TaskRef::toString() says it).
  void leaseAsked(const std::string& worker, std::vector<HeldFrame> held,
                  std::optional<std::string> leased, Seconds now);
  void heartbeat(const std::string& worker, double progress, Seconds now);
  // The lease of `what` expired on the worker: the task is no longer its current one.
  void leaseExpired(const std::string& worker, const std::string& what);
  // A completion (`done`) or failure the store accepted.
  void taskFinished(const std::string& worker, bool done, uint64_t cacheHits,
                    uint64_t cacheMisses, uint64_t treeBytes, Seconds now);
  std::map<std::string, WorkerActivity> workers() const;
  // A completion of the job's task of `kind` that took `seconds` (the worker's measure).
  void taskTook(int64_t job, TaskKind kind, double seconds);
  TaskDurations durations(int64_t job) const;

 private:
  mutable std::mutex mutex_;
  std::condition_variable cv_;
  uint64_t version_ = 1;
  bool stopped_ = false;
  std::map<std::string, WorkerActivity> workers_;
  std::map<int64_t, TaskDurations> durations_;
};

}  // namespace pbgi::farm
