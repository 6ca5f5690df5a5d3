#include "core/pbgi/tree_pager.h"

#include <limits>

#include <fmt/format.h>

#include "core/pbgi/tree_build.h"
#include "core/util/check.h"

namespace pbgi {

uint32_t TreePager::minPageSize(TreeEncoding encoding, int leafSize) {
  const size_t leaf = nodeRecordBytes(encoding) + size_t(leafSize) * surfelRecordBytes(encoding);
  // An interior node with 8 children in other pages: 8 ghosts, exact ones at worst.
  const size_t interior = nodeRecordBytes(encoding) + 8 * kChildRefBytes + kExactShBytes +
                          8 * (nodeRecordBytes(encoding) + kExactShBytes);
  return static_cast<uint32_t>(kTreePageHeaderBytes + std::max(leaf, interior));
}

TreePager::TreePager(const TreePagerOptions& options, const TreeCodebooks* codebooks,
                     PageSink sink)
    : options_(options), codebooks_(codebooks), sink_(std::move(sink)) {
  PBGI_CHECK(!quantized(options_.encoding) || codebooks_ != nullptr);
}

size_t TreePager::nodeBytes(const PageNode& node, size_t childCount) const {
  size_t bytes = nodeRecordBytes(options_.encoding) + childCount * kChildRefBytes +
                 node.surfels.size() * surfelRecordBytes(options_.encoding) +
                 (quantized(options_.encoding) && node.exact ? kExactShBytes : 0);
  for (const GhostNode& g : node.ghosts) bytes += ghostBytes(g);
  // Each wavelet entry counts the section's header too: a page holds at most that much more.
  if (node.wavelet && !node.wavelet->empty()) {
    bytes += kWaveletSectionHeaderBytes +
             waveletEntryBytes(node.waveletWhole ? *node.waveletWhole : *node.wavelet);
  }
  return bytes;
}

size_t TreePager::ghostBytes(const GhostNode& ghost) const {
  return nodeRecordBytes(options_.encoding) +
         (quantized(options_.encoding) && ghost.exact ? kExactShBytes : 0) +
         (ghost.wavelet && !ghost.wavelet->empty()
              ? kWaveletSectionHeaderBytes + waveletEntryBytes(*ghost.wavelet)
              : 0);
}

namespace {

// The record of a subtree's root, as a ghost in its parent's page.
GhostNode ghostOf(const PageNode& root) {
  std::shared_ptr<const WaveletRadiance> averages;
  if (root.wavelet && !root.wavelet->empty()) {
    const WaveletRadiance* own = root.wavelet.get();
    averages = std::make_shared<const WaveletRadiance>(
        WaveletRadiance::sum(std::span(&own, 1), std::numeric_limits<float>::infinity()));  // every detail dropped
  }
  return {.attributes = root.attributes,
          .powerIndex = root.powerIndex,
          .areaIndex = root.areaIndex,
          .exact = root.exact,
          .wavelet = std::move(averages)};
}

// `child` placed in another page becomes `parent`'s next child, with its ghost.
void adoptPlaced(PageNode& parent, const NodeRef& child, const GhostNode& root) {
  parent.ghosts.push_back(root);
  parent.ghosts.back().child = static_cast<uint32_t>(parent.children.size());
  parent.children.push_back(child);
}

}  // namespace

absl::Status TreePager::add(PageNode node, uint32_t childCount) {
  PBGI_CHECK_LE(childCount, stack_.size());
  const size_t own = nodeBytes(node, childCount);
  PBGI_CHECK_LE(kTreePageHeaderBytes + own, options_.pageSize);
  const auto children = std::span(stack_).subspan(stack_.size() - childCount);
  size_t pending = 0;  // children's subtrees that would join the node, and ghosts of the rest
  for (const Subtree& c : children) pending += c.placed ? ghostBytes(c.root) : c.bytes;

  Subtree tree;
  node.children.clear();
  node.ghosts.clear();
  if (kTreePageHeaderBytes + own + pending <= options_.pageSize) {
    // The node and its unplaced children fit one page: they stay together.
    tree.nodes.push_back(std::move(node));
    for (Subtree& c : children) {
      if (c.placed) {
        adoptPlaced(tree.nodes.front(), c.ref, c.root);
        continue;
      }
      const auto offset = static_cast<uint32_t>(tree.nodes.size());
      tree.nodes.front().children.push_back(NodeRef{kUnplaced, offset});
      for (PageNode& n : c.nodes) {
        for (NodeRef& r : n.children) {
          if (r.page == kUnplaced) r.index += offset;
        }
        tree.nodes.push_back(std::move(n));
      }
    }
    tree.bytes = own + pending;
  } else {
    // The children go to pages of their own; the node keeps their records as ghosts.
    for (Subtree& c : children) {
      if (!c.placed) {
        auto ref = place(c);
        if (!ref.ok()) return ref.status();
      }
      adoptPlaced(node, c.ref, c.root);
    }
    tree.bytes = nodeBytes(node, childCount);
    PBGI_CHECK_LE(kTreePageHeaderBytes + tree.bytes, options_.pageSize);
    tree.nodes.push_back(std::move(node));
  }
  stack_.resize(stack_.size() - childCount);
  stack_.push_back(std::move(tree));
  ++stats_.nodes;
  return absl::OkStatus();
}

absl::StatusOr<NodeRef> TreePager::place(Subtree& subtree) {
  if (kTreePageHeaderBytes + openBytes_ + subtree.bytes > options_.pageSize) {
    if (auto s = flushPage(); !s.ok()) return s;
  }
  const auto pageId = static_cast<uint32_t>(stats_.pages);
  const auto base = static_cast<uint32_t>(open_.size());
  subtree.root = ghostOf(subtree.nodes.front());
  for (PageNode& n : subtree.nodes) {
    for (NodeRef& r : n.children) {
      if (r.page == kUnplaced) r = NodeRef{pageId, base + r.index};
    }
    open_.push_back(std::move(n));
  }
  openBytes_ += subtree.bytes;
  subtree.nodes.clear();
  subtree.nodes.shrink_to_fit();
  subtree.placed = true;
  subtree.ref = NodeRef{pageId, base};
  return subtree.ref;
}

absl::Status TreePager::flushPage() {
  if (open_.empty()) return absl::OkStatus();
  const auto pageId = static_cast<uint32_t>(stats_.pages);
  const std::vector<uint8_t> bytes = encodeTreePage(pageId, options_.encoding, open_, codebooks_,
                                                    options_.waveletError, &stats_.wavelets);
  auto id = sink_(bytes);
  if (!id.ok()) return id.status();
  PBGI_CHECK_EQ(*id, pageId);
  ++stats_.pages;
  stats_.payloadBytes += bytes.size();
  open_.clear();
  openBytes_ = 0;
  return absl::OkStatus();
}

absl::StatusOr<NodeRef> TreePager::finish() {
  if (stack_.size() != 1) {
    return absl::FailedPreconditionError(
        fmt::format("tree pager: {} subtrees left at the end, expected one root", stack_.size()));
  }
  Subtree& root = stack_.front();
  if (!root.placed) {
    if (auto ref = place(root); !ref.ok()) return ref.status();
  }
  if (auto s = flushPage(); !s.ok()) return s;
  return root.ref;
}

}  // namespace pbgi
