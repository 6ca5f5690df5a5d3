#pragma once
// A file sent in chunks over the farm's RPCs (farm.proto: PutFile, GetFile), written once for
// both ends: the sender's chunks with the file's size and XXH3-64, and the receiver that
// writes them beside the final path and renames the file into place only when it arrived
// whole and unchanged, so that a reader never sees a partial or damaged file.
#include <cstdint>
#include <fstream>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "formats/util/atomic_file.h"

struct XXH3_state_s;

namespace pbgi::farm {

inline constexpr size_t kFileChunkBytes = 1 << 20;

// Calls `send(size, data, xxh3)` for each chunk of the file in order (at least one, empty for
// an empty file), reading it once: `size` is the whole file's, and the last chunk carries the
// XXH3-64 of the whole file (nullopt before). Stops, with Cancelled, when `send` returns
// false; DataLoss when the file changed size while it was read.
absl::Status sendFile(
    const std::string& path,
    const std::function<bool(uint64_t size, std::string_view data, std::optional<uint64_t> xxh3)>&
        send);

class FileReceiver {
 public:
  // Ready to receive `size` bytes into `path` (its folder made when missing).
  static absl::StatusOr<FileReceiver> begin(const std::string& path, uint64_t size);
  FileReceiver(FileReceiver&&) noexcept;
  FileReceiver& operator=(FileReceiver&&) noexcept;
  ~FileReceiver();

  // DataLoss when the data runs past the announced size.
  absl::Status add(std::string_view data);
  // Renames the file into place when its size is the announced one and its XXH3-64 is
  // `xxh3` (the sender's, from the last chunk); DataLoss naming the file otherwise (nothing is
  // written then).
  absl::Status finish(uint64_t xxh3);

 private:
  FileReceiver(AtomicFile file, uint64_t size);
  AtomicFile file_;
  uint64_t size_ = 0;
  uint64_t received_ = 0;
  std::unique_ptr<std::ofstream> out_;
  XXH3_state_s* hash_ = nullptr;
};

// Both ends in farm.proto's chunks (PutFileChunk, FileChunk: size in the first, XXH3-64 in the
// last, data in each), written once for the coordinator and the client.
//
// Sends the file at `path` through `write(chunk)` (false: the other end went away), `head`'s
// fields in the first chunk.
template <typename Chunk, typename Write>
absl::Status sendChunks(const std::string& path, const Chunk& head, Write&& write) {
  bool first = true;
  return sendFile(path, [&](uint64_t size, std::string_view data, std::optional<uint64_t> xxh3) {
    Chunk chunk;
    if (first) {
      chunk = head;
      chunk.set_size(size);
      first = false;
    }
    if (xxh3) chunk.set_xxh3(*xxh3);
    chunk.set_data(std::string(data));
    return write(chunk);
  });
}

// Receives into `path` the chunks from `chunk` (the first, already read) on, `next(&chunk)`
// reading each of the others (false: no more); renamed into place only when whole and
// unchanged (FileReceiver).
template <typename Chunk, typename Next>
absl::Status receiveChunks(const std::string& path, Chunk& chunk, Next&& next) {
  absl::StatusOr<FileReceiver> file = FileReceiver::begin(path, chunk.size());
  if (!file.ok()) return file.status();
  uint64_t xxh3 = 0;
  do {
    if (absl::Status s = file->add(chunk.data()); !s.ok()) return s;
    xxh3 = chunk.xxh3();  // the last chunk's counts
  } while (next(&chunk));
  return file->finish(xxh3);
}

}  // namespace pbgi::farm
