#pragma once
// External merge sort of surfels by (Morton key, sequence), the first stage of the out-of-core
// tree build (Kontkanen, Tabellion, Overbeck 2011): whatever the point count, the sort holds
// at most its memory budget of records and I/O buffers.
//
// Lifecycle: add() every surfel, finish() once, then next() until it yields false. The
// sequence number of a surfel is its add() index, so (key, sequence) is unique and the output
// order is total: the same stream whatever the budget (in-core or spilled, one merge pass or
// several) and whatever the thread count, as long as surfels are added in the same order.
//
// Memory: the add buffer holds up to bufferCapacityRecords() surfels (kBufferedRecordBytes
// each, counting the sort index) plus a spill write buffer of at most 1 MiB; the merge holds
// one read buffer per run of about budget/(runs+1) bytes (what is left after a few hundred
// bytes of bookkeeping per run), at least kMinMergeBufferBytes. When there are more runs than
// that allows, groups of runs are first merged into bigger runs (a multi-pass merge). When
// every surfel fits in the add buffer, nothing is written to disk. stats() reports the peak
// of these bytes; allocator overhead and file names are not counted.

#include <cstddef>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <string>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/pbgi/surfel.h"

namespace pbgi {

struct SortedSurfel {
  uint64_t key = 0;
  uint64_t sequence = 0;
  Surfel surfel;
};

// Spill files hold records in an explicit little-endian fixed-width layout, never a struct
// image (Surfel has padding): key u64, sequence u64, position 3xf32, normal 3xf32, radius f32,
// albedo 3xf32, radiance 3xf32, back radiance 3xf32, material class u8, triangle u32,
// barycentric 2xf32. Floats are
// stored as their bit patterns, so a record decodes to exactly what was encoded (NaN payloads
// and -0 included).
inline constexpr size_t kSurfelRecordBytes = 93;

void encodeSurfelRecord(const SortedSurfel& record, uint8_t* out);
// Fails (InvalidArgument) on a material class byte that names no MaterialClass.
absl::Status decodeSurfelRecord(const uint8_t* in, SortedSurfel* out);

struct ExternalSortOptions {
  size_t memoryBudgetBytes = size_t{1} << 30;
  // Where spill files go; empty means std::filesystem::temp_directory_path().
  std::string tempDir;
  // Threads for sorting the add buffer; 0 means all that TBB offers. The output does not
  // depend on it.
  int threads = 0;
};

// What the sort did, for logs and tests.
struct SortStats {
  uint64_t records = 0;
  uint64_t bufferCapacityRecords = 0;  // surfels the add buffer holds before it spills
  uint64_t runsSpilled = 0;            // sorted runs written from the add buffer
  uint64_t intermediateMerges = 0;     // runs written by merging runs (multi-pass merge)
  uint64_t finalMergeFanIn = 0;        // runs merged by the final, streaming pass
  uint64_t bytesWritten = 0;
  uint64_t bytesRead = 0;
  uint64_t peakBufferedBytes = 0;  // most bytes of records and I/O buffers held at once

  std::string toString() const;
};

class ExternalSurfelSorter {
 public:
  // The smallest budget that leaves a merge of two runs plus its output their minimum
  // buffers and bookkeeping; smaller budgets make add() and finish() fail with
  // InvalidArgument.
  static constexpr size_t kMinMergeBufferBytes = size_t{64} << 10;
  static constexpr size_t kMinMemoryBudgetBytes = 4 * kMinMergeBufferBytes;
  // Memory per surfel in the add buffer: the surfel, its key, and its 16-byte entry (key and
  // slot) in the sort index.
  static constexpr size_t kBufferedRecordBytes = sizeof(Surfel) + sizeof(uint64_t) + 16;

  // Checks the options without starting a sort, e.g. for a command-line flag.
  static absl::Status validateOptions(const ExternalSortOptions& options);

  explicit ExternalSurfelSorter(ExternalSortOptions options = {});
  // Removes every spill file still on disk, also after an error.
  ~ExternalSurfelSorter();
  ExternalSurfelSorter(const ExternalSurfelSorter&) = delete;
  ExternalSurfelSorter& operator=(const ExternalSurfelSorter&) = delete;

  // Buffers the surfel; when the buffer is full, sorts it and spills it as a run file first.
  // Errors name the file; after one, every later call returns it again.
  absl::Status add(uint64_t key, const Surfel& surfel);
  // After the last add(): sorts what is buffered and, if anything was spilled, spills the rest
  // and merges runs until one streaming pass can merge them all within the budget.
  absl::Status finish();
  // The next surfel in (key, sequence) order; false at the end, when the spill files are
  // removed.
  absl::StatusOr<bool> next(SortedSurfel* out);

  SortStats stats() const;
  size_t bufferCapacityRecords() const;

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pbgi
