#pragma once
// The top-down walk of a PBGI tree that both gathers share (gather.h's cube microbuffer and
// warped_gather.h's importance-warped one): a stack of node references, the pages in use
// held while the walk is in them (at most a few, let go when the walk ends), the culling
// tests, and the checks that turn damaged references into errors. What a gather does with a
// node is its own: run() is defined in gather_internal.h, which only the gathers include.
#include <cstdint>
#include <memory>
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
  // does not hold the receiver, `splat(attributes, bounds)` returns true when it took the node
  // whole, false to refine it. Leaves that are refined go to `leaf(page, node)`. Children are
  // visited in Morton order. Errors: the source's; DataLoss for damaged references.
  template <typename Splat, typename Leaf>
  absl::Status run(TreePageSource& tree, const Vec3f& p, const Vec3f& n, GatherStats* stats,
                   Splat&& splat, Leaf&& leaf);

 private:
  struct StackEntry {
    NodeRef ref;
    uint32_t depth;
  };
  struct HeldPage {
    uint32_t id = 0;
    std::shared_ptr<const TreePage> page;
    uint64_t lastUse = 0;
  };

  std::vector<StackEntry> stack_;
  std::vector<HeldPage> held_;
  uint64_t useClock_ = 0;
};

}  // namespace pbgi
