#pragma once
// The body of the .pbgi fuzz target. It lives in a header so that the corpus replay in
// tests/formats/pbgi/page_file_test.cpp runs every seed through the same code in builds
// without libFuzzer (CI builds with gcc).
//
// Each input is tried three ways:
//   - as a whole file, exactly as given: the checks up to and including the checksums;
//   - as a whole file with its file size and checksums repaired, so that mutations reach the
//     field validation and the page decoding behind the checksums (a random mutation almost
//     never keeps an XXH3 valid);
//   - as one raw page: a zstd frame followed by the uncompressed size it claims (u32 LE).

#include <algorithm>
#include <cstdint>
#include <span>
#include <vector>

#include "formats/pbgi/page_file.h"

namespace pbgi::fuzz {

// How far an image got; the replay test checks that valid seeds get all the way.
enum class PageFileStage { kNothing, kHeader, kDirectory, kSections, kPages };

// Pages decoded per input at most: enough to cover every seed, few enough to stay fast.
inline constexpr uint32_t kMaxPagesDecoded = 64;

// Decodes a whole file image region by region, as PageFileReader::open and readPage do.
inline PageFileStage decodePageFileImage(std::span<const uint8_t> image) {
  const auto header = decodePageFileHeader(
      image.first(std::min<size_t>(image.size(), kPageFileMaxHeaderSize)), image.size());
  if (!header.ok()) return PageFileStage::kNothing;
  // The header's offsets and sizes have been checked against the image size.
  const auto directory =
      decodePageDirectory(image.subspan(header->directoryOffset, header->directorySize), *header);
  if (!directory.ok()) return PageFileStage::kHeader;
  const auto sections =
      decodePageFileSections(image.subspan(header->sectionsOffset, header->sectionsSize), *header);
  if (!sections.ok()) return PageFileStage::kDirectory;
  bool allPages = true;
  const uint32_t pages = std::min(header->info.pageCount, kMaxPagesDecoded);
  for (uint32_t id = 0; id < pages; ++id) {
    const PageEntry& e = (*directory)[id];
    const auto page =
        decodePage(id, e, image.subspan(e.offset, e.compressedSize), header->info.pageSize);
    if (!page.ok()) {
      allPages = false;
    } else if (page->size() != e.uncompressedSize) {
      __builtin_trap();  // a page that decodes must have the size its entry promised
    }
  }
  return allPages ? PageFileStage::kPages : PageFileStage::kSections;
}

namespace detail {
// Header field offsets, version 1 (formats/pbgi/page_file.h draws the layout).
inline constexpr size_t kHeaderSizeAt = 12, kPageCountAt = 20, kFileSizeAt = 24,
                        kDirectoryChecksumAt = 32, kSectionsSizeAt = 40, kSectionsChecksumAt = 48,
                        kHeaderChecksumAt = 120;

inline uint64_t load(const std::vector<uint8_t>& b, size_t at, int bytes) {
  uint64_t v = 0;
  for (int i = 0; i < bytes; ++i) v |= uint64_t{b[at + i]} << (8 * i);
  return v;
}
inline void store(std::vector<uint8_t>& b, size_t at, int bytes, uint64_t v) {
  for (int i = 0; i < bytes; ++i) b[at + i] = static_cast<uint8_t>(v >> (8 * i));
}
}  // namespace detail

// The image with the file size and every checksum it can locate made consistent.
inline std::vector<uint8_t> withRepairedChecksums(std::span<const uint8_t> image) {
  using namespace detail;
  std::vector<uint8_t> out(image.begin(), image.end());
  if (out.size() < kPageFileHeaderSize ||
      !std::equal(kPageFileMagic.begin(), kPageFileMagic.end(), out.begin()) ||
      load(out, kHeaderSizeAt, 4) != kPageFileHeaderSize) {
    return out;
  }
  const uint64_t size = out.size();
  store(out, kFileSizeAt, 8, size);
  const uint64_t pageCount = load(out, kPageCountAt, 4);
  const uint64_t sectionsSize = load(out, kSectionsSizeAt, 8);
  const uint64_t directorySize = pageCount * kPageFileDirectoryEntrySize;
  if (sectionsSize <= size && directorySize <= size - sectionsSize &&
      kPageFileHeaderSize <= size - sectionsSize - directorySize) {
    const uint64_t sectionsOffset = size - sectionsSize;
    const uint64_t directoryOffset = sectionsOffset - directorySize;
    for (uint64_t i = 0; i < pageCount; ++i) {
      const size_t entry = directoryOffset + i * kPageFileDirectoryEntrySize;
      const uint64_t offset = load(out, entry, 8);
      const uint64_t compressed = load(out, entry + 8, 4);
      if (offset <= size && compressed <= size - offset) {
        store(out, entry + 16, 8,
              pageFileChecksum(std::span<const uint8_t>(out).subspan(offset, compressed)));
      }
    }
    const std::span<const uint8_t> all(out);
    store(out, kDirectoryChecksumAt, 8,
          pageFileChecksum(all.subspan(directoryOffset, directorySize)));
    store(out, kSectionsChecksumAt, 8, pageFileChecksum(all.subspan(sectionsOffset)));
  }
  store(out, kHeaderChecksumAt, 8,
        pageFileChecksum(std::span<const uint8_t>(out).first(kHeaderChecksumAt)));
  return out;
}

// The input as one page of a file with 64 KiB pages: a frame, then its claimed size.
inline bool decodeRawPage(std::span<const uint8_t> input) {
  if (input.size() < 5) return false;
  const std::span<const uint8_t> frame = input.first(input.size() - 4);
  const uint8_t* s = input.data() + frame.size();
  const uint32_t claimed =
      uint32_t{s[0]} | uint32_t{s[1]} << 8 | uint32_t{s[2]} << 16 | uint32_t{s[3]} << 24;
  const PageEntry entry{kPageFileHeaderSize, static_cast<uint32_t>(frame.size()), claimed,
                        pageFileChecksum(frame)};
  return decodePage(0, entry, frame, kDefaultPageSize).ok();
}

}  // namespace pbgi::fuzz
