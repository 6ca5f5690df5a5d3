#pragma once
// A bounded cache of decoded tree pages in front of any TreePageSource (a file read with
// pread now, the coordinator's page stream later): what lets a renderer or a multi-bounce bake
// traverse a tree far bigger than its memory.
//
// Budget: the decoded bytes of the pages held (TreePage::memoryBytes). Pages are handed out
// as shared_ptr, and a page someone still holds is pinned: eviction passes over it, so a
// traversal never loses a page under its feet; when everything left is pinned the cache runs
// over budget until the pins go (counted). The least used page goes first (uses counted over
// the cache's life, evicted pages remembering theirs), the least recently used among equals.
// Every gather starts at the root and cuts through the whole scene, so a frame's gathers
// cycle through more pages than a small cache holds: least-recently-used then evicts each
// page just before it is needed again. Counting uses keeps the pages near the root, which
// every gather reads, and lets the leaves of far-away surfaces come and go. Measured
// (accuracy_bench, Cornell box, 250k surfels, 96x96 pixels, 4 spp, default preset): hit rate
// 0.193 -> 0.269 at a 20 % budget, 0.135 -> 0.151 at 5 %. The cache is split
// into shards by page id, each with its own lock and a share of the budget, so that threads
// gathering in parallel rarely wait on one another. Loading (pread, checksum, decompression,
// decoding) happens outside the lock; a thread that misses a page another thread is loading
// waits for that load instead of loading it again (counted as a hit: it loaded nothing). A page the source fails to load is never cached:
// the error (which names the file and page) goes to the caller, every time it is asked for.
// PageCachePolicy::kLeastRecent serves sweeps instead (below).
#include <atomic>
#include <cstddef>
#include <cstdint>
#include <future>
#include <list>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include "core/pbgi/tree_page.h"

namespace pbgi {

// Which page goes first when the cache is full.
enum class PageCachePolicy {
  // The least used over the cache's life (evicted pages remember their uses), the least
  // recently used among equals: for traversals that each start at the root and cut through
  // the whole tree (the per-pixel gather), where the pages near the root are read by all.
  kLeastUsed,
  // The least recently used: for sweeps that read the pages in order, each page by many
  // traversals within a short time and then no more (the cut's lockstep sweeps of a render
  // unit). Counting uses would keep the pages of sweeps past and evict those of the sweep
  // under way.
  kLeastRecent,
  // The most recently used: for the same sweep repeated over more pages than the cache holds
  // (a bake's bounce: each batch of cuts sweeps the pages from the highest down, and the next
  // batch sweeps them again). Least recent would evict each page just before the next sweep
  // asks for it, and load every page of every sweep; evicting the page just finished keeps
  // the rest of the last sweep resident for the next (what Belady's optimal choice keeps on a
  // cyclic scan). Sponza at 4,000,000 surfels under 256M, whose batches sweep different but
  // overlapping pages: 2.90 million loads against least recent's 3.38 million.
  kSweeps,
};

struct PageCacheOptions {
  size_t budgetBytes = size_t{256} << 20;
  PageCachePolicy policy = PageCachePolicy::kLeastUsed;
  int shards = 16;  // at most; fewer when the budget is small (kMinShardBudget each)
};

// The smallest share of the budget a shard gets: a few decoded pages.
inline constexpr size_t kMinShardBudget = size_t{4} << 20;

struct PageCacheCounters {
  uint64_t hits = 0;          // served without a load (waits for others' loads included)
  uint64_t misses = 0;        // loads from the source
  uint64_t waits = 0;         // requests that waited for another thread's load of the page
  uint64_t failures = 0;      // requests that got an error (a failed load, and its waiters)
  uint64_t evictions = 0;
  uint64_t overBudget = 0;    // inserts that left a shard over its share (all pinned)
  uint64_t bytesLoaded = 0;   // decoded bytes of every page loaded
  uint64_t pagesResident = 0;
  uint64_t bytesResident = 0;
  double hitRate() const {
    return hits + misses > 0 ? double(hits) / double(hits + misses) : 0.0;
  }
  std::string toString() const;
};

class PageCache : public TreePageSource {
 public:
  // `source` must outlive the cache.
  PageCache(TreePageSource& source, const PageCacheOptions& options);
  PageCache(const PageCache&) = delete;
  PageCache& operator=(const PageCache&) = delete;

  NodeRef root() const override { return source_.root(); }
  absl::StatusOr<std::shared_ptr<const TreePage>> page(uint32_t id) override;

  PageCacheCounters counters() const;
  // The distinct pages ever loaded (a traversal's footprint, for "pages read / pages in file").
  uint64_t distinctPagesLoaded() const;

 private:
  struct Entry {
    std::shared_ptr<const TreePage> page;
    size_t bytes = 0;
    std::list<uint32_t>::iterator lru;
    uint64_t uses = 0;
  };
  struct Shard {
    std::mutex mutex;
    std::unordered_map<uint32_t, Entry> entries;
    std::list<uint32_t> lru;  // front: most recent
    std::unordered_map<uint32_t, uint64_t> evictedUses;
    // Loads under way, for threads that miss the same page meanwhile.
    std::unordered_map<uint32_t,
                       std::shared_future<absl::StatusOr<std::shared_ptr<const TreePage>>>>
        loading;
    size_t bytes = 0;
    uint64_t evictions = 0, overBudget = 0;
  };

  void evict(Shard& shard);

  TreePageSource& source_;
  PageCachePolicy policy_;
  size_t shardBudget_;
  std::vector<std::unique_ptr<Shard>> shards_;
  std::atomic<uint64_t> hits_{0}, misses_{0}, waits_{0}, failures_{0}, bytesLoaded_{0};
  mutable std::mutex seenMutex_;
  std::vector<uint8_t> seen_;
  uint64_t distinct_ = 0;
};

}  // namespace pbgi
