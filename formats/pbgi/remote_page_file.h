#pragma once
// A .pbgi file on another machine, read page by page: its head (header, directory, sections)
// fetched once, each page fetched when a reader first asks for it, checked against the
// directory's checksum (a damaged page is fetched once more, then named), and kept in a
// bounded local disk cache that outlives the task and is shared by the threads of a process.
// Where the bytes come from (the farm's page service over gRPC) is a PageFetcher; this layer
// owns what is stored and checked.

#include <atomic>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <span>
#include <string>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "formats/pbgi/page_file.h"

namespace pbgi {

// Where a remote file's bytes come from. Thread-safe.
class PageFetcher {
 public:
  virtual ~PageFetcher() = default;
  // Which file from where, for messages ("job 3 frame 1 from host:port").
  virtual const std::string& name() const = 0;
  virtual absl::StatusOr<PageFileHead> head() = 0;
  // The stored bytes of page `id` of the file whose head has this tree id (the source refuses
  // when its file is no longer that one).
  virtual absl::StatusOr<std::vector<uint8_t>> page(uint64_t treeId, uint32_t id) = 0;
};

struct PageDiskCacheStats {
  uint64_t hits = 0;
  uint64_t misses = 0;
  uint64_t damaged = 0;  // copies that failed their check on read, removed
  uint64_t evicted = 0;
  uint64_t bytes = 0;    // held now
  uint64_t pages = 0;    // held now
};

// Stored pages on local disk, one file per page named by tree id and page, within a byte
// budget, least recently used out first. One process owns a folder (a lock file says so);
// what a killed process left half written is removed when the next one opens it, and every
// page is checked against its directory entry when it is read, so a damaged copy is never
// used. Thread-safe.
class PageDiskCache {
 public:
  // Creates `dir` if needed. A budget of 0 keeps nothing.
  static absl::StatusOr<std::shared_ptr<PageDiskCache>> open(const std::string& dir,
                                                             uint64_t budgetBytes);
  ~PageDiskCache();

  // The page's stored bytes when a copy is held and passes its check against `entry`.
  std::optional<std::vector<uint8_t>> get(uint64_t treeId, uint32_t id, const PageEntry& entry);
  // Keeps a page, first evicting the least recently used until it fits. A page larger than
  // the budget is not kept. A disk that cannot take it is an error naming the folder and the
  // page: ResourceExhausted when the disk is full.
  absl::Status put(uint64_t treeId, uint32_t id, std::span<const uint8_t> bytes);

  PageDiskCacheStats stats() const;
  const std::string& dir() const { return dir_; }
  uint64_t budget() const { return budget_; }

 private:
  struct Entry {
    uint64_t bytes = 0;
    uint64_t lastUse = 0;
    bool writing = false;  // reserved by a put still writing its file
  };
  using Key = std::pair<uint64_t, uint32_t>;

  PageDiskCache(std::string dir, uint64_t budget, int lockFd);
  std::string pathOf(const Key& key) const;
  void touch(const Key& key, Entry& e);           // holds mutex_
  void drop(const Key& key, bool evicted);        // holds mutex_
  bool makeRoom(uint64_t bytes);                  // holds mutex_

  std::string dir_;
  uint64_t budget_;
  int lockFd_;
  mutable std::mutex mutex_;
  std::map<Key, Entry> entries_;
  std::set<std::pair<uint64_t, Key>> byUse_;  // (lastUse, key), oldest first
  uint64_t clock_ = 0;
  uint64_t tempCounter_ = 0;
  PageDiskCacheStats stats_;
};

// A snapshot of RemoteFetchStats; the difference of two is what happened between them.
struct RemoteFetchCounts {
  uint64_t headBytes = 0, pagesFetched = 0, bytesFetched = 0, diskHits = 0, damaged = 0;
  RemoteFetchCounts operator-(const RemoteFetchCounts& o) const {
    return {headBytes - o.headBytes, pagesFetched - o.pagesFetched, bytesFetched - o.bytesFetched,
            diskHits - o.diskHits, damaged - o.damaged};
  }
};

// What a remote file cost: pages and bytes over the network, pages found on local disk.
struct RemoteFetchStats {
  RemoteFetchCounts counts() const {
    return {headBytes.load(), pagesFetched.load(), bytesFetched.load(), diskHits.load(),
            damaged.load()};
  }
  std::atomic<uint64_t> headBytes{0};
  std::atomic<uint64_t> pagesFetched{0};
  std::atomic<uint64_t> bytesFetched{0};
  std::atomic<uint64_t> diskHits{0};
  std::atomic<uint64_t> damaged{0};  // pages that arrived damaged and were fetched again
};

// A store over a fetched head: the header, directory and sections from memory, each page from
// `disk` (may be null) or else from `fetcher`. `stats` (may be null) counts what it cost.
std::unique_ptr<PageFileStore> openRemotePageFile(PageFileHead head,
                                                  std::shared_ptr<PageFetcher> fetcher,
                                                  std::shared_ptr<PageDiskCache> disk,
                                                  std::shared_ptr<RemoteFetchStats> stats);

}  // namespace pbgi
