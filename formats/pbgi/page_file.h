#pragma once
// The `.pbgi` container: a header, fixed-capacity zstd pages addressed by id, a page directory
// and named metadata sections, every region under its own XXH3-64 checksum. What the pages
// hold (PBGI subtrees in depth-first Morton order) is the tree builder's business; this layer
// stores, finds and validates bytes.
//
// Byte layout, format version 1. Every field is little-endian and fixed-width, written and
// read field by field (no struct images, no padding). Regions follow each other with no gap,
// so every byte of a file belongs to exactly one checksummed region:
//
//   [0, 128)                        header
//   [128, directoryOffset)          pages, in id order, contiguous
//   [directoryOffset, +24 * count)  page directory
//   [sectionsOffset, fileSize)      sections
//
// The header and the directory are written last but the header stays first: pages stream to
// the file as they are appended, then the directory and sections are appended and the header
// is written over its placeholder at offset 0. Nothing is copied, so a bake of N bytes needs
// N bytes of disk, not 2N, and is written once.
//
// Header (128 bytes in version 1):
//   off size
//     0   8  magic "PBGITREE"                                 } the same in every version:
//     8   4  format version (u32)                             } a reader of any version can
//    12   4  header size in bytes, checksum included (u32)    } tell damage from newer files
//    16   4  page size: capacity of a page, uncompressed (u32, a power of two, 4 KiB..16 MiB)
//    20   4  page count (u32, at least 1)
//    24   8  file size (u64)
//    32   8  directory checksum: XXH3-64 of the directory's bytes
//    40   8  sections size in bytes (u64, at most kMaxPageFileSectionsSize)
//    48   8  sections checksum: XXH3-64 of the sections' bytes
//    56   4  root page id (u32)
//    60   4  root position within the root page, as its payload addresses things (u32;
//            tree pages: the root node's index)
//    64  24  scene bounds: min x, y, z, max x, y, z (f32, no NaN; min > max means empty)
//    88   8  point count (u64)
//    96   8  node count (u64)
//   104   8  leaf count (u64)
//   112   8  scene hash (u64)
//   120   8  header checksum: XXH3-64 of bytes [0, header size - 8)   } in every version
//
// The directory sits after the last page: directoryOffset = fileSize - sectionsSize -
// 24 * pageCount. One 24-byte entry per page, in id order:
//     0   8  file offset of the compressed page (u64); page 0 starts at the header's end and
//            each page starts where the previous one ends
//     8   4  compressed size (u32, at least 1, at most zstd's bound for the page size)
//    12   4  uncompressed size (u32, at most the page size)
//    16   8  XXH3-64 of the compressed bytes
//
// Pages are single zstd frames that record their content size; the frame's size must equal
// the directory's. Sections (the codebook, the bake parameters: opaque bytes here):
//     u32 section count, then per section: u8 name length (1..32), the name (printable ASCII,
//     unique in the file), u32 data length, the data.
//
// What a reader checks, in order, before it allocates anything a field claims: magic, header
// size against the file, header checksum, version, then every count and size against the file
// size. A damaged file fails with DataLossError naming the region ("header", "directory",
// "sections", "page N") with offsets, expected and found values; a file that is not a .pbgi
// fails with InvalidArgumentError; a newer format version with FailedPreconditionError.

#include <atomic>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/math/vec.h"

namespace pbgi {

inline constexpr std::string_view kPageFileMagic = "PBGITREE";
// The version this build writes, and the oldest it reads. A change to the layout above
// bumps kPageFileVersion; kPageFileMinReadableVersion moves only when old files are dropped.
inline constexpr uint32_t kPageFileVersion = 1;
inline constexpr uint32_t kPageFileMinReadableVersion = 1;

inline constexpr uint32_t kPageFileHeaderSize = 128;  // version 1
// Later versions may grow the header; no version may make it larger than this, so that a
// reader knows how much to read before it can check anything.
inline constexpr uint32_t kPageFileMaxHeaderSize = 64 * 1024;
inline constexpr uint32_t kPageFileDirectoryEntrySize = 24;
inline constexpr uint32_t kMinPageSize = 4 * 1024;
inline constexpr uint32_t kMaxPageSize = 16 * 1024 * 1024;
inline constexpr uint32_t kDefaultPageSize = 64 * 1024;
inline constexpr int kDefaultPageZstdLevel = 3;
inline constexpr size_t kMaxPageFileSectionNameSize = 32;
// A codebook of 64K entries x 27 floats is 7 MiB; the bound keeps a hostile size from
// becoming an allocation.
inline constexpr uint64_t kMaxPageFileSectionsSize = uint64_t{256} * 1024 * 1024;

// Named opaque metadata: the codebook, the bake parameters.
struct PageFileSection {
  std::string name;
  std::vector<uint8_t> bytes;

  bool operator==(const PageFileSection&) const = default;
};

// What the writer is told about the tree its pages hold.
struct PageFileMetadata {
  Bounds3f sceneBounds;
  uint64_t pointCount = 0;
  uint64_t nodeCount = 0;
  uint64_t leafCount = 0;
  uint64_t sceneHash = 0;
  // Where a traversal starts: a page id and a position in that page as its payload addresses
  // things (a tree page: a node index).
  uint32_t rootPage = 0;
  uint32_t rootOffset = 0;
  std::vector<PageFileSection> sections;

  // The section called `name`, or null.
  const PageFileSection* findSection(std::string_view name) const;
};

// Everything a reader knows about a file once it is open.
struct PageFileInfo : PageFileMetadata {
  uint32_t version = 0;
  uint32_t pageSize = 0;
  uint32_t pageCount = 0;
  uint64_t fileSize = 0;
};

// One page's place in the file (a directory entry).
struct PageEntry {
  uint64_t offset = 0;
  uint32_t compressedSize = 0;
  uint32_t uncompressedSize = 0;
  uint64_t checksum = 0;

  bool operator==(const PageEntry&) const = default;
};

// A decoded, validated header: the info (sections still empty) and where the other regions
// lie. Every offset and size in it has been checked against the file size.
struct PageFileHeader {
  PageFileInfo info;
  uint64_t directoryOffset = 0;
  uint64_t directorySize = 0;
  uint64_t directoryChecksum = 0;
  uint64_t sectionsOffset = 0;
  uint64_t sectionsSize = 0;
  uint64_t sectionsChecksum = 0;
};

// The checksum every region of the file carries (XXH3-64, seed 0).
uint64_t pageFileChecksum(std::span<const uint8_t> bytes);

// Decoding, one region at a time, without I/O: the reader is built from these, and the fuzz
// target drives them directly. Messages start with the region's name and carry no path.
//
// `bytes` holds the file's first bytes: at least as many as the header size it claims, up to
// kPageFileMaxHeaderSize, where the file has them (fewer are reported as truncation).
absl::StatusOr<PageFileHeader> decodePageFileHeader(std::span<const uint8_t> bytes,
                                                    uint64_t fileSize);
// `bytes` are the header.directorySize bytes at header.directoryOffset.
absl::StatusOr<std::vector<PageEntry>> decodePageDirectory(std::span<const uint8_t> bytes,
                                                           const PageFileHeader& header);
// `bytes` are the header.sectionsSize bytes at header.sectionsOffset.
absl::StatusOr<std::vector<PageFileSection>> decodePageFileSections(std::span<const uint8_t> bytes,
                                                                    const PageFileHeader& header);
// Checks stored page bytes against their directory entry: size and checksum (DataLoss).
absl::Status checkStoredPage(uint32_t id, const PageEntry& entry,
                             std::span<const uint8_t> compressed);
// Checks `compressed` (the bytes at entry.offset) against the entry and decompresses it.
absl::StatusOr<std::vector<uint8_t>> decodePage(uint32_t id, const PageEntry& entry,
                                                std::span<const uint8_t> compressed,
                                                uint32_t pageSize);

struct PageFileWriterOptions {
  uint32_t pageSize = kDefaultPageSize;
  int zstdLevel = kDefaultPageZstdLevel;
};

// Streams pages to a temporary file beside `path`; finish() completes it, flushes it to disk
// and renames it into place, so `path` holds the old file or the whole new one, never a part.
// Memory stays bounded: one page's compression buffer and 24 bytes per page of directory.
// A writer destroyed before finish() succeeds removes its temporary file. Move-only.
class PageFileWriter {
 public:
  static absl::StatusOr<PageFileWriter> create(const std::string& path,
                                               const PageFileWriterOptions& options = {});

  PageFileWriter(PageFileWriter&&) noexcept;
  PageFileWriter& operator=(PageFileWriter&&) noexcept;
  ~PageFileWriter();

  // Compresses and writes one page; returns its id (0, 1, 2, ... in call order). A page
  // larger than the page size is an InvalidArgumentError and leaves the writer as it was;
  // an I/O failure leaves the writer failed, and every later call returns that failure.
  absl::StatusOr<uint32_t> appendPage(std::span<const uint8_t> bytes);

  // Writes the directory, the sections and the header, flushes and renames. Called once:
  // whatever it returns, the writer is done afterwards, and on failure nothing is left
  // behind (neither the temporary nor a file at `path`).
  absl::Status finish(const PageFileMetadata& metadata);

  uint32_t pageCount() const;
  const std::string& path() const;

 private:
  struct State;
  explicit PageFileWriter(std::unique_ptr<State> state);
  std::unique_ptr<State> state_;
};

// Where a reader's bytes come from: a local file (pread), or a copy of a file on another
// machine (remote_page_file.h: its header, directory and sections held in memory, its pages
// fetched on demand). Thread-safe.
class PageFileStore {
 public:
  virtual ~PageFileStore() = default;
  // For messages: a path, or which tree from where.
  virtual const std::string& name() const = 0;
  virtual uint64_t size() const = 0;
  // Reads up to out.size() bytes at `offset`; returns how many (fewer only at the end).
  virtual absl::StatusOr<size_t> read(uint64_t offset, std::span<uint8_t> out) = 0;
  // The stored (compressed) bytes of page `id`, placed by its directory entry; the reader
  // checks them. This reads them with read(); a remote store fetches them.
  virtual absl::StatusOr<std::vector<uint8_t>> readPage(uint32_t id, const PageEntry& entry);
};

// A local file, read with pread.
absl::StatusOr<std::unique_ptr<PageFileStore>> openLocalPageFile(const std::string& path);

// The bytes of a file that are not pages: its header, and its tail (directory and sections).
// What a remote reader needs before it asks for its first page.
struct PageFileHead {
  std::vector<uint8_t> header;
  uint64_t tailOffset = 0;  // the directory's offset
  std::vector<uint8_t> tail;
  uint64_t fileSize = 0;

  // The file's identity: the header's checksum, which covers the directory's (so every
  // page's) and the sections' checksums.
  uint64_t treeId() const;
  uint64_t bytes() const { return header.size() + tail.size(); }
};

// Random access to the pages of a .pbgi file by id. open() validates the header, the
// directory and the sections; every page is validated when it is read. Thread-safe: pages
// are read with pread and nothing is cached here (the page cache is above this layer).
class PageFileReader {
 public:
  static absl::StatusOr<std::unique_ptr<PageFileReader>> open(const std::string& path);
  static absl::StatusOr<std::unique_ptr<PageFileReader>> open(
      std::unique_ptr<PageFileStore> store);

  PageFileReader(const PageFileReader&) = delete;
  PageFileReader& operator=(const PageFileReader&) = delete;
  ~PageFileReader();

  const PageFileInfo& info() const { return info_; }
  const std::vector<PageEntry>& directory() const { return directory_; }
  // The store's name: the file's path, for a local file.
  const std::string& path() const { return store_->name(); }
  PageFileStore& store() const { return *store_; }

  // The uncompressed bytes of page `id`, after checking its size and checksum.
  absl::StatusOr<std::vector<uint8_t>> readPage(uint32_t id) const;
  // The stored bytes of page `id`, checked against its directory entry (what a page service
  // sends).
  absl::StatusOr<std::vector<uint8_t>> readStoredPage(uint32_t id) const;
  // The header and tail bytes as they are in the file (what a page service sends first).
  const PageFileHead& head() const { return head_; }

  // Reads and checks every page. The error names the first damaged page and counts them all.
  absl::Status verifyAll() const;

  // Every byte read from the file since open (header, directory and sections included), and
  // the number of page reads: what a traversal cost.
  uint64_t bytesRead() const { return bytesRead_.load(std::memory_order_relaxed); }
  uint64_t pagesRead() const { return pagesRead_.load(std::memory_order_relaxed); }

 private:
  explicit PageFileReader(std::unique_ptr<PageFileStore> store);
  absl::StatusOr<std::vector<uint8_t>> storedPage(uint32_t id) const;

  std::unique_ptr<PageFileStore> store_;
  PageFileHead head_;
  PageFileInfo info_;
  std::vector<PageEntry> directory_;
  mutable std::atomic<uint64_t> bytesRead_{0};
  mutable std::atomic<uint64_t> pagesRead_{0};
};

}  // namespace pbgi
