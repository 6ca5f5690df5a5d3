#include "services/util/stage_time.h"

#include <algorithm>

#include <fmt/format.h>

namespace pbgi {

std::string formatStages(const std::vector<StageTime>& stages) {
  size_t width = 0;
  for (const StageTime& s : stages) width = std::max(width, s.stage.size());
  std::string out;
  for (const StageTime& s : stages) {
    out += fmt::format("  {:<{}} {:8.3f} s\n", s.stage, width, s.seconds);
  }
  return out;
}

}  // namespace pbgi
