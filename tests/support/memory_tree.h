#pragma once
// PBGI trees held in memory as decoded pages, for tests of what traverses them (the gather)
// without the page encoding or a file: buildTreeInMemory's post-order nodes laid out
// depth-first (a parent before its children, children in Morton order), in one page, or cut
// into a page per subtree at a chosen depth to exercise page crossings (with the ghosts of
// children in other pages that the pager writes).
//
// Only TreePage's fields are used, never its encoder or decoder.
#include <algorithm>
#include <cstdint>
#include <memory>
#include <set>
#include <span>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>
#include <fmt/format.h>

#include "core/pbgi/morton.h"
#include "core/pbgi/tree_build.h"
#include "core/pbgi/tree_page.h"
#include "core/util/check.h"

namespace pbgi::testing {

class MemoryTreeSource : public TreePageSource {
 public:
  // `postOrder` as buildTreeInMemory returns it (the root last). splitDepth 0 puts the whole
  // tree in page 0; splitDepth d > 0 starts a new page at every node of depth d (the root
  // has depth 0), holding that node's subtree.
  explicit MemoryTreeSource(std::span<const InMemoryNode> postOrder, int splitDepth = 0)
      : splitDepth_(splitDepth) {
    // Rebuild the tree's shape: a post-order node's children are the last childCount
    // subtrees not yet claimed.
    std::vector<std::vector<uint32_t>> children(postOrder.size());
    std::vector<uint32_t> open;
    for (uint32_t i = 0; i < postOrder.size(); ++i) {
      const uint32_t k = postOrder[i].childCount;
      PBGI_CHECK_LE(size_t{k}, open.size());  // a child the stream never emitted
      children[i].assign(open.end() - k, open.end());
      open.resize(open.size() - k);
      open.push_back(i);
    }
    PBGI_CHECK_EQ(open.size(), size_t{1});  // one root
    auto& root = newPage();
    emit(postOrder, children, root.id, open.front(), 0);
    // Ghosts, as the pager writes them: each child in another page copied into its parent's.
    for (auto& p : building_) {
      p->ghostOf.assign(p->children.size(), kNoGhost);
      for (uint32_t slot = 0; slot < p->children.size(); ++slot) {
        const NodeRef ref = p->children[slot];
        if (ref.page == p->id) continue;
        TreeNode ghost;
        ghost.attributes = building_[ref.page]->nodes[ref.index].attributes;
        ghost.first = slot;
        p->ghostOf[slot] = static_cast<uint32_t>(p->nodes.size());
        p->nodes.push_back(ghost);
      }
    }
    for (auto& p : building_) pages_.push_back(std::move(p));
    building_.clear();
  }

  NodeRef root() const override { return {0, 0}; }

  absl::StatusOr<std::shared_ptr<const TreePage>> page(uint32_t id) override {
    ++fetches_;
    if (id >= pages_.size()) {
      return absl::NotFoundError(fmt::format("memory tree: no page {} of {}", id, pages_.size()));
    }
    return pages_[id];
  }

  size_t pageCount() const { return pages_.size(); }
  const TreePage& pageAt(size_t i) const { return *pages_[i]; }
  uint64_t fetches() const { return fetches_; }

 private:
  TreePage& newPage() {
    auto page = std::make_shared<TreePage>();
    page->id = static_cast<uint32_t>(building_.size());
    page->encoding = TreeEncoding::kFloat;
    building_.push_back(page);
    return *page;
  }

  // Appends node `i` and its subtree (except subtrees cut into pages of their own) to page
  // `pageId`; returns its index there.
  uint32_t emit(std::span<const InMemoryNode> nodes, const std::vector<std::vector<uint32_t>>& kids,
                uint32_t pageId, uint32_t i, int depth) {
    TreePage* page = building_[pageId].get();
    const uint32_t index = static_cast<uint32_t>(page->nodes.size());
    TreeNode node;
    node.attributes = nodes[i].attributes;
    node.childCount = nodes[i].childCount;
    page->bounds.extend(node.attributes.bounds);
    if (node.childCount == 0) {
      node.first = static_cast<uint32_t>(page->surfels.size());
      node.surfelCount = static_cast<uint32_t>(nodes[i].surfels.size());
      page->surfels.insert(page->surfels.end(), nodes[i].surfels.begin(), nodes[i].surfels.end());
      page->nodes.push_back(node);
      return index;
    }
    node.first = static_cast<uint32_t>(page->children.size());
    page->children.resize(page->children.size() + node.childCount);
    page->nodes.push_back(node);
    for (uint32_t c = 0; c < node.childCount; ++c) {
      NodeRef ref;
      if (splitDepth_ > 0 && depth + 1 == splitDepth_) {
        ref.page = newPage().id;
        ref.index = emit(nodes, kids, ref.page, kids[i][c], depth + 1);
      } else {
        ref.page = pageId;
        ref.index = emit(nodes, kids, pageId, kids[i][c], depth + 1);
      }
      building_[pageId]->children[node.first + c] = ref;  // newPage may have moved `page`
    }
    return index;
  }

  int splitDepth_ = 0;
  std::vector<std::shared_ptr<TreePage>> building_;
  std::vector<std::shared_ptr<const TreePage>> pages_;
  uint64_t fetches_ = 0;
};

// Surfels in Morton order over their own bounds, numbered in input order: the builder's input.
inline std::vector<SortedSurfel> sortSurfels(std::span<const Surfel> surfels) {
  Bounds3f bounds;
  for (const Surfel& s : surfels) bounds.extend(s.position);
  std::vector<SortedSurfel> sorted(surfels.size());
  for (size_t i = 0; i < surfels.size(); ++i) {
    sorted[i].surfel = surfels[i];
    sorted[i].key = mortonKey(surfels[i].position, bounds);
    sorted[i].sequence = i;
  }
  std::sort(sorted.begin(), sorted.end(), [](const SortedSurfel& a, const SortedSurfel& b) {
    return a.key != b.key ? a.key < b.key : a.sequence < b.sequence;
  });
  return sorted;
}

// The tree of `surfels` (at least one) as a page source.
inline absl::StatusOr<std::unique_ptr<MemoryTreeSource>> memoryTree(std::span<const Surfel> surfels,
                                                                    int leafSize = kDefaultLeafSize,
                                                                    int splitDepth = 0) {
  TreeBuildOptions options;
  options.leafSize = leafSize;
  const std::vector<SortedSurfel> sorted = sortSurfels(surfels);
  absl::StatusOr<std::vector<InMemoryNode>> nodes = buildTreeInMemory(sorted, options);
  if (!nodes.ok()) return nodes.status();
  if (nodes->empty()) return absl::InvalidArgumentError("memory tree: no surfels");
  return std::make_unique<MemoryTreeSource>(*nodes, splitDepth);
}

// memoryTree for surfels known to make a tree (tests' own shapes): the source itself.
inline std::unique_ptr<MemoryTreeSource> treeOf(std::span<const Surfel> surfels, int splitDepth = 0) {
  auto tree = memoryTree(surfels, kDefaultLeafSize, splitDepth);
  PBGI_CHECK(tree.ok());
  return *std::move(tree);
}

// Every page it was asked for, to know which pages a gather touches.
class RecordingSource : public TreePageSource {
 public:
  explicit RecordingSource(TreePageSource* inner) : inner_(inner) {}
  NodeRef root() const override { return inner_->root(); }
  absl::StatusOr<std::shared_ptr<const TreePage>> page(uint32_t id) override {
    ids.insert(id);
    return inner_->page(id);
  }
  std::set<uint32_t> ids;

 private:
  TreePageSource* inner_;
};

// Another source with one page that fails, as a damaged page in a file does.
class FailingPageSource : public TreePageSource {
 public:
  FailingPageSource(TreePageSource* inner, uint32_t badPage) : inner_(inner), badPage_(badPage) {}
  NodeRef root() const override { return inner_->root(); }
  absl::StatusOr<std::shared_ptr<const TreePage>> page(uint32_t id) override {
    if (id == badPage_) {
      return absl::DataLossError(fmt::format("test.pbgi: page {}: checksum mismatch", id));
    }
    return inner_->page(id);
  }

 private:
  TreePageSource* inner_;
  uint32_t badPage_;
};

}  // namespace pbgi::testing
