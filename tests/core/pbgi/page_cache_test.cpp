#include "core/pbgi/page_cache.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <chrono>
#include <thread>
#include <vector>

#include <tbb/parallel_for.h>

#include "core/pbgi/tree_writer.h"
#include "tests/support/surfel_clouds.h"

namespace pbgi {
namespace {

// A MemoryTree that counts loads and can be told to fail one page.
class CountingSource : public TreePageSource {
 public:
  explicit CountingSource(std::unique_ptr<MemoryTree> tree) : tree_(std::move(tree)) {}
  NodeRef root() const override { return tree_->root(); }
  absl::StatusOr<std::shared_ptr<const TreePage>> page(uint32_t id) override {
    loads_.fetch_add(1);
    if (delay_.count() > 0) std::this_thread::sleep_for(delay_);
    if (id == failing_) return absl::DataLossError(fmt::format("tree.pbgi: page {}: damaged", id));
    return tree_->page(id);
  }
  size_t pageCount() const { return tree_->payloads().size(); }
  std::atomic<int> loads_{0};
  uint32_t failing_ = UINT32_MAX;
  std::chrono::milliseconds delay_{0};  // each load takes this long (a slow disk, a network)

 private:
  std::unique_ptr<MemoryTree> tree_;
};

std::unique_ptr<CountingSource> makeSource() {
  TreeWriteOptions o;
  o.encoding = TreeEncoding::kQuantized;
  o.pageSize = 4096;
  o.build.leafSize = 8;
  o.powerCentres = 32;
  o.areaCentres = 8;
  auto tree = buildMemoryTree(testing::makeSorted(20000, 31), o);
  PBGI_CHECK(tree.ok());
  return std::make_unique<CountingSource>(std::move(*tree));
}

size_t onePageBytes(CountingSource& source) { return (*source.page(0))->memoryBytes(); }

TEST(PageCache, HitsAfterTheFirstLoad) {
  auto source = makeSource();
  PageCache cache(*source, {.budgetBytes = size_t{1} << 30, .shards = 4});
  for (int round = 0; round < 3; ++round) {
    for (uint32_t id = 0; id < source->pageCount(); ++id) ASSERT_TRUE(cache.page(id).ok());
  }
  const PageCacheCounters c = cache.counters();
  EXPECT_EQ(c.misses, source->pageCount());
  EXPECT_EQ(c.hits, 2 * source->pageCount());
  EXPECT_EQ(c.evictions, 0u);
  EXPECT_EQ(c.pagesResident, source->pageCount());
  EXPECT_EQ(cache.distinctPagesLoaded(), source->pageCount());
}

TEST(PageCache, StaysWithinItsBudgetWhenNothingIsPinned) {
  auto source = makeSource();
  const size_t budget = 8 * onePageBytes(*source);
  PageCache cache(*source, {.budgetBytes = budget, .shards = 1});
  for (int round = 0; round < 2; ++round) {
    for (uint32_t id = 0; id < source->pageCount(); ++id) {
      ASSERT_TRUE(cache.page(id).ok());
      // Pages differ in size; one page of slack.
      EXPECT_LE(cache.counters().bytesResident, budget + 2 * onePageBytes(*source));
    }
  }
  EXPECT_GT(cache.counters().evictions, 0u);
}

TEST(PageCache, PinnedPagesAreNotEvicted) {
  auto source = makeSource();
  PageCache cache(*source, {.budgetBytes = 1, .shards = 1});
  auto pinned = cache.page(3);
  ASSERT_TRUE(pinned.ok());
  for (uint32_t id = 0; id < 10; ++id) ASSERT_TRUE(cache.page(id).ok());
  const int loads = source->loads_;
  auto again = cache.page(3);
  ASSERT_TRUE(again.ok());
  EXPECT_EQ(source->loads_, loads) << "page 3 was pinned and stays cached";
  EXPECT_EQ(again->get(), pinned->get());
}

TEST(PageCache, OnePageBudgetStillServesEveryPage) {
  auto source = makeSource();
  PageCache cache(*source, {.budgetBytes = 1, .shards = 1});
  for (uint32_t id = 0; id < source->pageCount(); ++id) {
    auto p = cache.page(id);
    ASSERT_TRUE(p.ok());
    EXPECT_EQ((*p)->id, id);
  }
  EXPECT_LE(cache.counters().pagesResident, 1u);
}

TEST(PageCache, FailuresAreReturnedEveryTimeAndNeverCached) {
  auto source = makeSource();
  source->failing_ = 2;
  PageCache cache(*source, {.budgetBytes = size_t{1} << 30, .shards = 2});
  for (int i = 0; i < 2; ++i) {
    auto p = cache.page(2);
    EXPECT_EQ(p.status().code(), absl::StatusCode::kDataLoss);
    EXPECT_NE(p.status().message().find("page 2"), std::string::npos);
  }
  EXPECT_EQ(cache.counters().failures, 2u);
  EXPECT_TRUE(cache.page(1).ok());
}

TEST(PageCache, ParallelReadersSeeConsistentPages) {
  auto source = makeSource();
  PageCache cache(*source, {.budgetBytes = 6 * onePageBytes(*source), .shards = 4});
  const size_t pages = source->pageCount();
  std::atomic<int> wrong{0};
  tbb::parallel_for(size_t{0}, size_t{20000}, [&](size_t i) {
    const auto id = static_cast<uint32_t>((i * 7919) % pages);
    auto p = cache.page(id);
    if (!p.ok() || (*p)->id != id || (*p)->nodes.empty()) wrong.fetch_add(1);
  });
  EXPECT_EQ(wrong.load(), 0);
  const PageCacheCounters c = cache.counters();
  EXPECT_EQ(c.hits + c.misses, 20000u);
}

// Threads that miss a page another thread is loading wait for that load: one load, whatever
// the number of threads asking, and a failed load fails every waiter without being cached.
TEST(PageCache, ThreadsMissingOnePageAtOnceLoadItOnce) {
  auto source = makeSource();
  source->delay_ = std::chrono::milliseconds(200);
  PageCache cache(*source, {.budgetBytes = size_t{1} << 30});
  for (const uint32_t id : {uint32_t{3}, uint32_t{4}}) {
    source->failing_ = 4;
    const int before = source->loads_.load();
    std::vector<std::thread> threads;
    std::atomic<int> ok{0}, failed{0};
    for (int t = 0; t < 4; ++t) {
      threads.emplace_back([&] { (cache.page(id).ok() ? ok : failed).fetch_add(1); });
    }
    for (std::thread& t : threads) t.join();
    // The first thread's load takes 200 ms; the others ask well within it.
    EXPECT_EQ(source->loads_.load() - before, 1) << id;
    EXPECT_EQ(id == 4 ? failed.load() : ok.load(), 4) << id;
  }
  EXPECT_EQ(cache.counters().waits, 6u);
  EXPECT_EQ(cache.counters().hits, 3u);  // the waits that got a page
  source->delay_ = std::chrono::milliseconds(0);
  const int before = source->loads_.load();
  EXPECT_FALSE(cache.page(4).ok());  // not cached: asked again, loaded again
  EXPECT_EQ(source->loads_.load() - before, 1);
  EXPECT_EQ(cache.counters().failures, 5u);  // every request that got the error
}

// Least recent: a sweep's pages stay while it needs them, whatever earlier sweeps used most.
TEST(PageCache, LeastRecentKeepsTheSweepUnderWay) {
  auto source = makeSource();
  size_t bytes = 0;  // room for the sweep's three pages
  for (uint32_t id : {10u, 11u, 12u}) bytes += (*source->page(id))->memoryBytes();
  for (const PageCachePolicy policy :
       {PageCachePolicy::kLeastUsed, PageCachePolicy::kLeastRecent}) {
    PageCache cache(*source, {.budgetBytes = bytes, .policy = policy});
    // Pages 0 and 1 read often, long ago; then a sweep reads 10, 11, 10, 11, ...
    for (int k = 0; k < 50; ++k) {
      ASSERT_TRUE(cache.page(0).ok());
      ASSERT_TRUE(cache.page(1).ok());
    }
    const uint64_t before = cache.counters().misses;
    for (int k = 0; k < 10; ++k) {
      for (uint32_t id : {10u, 11u, 12u}) ASSERT_TRUE(cache.page(id).ok());
    }
    const uint64_t loads = cache.counters().misses - before;
    if (policy == PageCachePolicy::kLeastRecent) {
      EXPECT_EQ(loads, 3u);  // each page of the sweep once
    } else {
      EXPECT_GT(loads, 3u);  // the old favourites hold two of the three places
    }
  }
}

// Sweeps: the same sweep from the highest page down, repeated over twice the pages the cache
// holds. Least recent evicts each page before the next sweep comes back to it and loads every
// page every time; evicting the page just finished keeps the rest of the sweep for the next.
TEST(PageCache, SweepsKeepMostOfARepeatedSweepTooBigForTheCache) {
  auto source = makeSource();
  const auto n = static_cast<uint32_t>(source->pageCount());
  ASSERT_GE(n, 8u);
  size_t half = 0;  // room for the largest half of the pages
  std::vector<size_t> sizes;
  for (uint32_t id = 0; id < n; ++id) sizes.push_back((*source->page(id))->memoryBytes());
  std::sort(sizes.rbegin(), sizes.rend());
  for (uint32_t k = 0; k < n / 2; ++k) half += sizes[k];
  const int sweeps = 5;
  uint64_t loads[2] = {0, 0};
  for (const PageCachePolicy policy : {PageCachePolicy::kLeastRecent, PageCachePolicy::kSweeps}) {
    PageCache cache(*source, {.budgetBytes = half, .policy = policy, .shards = 1});
    for (int k = 0; k < sweeps; ++k) {
      for (uint32_t id = n; id-- > 0;) ASSERT_TRUE(cache.page(id).ok());
    }
    loads[policy == PageCachePolicy::kSweeps] = cache.counters().misses;
    EXPECT_LE(cache.counters().bytesResident, half);
  }
  EXPECT_EQ(loads[0], uint64_t{sweeps} * n);
  // The first sweep loads all n; each later one about the n - n/2 the cache has no room for
  // (any n/2 pages fit), checked loosely (n - n/4).
  EXPECT_LE(loads[1], n + uint64_t{sweeps - 1} * (n - n / 4));
  EXPECT_LT(loads[1], loads[0] * 3 / 4) << loads[1] << " against " << loads[0];
}

}  // namespace
}  // namespace pbgi
