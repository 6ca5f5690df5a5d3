#pragma once
// Packs a PBGI tree, arriving node by node in post-order, into pages of subtrees (the layout
// is drawn in tree_page.h), so that a top-down traversal reads few pages.
//
// Bottom-up clustering: a finished node keeps its subtree in memory while the subtree fits in
// one page together with its own record; a node whose children's subtrees would overflow the
// page with it places them, in Morton order, into the page being filled (starting a new one
// when the next does not fit) and goes on alone. Every page is therefore whole subtrees,
// depth-first, parents before children, and small neighbouring subtrees share a page. A node
// whose children went to pages of their own keeps copies of their records (ghosts, see
// tree_page.h). Memory
// holds at most a few pages' worth of nodes per open level of the tree.
#include <cstdint>
#include <functional>
#include <span>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/pbgi/tree_page.h"

namespace pbgi {

// Receives each finished page's payload and returns its id: 0, 1, 2, ... in call order.
using PageSink = std::function<absl::StatusOr<uint32_t>(std::span<const uint8_t>)>;

struct TreePagerOptions {
  TreeEncoding encoding = TreeEncoding::kQuantized;
  uint32_t pageSize = 64 * 1024;
  float waveletError = 0.1f;  // what each wavelet vector is coded within (tree_page.h)
};

struct TreePagerStats {
  uint64_t pages = 0;
  uint64_t nodes = 0;
  uint64_t payloadBytes = 0;  // uncompressed, headers included
  WaveletPageStats wavelets;
};

class TreePager {
 public:
  // The smallest page that holds the largest node a tree with leaves of `leafSize` can have.
  static uint32_t minPageSize(TreeEncoding encoding, int leafSize);

  // `codebooks` (needed for quantized encodings) must outlive the pager.
  TreePager(const TreePagerOptions& options, const TreeCodebooks* codebooks, PageSink sink);

  // The next node in post-order: `node.children` is ignored and filled in here; its children
  // are the last `childCount` subtrees added and not yet claimed. Fails with the sink's error.
  absl::Status add(PageNode node, uint32_t childCount);
  // Places the root and writes the last page; returns where the root is.
  absl::StatusOr<NodeRef> finish();

  const TreePagerStats& stats() const { return stats_; }

 private:
  // A subtree not yet in a page: its nodes depth-first, children referring to each other by
  // page kUnplaced and their index within this vector.
  struct Subtree {
    std::vector<PageNode> nodes;
    size_t bytes = 0;
    bool placed = false;
    NodeRef ref;     // once placed
    GhostNode root;  // once placed: its root's record, for the parent's page
  };
  static constexpr uint32_t kUnplaced = UINT32_MAX;

  absl::StatusOr<NodeRef> place(Subtree& subtree);
  absl::Status flushPage();
  size_t nodeBytes(const PageNode& node, size_t childCount) const;
  size_t ghostBytes(const GhostNode& ghost) const;

  TreePagerOptions options_;
  const TreeCodebooks* codebooks_;
  PageSink sink_;
  std::vector<Subtree> stack_;
  std::vector<PageNode> open_;  // the page being filled
  size_t openBytes_ = 0;
  TreePagerStats stats_;
};

}  // namespace pbgi
