#include "core/pbgi/external_sort.h"

#include <fcntl.h>
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <bit>
#include <cerrno>
#include <limits>
#include <vector>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>
#include <tbb/parallel_sort.h>
#include <tbb/task_arena.h>

#include "core/pbgi/sort_runs.h"
#include "core/util/bytes.h"
#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi {
namespace {

using namespace sort_runs;

// ---- Record layout ------------------------------------------------------------------------

void putVec3(uint8_t* p, const Vec3f& v) {
  storeF32(p, v.x);
  storeF32(p + 4, v.y);
  storeF32(p + 8, v.z);
}
Vec3f getVec3(const uint8_t* p) { return {loadF32(p), loadF32(p + 4), loadF32(p + 8)}; }

// Byte offsets of the fields; the last one is the record size.
constexpr size_t kOffKey = 0, kOffSequence = 8, kOffPosition = 16, kOffNormal = 28, kOffRadius = 40,
                 kOffAlbedo = 44, kOffRadiance = 56, kOffBackRadiance = 68, kOffMaterial = 80,
                 kOffTriangle = 81, kOffBarycentric = 85, kOffEnd = 93;
static_assert(kOffEnd == kSurfelRecordBytes);


std::atomic<uint64_t> gSorterCounter{0};

// The sort index: the key copied next to the buffer slot so that sorting touches 16 bytes
// per surfel instead of the whole surfel.
struct SortEntry {
  uint64_t key;
  uint32_t slot;  // add order within the buffer, so (key, slot) orders like (key, sequence)
};
static_assert(sizeof(SortEntry) == 16);
static_assert(ExternalSurfelSorter::kBufferedRecordBytes ==
              sizeof(Surfel) + sizeof(uint64_t) + sizeof(SortEntry));

// A function object rather than a function pointer, so that the sorts inline it.
struct EntryBefore {
  bool operator()(const SortEntry& a, const SortEntry& b) const {
    return a.key != b.key ? a.key < b.key : a.slot < b.slot;
  }
};

// How many entries ahead of the one being copied to prefetch its surfel: the copy in key
// order is a random gather over the whole buffer, bound by cache misses otherwise.
constexpr size_t kPrefetchDistance = 16;

// Add-buffer chunks: the buffer grows chunk by chunk up to its capacity, so a small sort
// never holds the whole budget and growing never copies (a doubling vector would hold three
// times its contents while it moves them).
constexpr size_t kChunkRecords = 16384;

}  // namespace

// ---- Record encoding ----------------------------------------------------------------------

void encodeSurfelRecord(const SortedSurfel& r, uint8_t* out) {
  const Surfel& s = r.surfel;
  storeU64(out + kOffKey, r.key);
  storeU64(out + kOffSequence, r.sequence);
  putVec3(out + kOffPosition, s.position);
  putVec3(out + kOffNormal, s.normal);
  storeF32(out + kOffRadius, s.radius);
  putVec3(out + kOffAlbedo, s.albedo);
  putVec3(out + kOffRadiance, s.radiance);
  putVec3(out + kOffBackRadiance, s.backRadiance);
  out[kOffMaterial] = static_cast<uint8_t>(s.materialClass);
  storeU32(out + kOffTriangle, s.triangle);
  storeF32(out + kOffBarycentric, s.barycentric.x);
  storeF32(out + kOffBarycentric + 4, s.barycentric.y);
}

absl::Status decodeSurfelRecord(const uint8_t* in, SortedSurfel* out) {
  const uint8_t material = in[kOffMaterial];
  if (material > static_cast<uint8_t>(MaterialClass::kEmissive)) {
    return absl::InvalidArgumentError(
        fmt::format("material class byte {} names no material class (0 to {})", material,
                    static_cast<int>(MaterialClass::kEmissive)));
  }
  out->key = loadU64(in + kOffKey);
  out->sequence = loadU64(in + kOffSequence);
  Surfel& s = out->surfel;
  s.position = getVec3(in + kOffPosition);
  s.normal = getVec3(in + kOffNormal);
  s.radius = loadF32(in + kOffRadius);
  s.albedo = getVec3(in + kOffAlbedo);
  s.radiance = getVec3(in + kOffRadiance);
  s.backRadiance = getVec3(in + kOffBackRadiance);
  s.materialClass = static_cast<MaterialClass>(material);
  s.triangle = loadU32(in + kOffTriangle);
  s.barycentric = Vec2f(loadF32(in + kOffBarycentric), loadF32(in + kOffBarycentric + 4));
  return absl::OkStatus();
}

std::string SortStats::toString() const {
  return fmt::format(
      "records={} buffer_capacity={} runs_spilled={} intermediate_merges={} final_fan_in={} "
      "bytes_written={} bytes_read={} peak_buffered_bytes={}",
      records, bufferCapacityRecords, runsSpilled, intermediateMerges, finalMergeFanIn,
      bytesWritten, bytesRead, peakBufferedBytes);
}

// ---- The sorter ---------------------------------------------------------------------------

class ExternalSurfelSorter::Impl {
 public:
  explicit Impl(ExternalSortOptions options)
      : options_(std::move(options)),
        status_(validateOptions(options_)),
        sorterId_(gSorterCounter.fetch_add(1)),
        arena_(options_.threads > 0 ? options_.threads : tbb::task_arena::automatic) {
    if (!status_.ok()) return;
    const size_t budget = options_.memoryBudgetBytes;
    // The spill write buffer: large enough for efficient writes, small against the budget.
    spillBufferBytes_ =
        std::min<size_t>(size_t{1} << 20, budget / 8) / kSurfelRecordBytes * kSurfelRecordBytes;
    capacity_ = std::min<size_t>((budget - spillBufferBytes_) / kBufferedRecordBytes,
                                 std::numeric_limits<uint32_t>::max());
    PBGI_CHECK_GT(capacity_, 0u);
    // The largest merge fan-in whose read buffers stay at kMinMergeBufferBytes or more, with
    // one more buffer's worth for the output of an intermediate merge.
    maxFanIn_ = (budget - kMinMergeBufferBytes) / (kMinMergeBufferBytes + kMergeOverheadPerRun);
    PBGI_CHECK_GE(maxFanIn_, 2u);
  }

  ~Impl() { removeAllFiles(); }

  absl::Status add(uint64_t key, const Surfel& surfel) {
    PBGI_CHECK(phase_ == Phase::kAdding);
    if (!status_.ok()) return status_;
    if (buffered_ == capacity_) {
      if (absl::Status s = spill(); !s.ok()) return fail(s);
    }
    const size_t chunk = buffered_ / kChunkRecords;
    if (chunk == surfelChunks_.size()) {
      const size_t n = std::min(kChunkRecords, capacity_ - buffered_);
      surfelChunks_.push_back(std::make_unique<Surfel[]>(n));
      keyChunks_.push_back(std::make_unique<uint64_t[]>(n));
      chunkSizes_.push_back(n);
      meter_.acquire(n * (sizeof(Surfel) + sizeof(uint64_t)));
    }
    const size_t slot = buffered_ % kChunkRecords;
    surfelChunks_[chunk][slot] = surfel;
    keyChunks_[chunk][slot] = key;
    ++buffered_;
    ++records_;
    return absl::OkStatus();
  }

  absl::Status finish() {
    PBGI_CHECK(phase_ == Phase::kAdding);
    if (!status_.ok()) return status_;
    if (runs_.empty()) {
      // Everything fit: sort in memory and stream from the buffer; no file is written.
      sortBuffer();
      phase_ = Phase::kInCore;
      return absl::OkStatus();
    }
    if (buffered_ > 0) {
      if (absl::Status s = spill(); !s.ok()) return fail(s);
    }
    releaseAddBuffer();
    while (runs_.size() > maxFanIn_) {
      if (absl::Status s = mergeSmallestRuns(); !s.ok()) return fail(s);
    }
    finalFanIn_ = runs_.size();
    if (absl::Status s = merger_.open(runs_, mergeBufferBytes(runs_.size()), &meter_, &bytesRead_);
        !s.ok()) {
      return fail(s);
    }
    phase_ = Phase::kMerging;
    return absl::OkStatus();
  }

  absl::StatusOr<bool> next(SortedSurfel* out) {
    PBGI_CHECK(phase_ != Phase::kAdding);
    if (!status_.ok()) return status_;
    if (phase_ == Phase::kInCore) {
      if (streamed_ == entries_.size()) return endStream();
      if (streamed_ + kPrefetchDistance < entries_.size()) {
        __builtin_prefetch(&bufferedSurfel(entries_[streamed_ + kPrefetchDistance].slot));
      }
      const SortEntry& e = entries_[streamed_++];
      out->key = e.key;
      out->sequence = bufferBaseSequence_ + e.slot;
      out->surfel = bufferedSurfel(e.slot);
      return true;
    }
    if (phase_ == Phase::kMerging) {
      absl::StatusOr<bool> more = merger_.next(out);
      if (!more.ok()) return fail(more.status());
      if (*more) {
        ++streamed_;
        return true;
      }
      if (streamed_ != records_) {
        return fail(absl::DataLossError(fmt::format(
            "external sort: {} records were added but the merge yielded {}", records_, streamed_)));
      }
      return endStream();
    }
    return false;
  }

  SortStats stats() const {
    SortStats s;
    s.records = records_;
    s.bufferCapacityRecords = capacity_;
    s.runsSpilled = runsSpilled_;
    s.intermediateMerges = intermediateMerges_;
    s.finalMergeFanIn = finalFanIn_;
    s.bytesWritten = bytesWritten_;
    s.bytesRead = bytesRead_;
    s.peakBufferedBytes = meter_.peak();
    return s;
  }

  size_t bufferCapacityRecords() const { return capacity_; }

 private:
  enum class Phase { kAdding, kInCore, kMerging, kDone };

  absl::Status fail(absl::Status s) {
    status_ = s;
    // Nothing more will be read; the files go now rather than at destruction.
    removeAllFiles();
    return s;
  }

  bool endStream() {
    removeAllFiles();
    releaseAddBuffer();
    phase_ = Phase::kDone;
    return false;
  }

  void removeFile(const std::string& path) {
    std::error_code ec;
    std::filesystem::remove(path, ec);  // best effort: an error path must not throw
    std::erase(files_, path);
  }

  void removeAllFiles() {
    merger_.close();
    runs_.clear();
    for (const std::string& path : std::exchange(files_, {})) {
      std::error_code ec;
      std::filesystem::remove(path, ec);
    }
  }

  // A new run's id and file name template: pid, sorter and run id say who made it, the
  // XXXXXX that RunWriter::open() fills in makes it unique.
  Run newRun(uint64_t records) {
    std::filesystem::path dir = options_.tempDir;
    if (dir.empty()) {
      std::error_code ec;
      dir = std::filesystem::temp_directory_path(ec);
      if (ec) dir = "/tmp";
    }
    const uint64_t id = nextRunId_++;
    return Run{
        (dir / fmt::format("pbgi-sort-{}-{}-{}-XXXXXX.run", ::getpid(), sorterId_, id)).string(),
        records, id};
  }

  // Creates the run's file; from here on this sorter removes it whatever happens.
  absl::Status createRunFile(RunWriter* writer, Run* run) {
    if (absl::Status s = writer->open(); !s.ok()) return s;
    run->path = writer->path();
    files_.push_back(run->path);
    return absl::OkStatus();
  }

  void sortBuffer() {
    if (entries_.capacity() < buffered_) {
      meter_.release(entries_.capacity() * sizeof(SortEntry));
      std::vector<SortEntry>().swap(entries_);
      entries_.reserve(buffered_);
      meter_.acquire(entries_.capacity() * sizeof(SortEntry));
    }
    entries_.resize(buffered_);
    for (size_t i = 0; i < buffered_; ++i) {
      entries_[i] = {keyChunks_[i / kChunkRecords][i % kChunkRecords], static_cast<uint32_t>(i)};
    }
    // (key, slot) pairs are unique, so every sort algorithm, serial or parallel, gives the
    // same order: this is what makes the output independent of the thread count.
    if (options_.threads == 1) {
      std::sort(entries_.begin(), entries_.end(), EntryBefore());
    } else {
      arena_.execute([&] { tbb::parallel_sort(entries_.begin(), entries_.end(), EntryBefore()); });
    }
  }

  // Sorts the buffer and writes it as a run; the buffer is then empty.
  absl::Status spill() {
    sortBuffer();
    Run run = newRun(buffered_);
    RunWriter writer(run.path, spillBufferBytes_, &meter_, &bytesWritten_);
    if (absl::Status s = createRunFile(&writer, &run); !s.ok()) return s;
    const size_t block = writer.bufferRecords();
    for (size_t begin = 0; begin < buffered_; begin += block) {
      const size_t n = std::min(block, buffered_ - begin);
      absl::StatusOr<uint8_t*> slots = writer.appendSlots(n);
      if (!slots.ok()) return slots.status();
      auto encode = [&](size_t from, size_t to) {
        for (size_t i = from; i < to; ++i) {
          if (begin + i + kPrefetchDistance < buffered_) {
            __builtin_prefetch(&bufferedSurfel(entries_[begin + i + kPrefetchDistance].slot));
          }
          const SortEntry& e = entries_[begin + i];
          encodeSurfelRecord({e.key, bufferBaseSequence_ + e.slot, bufferedSurfel(e.slot)},
                             *slots + i * kSurfelRecordBytes);
        }
      };
      // Gathering surfels in key order is cache-missy, so it is worth threads; every thread
      // writes its own byte range, so the bytes do not depend on how the range is split.
      if (options_.threads == 1) {
        encode(0, n);
      } else {
        arena_.execute([&] {
          tbb::parallel_for(
              tbb::blocked_range<size_t>(0, n, 1024),
              [&](const tbb::blocked_range<size_t>& r) { encode(r.begin(), r.end()); });
        });
      }
    }
    absl::StatusOr<uint64_t> written = writer.close();
    if (!written.ok()) return written.status();
    PBGI_CHECK_EQ(*written, run.records);
    runs_.push_back(std::move(run));
    ++runsSpilled_;
    bufferBaseSequence_ += buffered_;
    buffered_ = 0;
    return absl::OkStatus();
  }

  const Surfel& bufferedSurfel(size_t slot) const {
    return surfelChunks_[slot / kChunkRecords][slot % kChunkRecords];
  }

  void releaseAddBuffer() {
    for (size_t n : chunkSizes_) meter_.release(n * (sizeof(Surfel) + sizeof(uint64_t)));
    surfelChunks_.clear();
    keyChunks_.clear();
    chunkSizes_.clear();
    meter_.release(entries_.capacity() * sizeof(SortEntry));
    std::vector<SortEntry>().swap(entries_);
    buffered_ = 0;
  }

  // Read (and write) buffer size for a merge of k runs: the budget split k + 1 ways after
  // the bookkeeping. maxFanIn_ guarantees at least kMinMergeBufferBytes.
  size_t mergeBufferBytes(size_t k) const {
    const size_t bytes = (options_.memoryBudgetBytes - k * kMergeOverheadPerRun) / (k + 1);
    PBGI_CHECK_GE(bytes, kMinMergeBufferBytes);
    return bytes;
  }

  // One intermediate merge, smallest runs first (an F-ary Huffman merge): the first merge
  // takes just enough runs that every later merge, the final one included, is full, which
  // rereads the fewest bytes. Any grouping gives the same final stream, since the order of
  // (key, sequence) is total.
  absl::Status mergeSmallestRuns() {
    const size_t f = maxFanIn_;
    const size_t k = intermediateMerges_ == 0 ? (runs_.size() - 2) % (f - 1) + 2 : f;
    std::sort(runs_.begin(), runs_.end(), [](const Run& a, const Run& b) {
      return a.records != b.records ? a.records < b.records : a.id < b.id;
    });
    std::vector<Run> inputs(runs_.begin(), runs_.begin() + k);
    runs_.erase(runs_.begin(), runs_.begin() + k);

    const size_t bufferBytes = mergeBufferBytes(k);
    RunMerger merger;
    if (absl::Status s = merger.open(inputs, bufferBytes, &meter_, &bytesRead_); !s.ok()) {
      return s;
    }
    uint64_t total = 0;
    for (const Run& r : inputs) total += r.records;
    Run out = newRun(total);
    RunWriter writer(out.path, bufferBytes, &meter_, &bytesWritten_);
    if (absl::Status s = createRunFile(&writer, &out); !s.ok()) return s;
    SortedSurfel record;
    while (true) {
      absl::StatusOr<bool> more = merger.next(&record);
      if (!more.ok()) return more.status();
      if (!*more) break;
      if (absl::Status s = writer.append(record); !s.ok()) return s;
    }
    merger.close();
    absl::StatusOr<uint64_t> written = writer.close();
    if (!written.ok()) return written.status();
    if (*written != total) {
      return absl::DataLossError(fmt::format(
          "merging sort runs into {}: read {} records, {} expected", out.path, *written, total));
    }
    for (const Run& r : inputs) removeFile(r.path);
    runs_.push_back(std::move(out));
    ++intermediateMerges_;
    return absl::OkStatus();
  }

  ExternalSortOptions options_;
  absl::Status status_;  // the first error; every later call returns it
  uint64_t sorterId_;
  tbb::task_arena arena_;
  Phase phase_ = Phase::kAdding;

  size_t spillBufferBytes_ = 0;
  size_t capacity_ = 0;
  size_t maxFanIn_ = 0;
  MemoryMeter meter_;

  // The add buffer.
  std::vector<std::unique_ptr<Surfel[]>> surfelChunks_;
  std::vector<std::unique_ptr<uint64_t[]>> keyChunks_;
  std::vector<size_t> chunkSizes_;
  std::vector<SortEntry> entries_;
  size_t buffered_ = 0;
  uint64_t bufferBaseSequence_ = 0;  // sequence of slot 0

  // Complete runs not yet merged, and every file this sorter created and has not removed
  // (complete or not), so that none outlives it.
  std::vector<Run> runs_;
  std::vector<std::string> files_;
  uint64_t nextRunId_ = 0;
  RunMerger merger_;

  uint64_t records_ = 0;
  uint64_t streamed_ = 0;
  uint64_t runsSpilled_ = 0;
  uint64_t intermediateMerges_ = 0;
  uint64_t finalFanIn_ = 0;
  uint64_t bytesWritten_ = 0;
  uint64_t bytesRead_ = 0;
};

absl::Status ExternalSurfelSorter::validateOptions(const ExternalSortOptions& options) {
  if (options.memoryBudgetBytes < kMinMemoryBudgetBytes) {
    return absl::InvalidArgumentError(
        fmt::format("external sort: a memory budget of {} bytes is below the minimum of {} "
                    "bytes (a two-way merge with its minimum buffers)",
                    options.memoryBudgetBytes, kMinMemoryBudgetBytes));
  }
  if (options.threads < 0) {
    return absl::InvalidArgumentError(
        fmt::format("external sort: threads must be 0 (all) or more, got {}", options.threads));
  }
  return absl::OkStatus();
}

ExternalSurfelSorter::ExternalSurfelSorter(ExternalSortOptions options)
    : impl_(std::make_unique<Impl>(std::move(options))) {}
ExternalSurfelSorter::~ExternalSurfelSorter() = default;

absl::Status ExternalSurfelSorter::add(uint64_t key, const Surfel& surfel) {
  return impl_->add(key, surfel);
}
absl::Status ExternalSurfelSorter::finish() { return impl_->finish(); }
absl::StatusOr<bool> ExternalSurfelSorter::next(SortedSurfel* out) { return impl_->next(out); }
SortStats ExternalSurfelSorter::stats() const { return impl_->stats(); }
size_t ExternalSurfelSorter::bufferCapacityRecords() const {
  return impl_->bufferCapacityRecords();
}

}  // namespace pbgi
