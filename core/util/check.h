#pragma once
// Invariant checks for programmer errors. They stay on in release builds and print their
// operands; expected failures (bad input, I/O) return absl::Status instead.

#include <cstdio>
#include <cstdlib>

#include <fmt/format.h>

namespace pbgi::detail {
[[noreturn]] inline void checkFailed(const char* file, int line, const std::string& what) {
  std::fprintf(stderr, "pbgi: internal error: %s:%d: check failed: %s\n", file, line, what.c_str());
  std::fflush(stderr);
  std::abort();
}
}  // namespace pbgi::detail

#define PBGI_CHECK(cond)                                              \
  do {                                                                \
    if (!(cond)) ::pbgi::detail::checkFailed(__FILE__, __LINE__, #cond); \
  } while (false)

#define PBGI_CHECK_OP(a, op, b)                                                      \
  do {                                                                               \
    const auto& pbgi_a_ = (a);                                                       \
    const auto& pbgi_b_ = (b);                                                       \
    if (!(pbgi_a_ op pbgi_b_))                                                       \
      ::pbgi::detail::checkFailed(                                                   \
          __FILE__, __LINE__,                                                        \
          fmt::format("{} {} {} ({} vs {})", #a, #op, #b, pbgi_a_, pbgi_b_));        \
  } while (false)

#define PBGI_CHECK_EQ(a, b) PBGI_CHECK_OP(a, ==, b)
#define PBGI_CHECK_NE(a, b) PBGI_CHECK_OP(a, !=, b)
#define PBGI_CHECK_LT(a, b) PBGI_CHECK_OP(a, <, b)
#define PBGI_CHECK_LE(a, b) PBGI_CHECK_OP(a, <=, b)
#define PBGI_CHECK_GT(a, b) PBGI_CHECK_OP(a, >, b)
#define PBGI_CHECK_GE(a, b) PBGI_CHECK_OP(a, >=, b)
