#include "core/util/log.h"

#include <spdlog/sinks/stdout_color_sinks.h>

namespace pbgi::log {

namespace {
spdlog::level::level_enum spdlogLevel(Level level) {
  switch (level) {
    case Level::kDebug:
      return spdlog::level::debug;
    case Level::kInfo:
      return spdlog::level::info;
    case Level::kWarn:
      return spdlog::level::warn;
    case Level::kError:
      return spdlog::level::err;
    case Level::kOff:
      break;
  }
  return spdlog::level::off;
}

std::shared_ptr<spdlog::logger> makeLogger() {
  auto logger = spdlog::stderr_color_mt("pbgi");
  logger->set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");
  return logger;
}
}  // namespace

void setLevel(Level level) {
  static const bool installed = [] {
    spdlog::set_default_logger(makeLogger());
    return true;
  }();
  (void)installed;
  spdlog::set_level(spdlogLevel(level));
}

bool shows(Level level) { return spdlog::should_log(spdlogLevel(level)); }

}  // namespace pbgi::log
