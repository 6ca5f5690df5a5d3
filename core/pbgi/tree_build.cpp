#include "core/pbgi/tree_build.h"

#include <fmt/format.h>

#include "core/pbgi/morton.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

// The deepest level of the extended key (Morton key, then sequence) whose cell holds both.
int extendedCommonLevel(uint64_t keyA, uint64_t seqA, uint64_t keyB, uint64_t seqB) {
  if (keyA != keyB) return commonLevel(keyA, keyB);
  return kMortonLevels + commonLevel(seqA, seqB);
}

int extendedCommonLevel(const SortedSurfel& a, const SortedSurfel& b) {
  return extendedCommonLevel(a.key, a.sequence, b.key, b.sequence);
}

}  // namespace

std::string TreeBuildStats::toString() const {
  return fmt::format("points={} nodes={} leaves={} peak_buffered_points={} peak_open_nodes={}",
                     points, nodes, leaves, peakBufferedPoints, peakOpenNodes);
}

TreeBuilder::TreeBuilder(const TreeBuildOptions& options, NodeSink sink)
    : options_(options), sink_(std::move(sink)) {
  PBGI_CHECK(options_.leafSize >= 1 && options_.leafSize <= kMaxLeafSize);
  buffer_.reserve(options_.leafSize + 1);
  leafScratch_.reserve(options_.leafSize + 1);
}

absl::Status TreeBuilder::emitLeaf(std::span<const SortedSurfel> points, OpenNode* parent) {
  leafScratch_.clear();
  for (const SortedSurfel& p : points) leafScratch_.push_back(p.surfel);
  BuiltNode node;
  node.attributes = leafAttributes(leafScratch_);
  node.surfels = leafScratch_;
  ++stats_.nodes;
  ++stats_.leaves;
  if (parent != nullptr) parent->children.push_back(node.attributes);
  return sink_(node);
}

absl::Status TreeBuilder::closeTop(NodeAttributes* closed) {
  OpenNode& top = stack_.back();
  BuiltNode node;
  node.attributes = mergeAttributes(top.children);
  node.childCount = static_cast<uint32_t>(top.children.size());
  *closed = node.attributes;
  stack_.pop_back();
  ++stats_.nodes;
  return sink_(node);
}

absl::Status TreeBuilder::splitBuffer() {
  const SortedSurfel& first = buffer_.front();
  const int level = extendedCommonLevel(first, buffer_.back());
  // Unique (key, sequence) pairs always differ somewhere above the last level.
  PBGI_CHECK_LT(level, kMaxTreeLevels);
  if (!stack_.empty()) PBGI_CHECK_GT(level, stack_.back().level);
  stack_.push_back(OpenNode{level, first.key, first.sequence, {}});
  stats_.peakOpenNodes = std::max(stats_.peakOpenNodes, static_cast<int>(stack_.size()));
  // Every child cell before the last point's is complete: at most m points under a parent
  // with more, a leaf.
  size_t start = 0;
  for (size_t i = 1; i < buffer_.size(); ++i) {
    if (extendedCommonLevel(buffer_[start], buffer_[i]) > level) continue;
    if (auto s = emitLeaf(std::span(buffer_).subspan(start, i - start), &stack_.back()); !s.ok()) {
      return s;
    }
    start = i;
  }
  buffer_.erase(buffer_.begin(), buffer_.begin() + static_cast<ptrdiff_t>(start));
  return absl::OkStatus();
}

absl::Status TreeBuilder::add(const SortedSurfel& point) {
  if (!failure_.ok()) return failure_;
  PBGI_CHECK_LE(point.sequence, kMortonMaxKey);
  if (haveLast_) {
    if (!(point.key > lastKey_ || (point.key == lastKey_ && point.sequence > lastSequence_))) {
      detail::checkFailed(__FILE__, __LINE__,
                          fmt::format("surfels out of order: ({}, {}) after ({}, {})", point.key,
                                      point.sequence, lastKey_, lastSequence_));
    }
  }
  haveLast_ = true;
  lastKey_ = point.key;
  lastSequence_ = point.sequence;
  ++stats_.points;

  auto run = [&]() -> absl::Status {
    auto contains = [&](const OpenNode& node) {
      return extendedCommonLevel(node.key, node.sequence, point.key, point.sequence) >=
             node.level;
    };
    // Close every open node the point lies outside of; each joins its parent, or a new
    // ancestor that holds both it and the point.
    while (!stack_.empty() && !contains(stack_.back())) {
      if (!buffer_.empty()) {
        if (auto s = emitLeaf(buffer_, &stack_.back()); !s.ok()) return s;
        buffer_.clear();
      }
      const uint64_t key = stack_.back().key, sequence = stack_.back().sequence;
      NodeAttributes closed;
      if (auto s = closeTop(&closed); !s.ok()) return s;
      if (!stack_.empty() && !contains(stack_.back())) {
        stack_.back().children.push_back(closed);
        continue;
      }
      const int level = extendedCommonLevel(key, sequence, point.key, point.sequence);
      if (!stack_.empty() && level == stack_.back().level) {
        stack_.back().children.push_back(closed);
      } else {
        stack_.push_back(OpenNode{level, key, sequence, {closed}});
        stats_.peakOpenNodes = std::max(stats_.peakOpenNodes, static_cast<int>(stack_.size()));
      }
      break;
    }
    // The buffer's child cell of the innermost open node is complete once a point lands in
    // another one.
    if (!stack_.empty() && !buffer_.empty() &&
        extendedCommonLevel(buffer_.front(), point) <= stack_.back().level) {
      if (auto s = emitLeaf(buffer_, &stack_.back()); !s.ok()) return s;
      buffer_.clear();
    }
    buffer_.push_back(point);
    facingBrighterSide(buffer_.back().surfel);
    stats_.peakBufferedPoints = std::max<uint64_t>(stats_.peakBufferedPoints, buffer_.size());
    if (buffer_.size() > static_cast<size_t>(options_.leafSize)) return splitBuffer();
    return absl::OkStatus();
  };
  failure_ = run();
  return failure_;
}

absl::Status TreeBuilder::finish() {
  if (!failure_.ok()) return failure_;
  auto run = [&]() -> absl::Status {
    if (!buffer_.empty()) {
      if (auto s = emitLeaf(buffer_, stack_.empty() ? nullptr : &stack_.back()); !s.ok()) {
        return s;
      }
      buffer_.clear();
    }
    while (!stack_.empty()) {
      NodeAttributes closed;
      if (auto s = closeTop(&closed); !s.ok()) return s;
      if (!stack_.empty()) stack_.back().children.push_back(closed);
    }
    return absl::OkStatus();
  };
  failure_ = run();
  return failure_;
}

absl::StatusOr<std::vector<InMemoryNode>> buildTreeInMemory(std::span<const SortedSurfel> sorted,
                                                            const TreeBuildOptions& options) {
  std::vector<InMemoryNode> nodes;
  TreeBuilder builder(options, [&](const BuiltNode& n) {
    nodes.push_back(
        InMemoryNode{n.attributes, n.childCount, {n.surfels.begin(), n.surfels.end()}});
    return absl::OkStatus();
  });
  for (const SortedSurfel& p : sorted) {
    if (auto s = builder.add(p); !s.ok()) return s;
  }
  if (auto s = builder.finish(); !s.ok()) return s;
  return nodes;
}

}  // namespace pbgi
