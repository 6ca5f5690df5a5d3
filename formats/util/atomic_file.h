#pragma once
// Commit once: every file pbgi writes is written under a temporary name beside its final path,
// flushed to disk and renamed into place, so a reader sees the old file or the whole new one
// and a crash never leaves a truncated file under the final name.

#include <string>

#include <absl/status/statusor.h>

namespace pbgi {

class AtomicFile {
 public:
  // Creates the final path's folder if it is missing and picks a temporary name beside it
  // that no other writer (process or thread) picks. The temporary file is not created here:
  // the caller's writer creates it at tempPath().
  static absl::StatusOr<AtomicFile> begin(const std::string& path);

  AtomicFile(AtomicFile&& other) noexcept;
  AtomicFile& operator=(AtomicFile&& other) noexcept;
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;
  // Removes the temporary unless it was committed.
  ~AtomicFile();

  const std::string& path() const { return path_; }
  const std::string& tempPath() const { return tempPath_; }

  // Flushes the (closed) temporary to disk, renames it over path() and flushes the folder.
  // On failure before the rename the temporary is removed; a failure of the folder flush
  // says the file is in place but the rename may not survive a crash.
  absl::Status commit();
  // Removes the temporary now.
  void discard();

 private:
  AtomicFile(std::string path, std::string tempPath)
      : path_(std::move(path)), tempPath_(std::move(tempPath)) {}

  std::string path_;
  std::string tempPath_;
  bool committed_ = false;
};

}  // namespace pbgi
