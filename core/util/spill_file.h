#pragma once
// A temporary file written once front to back and then read front to back, once or more, through one
// bounded buffer: what the out-of-core build spills between its passes. The file is unlinked
// as soon as it is created, so it never outlives its process, even one killed with -9.
#include <cstddef>
#include <cstdint>
#include <span>
#include <string>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

namespace pbgi {

class SpillFile {
 public:
  // Creates the file in `dir` (empty: the system's temporary folder) with a unique name
  // starting with `prefix`.
  static absl::StatusOr<SpillFile> create(const std::string& dir, const std::string& prefix,
                                          size_t bufferBytes = size_t{1} << 20);
  SpillFile(SpillFile&& o) noexcept;
  SpillFile& operator=(SpillFile&& o) noexcept;
  SpillFile(const SpillFile&) = delete;
  ~SpillFile();

  absl::Status write(std::span<const uint8_t> bytes);
  // Ends writing (the first time); reading starts again at the first byte, as often as wanted.
  absl::Status rewind();
  // Exactly bytes.size() bytes; running out is a DataLoss error naming the file.
  absl::Status read(std::span<uint8_t> bytes);

  uint64_t bytesWritten() const { return written_; }
  const std::string& name() const { return name_; }

 private:
  SpillFile(int fd, std::string name, size_t bufferBytes);
  absl::Status flush();

  int fd_ = -1;
  std::string name_;  // for messages; the file itself is already unlinked
  std::vector<uint8_t> buffer_;
  size_t used_ = 0;    // writing: bytes buffered; reading: bytes consumed
  size_t filled_ = 0;  // reading: bytes in the buffer
  uint64_t written_ = 0;
  bool reading_ = false;
};

}  // namespace pbgi
