#pragma once
// Where a user-facing value came from, so that errors can say file:line:column.

#include <string>

#include <fmt/format.h>

namespace pbgi {

struct SourceLocation {
  std::string file;
  int line = 0;    // 1-based; 0 when unknown
  int column = 0;  // 1-based; 0 when unknown

  std::string toString() const {
    if (line <= 0) return file;
    if (column <= 0) return fmt::format("{}:{}", file, line);
    return fmt::format("{}:{}:{}", file, line, column);
  }
};

}  // namespace pbgi
