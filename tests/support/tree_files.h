#pragma once
// What an unlimited page cache would hold for a tree file: the decoded bytes of every page.
// Tests and benchmarks size small caches as fractions of it.

#include <cstdint>
#include <string>

#include <absl/status/statusor.h>

#include "formats/pbgi/tree_file.h"

namespace pbgi::testing {

inline absl::StatusOr<uint64_t> decodedTreeBytes(const std::string& path) {
  auto file = TreeFile::open(path);
  if (!file.ok()) return file.status();
  uint64_t bytes = 0;
  for (uint32_t id = 0; id < (*file)->container().directory().size(); ++id) {
    auto page = (*file)->page(id);
    if (!page.ok()) return page.status();
    bytes += (*page)->memoryBytes();
  }
  return bytes;
}

}  // namespace pbgi::testing
