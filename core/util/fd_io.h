#pragma once
// Whole reads and writes on file descriptors: the retry loops (short counts, EINTR) that
// every file pbgi writes itself needs, in one place. Errors carry errno and the byte counts;
// callers add the file's name.
#include <cstddef>
#include <cstdint>
#include <string>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

namespace pbgi {

// errno as a Status: "<what> <name>: <strerror>".
absl::Status errnoError(int error, const std::string& what, const std::string& name);

// Writes all `size` bytes at the file position.
absl::Status writeAll(int fd, const uint8_t* data, size_t size);
// Writes all `size` bytes at `offset`.
absl::Status pwriteAll(int fd, const uint8_t* data, size_t size, uint64_t offset);
// Reads up to `size` bytes from the file position; fewer only at the end of the file.
absl::StatusOr<size_t> readFull(int fd, uint8_t* data, size_t size);
// Reads up to `size` bytes at `offset`; fewer only at the end of the file.
absl::StatusOr<size_t> preadAll(int fd, uint8_t* data, size_t size, uint64_t offset);

}  // namespace pbgi
