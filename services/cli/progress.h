#pragma once
// Progress of long work: a bar redrawn in place on a terminal, plain lines at every tenth
// otherwise (logs and CI). Thread-safe: renderers report from worker threads.

#include <cstdint>
#include <mutex>
#include <string>

namespace pbgi::cli {

class Progress {
 public:
  explicit Progress(std::string label);
  void update(uint64_t done, uint64_t total);
  // Ends the bar's line on a terminal.
  void finish();

 private:
  std::mutex mutex_;
  std::string label_;
  bool terminal_ = false;
  int lastTenth_ = -1;
  int lastPercent_ = -1;
};

}  // namespace pbgi::cli
