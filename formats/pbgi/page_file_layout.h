#pragma once
// Private to formats/pbgi: the version 1 header's field offsets and the little-endian field
// helpers that page_file.cpp (writing, reading) and page_file_decode.cpp share. The layout
// itself is drawn in page_file.h.

#include <bit>
#include <cmath>
#include <cstdint>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/status.h>

#include "core/util/bytes.h"
#include "core/util/status.h"
#include "formats/pbgi/page_file.h"

namespace pbgi::page_file_internal {

// Header fields, version 1 (the layout is drawn in page_file.h).
inline constexpr size_t kOffVersion = 8;
inline constexpr size_t kOffHeaderSize = 12;
inline constexpr size_t kOffPageSize = 16;
inline constexpr size_t kOffPageCount = 20;
inline constexpr size_t kOffFileSize = 24;
inline constexpr size_t kOffDirectoryChecksum = 32;
inline constexpr size_t kOffSectionsSize = 40;
inline constexpr size_t kOffSectionsChecksum = 48;
inline constexpr size_t kOffRootPage = 56;
inline constexpr size_t kOffRootOffset = 60;
inline constexpr size_t kOffBounds = 64;
inline constexpr size_t kOffPointCount = 88;
inline constexpr size_t kOffNodeCount = 96;
inline constexpr size_t kOffLeafCount = 104;
inline constexpr size_t kOffSceneHash = 112;
inline constexpr size_t kOffHeaderChecksum = 120;
static_assert(kOffHeaderChecksum + 8 == kPageFileHeaderSize);

// Magic, version and header size: what every version keeps where it is.
inline constexpr size_t kPreambleSize = 16;
inline constexpr uint32_t kMinHeaderSize = kPreambleSize + 8;
// Section count, then per section at least a name length, a 1-byte name and a data length.
inline constexpr uint64_t kMinSectionsSize = 4;
inline constexpr uint64_t kMinSectionSize = 1 + 1 + 4;
inline constexpr uint32_t kMaxPageCount = UINT32_MAX;

using ::pbgi::loadF32;
using ::pbgi::loadU32;
using ::pbgi::loadU64;
using ::pbgi::storeF32;
using ::pbgi::storeU32;
using ::pbgi::storeU64;

inline void appendU32(std::vector<uint8_t>& out, uint32_t v) {
  const size_t at = out.size();
  out.resize(at + 4);
  storeU32(out.data() + at, v);
}

inline std::string hex(uint64_t v) { return fmt::format("{:#018x}", v); }

// Bytes as they would read in a string, unprintable ones escaped: for messages about names
// and magic numbers that a hostile file chooses.
inline std::string printable(std::span<const uint8_t> bytes) {
  std::string s;
  for (uint8_t b : bytes) {
    if (b >= 0x20 && b < 0x7f && b != '"' && b != '\\') {
      s += static_cast<char>(b);
    } else {
      s += fmt::format("\\x{:02x}", b);
    }
  }
  return s;
}

inline bool validPageSize(uint64_t size) {
  return std::has_single_bit(size) && size >= kMinPageSize && size <= kMaxPageSize;
}

inline std::string pageSizeRule() {
  return fmt::format("a power of two between {} and {}", kMinPageSize, kMaxPageSize);
}

inline bool hasNaN(const Bounds3f& b) {
  return std::isnan(b.min.x) || std::isnan(b.min.y) || std::isnan(b.min.z) || std::isnan(b.max.x) ||
         std::isnan(b.max.y) || std::isnan(b.max.z);
}

inline std::string describePage(uint32_t id, const PageEntry& entry) {
  return fmt::format("page {} (offset {}, {} bytes)", id, entry.offset, entry.compressedSize);
}

// A section name is what its users look it up by and what messages print: short, printable
// and without spaces.
inline absl::Status checkSectionName(std::span<const uint8_t> name) {
  if (name.empty() || name.size() > kMaxPageFileSectionNameSize) {
    return absl::InvalidArgumentError(
        fmt::format("section name \"{}\" is {} bytes; expected 1 to {}", printable(name),
                    name.size(), kMaxPageFileSectionNameSize));
  }
  for (uint8_t c : name) {
    if (c <= 0x20 || c >= 0x7f) {
      return absl::InvalidArgumentError(fmt::format(
          "section name \"{}\" holds byte {:#04x}; expected printable ASCII without spaces",
          printable(name), c));
    }
  }
  return absl::OkStatus();
}

inline std::span<const uint8_t> asBytes(std::string_view s) {
  return {reinterpret_cast<const uint8_t*>(s.data()), s.size()};
}

}  // namespace pbgi::page_file_internal
