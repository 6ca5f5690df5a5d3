#pragma once
// A file sent in chunks over the farm's RPCs (farm.proto: PutFile, GetFile), written once for
// both ends: the sender's chunks with the file's size and XXH3-64, and the receiver that
// writes them beside the final path and renames the file into place only when it arrived
// whole and unchanged, so that a reader never sees a partial or damaged file.
#include <cstdint>
#include <fstream>
#include <functional>
#include <memory>
#include <string>
#include <string_view>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "formats/util/atomic_file.h"

struct XXH3_state_s;

namespace pbgi::farm {

inline constexpr size_t kFileChunkBytes = 1 << 20;

struct FileDigest {
  uint64_t size = 0;
  uint64_t xxh3 = 0;
};
// The file's size and XXH3-64 (NotFound naming it when it cannot be read).
absl::StatusOr<FileDigest> digestFile(const std::string& path);

// Calls `send(digest, data)` for each chunk of the file in order (at least one, empty for an
// empty file); stops, with Cancelled, when `send` returns false.
absl::Status sendFile(const std::string& path,
                      const std::function<bool(const FileDigest&, std::string_view)>& send);

class FileReceiver {
 public:
  // Ready to receive `expected` into `path` (its folder made when missing).
  static absl::StatusOr<FileReceiver> begin(const std::string& path, FileDigest expected);
  FileReceiver(FileReceiver&&) noexcept;
  FileReceiver& operator=(FileReceiver&&) noexcept;
  ~FileReceiver();

  // DataLoss when the data runs past the announced size.
  absl::Status add(std::string_view data);
  // Renames the file into place when its size and hash are the announced ones; DataLoss
  // naming the file otherwise (nothing is written then).
  absl::Status finish();

 private:
  FileReceiver(AtomicFile file, FileDigest expected);
  AtomicFile file_;
  FileDigest expected_;
  uint64_t received_ = 0;
  std::unique_ptr<std::ofstream> out_;
  XXH3_state_s* hash_ = nullptr;
};

}  // namespace pbgi::farm
