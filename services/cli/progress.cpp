#include "services/cli/progress.h"

#include <unistd.h>

#include <cstdio>

namespace pbgi::cli {

Progress::Progress(std::string label) : label_(std::move(label)), terminal_(isatty(2) != 0) {}

void Progress::update(int done, int total) {
  if (total <= 0) return;
  std::lock_guard<std::mutex> lock(mutex_);
  const int percent = static_cast<int>(100LL * done / total);
  if (terminal_) {
    if (percent == lastPercent_) return;
    lastPercent_ = percent;
    constexpr int kWidth = 40;
    const int filled = kWidth * done / total;
    std::fprintf(stderr, "\r%s [%.*s%*s] %3d%% (%d/%d)", label_.c_str(), filled,
                 "========================================", kWidth - filled, "", percent, done,
                 total);
    std::fflush(stderr);
    return;
  }
  const int tenth = percent / 10;
  if (tenth == lastTenth_) return;
  lastTenth_ = tenth;
  std::fprintf(stderr, "%s: %d%% (%d/%d)\n", label_.c_str(), percent, done, total);
}

void Progress::finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (terminal_ && lastPercent_ >= 0) std::fprintf(stderr, "\n");
}

}  // namespace pbgi::cli
