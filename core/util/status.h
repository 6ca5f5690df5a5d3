#pragma once
// absl::Status helpers. Debian's abseil has its own string_view type (not std's), so fmt
// needs to be told how to format it.

#include <string>

#include <utility>

#include <absl/status/status.h>
#include <absl/status/statusor.h>
#include <absl/strings/string_view.h>
#include <fmt/format.h>

template <>
struct fmt::formatter<absl::string_view> : fmt::formatter<fmt::string_view> {
  template <typename Ctx>
  auto format(absl::string_view s, Ctx& ctx) const {
    return fmt::formatter<fmt::string_view>::format(fmt::string_view(s.data(), s.size()), ctx);
  }
};

// Where nearly every call can fail (reading a shot file, a job store's statements), the
// plumbing is spelled once: return the error, or take the value.
#define PBGI_STATUS_CONCAT_INNER(a, b) a##b
#define PBGI_STATUS_CONCAT(a, b) PBGI_STATUS_CONCAT_INNER(a, b)
#define PBGI_RETURN_IF_ERROR(expr)                                                   \
  do {                                                                               \
    if (absl::Status pbgi_status_ = (expr); !pbgi_status_.ok()) return pbgi_status_; \
  } while (false)
#define PBGI_ASSIGN_OR_RETURN(lhs, expr) \
  PBGI_ASSIGN_OR_RETURN_IMPL(PBGI_STATUS_CONCAT(pbgi_statusor_, __LINE__), lhs, expr)
#define PBGI_ASSIGN_OR_RETURN_IMPL(tmp, lhs, expr) \
  auto tmp = (expr);                               \
  if (!tmp.ok()) return std::move(tmp).status();   \
  lhs = *std::move(tmp)

namespace pbgi {

// The same error with "context: " in front of its message.
inline absl::Status withContext(const absl::Status& status, const std::string& context) {
  if (status.ok()) return status;
  return absl::Status(status.code(), fmt::format("{}: {}", context, status.message()));
}

}  // namespace pbgi
