#include "core/util/log.h"

#include <spdlog/sinks/stdout_color_sinks.h>

namespace pbgi::log {

namespace {
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
  switch (level) {
    case Level::kDebug: spdlog::set_level(spdlog::level::debug); break;
    case Level::kInfo: spdlog::set_level(spdlog::level::info); break;
    case Level::kWarn: spdlog::set_level(spdlog::level::warn); break;
    case Level::kError: spdlog::set_level(spdlog::level::err); break;
    case Level::kOff: spdlog::set_level(spdlog::level::off); break;
  }
}

}  // namespace pbgi::log
