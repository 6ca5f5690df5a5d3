#pragma once
// The top-down walk of a PBGI tree that both gathers share (gather.h's cube microbuffer and
// warped_gather.h's importance-warped one): a stack of node references, the pages in use
// held while the walk is in them (at most a few, let go when the walk ends), the culling
// tests, and the checks that turn damaged references into errors. What a gather does with a
// node is its own: run() is defined in gather_internal.h, which only the gathers include.
#include <cstdint>
#include <memory>
#include <optional>
#include <queue>
#include <span>
#include <unordered_map>
#include <vector>

#include <absl/status/status.h>

#include "core/math/vec.h"
#include "core/pbgi/tree_page.h"

namespace pbgi {

struct GatherStats;

class TreeWalk {
 public:
  // Walks the tree from its root for a receiver at p facing n (unit). Nodes entirely behind
  // the tangent plane or facing away are culled (counted). For a node whose bounding sphere
  // does not hold the receiver, `splat(attributes, bounds, wavelet)` (the node's glossy light, or
  // null) returns true when it took the node
  // whole, false to refine it. Leaves that are refined go to `leaf(page, node)`. Children are
  // visited in Morton order. Errors: the source's; DataLoss for damaged references.
  template <typename Splat, typename Leaf>
  absl::Status run(TreePageSource& tree, const Vec3f& p, const Vec3f& n, GatherStats* stats,
                   Splat&& splat, Leaf&& leaf);

  // A node and its depth below the root.
  struct StackEntry {
    NodeRef ref;
    uint32_t depth;
  };
  // The same walk from given nodes instead of the root (the subtrees of nodes splatted before,
  // walked again: adaptive_gather.h), in the order given.
  template <typename Splat, typename Leaf>
  absl::Status runFrom(TreePageSource& tree, std::span<const StackEntry> starts, const Vec3f& p,
                       const Vec3f& n, GatherStats* stats, Splat&& splat, Leaf&& leaf);
  // The node being visited, for splat and leaf callbacks that record what they took.
  const StackEntry& current() const { return current_; }

 private:
  struct HeldPage {
    uint32_t id = 0;
    std::shared_ptr<const TreePage> page;
    uint64_t lastUse = 0;
  };

  std::vector<StackEntry> stack_;
  std::vector<HeldPage> held_;
  uint64_t useClock_ = 0;
  StackEntry current_{};
};

// TreeWalk's walk (the same tests, the same nodes taken or refined), page by page: the nodes
// still to visit wait in one bucket per page, and pages are visited from the highest id down,
// depth first within a page (children live in their parent's page or a lower one: the tree
// writer places children first), so that a walk asks for each page once. Walks of many
// receivers then run in step (gatherTogether in gather.h), each asking for the page of the
// step, so that a small page cache loads it once for all of them. A walk's order of nodes
// depends on its receiver and the tree alone, never on the walks beside it. (A tree whose
// references point up is still walked right, asking for a page again.)
class SweptWalk {
 public:
  void begin(NodeRef root, const Vec3f& p, const Vec3f& n);
  // The highest page with nodes waiting; nullopt when the walk is done.
  std::optional<uint32_t> nextPage() const {
    if (pages_.empty()) return std::nullopt;
    return pages_.top();
  }
  // Visits the nodes waiting on pages `lowest` and up, as TreeWalk::run does.
  template <typename Splat, typename Leaf>
  absl::Status sweep(TreePageSource& tree, uint32_t lowest, GatherStats* stats, Splat&& splat,
                     Leaf&& leaf);

 private:
  struct Entry {
    NodeRef ref;
    uint32_t depth;
  };
  void push(const Entry& e);

  Vec3f p_{0.0f}, n_{0.0f, 0.0f, 1.0f};
  std::unordered_map<uint32_t, std::vector<Entry>> buckets_;
  std::priority_queue<uint32_t> pages_;
  std::vector<Entry> stack_;
};

}  // namespace pbgi
