#pragma once
// absl::Status helpers. Debian's abseil has its own string_view type (not std's), so fmt
// needs to be told how to format it.

#include <string>

#include <absl/status/status.h>
#include <absl/strings/string_view.h>
#include <fmt/format.h>

template <>
struct fmt::formatter<absl::string_view> : fmt::formatter<fmt::string_view> {
  template <typename Ctx>
  auto format(absl::string_view s, Ctx& ctx) const {
    return fmt::formatter<fmt::string_view>::format(fmt::string_view(s.data(), s.size()), ctx);
  }
};

namespace pbgi {

// The same error with "context: " in front of its message.
inline absl::Status withContext(const absl::Status& status, const std::string& context) {
  if (status.ok()) return status;
  return absl::Status(status.code(), fmt::format("{}: {}", context, status.message()));
}

}  // namespace pbgi
