#include "services/cli/progress.h"

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include <fmt/format.h>

#include "core/util/log.h"

namespace pbgi::cli {

namespace {
// A rate measured over less than this says little about the time left.
constexpr double kMinSecondsForRate = 1.0;
}  // namespace

Progress::Progress(std::string label)
    : label_(std::move(label)), terminal_(isatty(2) != 0), stageStart_(Clock::now()) {}

std::string Progress::timeLeft(double elapsedSeconds, uint64_t done, uint64_t total) {
  if (done == 0 || done >= total || !(elapsedSeconds >= kMinSecondsForRate)) return {};
  const double left = elapsedSeconds * static_cast<double>(total - done) / static_cast<double>(done);
  const long seconds = std::lround(std::ceil(left));
  if (seconds < 60) return fmt::format("{} s left", seconds);
  if (seconds < 3600) return fmt::format("{} min {} s left", seconds / 60, seconds % 60);
  return fmt::format("{} h {} min left", seconds / 3600, (seconds % 3600) / 60);
}

void Progress::update(const std::string& stage, uint64_t done, uint64_t total) {
  if (total == 0 || !log::shows(log::Level::kInfo)) return;  // -q: errors only
  done = std::min(done, total);
  std::lock_guard<std::mutex> lock(mutex_);
  if (stage != stage_) {
    // A new stage: the last one's line stays as it ended; the rate starts over.
    if (terminal_ && lastPercent_ >= 0) std::fprintf(stderr, "\n");
    stage_ = stage;
    stageStart_ = Clock::now();
    lastTenth_ = lastPercent_ = lastSecondsLeft_ = -1;
  }
  const int percent = static_cast<int>(100 * done / total);
  const double elapsed = std::chrono::duration<double>(Clock::now() - stageStart_).count();
  const std::string left = timeLeft(elapsed, done, total);
  const std::string name = stage_.empty() ? label_ : label_ + ": " + stage_;
  if (terminal_) {
    const int secondsLeft = left.empty() ? -1 : static_cast<int>(elapsed);
    if (percent == lastPercent_ && secondsLeft == lastSecondsLeft_) return;
    lastPercent_ = percent;
    lastSecondsLeft_ = secondsLeft;
    constexpr int kWidth = 30;
    const int filled = static_cast<int>(kWidth * done / total);
    std::fprintf(stderr, "\r%s [%.*s%*s] %3d%% (%llu/%llu)%s%s\033[K", name.c_str(), filled,
                 "==============================", kWidth - filled, "", percent,
                 static_cast<unsigned long long>(done), static_cast<unsigned long long>(total),
                 left.empty() ? "" : ", ", left.c_str());
    std::fflush(stderr);
    return;
  }
  const int tenth = percent / 10;
  if (tenth == lastTenth_) return;
  lastTenth_ = tenth;
  std::fprintf(stderr, "%s %d%% (%llu/%llu)%s%s\n", name.c_str(), percent,
               static_cast<unsigned long long>(done), static_cast<unsigned long long>(total),
               left.empty() ? "" : ", ", left.c_str());
}

void Progress::finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (terminal_ && lastPercent_ >= 0) std::fprintf(stderr, "\n");
  lastPercent_ = -1;
}

}  // namespace pbgi::cli
