#include "formats/pbgi/remote_page_file.h"

#include <fcntl.h>
#include <sys/file.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <charconv>
#include <cerrno>
#include <filesystem>
#include <system_error>

#include <fmt/format.h>

#include "core/util/fd_io.h"
#include "core/util/status.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

constexpr std::string_view kPageSuffix = ".page";
constexpr std::string_view kTempMarker = ".tmp";
constexpr std::string_view kLockName = "lock";

// "<tree id, 16 hex>.<page, 8 hex>.page"; nullopt for any other name.
std::optional<std::pair<uint64_t, uint32_t>> parsePageName(const std::string& name) {
  if (name.size() != 16 + 1 + 8 + kPageSuffix.size() || name[16] != '.' ||
      !name.ends_with(kPageSuffix)) {
    return std::nullopt;
  }
  const auto hex = [&](size_t from, size_t n, auto& value) {
    const char* end = name.data() + from + n;
    const auto [ptr, ec] = std::from_chars(name.data() + from, end, value, 16);
    return ec == std::errc() && ptr == end;
  };
  uint64_t tree = 0;
  uint32_t page = 0;
  if (!hex(0, 16, tree) || !hex(17, 8, page)) return std::nullopt;
  return std::pair{tree, page};
}

absl::Status writeFile(const std::string& path, std::span<const uint8_t> bytes) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
  if (fd < 0) return errnoError(errno, "cannot create", path);
  absl::Status written = writeAll(fd, bytes.data(), bytes.size());
  if (::close(fd) != 0 && written.ok()) written = errnoError(errno, "cannot close", path);
  return written;
}

absl::StatusOr<std::vector<uint8_t>> readFile(const std::string& path, uint64_t expected) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return errnoError(errno, "cannot open", path);
  std::vector<uint8_t> bytes(expected + 1);  // one more: a longer file is not the page
  absl::StatusOr<size_t> n = readFull(fd, bytes.data(), bytes.size());
  ::close(fd);
  if (!n.ok()) return n.status();
  bytes.resize(*n);
  return bytes;
}

}  // namespace

// ---- PageDiskCache ---------------------------------------------------------------------------

absl::StatusOr<std::shared_ptr<PageDiskCache>> PageDiskCache::open(const std::string& dir,
                                                                   uint64_t budgetBytes) {
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) {
    return absl::PermissionDeniedError(
        fmt::format("page disk cache {}: cannot create the folder: {}", dir, ec.message()));
  }
  const std::string lockPath = (fs::path(dir) / kLockName).string();
  const int lockFd = ::open(lockPath.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (lockFd < 0) return errnoError(errno, "page disk cache: cannot create", lockPath);
  if (::flock(lockFd, LOCK_EX | LOCK_NB) != 0) {
    const int e = errno;
    ::close(lockFd);
    if (e == EWOULDBLOCK) {
      return absl::FailedPreconditionError(fmt::format(
          "page disk cache {}: another process holds it (one worker per cache folder)", dir));
    }
    return errnoError(e, "page disk cache: cannot lock", lockPath);
  }
  std::shared_ptr<PageDiskCache> cache(new PageDiskCache(dir, budgetBytes, lockFd));

  // What is there: pages, oldest modified first; half-written temporaries of a killed
  // process, and anything else that is not a page, are removed.
  std::vector<std::tuple<fs::file_time_type, PageDiskCache::Key, uint64_t>> found;
  for (const fs::directory_entry& e : fs::directory_iterator(dir, ec)) {
    const std::string name = e.path().filename().string();
    if (name == kLockName) continue;
    const auto key = parsePageName(name);
    std::error_code sizeEc, timeEc;
    const uint64_t size = e.is_regular_file() ? e.file_size(sizeEc) : 0;
    const fs::file_time_type time = e.last_write_time(timeEc);
    if (!key || !e.is_regular_file() || sizeEc || timeEc) {
      fs::remove_all(e.path(), sizeEc);
      continue;
    }
    found.emplace_back(time, *key, size);
  }
  if (ec) {
    return absl::PermissionDeniedError(
        fmt::format("page disk cache {}: cannot list the folder: {}", dir, ec.message()));
  }
  std::sort(found.begin(), found.end());
  std::lock_guard lock(cache->mutex_);
  for (const auto& [time, key, size] : found) {
    PageDiskCache::Entry& entry = cache->entries_[key];
    entry.bytes = size;
    cache->stats_.bytes += size;
    ++cache->stats_.pages;
    cache->touch(key, entry);
  }
  cache->makeRoom(0);
  cache->stats_.evicted = 0;  // what a smaller budget dropped is not this run's eviction
  return cache;
}

PageDiskCache::PageDiskCache(std::string dir, uint64_t budget, int lockFd)
    : dir_(std::move(dir)), budget_(budget), lockFd_(lockFd) {}

PageDiskCache::~PageDiskCache() { ::close(lockFd_); }

std::string PageDiskCache::pathOf(const Key& key) const {
  return (fs::path(dir_) / fmt::format("{:016x}.{:08x}{}", key.first, key.second, kPageSuffix))
      .string();
}

void PageDiskCache::touch(const Key& key, Entry& e) {
  byUse_.erase({e.lastUse, key});
  e.lastUse = ++clock_;
  byUse_.insert({e.lastUse, key});
}

void PageDiskCache::drop(const Key& key, bool evicted) {
  auto it = entries_.find(key);
  if (it == entries_.end()) return;
  byUse_.erase({it->second.lastUse, key});
  stats_.bytes -= it->second.bytes;
  --stats_.pages;
  if (evicted) ++stats_.evicted;
  entries_.erase(it);
  std::error_code ec;
  fs::remove(pathOf(key), ec);
}

bool PageDiskCache::makeRoom(uint64_t bytes) {
  if (bytes > budget_) return false;
  auto it = byUse_.begin();
  while (stats_.bytes + bytes > budget_ && it != byUse_.end()) {
    const Key key = it->second;
    ++it;
    if (entries_.at(key).writing) continue;  // its writer frees it if it fails
    drop(key, true);
  }
  return stats_.bytes + bytes <= budget_;
}

std::optional<std::vector<uint8_t>> PageDiskCache::get(uint64_t treeId, uint32_t id,
                                                       const PageEntry& entry) {
  const Key key{treeId, id};
  {
    std::lock_guard lock(mutex_);
    auto it = entries_.find(key);
    if (it == entries_.end() || it->second.writing) {
      ++stats_.misses;
      return std::nullopt;
    }
    touch(key, it->second);
  }
  absl::StatusOr<std::vector<uint8_t>> bytes = readFile(pathOf(key), entry.compressedSize);
  std::lock_guard lock(mutex_);
  if (bytes.ok() && checkStoredPage(id, entry, *bytes).ok()) {
    ++stats_.hits;
    return *std::move(bytes);
  }
  // Gone (evicted while this read) or damaged: either way not a page to use.
  auto it = entries_.find(key);
  if (it != entries_.end() && !it->second.writing) {
    if (bytes.ok()) ++stats_.damaged;
    drop(key, false);
  }
  ++stats_.misses;
  return std::nullopt;
}

absl::Status PageDiskCache::put(uint64_t treeId, uint32_t id, std::span<const uint8_t> bytes) {
  const Key key{treeId, id};
  std::string temp;
  {
    std::lock_guard lock(mutex_);
    if (entries_.count(key)) return absl::OkStatus();  // another thread has it, or is writing it
    if (!makeRoom(bytes.size())) return absl::OkStatus();  // larger than the budget
    Entry& e = entries_[key];
    e.bytes = bytes.size();
    e.writing = true;
    touch(key, e);
    stats_.bytes += bytes.size();
    ++stats_.pages;
    temp = fmt::format("{}{}{}", pathOf(key), kTempMarker, ++tempCounter_);
  }
  absl::Status written = writeFile(temp, bytes);
  if (written.ok() && ::rename(temp.c_str(), pathOf(key).c_str()) != 0) {
    written = errnoError(errno, "cannot rename into place", temp);
  }
  std::lock_guard lock(mutex_);
  if (written.ok()) {
    entries_.at(key).writing = false;
    return absl::OkStatus();
  }
  std::error_code ec;
  fs::remove(temp, ec);
  entries_.at(key).writing = false;
  drop(key, false);
  const std::string what =
      fmt::format("page disk cache {}: page {} of tree {:016x} ({} bytes; {} held of a {} byte "
                  "budget)",
                  dir_, id, treeId, bytes.size(), stats_.bytes, budget_);
  if (absl::IsResourceExhausted(written)) {  // ENOSPC, EDQUOT
    return absl::ResourceExhaustedError(
        fmt::format("{}: the disk is full: {}", what, written.message()));
  }
  return absl::Status(written.code(), fmt::format("{}: {}", what, written.message()));
}

PageDiskCacheStats PageDiskCache::stats() const {
  std::lock_guard lock(mutex_);
  return stats_;
}

// ---- The remote store ------------------------------------------------------------------------

namespace {

class RemotePageFile final : public PageFileStore {
 public:
  RemotePageFile(PageFileHead head, std::shared_ptr<PageFetcher> fetcher,
                 std::shared_ptr<PageDiskCache> disk, std::shared_ptr<RemoteFetchStats> stats)
      : head_(std::move(head)),
        treeId_(head_.treeId()),
        fetcher_(std::move(fetcher)),
        disk_(std::move(disk)),
        stats_(stats ? std::move(stats) : std::make_shared<RemoteFetchStats>()) {}

  const std::string& name() const override { return fetcher_->name(); }
  uint64_t size() const override { return head_.fileSize; }

  absl::StatusOr<size_t> read(uint64_t offset, std::span<uint8_t> out) override {
    const auto from = [&](const std::vector<uint8_t>& bytes, uint64_t at) -> std::optional<size_t> {
      if (offset < at || offset - at > bytes.size()) return std::nullopt;
      const uint64_t begin = offset - at;
      const size_t n = static_cast<size_t>(std::min<uint64_t>(out.size(), bytes.size() - begin));
      // Whole requests only, except at the end of the file.
      if (n < out.size() && at + bytes.size() < head_.fileSize) return std::nullopt;
      std::copy_n(bytes.begin() + static_cast<std::ptrdiff_t>(begin), n, out.begin());
      return n;
    };
    if (auto n = from(head_.header, 0)) return *n;
    if (auto n = from(head_.tail, head_.tailOffset)) return *n;
    return absl::InvalidArgumentError(fmt::format(
        "{}: bytes [{}, {}) are neither the header nor the tail that were fetched", name(), offset,
        offset + out.size()));
  }

  absl::StatusOr<std::vector<uint8_t>> readPage(uint32_t id, const PageEntry& entry) override {
    if (disk_) {
      if (std::optional<std::vector<uint8_t>> held = disk_->get(treeId_, id, entry)) {
        stats_->diskHits.fetch_add(1, std::memory_order_relaxed);
        return *std::move(held);
      }
    }
    // A page damaged on the way is fetched once more; twice is the source's fault, named.
    absl::Status damage;
    for (int attempt = 0; attempt < 2; ++attempt) {
      absl::StatusOr<std::vector<uint8_t>> bytes = fetcher_->page(treeId_, id);
      if (!bytes.ok()) return bytes.status();
      stats_->pagesFetched.fetch_add(1, std::memory_order_relaxed);
      stats_->bytesFetched.fetch_add(bytes->size(), std::memory_order_relaxed);
      damage = checkStoredPage(id, entry, *bytes);
      if (damage.ok()) {
        if (disk_) {
          if (absl::Status kept = disk_->put(treeId_, id, *bytes); !kept.ok()) return kept;
        }
        return bytes;
      }
      stats_->damaged.fetch_add(1, std::memory_order_relaxed);
    }
    return absl::DataLossError(
        fmt::format("{}: arrived damaged twice: {}", name(), damage.message()));
  }

 private:
  PageFileHead head_;
  uint64_t treeId_;
  std::shared_ptr<PageFetcher> fetcher_;
  std::shared_ptr<PageDiskCache> disk_;
  std::shared_ptr<RemoteFetchStats> stats_;
};

}  // namespace

std::unique_ptr<PageFileStore> openRemotePageFile(PageFileHead head,
                                                  std::shared_ptr<PageFetcher> fetcher,
                                                  std::shared_ptr<PageDiskCache> disk,
                                                  std::shared_ptr<RemoteFetchStats> stats) {
  if (stats) stats->headBytes.fetch_add(head.bytes(), std::memory_order_relaxed);
  return std::make_unique<RemotePageFile>(std::move(head), std::move(fetcher), std::move(disk),
                                          std::move(stats));
}

}  // namespace pbgi
