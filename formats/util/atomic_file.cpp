#include "formats/util/atomic_file.h"

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <filesystem>
#include <random>

#include <fmt/format.h>

namespace pbgi {

namespace fs = std::filesystem;

namespace {

// fsync of a file or folder by name.
int syncPath(const std::string& path, int flags) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC | flags);
  if (fd < 0) return errno;
  const int error = ::fsync(fd) != 0 ? errno : 0;
  ::close(fd);
  return error;
}

}  // namespace

absl::StatusOr<AtomicFile> AtomicFile::begin(const std::string& path) {
  if (path.empty()) return absl::InvalidArgumentError("empty output path");
  const fs::path parent = fs::path(path).parent_path();
  if (!parent.empty()) {
    std::error_code ec;
    fs::create_directories(parent, ec);
    if (ec) {
      return absl::ErrnoToStatus(ec.value(),
                                 fmt::format("{}: cannot create folder {}", path, parent.string()));
    }
  }
  thread_local std::mt19937_64 rng{std::random_device{}()};
  return AtomicFile(path, fmt::format("{}.tmp-{}-{:016x}", path, ::getpid(), rng()));
}

AtomicFile::AtomicFile(AtomicFile&& other) noexcept
    : path_(std::move(other.path_)), tempPath_(std::move(other.tempPath_)),
      committed_(other.committed_) {
  other.tempPath_.clear();
}

AtomicFile& AtomicFile::operator=(AtomicFile&& other) noexcept {
  if (this != &other) {
    discard();
    path_ = std::move(other.path_);
    tempPath_ = std::move(other.tempPath_);
    committed_ = other.committed_;
    other.tempPath_.clear();
  }
  return *this;
}

AtomicFile::~AtomicFile() { discard(); }

void AtomicFile::discard() {
  if (!committed_ && !tempPath_.empty()) ::unlink(tempPath_.c_str());
  tempPath_.clear();
}

absl::Status AtomicFile::commit() {
  if (committed_ || tempPath_.empty()) {
    return absl::FailedPreconditionError(fmt::format("{}: nothing to commit", path_));
  }
  if (const int error = syncPath(tempPath_, 0); error != 0) {
    const std::string tmp = tempPath_;
    discard();
    return absl::ErrnoToStatus(error, fmt::format("{}: cannot flush {}", path_, tmp));
  }
  if (::rename(tempPath_.c_str(), path_.c_str()) != 0) {
    const int error = errno;
    const std::string tmp = tempPath_;
    discard();
    return absl::ErrnoToStatus(error, fmt::format("{}: cannot rename {} into place", path_, tmp));
  }
  committed_ = true;
  tempPath_.clear();
  const fs::path parent = fs::path(path_).parent_path();
  const std::string folder = parent.empty() ? std::string(".") : parent.string();
  if (const int error = syncPath(folder, O_DIRECTORY); error != 0) {
    return absl::ErrnoToStatus(
        error, fmt::format("{}: written and renamed into place, but flushing the folder {} "
                           "failed, so the rename may not survive a crash",
                           path_, folder));
  }
  return absl::OkStatus();
}

}  // namespace pbgi
