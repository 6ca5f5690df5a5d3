#include "services/coordinator/file_transfer.h"

#include <vector>

#include <fmt/format.h>
#include <xxhash.h>

#include "core/util/status.h"

namespace pbgi::farm {

absl::StatusOr<FileDigest> digestFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(fmt::format("{}: cannot read it", path));
  XXH3_state_t* state = XXH3_createState();
  XXH3_64bits_reset(state);
  std::vector<char> buffer(kFileChunkBytes);
  FileDigest digest;
  while (in) {
    in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    const auto n = static_cast<size_t>(in.gcount());
    XXH3_64bits_update(state, buffer.data(), n);
    digest.size += n;
  }
  const bool failed = in.bad();
  digest.xxh3 = XXH3_64bits_digest(state);
  XXH3_freeState(state);
  if (failed) return absl::DataLossError(fmt::format("{}: reading it failed", path));
  return digest;
}

absl::Status sendFile(const std::string& path,
                      const std::function<bool(const FileDigest&, std::string_view)>& send) {
  PBGI_ASSIGN_OR_RETURN(const FileDigest digest, digestFile(path));
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(fmt::format("{}: cannot read it", path));
  std::vector<char> buffer(kFileChunkBytes);
  uint64_t sent = 0;
  do {
    in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    const auto n = static_cast<size_t>(in.gcount());
    if (!send(digest, std::string_view(buffer.data(), n))) {
      return absl::CancelledError(fmt::format("{}: the other end stopped reading", path));
    }
    sent += n;
  } while (in && sent < digest.size);
  if (sent != digest.size) {
    return absl::DataLossError(
        fmt::format("{}: changed while it was sent ({} of {} bytes)", path, sent, digest.size));
  }
  return absl::OkStatus();
}

absl::StatusOr<FileReceiver> FileReceiver::begin(const std::string& path, FileDigest expected) {
  PBGI_ASSIGN_OR_RETURN(AtomicFile file, AtomicFile::begin(path));
  FileReceiver r(std::move(file), expected);
  r.out_ = std::make_unique<std::ofstream>(r.file_.tempPath(), std::ios::binary);
  if (!*r.out_) {
    return absl::UnavailableError(fmt::format("{}: cannot write {}", path, r.file_.tempPath()));
  }
  return r;
}

FileReceiver::FileReceiver(AtomicFile file, FileDigest expected)
    : file_(std::move(file)), expected_(expected), hash_(XXH3_createState()) {
  XXH3_64bits_reset(hash_);
}

FileReceiver::FileReceiver(FileReceiver&& o) noexcept
    : file_(std::move(o.file_)),
      expected_(o.expected_),
      received_(o.received_),
      out_(std::move(o.out_)),
      hash_(std::exchange(o.hash_, nullptr)) {}

FileReceiver& FileReceiver::operator=(FileReceiver&& o) noexcept {
  if (this != &o) {
    if (hash_ != nullptr) XXH3_freeState(hash_);
    file_ = std::move(o.file_);
    expected_ = o.expected_;
    received_ = o.received_;
    out_ = std::move(o.out_);
    hash_ = std::exchange(o.hash_, nullptr);
  }
  return *this;
}

FileReceiver::~FileReceiver() {
  if (hash_ != nullptr) XXH3_freeState(hash_);
}

absl::Status FileReceiver::add(std::string_view data) {
  if (received_ + data.size() > expected_.size) {
    return absl::DataLossError(fmt::format("{}: more than the {} bytes announced arrived",
                                           file_.path(), expected_.size));
  }
  out_->write(data.data(), static_cast<std::streamsize>(data.size()));
  if (!*out_) {
    return absl::ResourceExhaustedError(
        fmt::format("{}: writing {} failed (disk full?)", file_.path(), file_.tempPath()));
  }
  XXH3_64bits_update(hash_, data.data(), data.size());
  received_ += data.size();
  return absl::OkStatus();
}

absl::Status FileReceiver::finish() {
  out_->close();
  if (!*out_) {
    return absl::ResourceExhaustedError(
        fmt::format("{}: writing {} failed (disk full?)", file_.path(), file_.tempPath()));
  }
  const uint64_t hash = XXH3_64bits_digest(hash_);
  if (received_ != expected_.size || hash != expected_.xxh3) {
    return absl::DataLossError(fmt::format(
        "{}: arrived damaged or cut short ({} of {} bytes, XXH3 {:016x}, announced {:016x})",
        file_.path(), received_, expected_.size, hash, expected_.xxh3));
  }
  return file_.commit();
}

}  // namespace pbgi::farm
