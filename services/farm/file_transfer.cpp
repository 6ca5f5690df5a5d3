#include "services/farm/file_transfer.h"

#include <filesystem>
#include <vector>

#include <fmt/format.h>
#include <xxhash.h>

#include "core/util/status.h"

namespace pbgi::farm {

absl::Status sendFile(
    const std::string& path,
    const std::function<bool(uint64_t size, std::string_view data, std::optional<uint64_t> xxh3)>&
        send) {
  std::ifstream in(path, std::ios::binary);
  std::error_code ec;
  const uint64_t size = std::filesystem::file_size(path, ec);
  if (!in || ec) return absl::NotFoundError(fmt::format("{}: cannot read it", path));
  std::unique_ptr<XXH3_state_t, decltype(&XXH3_freeState)> state(XXH3_createState(),
                                                                  &XXH3_freeState);
  XXH3_64bits_reset(state.get());
  std::vector<char> buffer(kFileChunkBytes);
  uint64_t sent = 0;
  do {
    in.read(buffer.data(), static_cast<std::streamsize>(buffer.size()));
    const auto n = static_cast<size_t>(in.gcount());
    XXH3_64bits_update(state.get(), buffer.data(), n);
    sent += n;
    const bool last = !in || sent >= size;
    if (last && sent != size) {
      return absl::DataLossError(
          fmt::format("{}: changed while it was sent ({} of {} bytes)", path, sent, size));
    }
    const std::optional<uint64_t> hash =
        last ? std::optional<uint64_t>(XXH3_64bits_digest(state.get())) : std::nullopt;
    if (!send(size, std::string_view(buffer.data(), n), hash)) {
      return absl::CancelledError(fmt::format("{}: the other end stopped reading", path));
    }
    if (last) return absl::OkStatus();
  } while (true);
}

absl::StatusOr<FileReceiver> FileReceiver::begin(const std::string& path, uint64_t size) {
  PBGI_ASSIGN_OR_RETURN(AtomicFile file, AtomicFile::begin(path));
  FileReceiver r(std::move(file), size);
  r.out_ = std::make_unique<std::ofstream>(r.file_.tempPath(), std::ios::binary);
  if (!*r.out_) {
    return absl::UnavailableError(fmt::format("{}: cannot write {}", path, r.file_.tempPath()));
  }
  return r;
}

FileReceiver::FileReceiver(AtomicFile file, uint64_t size)
    : file_(std::move(file)), size_(size), hash_(XXH3_createState()) {
  XXH3_64bits_reset(hash_);
}

FileReceiver::FileReceiver(FileReceiver&& o) noexcept
    : file_(std::move(o.file_)),
      size_(o.size_),
      received_(o.received_),
      out_(std::move(o.out_)),
      hash_(std::exchange(o.hash_, nullptr)) {}

FileReceiver& FileReceiver::operator=(FileReceiver&& o) noexcept {
  if (this != &o) {
    if (hash_ != nullptr) XXH3_freeState(hash_);
    file_ = std::move(o.file_);
    size_ = o.size_;
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
  if (received_ + data.size() > size_) {
    return absl::DataLossError(fmt::format("{}: more than the {} bytes announced arrived",
                                           file_.path(), size_));
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

absl::Status FileReceiver::finish(uint64_t xxh3) {
  out_->close();
  if (!*out_) {
    return absl::ResourceExhaustedError(
        fmt::format("{}: writing {} failed (disk full?)", file_.path(), file_.tempPath()));
  }
  const uint64_t hash = XXH3_64bits_digest(hash_);
  if (received_ != size_ || hash != xxh3) {
    return absl::DataLossError(fmt::format(
        "{}: arrived damaged or cut short ({} of {} bytes, XXH3 {:016x}, announced {:016x})",
        file_.path(), received_, size_, hash, xxh3));
  }
  return file_.commit();
}

}  // namespace pbgi::farm
