#pragma once
// The one-sweep octree build of out-of-core PBGI (Kontkanen, Tabellion, Overbeck 2011): from
// surfels sorted by Morton key, nodes come out in post-order while at most m + 1 surfels
// (m = points per leaf) are held, whatever the point count.
//
// The tree. A cell holding more than m surfels is an interior node; a cell holding at most m
// whose parent holds more is a leaf. Levels where a cell has a single non-empty child are
// skipped (a compressed octree: every interior node has 2 to 8 children), since node bounds
// come from the surfels, not from the cells. The key of a surfel is extended by its sequence
// number (its place in the sorted stream's input) as 21 more levels of 3 bits: surfels that
// share a finest Morton cell, as hostile or degenerate input does, still split into leaves of
// at most m, and the tree stays at most 42 levels deep.
//
// The sweep. Points arrive in key order, so every cell is a run of the stream. The builder
// keeps a stack of open interior nodes (each with the attributes of its finished children,
// at most 8) and a buffer of the points not yet given to a leaf, all inside one child cell of
// the innermost open node. A point outside that child finishes it: its buffered points become
// a leaf (at most m of them, and the parent holds more, so it is a leaf). When the buffer
// reaches m + 1 points, the deepest cell holding them all is an interior node: it is opened,
// and every child of it before the one holding the last point becomes a leaf. A point outside
// the innermost open node closes it: the node is emitted after its children and joins its
// parent, or a new ancestor when it had none.
//
// Output. The sink gets each node once, in post-order: a leaf with its surfels, an interior
// node with its child count, its children being the last childCount subtrees emitted before
// it that no node has claimed yet (a consumer keeps a stack). Children are in Morton order,
// the root comes last. The same stream gives the same nodes, bit for bit.
#include <cstdint>
#include <functional>
#include <span>
#include <string>
#include <vector>

#include <absl/status/status.h>

#include "core/pbgi/external_sort.h"
#include "core/pbgi/morton.h"
#include "core/pbgi/tree.h"

namespace pbgi {

inline constexpr int kDefaultLeafSize = 16;
inline constexpr int kMaxLeafSize = 255;  // a leaf's count fits the page format's byte
inline constexpr int kMaxTreeLevels = 2 * kMortonLevels;

struct TreeBuildOptions {
  int leafSize = kDefaultLeafSize;  // m: most surfels in a leaf, 1..kMaxLeafSize
};

struct BuiltNode {
  NodeAttributes attributes;
  uint32_t childCount = 0;          // 0 for a leaf
  std::span<const Surfel> surfels;  // a leaf's, in key order; empty for interior nodes
  bool leaf() const { return childCount == 0; }
};

using NodeSink = std::function<absl::Status(const BuiltNode&)>;

struct TreeBuildStats {
  uint64_t points = 0;
  uint64_t nodes = 0;
  uint64_t leaves = 0;
  uint64_t peakBufferedPoints = 0;  // most surfels held at once: at most m + 1
  int peakOpenNodes = 0;            // deepest the stack of open nodes grew
  std::string toString() const;
};

class TreeBuilder {
 public:
  TreeBuilder(const TreeBuildOptions& options, NodeSink sink);

  // The next surfel of the sorted stream. Keys must strictly increase in (key, sequence)
  // order and sequences stay below 2^63 (what the sorter produces; anything else is a caller
  // bug and fails a check). Returns the first error the sink returned, and again afterwards.
  absl::Status add(const SortedSurfel& point);
  // Emits what is left, the root last. A stream without points emits nothing.
  absl::Status finish();

  const TreeBuildStats& stats() const { return stats_; }

 private:
  struct OpenNode {
    int level = 0;
    uint64_t key = 0;  // the extended key of any point inside, to compare prefixes
    uint64_t sequence = 0;
    std::vector<NodeAttributes> children;
  };

  absl::Status emitLeaf(std::span<const SortedSurfel> points, OpenNode* parent);
  absl::Status closeTop(NodeAttributes* closed);
  absl::Status splitBuffer();

  TreeBuildOptions options_;
  NodeSink sink_;
  std::vector<SortedSurfel> buffer_;
  std::vector<OpenNode> stack_;
  std::vector<Surfel> leafScratch_;
  TreeBuildStats stats_;
  absl::Status failure_;
  bool haveLast_ = false;
  uint64_t lastKey_ = 0, lastSequence_ = 0;
};

// Builds the tree of an in-memory stream (tests, small clouds): the nodes in post-order.
struct InMemoryNode {
  NodeAttributes attributes;
  uint32_t childCount = 0;
  std::vector<Surfel> surfels;
};
absl::StatusOr<std::vector<InMemoryNode>> buildTreeInMemory(std::span<const SortedSurfel> sorted,
                                                            const TreeBuildOptions& options);

}  // namespace pbgi
