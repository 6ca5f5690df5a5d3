#include "core/util/fd_io.h"

#include <unistd.h>

#include <cerrno>

#include <fmt/format.h>

namespace pbgi {

namespace {

// One loop for the four calls: `io(done)` moves bytes from `done` on and returns what
// ::read/::write would. Reads stop at the end of the file; writes never see 0.
template <typename Io>
absl::StatusOr<size_t> loop(size_t size, uint64_t offset, const char* verb, Io io) {
  size_t done = 0;
  while (done < size) {
    const ssize_t n = io(done);
    if (n < 0) {
      if (errno == EINTR) continue;
      return absl::ErrnoToStatus(errno, fmt::format("cannot {} {} bytes at offset {}", verb,
                                                     size - done, offset + done));
    }
    if (n == 0) break;
    done += static_cast<size_t>(n);
  }
  return done;
}

}  // namespace

absl::Status errnoError(int error, const std::string& what, const std::string& name) {
  return absl::ErrnoToStatus(error, fmt::format("{} {}", what, name));
}

absl::Status writeAll(int fd, const uint8_t* data, size_t size) {
  return loop(size, 0, "write",
              [&](size_t done) { return ::write(fd, data + done, size - done); })
      .status();
}

absl::Status pwriteAll(int fd, const uint8_t* data, size_t size, uint64_t offset) {
  return loop(size, offset, "write", [&](size_t done) {
           return ::pwrite(fd, data + done, size - done, static_cast<off_t>(offset + done));
         })
      .status();
}

absl::StatusOr<size_t> readFull(int fd, uint8_t* data, size_t size) {
  return loop(size, 0, "read", [&](size_t done) { return ::read(fd, data + done, size - done); });
}

absl::StatusOr<size_t> preadAll(int fd, uint8_t* data, size_t size, uint64_t offset) {
  return loop(size, offset, "read", [&](size_t done) {
    return ::pread(fd, data + done, size - done, static_cast<off_t>(offset + done));
  });
}

}  // namespace pbgi
