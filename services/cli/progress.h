#pragma once
// Progress of long work, by stage (a bake's "shade", "bounce 1 of 3", "build"): a bar redrawn
// in place on a terminal, each stage's last state left on a line of its own; plain lines at
// every tenth of each stage otherwise (logs and CI). Each line names the stage and, once a
// stage has run a moment, the time it has left at its rate so far. Thread-safe: renderers
// report from worker threads.

#include <chrono>
#include <cstdint>
#include <mutex>
#include <string>

namespace pbgi::cli {

class Progress {
 public:
  explicit Progress(std::string label);
  // `stage` empty: the work has no stages.
  void update(const std::string& stage, uint64_t done, uint64_t total);
  void update(uint64_t done, uint64_t total) { update(std::string(), done, total); }
  // Ends the bar's line on a terminal.
  void finish();

  // "12 s left", "3 min 20 s left", or "" before there is a rate to go by.
  static std::string timeLeft(double elapsedSeconds, uint64_t done, uint64_t total);

 private:
  using Clock = std::chrono::steady_clock;

  std::mutex mutex_;
  std::string label_;
  bool terminal_ = false;
  std::string stage_;
  Clock::time_point stageStart_;
  int lastTenth_ = -1;
  int lastPercent_ = -1;
  int lastSecondsLeft_ = -1;
};

}  // namespace pbgi::cli
