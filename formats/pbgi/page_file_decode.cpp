// Decoding the regions of a .pbgi file from bytes in memory: what the reader runs on what it
// reads, and what the fuzz target drives directly. No I/O here.

#include <algorithm>
#include <memory>
#include <set>
#include <utility>

#include <xxhash.h>
#include <zstd.h>

#include "formats/pbgi/page_file.h"
#include "formats/pbgi/page_file_layout.h"

namespace pbgi {
namespace {

using namespace page_file_internal;

struct ZstdDCtxDeleter {
  void operator()(ZSTD_DCtx* c) const { ZSTD_freeDCtx(c); }
};

}  // namespace

const PageFileSection* PageFileMetadata::findSection(std::string_view name) const {
  for (const PageFileSection& s : sections) {
    if (s.name == name) return &s;
  }
  return nullptr;
}

uint64_t pageFileChecksum(std::span<const uint8_t> bytes) {
  return XXH3_64bits(bytes.data(), bytes.size());
}

// ---------------------------------------------------------------------------------------------
// Decoding

namespace {

// The header's frame: the magic, its size and checksum, and a version this build reads.
struct HeaderFrame {
  uint32_t version = 0;
  uint32_t headerSize = 0;
};

absl::StatusOr<HeaderFrame> checkHeaderFrame(std::span<const uint8_t> bytes, uint64_t fileSize) {
  if (bytes.size() > fileSize) {
    return absl::InvalidArgumentError(fmt::format(
        "header: given {} bytes of a file said to be {} bytes long", bytes.size(), fileSize));
  }
  const size_t magicSeen = std::min(bytes.size(), kPageFileMagic.size());
  if (!std::equal(bytes.begin(), bytes.begin() + magicSeen, asBytes(kPageFileMagic).begin())) {
    return absl::InvalidArgumentError(
        fmt::format("header: expected the magic \"{}\" at offset 0, found \"{}\": not a .pbgi "
                    "file",
                    kPageFileMagic, printable(bytes.first(magicSeen))));
  }
  if (bytes.size() < kPreambleSize) {
    return absl::DataLossError(fmt::format(
        "header: file is {} bytes, {} could be read; a .pbgi header is at least {}: truncated",
        fileSize, bytes.size(), kMinHeaderSize));
  }
  const uint32_t version = loadU32(bytes.data() + kOffVersion);
  const uint32_t headerSize = loadU32(bytes.data() + kOffHeaderSize);
  auto versionError = [&]() -> absl::Status {
    const std::string readable =
        kPageFileMinReadableVersion == kPageFileVersion
            ? fmt::format("{}", kPageFileVersion)
            : fmt::format("{} to {}", kPageFileMinReadableVersion, kPageFileVersion);
    if (version > kPageFileVersion) {
      return absl::FailedPreconditionError(
          fmt::format("header: written by a newer pbgi: format version {}, this build reads {}",
                      version, readable));
    }
    if (version < kPageFileMinReadableVersion) {
      return absl::FailedPreconditionError(fmt::format(
          "header: format version {} is older than this build reads ({})", version, readable));
    }
    return absl::OkStatus();
  };
  if (headerSize < kMinHeaderSize || headerSize > kPageFileMaxHeaderSize) {
    // The checksum cannot be found, so a newer version is the likelier story than damage.
    if (version > kPageFileVersion) return versionError();
    return absl::DataLossError(
        fmt::format("header: header size (offset {}) is {}; expected {} to {}", kOffHeaderSize,
                    headerSize, kMinHeaderSize, kPageFileMaxHeaderSize));
  }
  if (headerSize > fileSize || headerSize > bytes.size()) {
    return absl::DataLossError(fmt::format(
        "header: the header is {} bytes (offset {}), the file is {} bytes and {} could be read: "
        "truncated",
        headerSize, kOffHeaderSize, fileSize, bytes.size()));
  }
  const uint64_t recordedChecksum = loadU64(bytes.data() + headerSize - 8);
  const uint64_t checksum = pageFileChecksum(bytes.first(headerSize - 8));
  if (checksum != recordedChecksum) {
    return absl::DataLossError(fmt::format(
        "header: checksum mismatch: bytes [0, {}) hash to {}, the header records {} at offset {}",
        headerSize - 8, hex(checksum), hex(recordedChecksum), headerSize - 8));
  }
  if (absl::Status s = versionError(); !s.ok()) return s;
  if (headerSize != kPageFileHeaderSize) {
    return absl::DataLossError(
        fmt::format("header: a version {} header is {} bytes, this one says {} (offset {})",
                    version, kPageFileHeaderSize, headerSize, kOffHeaderSize));
  }
  return HeaderFrame{.version = version, .headerSize = headerSize};
}

// The header's fields, as stored (checkHeaderFields checks them).
PageFileHeader readHeaderFields(const uint8_t* h, uint32_t version) {
  PageFileHeader header;
  PageFileInfo& info = header.info;
  info.version = version;
  info.pageSize = loadU32(h + kOffPageSize);
  info.pageCount = loadU32(h + kOffPageCount);
  info.fileSize = loadU64(h + kOffFileSize);
  header.directoryChecksum = loadU64(h + kOffDirectoryChecksum);
  header.sectionsSize = loadU64(h + kOffSectionsSize);
  header.sectionsChecksum = loadU64(h + kOffSectionsChecksum);
  info.rootPage = loadU32(h + kOffRootPage);
  info.rootOffset = loadU32(h + kOffRootOffset);
  info.sceneBounds.min =
      Vec3f(loadF32(h + kOffBounds), loadF32(h + kOffBounds + 4), loadF32(h + kOffBounds + 8));
  info.sceneBounds.max = Vec3f(loadF32(h + kOffBounds + 12), loadF32(h + kOffBounds + 16),
                               loadF32(h + kOffBounds + 20));
  info.pointCount = loadU64(h + kOffPointCount);
  info.nodeCount = loadU64(h + kOffNodeCount);
  info.leafCount = loadU64(h + kOffLeafCount);
  info.sceneHash = loadU64(h + kOffSceneHash);

  return header;
}

// DataLoss naming the field when the header does not describe this file: its size, page size
// and count, sections, root and bounds. Fills in where the directory and sections lie.
absl::Status checkHeaderFields(PageFileHeader& header, uint32_t headerSize, uint64_t fileSize) {
  const PageFileInfo& info = header.info;
  if (info.fileSize != fileSize) {
    if (fileSize < info.fileSize) {
      return absl::DataLossError(fmt::format(
          "header: the file is {} bytes, the header records {} (offset {}): truncated, {} bytes "
          "missing",
          fileSize, info.fileSize, kOffFileSize, info.fileSize - fileSize));
    }
    return absl::DataLossError(fmt::format(
        "header: the file is {} bytes, the header records {} (offset {}): {} trailing bytes",
        fileSize, info.fileSize, kOffFileSize, fileSize - info.fileSize));
  }
  if (!validPageSize(info.pageSize)) {
    return absl::DataLossError(fmt::format("header: page size (offset {}) is {}; expected {}",
                                           kOffPageSize, info.pageSize, pageSizeRule()));
  }
  if (info.pageCount == 0) {
    return absl::DataLossError(fmt::format(
        "header: page count (offset {}) is 0; a file holds at least its root page", kOffPageCount));
  }
  if (header.sectionsSize < kMinSectionsSize || header.sectionsSize > kMaxPageFileSectionsSize) {
    return absl::DataLossError(
        fmt::format("header: sections size (offset {}) is {}; expected {} to {}", kOffSectionsSize,
                    header.sectionsSize, kMinSectionsSize, kMaxPageFileSectionsSize));
  }
  // Every page takes at least one byte and a directory entry. No overflow: the page count is
  // 32 bits and the sections size is bounded above.
  header.directorySize = uint64_t{info.pageCount} * kPageFileDirectoryEntrySize;
  const uint64_t needed =
      uint64_t{headerSize} + info.pageCount + header.directorySize + header.sectionsSize;
  if (needed > fileSize) {
    return absl::DataLossError(fmt::format(
        "header: {} pages (offset {}) and {} bytes of sections need at least {} bytes, the "
        "file is {} bytes",
        info.pageCount, kOffPageCount, header.sectionsSize, needed, fileSize));
  }
  header.sectionsOffset = fileSize - header.sectionsSize;
  header.directoryOffset = header.sectionsOffset - header.directorySize;
  if (info.rootPage >= info.pageCount) {
    return absl::DataLossError(
        fmt::format("header: root page (offset {}) is {}, the file has {} pages", kOffRootPage,
                    info.rootPage, info.pageCount));
  }
  if (info.rootOffset >= info.pageSize) {
    return absl::DataLossError(
        fmt::format("header: root offset (offset {}) is {}, beyond the page size {}",
                    kOffRootOffset, info.rootOffset, info.pageSize));
  }
  if (hasNaN(info.sceneBounds)) {
    return absl::DataLossError(
        fmt::format("header: scene bounds (offset {}) hold a NaN: min {}, max {}", kOffBounds,
                    info.sceneBounds.min, info.sceneBounds.max));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<PageFileHeader> decodePageFileHeader(std::span<const uint8_t> bytes,
                                                    uint64_t fileSize) {
  PBGI_ASSIGN_OR_RETURN(const HeaderFrame frame, checkHeaderFrame(bytes, fileSize));
  PageFileHeader header = readHeaderFields(bytes.data(), frame.version);
  PBGI_RETURN_IF_ERROR(checkHeaderFields(header, frame.headerSize, fileSize));
  return header;
}

absl::StatusOr<std::vector<PageEntry>> decodePageDirectory(std::span<const uint8_t> bytes,
                                                           const PageFileHeader& header) {
  const PageFileInfo& info = header.info;
  if (bytes.size() != header.directorySize) {
    return absl::DataLossError(
        fmt::format("directory: expected {} bytes at offset {}, {} could be read: truncated",
                    header.directorySize, header.directoryOffset, bytes.size()));
  }
  const uint64_t checksum = pageFileChecksum(bytes);
  if (checksum != header.directoryChecksum) {
    return absl::DataLossError(fmt::format(
        "directory: checksum mismatch: bytes [{}, {}) hash to {}, the header records {} (header "
        "offset {})",
        header.directoryOffset, header.directoryOffset + header.directorySize, hex(checksum),
        hex(header.directoryChecksum), kOffDirectoryChecksum));
  }
  const uint64_t maxCompressed = ZSTD_compressBound(info.pageSize);
  std::vector<PageEntry> entries(info.pageCount);
  uint64_t expectedOffset = kPageFileHeaderSize;
  for (uint32_t i = 0; i < info.pageCount; ++i) {
    const uint8_t* p = bytes.data() + uint64_t{i} * kPageFileDirectoryEntrySize;
    const uint64_t at = header.directoryOffset + uint64_t{i} * kPageFileDirectoryEntrySize;
    PageEntry& e = entries[i];
    e.offset = loadU64(p);
    e.compressedSize = loadU32(p + 8);
    e.uncompressedSize = loadU32(p + 12);
    e.checksum = loadU64(p + 16);
    if (e.offset != expectedOffset) {
      return absl::DataLossError(fmt::format(
          "directory: page {} (entry at offset {}) starts at {}; expected {}, where {} ends", i, at,
          e.offset, expectedOffset,
          i == 0 ? std::string("the header") : fmt::format("page {}", i - 1)));
    }
    if (e.compressedSize == 0 || e.compressedSize > maxCompressed) {
      return absl::DataLossError(fmt::format(
          "directory: page {} (entry at offset {}) claims {} compressed bytes; expected 1 to {} "
          "for {}-byte pages",
          i, at, e.compressedSize, maxCompressed, info.pageSize));
    }
    if (e.uncompressedSize > info.pageSize) {
      return absl::DataLossError(fmt::format(
          "directory: page {} (entry at offset {}) claims {} uncompressed bytes, more than the "
          "page size {}",
          i, at, e.uncompressedSize, info.pageSize));
    }
    expectedOffset += e.compressedSize;
  }
  if (expectedOffset != header.directoryOffset) {
    return absl::DataLossError(
        fmt::format("directory: the pages end at offset {}, the directory starts at {}",
                    expectedOffset, header.directoryOffset));
  }
  const PageEntry& root = entries[info.rootPage];
  if (info.rootOffset >= root.uncompressedSize) {
    return absl::DataLossError(fmt::format(
        "directory: the header's root offset {} is not inside root page {}, which holds {} bytes",
        info.rootOffset, info.rootPage, root.uncompressedSize));
  }
  return entries;
}

absl::StatusOr<std::vector<PageFileSection>> decodePageFileSections(std::span<const uint8_t> bytes,
                                                                    const PageFileHeader& header) {
  if (bytes.size() != header.sectionsSize) {
    return absl::DataLossError(
        fmt::format("sections: expected {} bytes at offset {}, {} could be read: truncated",
                    header.sectionsSize, header.sectionsOffset, bytes.size()));
  }
  const uint64_t checksum = pageFileChecksum(bytes);
  if (checksum != header.sectionsChecksum) {
    return absl::DataLossError(fmt::format(
        "sections: checksum mismatch: bytes [{}, {}) hash to {}, the header records {} (header "
        "offset {})",
        header.sectionsOffset, header.sectionsOffset + header.sectionsSize, hex(checksum),
        hex(header.sectionsChecksum), kOffSectionsChecksum));
  }
  if (bytes.size() < kMinSectionsSize) {
    return absl::DataLossError(
        fmt::format("sections: {} bytes; expected at least {} (the section count)", bytes.size(),
                    kMinSectionsSize));
  }
  const uint32_t count = loadU32(bytes.data());
  if (count > (bytes.size() - kMinSectionsSize) / kMinSectionSize) {
    return absl::DataLossError(
        fmt::format("sections: the count (offset {}) is {}; {} bytes hold at most {} sections",
                    header.sectionsOffset, count, bytes.size(),
                    (bytes.size() - kMinSectionsSize) / kMinSectionSize));
  }
  std::vector<PageFileSection> sections;
  sections.reserve(count);
  std::set<std::string, std::less<>> names;
  size_t pos = kMinSectionsSize;
  auto atFile = [&](size_t p) { return header.sectionsOffset + p; };
  for (uint32_t i = 0; i < count; ++i) {
    if (bytes.size() - pos < 1) {
      return absl::DataLossError(
          fmt::format("sections: section {} of {} would start at offset {}, where the sections end",
                      i, count, atFile(pos)));
    }
    const size_t nameSize = bytes[pos];
    if (bytes.size() - pos - 1 < nameSize + 4) {
      return absl::DataLossError(fmt::format(
          "sections: section {} (offset {}) claims a {}-byte name; only {} bytes remain", i,
          atFile(pos), nameSize, bytes.size() - pos - 1));
    }
    const std::span<const uint8_t> name = bytes.subspan(pos + 1, nameSize);
    if (absl::Status s = checkSectionName(name); !s.ok()) {
      return absl::DataLossError(
          fmt::format("sections: section {} (offset {}): {}", i, atFile(pos), s.message()));
    }
    std::string nameString(name.begin(), name.end());
    if (names.contains(nameString)) {
      return absl::DataLossError(fmt::format("sections: section {} (offset {}) is a second \"{}\"",
                                             i, atFile(pos), nameString));
    }
    pos += 1 + nameSize;
    const uint32_t dataSize = loadU32(bytes.data() + pos);
    pos += 4;
    if (bytes.size() - pos < dataSize) {
      return absl::DataLossError(
          fmt::format("sections: section \"{}\" claims {} bytes at offset {}; only {} remain",
                      nameString, dataSize, atFile(pos), bytes.size() - pos));
    }
    const std::span<const uint8_t> data = bytes.subspan(pos, dataSize);
    pos += dataSize;
    names.insert(nameString);
    sections.push_back({std::move(nameString), std::vector<uint8_t>(data.begin(), data.end())});
  }
  if (pos != bytes.size()) {
    return absl::DataLossError(
        fmt::format("sections: {} bytes follow the last of the {} sections (offset {})",
                    bytes.size() - pos, count, atFile(pos)));
  }
  return sections;
}

absl::Status checkStoredPage(uint32_t id, const PageEntry& entry,
                             std::span<const uint8_t> compressed) {
  if (compressed.size() != entry.compressedSize) {
    return absl::DataLossError(fmt::format("{}: {} bytes could be read: truncated",
                                           describePage(id, entry), compressed.size()));
  }
  const uint64_t checksum = pageFileChecksum(compressed);
  if (checksum != entry.checksum) {
    return absl::DataLossError(
        fmt::format("{}: checksum mismatch: the bytes hash to {}, the directory records {}",
                    describePage(id, entry), hex(checksum), hex(entry.checksum)));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<uint8_t>> decodePage(uint32_t id, const PageEntry& entry,
                                                std::span<const uint8_t> compressed,
                                                uint32_t pageSize) {
  if (!validPageSize(pageSize)) {
    return absl::InvalidArgumentError(
        fmt::format("page {}: page size {}; expected {}", id, pageSize, pageSizeRule()));
  }
  const std::string what = describePage(id, entry);
  if (absl::Status s = checkStoredPage(id, entry, compressed); !s.ok()) return s;
  if (entry.uncompressedSize > pageSize) {
    return absl::DataLossError(
        fmt::format("{}: claims {} uncompressed bytes, more than the page size {}", what,
                    entry.uncompressedSize, pageSize));
  }
  // Everything zstd is told comes from the frame itself; check it against the directory before
  // allocating or decompressing.
  const size_t frameSize = ZSTD_findFrameCompressedSize(compressed.data(), compressed.size());
  if (ZSTD_isError(frameSize)) {
    return absl::DataLossError(
        fmt::format("{}: not a zstd frame: {}", what, ZSTD_getErrorName(frameSize)));
  }
  if (frameSize != compressed.size()) {
    return absl::DataLossError(fmt::format("{}: the zstd frame ends after {} of the {} bytes", what,
                                           frameSize, compressed.size()));
  }
  const unsigned long long contentSize =
      ZSTD_getFrameContentSize(compressed.data(), compressed.size());
  if (contentSize == ZSTD_CONTENTSIZE_UNKNOWN || contentSize == ZSTD_CONTENTSIZE_ERROR) {
    return absl::DataLossError(
        fmt::format("{}: the zstd frame does not record its content size", what));
  }
  if (contentSize != entry.uncompressedSize) {
    return absl::DataLossError(
        fmt::format("{}: the zstd frame holds {} bytes, the directory records {}", what,
                    contentSize, entry.uncompressedSize));
  }
  thread_local std::unique_ptr<ZSTD_DCtx, ZstdDCtxDeleter> dctx(ZSTD_createDCtx());
  if (!dctx) return absl::ResourceExhaustedError("cannot create a zstd decompression context");
  std::vector<uint8_t> out(entry.uncompressedSize);
  uint8_t unused = 0;  // zstd wants a valid pointer even for an empty page
  const size_t n = ZSTD_decompressDCtx(dctx.get(), out.empty() ? &unused : out.data(), out.size(),
                                       compressed.data(), compressed.size());
  if (ZSTD_isError(n)) {
    return absl::DataLossError(
        fmt::format("{}: zstd cannot decompress it: {}", what, ZSTD_getErrorName(n)));
  }
  if (n != out.size()) {
    return absl::DataLossError(
        fmt::format("{}: decompressed to {} bytes, the directory records {}", what, n, out.size()));
  }
  return out;
}

}  // namespace pbgi
