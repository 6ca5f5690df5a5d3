#include "core/pbgi/page_cache.h"

#include <algorithm>

#include <fmt/format.h>

#include "core/util/check.h"

namespace pbgi {

std::string PageCacheCounters::toString() const {
  return fmt::format(
      "hits={} misses={} hit_rate={:.4f} waits={} failures={} evictions={} over_budget={} "
      "bytes_loaded={} pages_resident={} bytes_resident={}",
      hits, misses, hitRate(), waits, failures, evictions, overBudget, bytesLoaded,
      pagesResident, bytesResident);
}

PageCache::PageCache(TreePageSource& source, const PageCacheOptions& options)
    : source_(source), policy_(options.policy) {
  PBGI_CHECK_GE(options.shards, 1);
  // Each shard gets an equal share of the budget, so a small budget split many ways would
  // hold less than a page per shard and evict everything: fewer shards, never under
  // kMinShardBudget each (one shard below that).
  const size_t shards = std::clamp<size_t>(options.budgetBytes / kMinShardBudget, 1,
                                           static_cast<size_t>(options.shards));
  shardBudget_ = options.budgetBytes / shards;
  for (size_t i = 0; i < shards; ++i) shards_.push_back(std::make_unique<Shard>());
}

void PageCache::evict(Shard& shard) {
  while (shard.bytes > shardBudget_) {
    auto victim = shard.entries.end();
    std::list<uint32_t>::iterator victimLru;
    if (policy_ == PageCachePolicy::kSweeps) {
      // The most recent unpinned page: scanning from the new end.
      for (auto it = shard.lru.begin(); it != shard.lru.end(); ++it) {
        auto entry = shard.entries.find(*it);
        PBGI_CHECK(entry != shard.entries.end());
        if (entry->second.page.use_count() > 1) continue;
        victim = entry;
        victimLru = it;
        break;
      }
    } else {
      // The least used unpinned page (pinned ones are held outside the cache), the least
      // recently used among equals: scanning from the old end, the first of the fewest uses.
      for (auto it = shard.lru.end(); it != shard.lru.begin();) {
        --it;
        auto entry = shard.entries.find(*it);
        PBGI_CHECK(entry != shard.entries.end());
        if (entry->second.page.use_count() > 1) continue;
        if (victim == shard.entries.end() || entry->second.uses < victim->second.uses) {
          victim = entry;
          victimLru = it;
        }
        if (policy_ == PageCachePolicy::kLeastRecent) break;  // the oldest unpinned page
      }
    }
    if (victim == shard.entries.end()) break;
    shard.bytes -= victim->second.bytes;
    shard.evictedUses[victim->first] = victim->second.uses;
    shard.lru.erase(victimLru);
    shard.entries.erase(victim);
    ++shard.evictions;
  }
  if (shard.bytes > shardBudget_) ++shard.overBudget;
}

absl::StatusOr<std::shared_ptr<const TreePage>> PageCache::page(uint32_t id) {
  Shard& shard = *shards_[id % shards_.size()];
  std::promise<absl::StatusOr<std::shared_ptr<const TreePage>>> promise;
  {
    std::unique_lock lock(shard.mutex);
    auto it = shard.entries.find(id);
    if (it != shard.entries.end()) {
      shard.lru.splice(shard.lru.begin(), shard.lru, it->second.lru);
      ++it->second.uses;
      hits_.fetch_add(1, std::memory_order_relaxed);
      return it->second.page;
    }
    if (auto pending = shard.loading.find(id); pending != shard.loading.end()) {
      auto future = pending->second;
      lock.unlock();
      waits_.fetch_add(1, std::memory_order_relaxed);
      absl::StatusOr<std::shared_ptr<const TreePage>> result = future.get();
      (result.ok() ? hits_ : failures_).fetch_add(1, std::memory_order_relaxed);
      return result;
    }
    shard.loading.emplace(id, promise.get_future().share());
  }
  misses_.fetch_add(1, std::memory_order_relaxed);
  auto loaded = source_.page(id);
  // Whatever came of the load, those waiting for it get it, and the next miss loads again.
  auto finishLoad = [&] {
    promise.set_value(loaded);
    shard.loading.erase(id);
  };
  if (!loaded.ok()) {
    failures_.fetch_add(1, std::memory_order_relaxed);
    std::lock_guard lock(shard.mutex);
    finishLoad();
    return loaded.status();
  }
  const size_t bytes = (*loaded)->memoryBytes();
  bytesLoaded_.fetch_add(bytes, std::memory_order_relaxed);
  {
    std::lock_guard lock(seenMutex_);
    if (seen_.size() <= id) seen_.resize(size_t{id} + 1, 0);
    if (!seen_[id]) {
      seen_[id] = 1;
      ++distinct_;
    }
  }
  std::lock_guard lock(shard.mutex);
  finishLoad();
  auto [it, inserted] = shard.entries.try_emplace(id);
  PBGI_CHECK(inserted);  // only this thread loads it
  shard.lru.push_front(id);
  uint64_t uses = 1;
  if (auto old = shard.evictedUses.find(id); old != shard.evictedUses.end()) {
    uses += old->second;
    shard.evictedUses.erase(old);
  }
  it->second = Entry{*loaded, bytes, shard.lru.begin(), uses};
  shard.bytes += bytes;
  // The page just loaded is returned pinned, so it survives its own insertion.
  std::shared_ptr<const TreePage> result = it->second.page;
  evict(shard);
  return result;
}

PageCacheCounters PageCache::counters() const {
  PageCacheCounters c;
  c.hits = hits_.load(std::memory_order_relaxed);
  c.misses = misses_.load(std::memory_order_relaxed);
  c.waits = waits_.load(std::memory_order_relaxed);
  c.failures = failures_.load(std::memory_order_relaxed);
  c.bytesLoaded = bytesLoaded_.load(std::memory_order_relaxed);
  for (const auto& shard : shards_) {
    std::lock_guard lock(shard->mutex);
    c.evictions += shard->evictions;
    c.overBudget += shard->overBudget;
    c.pagesResident += shard->entries.size();
    c.bytesResident += shard->bytes;
  }
  return c;
}

uint64_t PageCache::distinctPagesLoaded() const {
  std::lock_guard lock(seenMutex_);
  return distinct_;
}

}  // namespace pbgi
