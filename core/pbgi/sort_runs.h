#pragma once
// Private to external_sort.cpp: the memory meter that holds the sort to its budget, and the
// run files (writer, reader, k-way merger) it spills to and merges from.

#include <fcntl.h>
#include <stdlib.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cerrno>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <absl/status/status.h>
#include <fmt/format.h>

#include "core/pbgi/external_sort.h"
#include "core/util/check.h"
#include "core/util/fd_io.h"
#include "core/util/status.h"

namespace pbgi::sort_runs {

// ---- Memory accounting --------------------------------------------------------------------

// Bytes held for records and I/O buffers; every allocation the budget covers goes through here.
class MemoryMeter {
 public:
  void acquire(uint64_t bytes) {
    held_ += bytes;
    peak_ = std::max(peak_, held_);
  }
  void release(uint64_t bytes) {
    PBGI_CHECK_LE(bytes, held_);
    held_ -= bytes;
  }
  uint64_t held() const { return held_; }
  uint64_t peak() const { return peak_; }

 private:
  uint64_t held_ = 0;
  uint64_t peak_ = 0;
};

// A charge against the meter, given back on destruction.
class MeterCharge {
 public:
  MeterCharge() = default;
  MeterCharge(uint64_t bytes, MemoryMeter* meter) : bytes_(bytes), meter_(meter) {
    meter_->acquire(bytes_);
  }
  MeterCharge(MeterCharge&& o) noexcept { *this = std::move(o); }
  MeterCharge& operator=(MeterCharge&& o) noexcept {
    reset();
    bytes_ = std::exchange(o.bytes_, 0);
    meter_ = std::exchange(o.meter_, nullptr);
    return *this;
  }
  ~MeterCharge() { reset(); }
  void reset() {
    if (meter_ != nullptr) meter_->release(bytes_);
    bytes_ = 0;
    meter_ = nullptr;
  }

 private:
  uint64_t bytes_ = 0;
  MemoryMeter* meter_ = nullptr;
};

// A buffer the meter accounts for. Not zero-filled: every byte read from it was first
// written.
class MeteredBuffer {
 public:
  MeteredBuffer() = default;
  MeteredBuffer(size_t bytes, MemoryMeter* meter)
      : data_(new uint8_t[bytes]), bytes_(bytes), charge_(bytes, meter) {}
  void reset() {
    data_.reset();
    bytes_ = 0;
    charge_.reset();
  }
  uint8_t* data() { return data_.get(); }
  size_t size() const { return bytes_; }

 private:
  std::unique_ptr<uint8_t[]> data_;
  size_t bytes_ = 0;
  MeterCharge charge_;
};

// ---- Run files ----------------------------------------------------------------------------

struct Run {
  std::string path;
  uint64_t records = 0;
  uint64_t id = 0;  // creation order; breaks ties when choosing runs to merge
};

class RunWriter {
 public:
  RunWriter(std::string path, size_t bufferBytes, MemoryMeter* meter, uint64_t* bytesWritten)
      : path_(std::move(path)),
        buffer_(bufferBytes / kSurfelRecordBytes * kSurfelRecordBytes, meter),
        bytesWritten_(bytesWritten) {
    PBGI_CHECK_GE(buffer_.size(), kSurfelRecordBytes);
  }
  ~RunWriter() {
    if (fd_ >= 0) ::close(fd_);
  }

  // Creates the file from the path given, a template ending in "XXXXXX.run": mkostemps
  // creates it exclusively under a name no other file has, so neither another sorter nor a
  // file a crashed process left behind with a recycled pid is ever written into.
  absl::Status open() {
    std::string path = path_;
    fd_ = ::mkostemps(path.data(), 4, O_CLOEXEC);
    if (fd_ < 0) return errnoError(errno, "creating sort run file", path_);
    path_ = std::move(path);
    return absl::OkStatus();
  }

  const std::string& path() const { return path_; }

  size_t bufferRecords() const { return buffer_.size() / kSurfelRecordBytes; }

  // Room for n records (n <= bufferRecords()) at the end of the buffer, flushing it first if
  // needed; the caller encodes into it.
  absl::StatusOr<uint8_t*> appendSlots(size_t n) {
    PBGI_CHECK_LE(n, bufferRecords());
    if (used_ + n * kSurfelRecordBytes > buffer_.size()) {
      if (absl::Status s = flush(); !s.ok()) return s;
    }
    uint8_t* slots = buffer_.data() + used_;
    used_ += n * kSurfelRecordBytes;
    records_ += n;
    return slots;
  }

  absl::Status append(const SortedSurfel& record) {
    absl::StatusOr<uint8_t*> slot = appendSlots(1);
    if (!slot.ok()) return slot.status();
    encodeSurfelRecord(record, *slot);
    return absl::OkStatus();
  }

  // Flushes and closes; the run is complete only when this succeeds.
  absl::StatusOr<uint64_t> close() {
    if (absl::Status s = flush(); !s.ok()) return s;
    const int fd = std::exchange(fd_, -1);
    // close() reports delayed write errors (NFS, full disks); they make the run unusable.
    if (::close(fd) != 0) return errnoError(errno, "closing sort run file", path_);
    buffer_.reset();
    return records_;
  }

 private:
  absl::Status flush() {
    if (auto s = writeAll(fd_, buffer_.data(), used_); !s.ok()) {
      return withContext(s, fmt::format("writing sort run file {}", path_));
    }
    *bytesWritten_ += used_;
    used_ = 0;
    return absl::OkStatus();
  }

  std::string path_;
  int fd_ = -1;
  MeteredBuffer buffer_;
  size_t used_ = 0;
  uint64_t records_ = 0;
  uint64_t* bytesWritten_;
};

// Reads a run back one record at a time through a bounded buffer, and checks what it reads:
// the record count the writer reported, the layout, and strictly increasing (key, sequence).
// A run file damaged on disk is an error naming it, never a silently misordered stream.
class RunReader {
 public:
  RunReader(Run run, size_t bufferBytes, MemoryMeter* meter, uint64_t* bytesRead)
      : run_(std::move(run)),
        buffer_(bufferBytes / kSurfelRecordBytes * kSurfelRecordBytes, meter),
        bytesRead_(bytesRead) {
    PBGI_CHECK_GE(buffer_.size(), kSurfelRecordBytes);
  }
  ~RunReader() {
    if (fd_ >= 0) ::close(fd_);
  }

  // Opens the file and loads the first record.
  absl::Status open() {
    fd_ = ::open(run_.path.c_str(), O_RDONLY | O_CLOEXEC);
    if (fd_ < 0) return errnoError(errno, "opening sort run file", run_.path);
#ifdef POSIX_FADV_SEQUENTIAL
    ::posix_fadvise(fd_, 0, 0, POSIX_FADV_SEQUENTIAL);
#endif
    return advance();
  }

  bool valid() const { return valid_; }
  const SortedSurfel& current() const { return current_; }

  absl::Status advance() {
    if (delivered_ == run_.records) {
      valid_ = false;
      return checkAtEnd();
    }
    if (pos_ == filled_) {
      if (absl::Status s = refill(); !s.ok()) return s;
    }
    SortedSurfel next;
    if (absl::Status s = decodeSurfelRecord(buffer_.data() + pos_, &next); !s.ok()) {
      return absl::DataLossError(
          fmt::format("sort run file {}: record {}: {}", run_.path, delivered_, s.message()));
    }
    if (delivered_ > 0 && !(next.key > current_.key ||
                            (next.key == current_.key && next.sequence > current_.sequence))) {
      return absl::DataLossError(fmt::format(
          "sort run file {}: record {} (key {}, sequence {}) does not follow (key {}, sequence "
          "{}): the file is damaged",
          run_.path, delivered_, next.key, next.sequence, current_.key, current_.sequence));
    }
    current_ = next;
    valid_ = true;
    pos_ += kSurfelRecordBytes;
    ++delivered_;
    return absl::OkStatus();
  }

  const std::string& path() const { return run_.path; }

 private:
  absl::Status refill() {
    const uint64_t wantRecords =
        std::min<uint64_t>(buffer_.size() / kSurfelRecordBytes, run_.records - delivered_);
    const size_t want = wantRecords * kSurfelRecordBytes;
    auto read = readFull(fd_, buffer_.data(), want);
    if (!read.ok()) return withContext(read.status(), fmt::format("reading sort run file {}", run_.path));
    const size_t got = *read;
    if (got < want) {
      return absl::DataLossError(fmt::format(
          "sort run file {} is truncated: expected {} records ({} bytes), it ends at byte {}",
          run_.path, run_.records, run_.records * kSurfelRecordBytes,
          delivered_ * kSurfelRecordBytes + got));
    }
    *bytesRead_ += got;
    pos_ = 0;
    filled_ = got;
    return absl::OkStatus();
  }

  absl::Status checkAtEnd() {
    uint8_t extra;
    auto n = readFull(fd_, &extra, 1);
    if (!n.ok()) return withContext(n.status(), fmt::format("reading sort run file {}", run_.path));
    if (*n > 0) {
      return absl::DataLossError(
          fmt::format("sort run file {} is longer than the {} records ({} bytes) written to it",
                      run_.path, run_.records, run_.records * kSurfelRecordBytes));
    }
    return absl::OkStatus();
  }

  Run run_;
  int fd_ = -1;
  MeteredBuffer buffer_;
  size_t pos_ = 0;
  size_t filled_ = 0;
  uint64_t delivered_ = 0;
  SortedSurfel current_;
  bool valid_ = false;
  uint64_t* bytesRead_;
};

// Bookkeeping per merged run besides its read buffer: its reader (with the current record)
// and its heap entry. Counted against the budget so that the budget holds exactly.
struct HeapItem {
  uint64_t key;
  uint64_t sequence;
  uint32_t run;
};
constexpr size_t kMergeOverheadPerRun =
    sizeof(RunReader) + sizeof(std::unique_ptr<RunReader>) + sizeof(HeapItem);
// The minimum budget must allow a two-way merge with minimum buffers.
static_assert((ExternalSurfelSorter::kMinMemoryBudgetBytes -
               ExternalSurfelSorter::kMinMergeBufferBytes) /
                  (ExternalSurfelSorter::kMinMergeBufferBytes + kMergeOverheadPerRun) >=
              2);

// Later in (key, sequence, run) order: the heap's comparator, so its top is the smallest.
// A function object so that the heap operations inline it.
struct HeapAfter {
  bool operator()(const HeapItem& a, const HeapItem& b) const {
    if (a.key != b.key) return a.key > b.key;
    if (a.sequence != b.sequence) return a.sequence > b.sequence;
    return a.run > b.run;
  }
};

// k-way merge of runs through a binary heap of their current records.
class RunMerger {
 public:
  // Read buffers of bufferBytes each, plus the bookkeeping, all charged to meter.
  absl::Status open(const std::vector<Run>& runs, size_t bufferBytes, MemoryMeter* meter,
                    uint64_t* bytesRead) {
    overhead_ = MeterCharge(runs.size() * kMergeOverheadPerRun, meter);
    readers_.reserve(runs.size());
    heap_.reserve(runs.size());
    for (const Run& run : runs) {
      readers_.push_back(std::make_unique<RunReader>(run, bufferBytes, meter, bytesRead));
      RunReader& reader = *readers_.back();
      if (absl::Status s = reader.open(); !s.ok()) return s;
      if (reader.valid()) {
        heap_.push_back({reader.current().key, reader.current().sequence,
                         static_cast<uint32_t>(readers_.size() - 1)});
      }
    }
    std::make_heap(heap_.begin(), heap_.end(), HeapAfter());
    return absl::OkStatus();
  }

  absl::StatusOr<bool> next(SortedSurfel* out) {
    if (heap_.empty()) return false;
    std::pop_heap(heap_.begin(), heap_.end(), HeapAfter());
    RunReader& reader = *readers_[heap_.back().run];
    *out = reader.current();
    if (absl::Status s = reader.advance(); !s.ok()) return s;
    if (reader.valid()) {
      heap_.back().key = reader.current().key;
      heap_.back().sequence = reader.current().sequence;
      std::push_heap(heap_.begin(), heap_.end(), HeapAfter());
    } else {
      heap_.pop_back();
    }
    return true;
  }

  // Closes the files and gives the buffers back.
  void close() {
    readers_.clear();
    heap_.clear();
    overhead_.reset();
  }

 private:
  std::vector<std::unique_ptr<RunReader>> readers_;
  std::vector<HeapItem> heap_;
  MeterCharge overhead_;  // readers_ and heap_
};

}  // namespace pbgi::sort_runs
