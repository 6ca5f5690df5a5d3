#pragma once
// How long each stage of a piece of work took, for the reports that `pbgi render`, `pbgi
// bake` and the farm print and log.
#include <chrono>
#include <string>
#include <vector>

namespace pbgi {

struct StageTime {
  std::string stage;
  double seconds = 0.0;
};

// Times consecutive stages: each lap() ends the stage running since the last lap (or since
// construction) and starts the next.
class StageClock {
 public:
  using Clock = std::chrono::steady_clock;
  explicit StageClock(std::vector<StageTime>* stages) : stages_(stages) {}
  void lap(std::string stage) {
    const auto now = Clock::now();
    stages_->push_back({std::move(stage), std::chrono::duration<double>(now - lapStart_).count()});
    lapStart_ = now;
  }
  // Since construction.
  double totalSeconds() const {
    return std::chrono::duration<double>(Clock::now() - start_).count();
  }

 private:
  std::vector<StageTime>* stages_;
  Clock::time_point start_ = Clock::now();
  Clock::time_point lapStart_ = start_;
};

// One line per stage, indented, names padded to the longest: what the CLI prints.
std::string formatStages(const std::vector<StageTime>& stages);

}  // namespace pbgi
