#include "core/pbgi/pair_gather.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <memory>
#include <optional>
#include <vector>

#include <fmt/format.h>
#include <tbb/parallel_invoke.h>

#include "core/pbgi/gather_internal.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

// Groups of at least this many receivers run their two halves in parallel.
constexpr uint32_t kParallelReceivers = 32;

absl::Status receiverError(size_t i, const PairReceiver& r) {
  return absl::InvalidArgumentError(
      fmt::format("pair gather: receiver {} at {} with normal {}: expected a finite position and "
                  "a finite, non-zero normal",
                  i, r.position, r.normal));
}

// A node of the receiver tree: a single receiver (no children) or a group.
struct ReceiverNode {
  Vec3f centre{0.0f};
  float radius = 0.0f;
  uint32_t first = 0, count = 0;  // its receivers: order[first, first + count)
  // The receivers' tangent planes: their normals (either way) lie within acos(cosSpread) of
  // ±axis. A sender seen near a receiver's horizon is left to the receiver's own walk.
  Vec3f axis{0.0f, 0.0f, 1.0f};
  float cosSpread = 1.0f;
  int32_t children[2] = {-1, -1};
  bool single() const { return children[0] < 0; }
};

// A page a group's refinement holds (gather_internal::holdPage).
struct HeldPage {
  uint32_t id = 0;
  std::shared_ptr<const TreePage> page;
  uint64_t lastUse = 0;
};

// What one subtree of the receiver tree did.
struct Outcome {
  absl::Status status;
  GatherStats gather;
  PairGatherStats pairs;
  void add(Outcome&& o) {
    if (status.ok()) status = std::move(o.status);
    gather += o.gather;
    pairs += o.pairs;
  }
};

}  // namespace

absl::Status PairGatherOptions::validate() const {
  PBGI_RETURN_IF_ERROR(gather.validate());
  if (!(receiverSolidAngle >= 0.0f && receiverSolidAngle <= 4.0f * kPi)) {
    return absl::InvalidArgumentError(fmt::format(
        "pair gather: receiverSolidAngle must be in [0, 4 pi], got {}", receiverSolidAngle));
  }
  return absl::OkStatus();
}

PairGatherStats& PairGatherStats::operator+=(const PairGatherStats& o) {
  receivers += o.receivers;
  groups += o.groups;
  groupBuffers += o.groupBuffers;
  pairs += o.pairs;
  groupSplats += o.groupSplats;
  splatsServed += o.splatsServed;
  refinedSender += o.refinedSender;
  refinedReceiver += o.refinedReceiver;
  composed += o.composed;
  return *this;
}

std::string PairGatherStats::toString() const {
  return fmt::format(
      "receivers={} groups={} group_buffers={} pairs={} group_splats={} splats_served={} "
      "refined_sender={} refined_receiver={} composed={}",
      receivers, groups, groupBuffers, pairs, groupSplats, splatsServed, refinedSender,
      refinedReceiver, composed);
}

// The refinement of one pairGather call: the receiver tree, then its nodes depth first, each
// group handing its children the senders it did not take and its buffer.
class PairWalk {
 public:
  using Entry = TreeWalk::StackEntry;

  PairWalk(TreePageSource& tree, std::span<const PairReceiver> receivers,
           std::span<const Vec3f> units, const PairGatherOptions& options, const PairGatherUse& use)
      : tree_(tree),
        receivers_(receivers),
        units_(units),
        options_(options),
        use_(use),
        pixelAngle_(0.5f * kPi / static_cast<float>(options.gather.resolution)) {
    order_.resize(receivers.size());
    for (uint32_t i = 0; i < order_.size(); ++i) order_[i] = i;
    nodes_.reserve(2 * receivers.size());
    build(0, static_cast<uint32_t>(receivers.size()));
  }

  Outcome run() {
    const Entry root{tree_.root(), 0};
    return visit(0, {root}, {});
  }

 private:
  // Node for order_[first, first + count), its subtree after it; returns its index.
  int32_t build(uint32_t first, uint32_t count) {
    const auto index = static_cast<int32_t>(nodes_.size());
    nodes_.emplace_back();
    Bounds3f box;
    for (uint32_t k = first; k < first + count; ++k) box.extend(receivers_[order_[k]].position);
    ReceiverNode node;
    node.centre = box.center();
    node.first = first;
    node.count = count;
    for (uint32_t k = first; k < first + count; ++k) {
      node.radius = std::max(node.radius, length(receivers_[order_[k]].position - node.centre));
    }
    // Normals turned to the first's side: a plane's two normals are one horizon.
    Vec3f sum(0.0f);
    const Vec3f& n0 = units_[order_[first]];
    for (uint32_t k = first; k < first + count; ++k) {
      const Vec3f& n = units_[order_[k]];
      sum += dot(n, n0) < 0.0f ? -n : n;
    }
    node.axis = sum.length2() > 0.0f ? normalize(sum) : n0;
    for (uint32_t k = first; k < first + count; ++k) {
      node.cosSpread = std::min(node.cosSpread, std::abs(dot(units_[order_[k]], node.axis)));
    }
    if (count > 1) {
      const Vec3f extent = box.diagonal();
      const int axis =
          extent.x >= extent.y && extent.x >= extent.z ? 0 : (extent.y >= extent.z ? 1 : 2);
      // By position along the axis, then index: the same tree whatever the sort does with ties.
      std::sort(order_.begin() + first, order_.begin() + first + count,
                [&](uint32_t a, uint32_t b) {
                  const float pa = receivers_[a].position[axis], pb = receivers_[b].position[axis];
                  return pa < pb || (pa == pb && a < b);
                });
      const uint32_t half = count / 2;
      node.children[0] = build(first, half);
      node.children[1] = build(first + half, count - half);
    }
    nodes_[static_cast<size_t>(index)] = node;
    return index;
  }

  Outcome visit(int32_t index, std::vector<Entry> senders, std::vector<const Microbuffer*> groups) {
    const ReceiverNode& node = nodes_[static_cast<size_t>(index)];
    if (node.single()) return receive(order_[node.first], senders, groups);
    Outcome out;
    ++out.pairs.groups;
    std::optional<Gatherer> own;
    std::vector<Entry> passed;
    if (absl::Status s = refine(node, senders, &own, &passed, &out); !s.ok()) {
      out.status = s;
      return out;
    }
    senders.clear();
    senders.shrink_to_fit();
    if (own) groups.push_back(&own->buffer_);
    Outcome halves[2];
    auto half = [&](int c) { halves[c] = visit(node.children[c], passed, groups); };
    if (node.count >= kParallelReceivers) {
      tbb::parallel_invoke([&] { half(0); }, [&] { half(1); });
    } else {
      half(0);
      half(1);
    }
    out.add(std::move(halves[0]));
    out.add(std::move(halves[1]));
    return out;
  }

  // The group's pairs (see the header): senders it takes go into `own` (made at the first),
  // those its children must look at into `passed`, in the order the walk meets them.
  absl::Status refine(const ReceiverNode& node, const std::vector<Entry>& senders,
                      std::optional<Gatherer>* own, std::vector<Entry>* passed, Outcome* out) {
    using namespace gather_internal;
    std::vector<HeldPage> held;
    uint64_t clock = 0;
    std::vector<Entry> stack(senders.rbegin(), senders.rend());
    const float epsilon = options_.receiverSolidAngle;
    const float groupArea = kPi * node.radius * node.radius;
    bool tookAny = false;
    while (!stack.empty()) {
      const Entry entry = stack.back();
      stack.pop_back();
      ++out->pairs.pairs;
      PBGI_ASSIGN_OR_RETURN(const TreePage* page,
                            holdPage(held, clock, tree_, entry.ref.page, &out->gather));
      PBGI_ASSIGN_OR_RETURN(const TreeNode* tn, nodeAt(*page, entry.ref));
      const NodeAttributes& a = tn->attributes;
      if (a.bounds.empty()) continue;
      const Vec3f half = a.bounds.diagonal() * 0.5f;
      NodeBounds bounds;
      bounds.boundRadius2 = half.length2();
      bounds.centerDistance2 = (a.bounds.center() - node.centre).length2();
      const float centreDistance = std::sqrt(bounds.centerDistance2);
      // Too wide to be a cluster from any receiver of the group (gather.h's extent test from
      // the group's farthest point): every receiver's walk would refine it, so it is refined
      // here once. Exact: the walks' order and culling are kept (a culled node's children
      // are culled).
      const float farthest = centreDistance + node.radius;
      if (!tn->leaf() && kPi * bounds.boundRadius2 > kMaxExtentFactor *
                                                         options_.gather.maxSolidAngle * farthest *
                                                         farthest) {
        PBGI_RETURN_IF_ERROR(refineSender(*page, *tn, entry, &stack));
        ++out->pairs.refinedSender;
        continue;
      }
      // alpha_RS < epsilon: the group, seen from the nearest point of the sender's sphere.
      const float gap = centreDistance - std::sqrt(bounds.boundRadius2);
      // ... and away from every receiver's horizon by more than its own angular radius, the
      // parallax and a pixel, so that its footprint falls where each receiver's walk would
      // put it, not across a horizon the group's picture does not have.
      bool nearHorizon = true;
      if (gap > node.radius) {
        const float angle =
            std::asin(std::min(1.0f, std::sqrt(bounds.boundRadius2) / centreDistance)) +
            std::asin(std::min(1.0f, node.radius / gap)) + pixelAngle_ +
            std::acos(std::clamp(node.cosSpread, -1.0f, 1.0f));
        nearHorizon =
            angle >= 0.5f * kPi || std::abs(dot(a.bounds.center() - node.centre, node.axis)) <
                                       std::sin(angle) * centreDistance;
      }
      if (getenv("NOHOR")) nearHorizon = false;
      if (nearHorizon || !(gap > node.radius) || !(groupArea < epsilon * gap * gap)) {
        passed->push_back(entry);
        ++out->pairs.refinedReceiver;
        continue;
      }
      if (!*own) {
        own->emplace(options_.gather);
        (*own)->buffer_.clear(node.centre);
      }
      if ((*own)->splatNode(a, bounds, page->waveletOf(*tn), node.centre, &out->gather)) {
        tookAny = true;
        ++out->pairs.groupSplats;
        out->pairs.splatsServed += node.count;
        continue;
      }
      if (tn->leaf()) {
        // Its surfels are gathered receiver by receiver (near field, self skip).
        PBGI_RETURN_IF_ERROR(checkLeaf(*page, *tn, entry.ref));
        passed->push_back(entry);
        ++out->pairs.refinedReceiver;
        continue;
      }
      PBGI_RETURN_IF_ERROR(refineSender(*page, *tn, entry, &stack));
      ++out->pairs.refinedSender;
    }
    if (!tookAny) own->reset();
    if (*own) ++out->pairs.groupBuffers;
    return absl::OkStatus();
  }

  // An interior sender's children onto the stack, to come off in Morton order.
  static absl::Status refineSender(const TreePage& page, const TreeNode& node, const Entry& entry,
                                   std::vector<Entry>* stack) {
    PBGI_RETURN_IF_ERROR(gather_internal::checkInterior(page, node, entry.ref, entry.depth));
    const std::span<const NodeRef> children = page.childrenOf(node);
    for (size_t i = children.size(); i-- > 0;) stack->push_back({children[i], entry.depth + 1});
    return absl::OkStatus();
  }

  // A single receiver: its groups' buffers, then the walk of what came down to it.
  Outcome receive(uint32_t i, const std::vector<Entry>& senders,
                  const std::vector<const Microbuffer*>& groups) {
    thread_local std::optional<std::array<Gatherer, 2>> gatherers;
    if (!gatherers || gatherers->front().options() != options_.gather) {
      gatherers.emplace(
          std::array<Gatherer, 2>{Gatherer(options_.gather), Gatherer(options_.gather)});
    }
    Outcome out;
    ++out.pairs.receivers;
    const PairReceiver& r = receivers_[i];
    const int sides = r.twoSided ? 2 : 1;
    for (int side = 0; side < sides; ++side) {
      Gatherer& g = (*gatherers)[side];
      const Vec3f n = side == 0 ? units_[i] : -units_[i];
      GatherStats local;
      local.gathers = 1;
      g.buffer_.clear(r.position, n);
      out.status = g.walk_.runFrom(
          tree_, senders, r.position, n, &local,
          [&](const NodeAttributes& a, const gather_internal::NodeBounds& bounds,
              const WaveletRadiance* w) { return g.splatNode(a, bounds, w, r.position, &local); },
          [&](const TreePage& page, const TreeNode& leaf) {
            g.gatherSurfels(page, leaf, r.position, n, &local);
          });
      // Then the groups' pictures, the smallest group's first: roughly front to back, as a
      // layered pixel holds best (their senders lie the farther the larger the group).
      for (size_t j = groups.size(); j-- > 0;) g.buffer_.composeBuffer(*groups[j]);
      out.pairs.composed += groups.size();
      local.facesSkipped = static_cast<uint64_t>(g.buffer_.skippedFaces());
      local.pixelsSkipped = static_cast<uint64_t>(g.buffer_.skippedPixels());
      out.gather += local;
      if (!out.status.ok()) return out;
    }
    use_(i, (*gatherers)[0].buffer_, r.twoSided ? &(*gatherers)[1].buffer_ : nullptr);
    return out;
  }

  TreePageSource& tree_;
  std::span<const PairReceiver> receivers_;
  std::span<const Vec3f> units_;
  const PairGatherOptions& options_;
  const PairGatherUse& use_;
  float pixelAngle_;  // about a buffer pixel's width (a face spans pi/2)
  std::vector<uint32_t> order_;
  std::vector<ReceiverNode> nodes_;
};

absl::Status pairGather(TreePageSource& tree, std::span<const PairReceiver> receivers,
                        const PairGatherOptions& options, const PairGatherUse& use,
                        GatherStats* gatherStats, PairGatherStats* stats) {
  PBGI_RETURN_IF_ERROR(options.validate());
  std::vector<Vec3f> units(receivers.size());
  for (size_t i = 0; i < receivers.size(); ++i) {
    const PairReceiver& r = receivers[i];
    const float len = length(r.normal);
    if (!isFinite(r.position) || !isFinite(r.normal) || !(len > 0.0f) || !std::isfinite(len)) {
      return receiverError(i, r);
    }
    units[i] = r.normal / len;
  }
  if (receivers.empty()) return absl::OkStatus();
  PairWalk walk(tree, receivers, units, options, use);
  Outcome out = walk.run();
  if (gatherStats != nullptr) *gatherStats += out.gather;
  if (stats != nullptr) *stats += out.pairs;
  return out.status;
}

}  // namespace pbgi
