#pragma once
// One small wrapper over spdlog. Messages carry key=value fields (job= frame= tile= worker=)
// so that farm logs can be grepped and parsed.

#include <string_view>

#include <spdlog/spdlog.h>

namespace pbgi::log {

enum class Level { kDebug, kInfo, kWarn, kError, kOff };

// Sets the level of the process-wide logger; messages go to stderr.
void setLevel(Level level);
// Whether messages of `level` are shown (progress output follows the info level: -q hides it).
bool shows(Level level);

template <typename... Args>
void debug(fmt::format_string<Args...> f, Args&&... args) {
  spdlog::debug(f, std::forward<Args>(args)...);
}
template <typename... Args>
void info(fmt::format_string<Args...> f, Args&&... args) {
  spdlog::info(f, std::forward<Args>(args)...);
}
template <typename... Args>
void warn(fmt::format_string<Args...> f, Args&&... args) {
  spdlog::warn(f, std::forward<Args>(args)...);
}
template <typename... Args>
void error(fmt::format_string<Args...> f, Args&&... args) {
  spdlog::error(f, std::forward<Args>(args)...);
}

}  // namespace pbgi::log
