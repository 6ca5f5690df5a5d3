#include "services/cli/progress.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>

namespace pbgi::cli {

Progress::Progress(std::string label) : label_(std::move(label)), terminal_(isatty(2) != 0) {}

void Progress::update(uint64_t done, uint64_t total) {
  if (total == 0) return;
  done = std::min(done, total);
  std::lock_guard<std::mutex> lock(mutex_);
  const int percent = static_cast<int>(100 * done / total);
  if (terminal_) {
    if (percent == lastPercent_) return;
    lastPercent_ = percent;
    constexpr int kWidth = 40;
    const int filled = static_cast<int>(kWidth * done / total);
    std::fprintf(stderr, "\r%s [%.*s%*s] %3d%% (%llu/%llu)", label_.c_str(), filled,
                 "========================================", kWidth - filled, "", percent,
                 static_cast<unsigned long long>(done), static_cast<unsigned long long>(total));
    std::fflush(stderr);
    return;
  }
  const int tenth = percent / 10;
  if (tenth == lastTenth_) return;
  lastTenth_ = tenth;
  std::fprintf(stderr, "%s: %d%% (%llu/%llu)\n", label_.c_str(), percent,
               static_cast<unsigned long long>(done), static_cast<unsigned long long>(total));
}

void Progress::finish() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (terminal_ && lastPercent_ >= 0) std::fprintf(stderr, "\n");
}

}  // namespace pbgi::cli
