#include "core/util/spill_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <filesystem>
#include <utility>

#include <fmt/format.h>

#include "core/util/check.h"
#include "core/util/fd_io.h"
#include "core/util/status.h"

namespace pbgi {

absl::StatusOr<SpillFile> SpillFile::create(const std::string& dir, const std::string& prefix,
                                            size_t bufferBytes) {
  std::filesystem::path folder = dir;
  if (folder.empty()) {
    std::error_code ec;
    folder = std::filesystem::temp_directory_path(ec);
    if (ec) folder = "/tmp";
  }
  std::string path = (folder / fmt::format("{}-{}-XXXXXX", prefix, ::getpid())).string();
  const int fd = ::mkostemp(path.data(), O_CLOEXEC);
  if (fd < 0) return errnoError(errno, "creating spill file in", folder.string());
  ::unlink(path.c_str());
  return SpillFile(fd, path, std::max<size_t>(bufferBytes, 4096));
}

SpillFile::SpillFile(int fd, std::string name, size_t bufferBytes)
    : fd_(fd), name_(std::move(name)), buffer_(bufferBytes) {}

SpillFile::SpillFile(SpillFile&& o) noexcept { *this = std::move(o); }

SpillFile& SpillFile::operator=(SpillFile&& o) noexcept {
  if (this != &o) {
    if (fd_ >= 0) ::close(fd_);
    fd_ = std::exchange(o.fd_, -1);
    name_ = std::move(o.name_);
    buffer_ = std::move(o.buffer_);
    used_ = o.used_;
    filled_ = o.filled_;
    written_ = o.written_;
    reading_ = o.reading_;
  }
  return *this;
}

SpillFile::~SpillFile() {
  if (fd_ >= 0) ::close(fd_);
}

absl::Status SpillFile::flush() {
  if (auto s = writeAll(fd_, buffer_.data(), used_); !s.ok()) {
    return withContext(s, fmt::format("spill file {}", name_));
  }
  used_ = 0;
  return absl::OkStatus();
}

absl::Status SpillFile::write(std::span<const uint8_t> bytes) {
  PBGI_CHECK(!reading_);
  while (!bytes.empty()) {
    if (used_ == buffer_.size()) {
      if (auto s = flush(); !s.ok()) return s;
    }
    const size_t n = std::min(bytes.size(), buffer_.size() - used_);
    std::memcpy(buffer_.data() + used_, bytes.data(), n);
    used_ += n;
    written_ += n;
    bytes = bytes.subspan(n);
  }
  return absl::OkStatus();
}

absl::Status SpillFile::rewind() {
  if (!reading_) {
    if (auto s = flush(); !s.ok()) return s;
  }
  if (::lseek(fd_, 0, SEEK_SET) != 0) return errnoError(errno, "rewinding spill file", name_);
#ifdef POSIX_FADV_SEQUENTIAL
  ::posix_fadvise(fd_, 0, 0, POSIX_FADV_SEQUENTIAL);
#endif
  reading_ = true;
  used_ = filled_ = 0;
  return absl::OkStatus();
}

absl::Status SpillFile::read(std::span<uint8_t> bytes) {
  PBGI_CHECK(reading_);
  while (!bytes.empty()) {
    if (used_ == filled_) {
      auto n = readFull(fd_, buffer_.data(), buffer_.size());
      if (!n.ok()) return withContext(n.status(), fmt::format("spill file {}", name_));
      if (*n == 0) {
        return absl::DataLossError(
            fmt::format("spill file {} ended {} bytes early", name_, bytes.size()));
      }
      used_ = 0;
      filled_ = *n;
    }
    const size_t n = std::min(bytes.size(), filled_ - used_);
    std::memcpy(bytes.data(), buffer_.data() + used_, n);
    used_ += n;
    bytes = bytes.subspan(n);
  }
  return absl::OkStatus();
}

}  // namespace pbgi
