#pragma once
// What the two gathers share, the cube one (gather.cpp, Christensen 2008) and the
// importance-warped one (warped_gather.cpp, Ritschel et al. 2009): the traversal's culling
// tests, how a cluster looks from the receiver, the checks of what a page claims, and the
// pages a traversal holds. Private to core/pbgi.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <memory>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>
#include <fmt/format.h>

#include "core/math/vec.h"
#include "core/pbgi/gather.h"
#include "core/pbgi/sh.h"
#include "core/pbgi/surfel.h"
#include "core/pbgi/tree.h"
#include "core/pbgi/tree_build.h"
#include "core/pbgi/tree_page.h"
#include "core/pbgi/tree_walk.h"
#include "core/util/check.h"

namespace pbgi::gather_internal {

// A node's bounding sphere may cover this many times the solid angle a cluster may have
// before the node must be refined, whatever its projected area: a node seen edge-on has a
// small projected area but spreads across the buffer, and one round footprint would misplace
// its occlusion.
inline constexpr float kMaxExtentFactor = 4.0f;
// Pages held at once by one traversal. Depth-first order leaves a page's subtree before
// returning to its parent page, so a few suffice; evicting one is safe (it is fetched again).
inline constexpr size_t kMaxHeldPages = 4;
// Deeper than any tree the builder makes: a reference cycle in a damaged file stops here.
inline constexpr uint32_t kMaxGatherDepth = 2 * kMaxTreeLevels;
// A disk's splat reaches this many radii in depth either way: its round footprint spreads
// past the disk's true outline (most at grazing views), onto pixels where the same surface
// lies up to a diameter nearer or farther, and those must count as one surface (coverage adds
// up) rather than as layers that hide each other.
inline constexpr float kLayerExtentFactor = 2.0f;
// Surfels centred within this fraction of their radius of the receiver's tangent plane
// (or behind it) are on the receiver's own surface.
inline constexpr float kCoplanarFraction = 0.01f;
// A receiver within this fraction of a radius of a surfel's plane (and within the self-skip
// radius of its centre) lies on the surfel's disk.
inline constexpr float kOwnSurfaceFraction = 0.1f;
// ... and, for the bidirectional cut, faces the receiver's way within 60 degrees (a wall
// whose disk reaches a floor receiver at its foot is not the floor).
inline constexpr float kOwnSurfaceCos = 0.5f;

inline float absDotExtent(const Vec3f& n, const Vec3f& half) {
  return std::abs(n.x) * half.x + std::abs(n.y) * half.y + std::abs(n.z) * half.z;
}

// How the traversal sees a node from the receiver at p with normal n (unit): culled when its
// bounds lie entirely behind the tangent plane (their largest height above it is at most 0).
// Surfels are two-sided (each side sends its own radiance and both occlude), so a node whose
// normals all face away is not culled: the receiver sees its back sides.
enum class NodeCull { kNone, kPlane };
struct NodeBounds {
  float boundRadius2 = 0.0f;     // of the sphere around the bounds' centre
  float centerDistance2 = 0.0f;  // from the receiver to that centre
  bool outside() const { return centerDistance2 > boundRadius2; }
};

inline NodeCull cullNode(const NodeAttributes& a, const Vec3f& p, const Vec3f& n, float planeSlack,
                         NodeBounds* b) {
  const Vec3f center = a.bounds.center();
  const Vec3f half = a.bounds.diagonal() * 0.5f;
  const Vec3f fromReceiver = center - p;
  if (a.bounds.empty() || dot(fromReceiver, n) + absDotExtent(n, half) <= planeSlack) {
    return NodeCull::kPlane;
  }
  b->boundRadius2 = half.length2();
  b->centerDistance2 = fromReceiver.length2();
  return NodeCull::kNone;
}

// How the traversal sees a surfel: skipped when centred on or behind the receiver's tangent
// plane, or when the receiver lies on its disk grown by selfSkipRadius (within that many radii
// of its centre and within a tenth of a radius of its plane) and the disk's normal is within
// acos(ownSurfaceCos) of the receiver's, either way: the receiver's own surface, which would
// shadow the receiver with itself. A surfel on another surface right next to the receiver (a
// wall at the floor's edge) is gathered however near. The bidirectional cut, which integrates
// a near disk exactly, passes kOwnSurfaceCos: a wall's disk that reaches a floor receiver is
// gathered too (skipped, Sponza's points within half a radius of other geometry gathered 0.79
// of what rays measure, 1.04 gathered: transfer_bench --light bounce). The microbuffer gathers
// keep 0, any orientation. `v` receives the surfel's centre from the receiver and `dist2` its
// length squared.
inline bool skipSurfel(const Surfel& s, const Vec3f& p, const Vec3f& n, float slack,
                       float selfSkipRadius, Vec3f* v, float* dist2, float ownSurfaceCos = 0.0f) {
  *v = s.position - p;
  *dist2 = v->length2();
  return dot(*v, n) <= kCoplanarFraction * s.radius + slack ||
         (*dist2 <= sqr(selfSkipRadius * s.radius) &&
          std::abs(dot(*v, s.normal)) <= kOwnSurfaceFraction * s.radius &&
          std::abs(dot(n, s.normal)) >= ownSurfaceCos);
}

// The side of a two-sided surfel that faces a receiver at `v` from it (v: receiver to
// surfel): its normal and radiance on that side, and whether it is the back.
struct FacingSide {
  Vec3f normal;
  Rgb radiance;
  bool back;
};
inline FacingSide facingSide(const Surfel& s, const Vec3f& v) {
  if (dot(s.normal, v) < 0.0f) return {s.normal, s.radiance, false};
  return {-s.normal, s.backRadiance, true};
}

// A leaf's surfel as a microbuffer gather at p sees it: the side facing p, the vector to the
// surfel and its length squared, and whether it lies within the near field (nearFieldFactor of
// its radii), where gathers integrate its disk exactly.
struct SeenSurfel {
  const Surfel* surfel = nullptr;
  FacingSide side;
  Vec3f v;
  float dist2 = 0.0f;
  bool near = false;
};

// The surfel loop of every microbuffer gather: each surfel of `leaf` a receiver at p facing n
// gathers, to `visit(const SeenSurfel&)`; those on the receiver's own surface are skipped and
// counted, back sides counted.
template <typename Visit>
void forEachSeenSurfel(const TreePage& page, const TreeNode& leaf, const Vec3f& p, const Vec3f& n,
                       float selfSkipRadius, float nearFieldFactor, GatherStats* stats,
                       Visit&& visit) {
  const float slack = 1e-6f * maxAbsComponent(p);  // float rounding of coplanar positions
  for (const Surfel& s : page.surfelsOf(leaf)) {
    SeenSurfel seen{.surfel = &s};
    if (skipSurfel(s, p, n, slack, selfSkipRadius, &seen.v, &seen.dist2)) {
      ++stats->surfelsSkipped;
      continue;
    }
    // Two-sided: the side facing the receiver, with its own radiance.
    seen.side = facingSide(s, seen.v);
    if (seen.side.back) ++stats->surfelsBackFacing;
    seen.near = seen.dist2 < sqr(nearFieldFactor * s.radius);
    visit(seen);
  }
}

// A near disk (centre, normal, radius) as rays from a receiver at p meet it, for the gathers
// that ray-cast near disks after their traversal. Rays that hit it lie in the cone around its
// centre holding its bounding sphere (every ray, from inside the sphere).
class DiskHitTest {
 public:
  DiskHitTest(const Vec3f& center, const Vec3f& normal, float radius, const Vec3f& p)
      : v_(center - p), normal_(normal) {
    const float distance = length(v_);
    planeDistance_ = dot(v_, normal);  // < 0: the receiver is in front
    const float sinAngle = radius / distance;
    cosAngle_ = sinAngle < 1.0f ? std::sqrt(1.0f - sinAngle * sinAngle) : -1.0f;
    axis_ = v_ / distance;
    r2_ = radius * radius;
  }
  // Whether the ray from p along unit w meets the disk's front, at distance *t.
  bool hit(const Vec3f& w, float* t) const {
    if (dot(w, axis_) < cosAngle_) return false;
    const float denom = dot(w, normal_);
    if (!(denom < 0.0f)) return false;
    *t = planeDistance_ / denom;
    return !((w * *t - v_).length2() > r2_);
  }

 private:
  Vec3f v_, normal_, axis_;
  float planeDistance_ = 0.0f, cosAngle_ = 0.0f, r2_ = 0.0f;
};

// A far surfel's disk from the receiver: the unit direction to it, its distance, and its solid
// angle seen face-on times the cosine it is seen at.
struct FarDisk {
  Vec3f dir;
  float distance = 0.0f;
  float omega = 0.0f;
};
inline FarDisk farDisk(const SeenSurfel& seen) {
  const float radius = seen.surfel->radius;
  const float distance = std::sqrt(seen.dist2);
  const Vec3f dir = seen.v / distance;
  const float facing = -dot(dir, seen.side.normal);
  const float sq = std::sqrt(seen.dist2 + radius * radius);
  return {.dir = dir,
          .distance = distance,
          .omega = 2.0f * kPi * radius * radius * facing / (sq * (sq + distance))};
}

// The projected area of a node's front sides towards w (unit, from the node to the
// receiver): its SH estimate held within what the normal cone allows, area * cos(angle to w)
// between the cone's extremes. Band-2 SH overshoot a clamped cosine by 6 % face-on and ring
// above 0 past 90 degrees; coverage is energy here, so a flat cluster (narrow cone) must get
// its exact area * cos, and only a curved one the SH's shape.
inline float boundedProjectedArea(const NodeAttributes& a, float shArea, const Vec3f& w) {
  const float cosT = dot(a.cone.axis, w);
  const float sinT = safeSqrt(1.0f - cosT * cosT);
  const float cosG = a.cone.cosAngle;
  const float sinG = safeSqrt(1.0f - cosG * cosG);
  // Largest n.w over the cone: cos(max(0, angle - half-angle)); smallest: cos(angle +
  // half-angle) while that stays below 90 degrees, else 0.
  const float upper = cosT >= cosG ? 1.0f : cosT * cosG + sinT * sinG;
  const float lower = cosG > 0.0f ? cosT * cosG - sinT * sinG : 0.0f;
  return std::clamp(shArea, a.area * std::max(0.0f, lower), a.area * std::max(0.0f, upper));
}

// How far a cluster's splat reaches in depth either way, seen along unit `dir`: the half-depth
// of its bounding box along the view (the range its disks lie in) plus one mean surfel radius
// (as disks reach past their own extent). Neighbouring pieces of one surface overlap in that
// range and add up; an occluder and what it hides (a column and the wall behind) do not, and
// the front one hides the back. Two bounding radii instead (as for disks) merged occluders
// with what they hide. Measured, one bounce (max_depth 2, 250k surfels, draft) against the
// path tracer's indirect light: Sponza +21.6 % with bounding radii, +3.6 % with this (+1.3 %
// at the default preset); Cornell box +6.6 %, then +0.0 % (-0.8 %). Without the surfel
// radius a disk seen from close by loses 2.1 % (Gather.CoaxialDiskMatchesFormFactor).
// The mean radius of a node's surfels: sqrt(area / (pi count)), 0 for an empty node.
inline float meanSurfelRadius(const NodeAttributes& a) {
  return a.pointCount > 0 ? std::sqrt(a.area / (kPi * static_cast<float>(a.pointCount))) : 0.0f;
}

inline float clusterDepthExtent(const NodeAttributes& a, const Vec3f& dir) {
  return absDotExtent(dir, a.bounds.diagonal() * 0.5f) + meanSurfelRadius(a);
}

// A node seen from the receiver along unit `dir` (receiver to centroid): the SH basis
// towards the receiver, the raw SH projected area of the front sides and the bounded one, the
// bounded area of the back sides (the front area seen from the other way: a surfel shows the
// receiver its back when its front faces away), and all it covers.
struct ClusterView {
  float basis[kShCoefficients];
  Vec3f toReceiver{0.0f};  // unit, from the node towards the receiver
  float shArea = 0.0f;
  float area = 0.0f;      // front sides
  float backArea = 0.0f;  // back sides
  float coverage() const { return area + backArea; }
};

inline void viewCluster(const NodeAttributes& a, const Vec3f& dir, ClusterView* view) {
  view->toReceiver = -dir;
  evalShBasis(-dir, view->basis);  // towards the receiver, as the node's functions expect
  float shArea = 0.0f, shBack = 0.0f;
  for (int i = 0; i < kShCoefficients; ++i) {
    const float term = a.areaSh.c[i] * view->basis[i];
    shArea += term;
    // At dir rather than -dir: band 1 (i = 1..3) changes sign, bands 0 and 2 do not.
    shBack += (i >= 1 && i <= 3) ? -term : term;
  }
  view->shArea = shArea;
  view->area = boundedProjectedArea(a, shArea, -dir);
  view->backArea = boundedProjectedArea(a, shBack, dir);
}

// The mean radiance the cluster sends the receiver over all it covers: its front sides' from
// the SH ratio (in which their common ringing cancels), its back sides' the mean back
// radiance, weighted by the areas each side shows, and its glossy surfels' intensity towards
// the receiver (`wavelet`, when it has one: tree_page.h) over all it covers.
inline Rgb clusterRadiance(const NodeAttributes& a, const ClusterView& view,
                           const WaveletRadiance* wavelet) {
  Rgb front(0.0f);
  if (view.shArea > 0.0f) {
    for (int i = 0; i < kShCoefficients; ++i) front += a.powerSh.c[i] * view.basis[i];
    front = vmax(front, Rgb(0.0f)) / view.shArea;
  }
  const float covered = view.coverage();
  if (!(covered > 0.0f)) return Rgb(0.0f);
  const Rgb back = a.area > 0.0f ? vmax(a.backPower, Rgb(0.0f)) / a.area : Rgb(0.0f);
  Rgb sum = front * view.area + back * view.backArea;
  if (wavelet != nullptr) sum += vmax(wavelet->evaluate(view.toReceiver), Rgb(0.0f));
  return sum / covered;
}

// The node a reference names, DataLoss when the page has no such node.
inline absl::StatusOr<const TreeNode*> nodeAt(const TreePage& page, NodeRef ref) {
  if (ref.index >= page.nodes.size()) {
    return absl::DataLossError(
        fmt::format("gather: page {} has {} nodes, a reference names node {}", ref.page,
                    page.nodes.size(), ref.index));
  }
  return &page.nodes[ref.index];
}

// DataLoss when a leaf's surfels or an interior node's children lie outside its page, or the
// traversal is deeper than any tree the builder makes.
inline absl::Status checkLeaf(const TreePage& page, const TreeNode& node, NodeRef ref) {
  if (uint64_t{node.first} + node.surfelCount > page.surfels.size()) {
    return absl::DataLossError(
        fmt::format("gather: page {} node {} names surfels {}..{} of {}", ref.page, ref.index,
                    node.first, uint64_t{node.first} + node.surfelCount, page.surfels.size()));
  }
  return absl::OkStatus();
}

inline absl::Status checkInterior(const TreePage& page, const TreeNode& node, NodeRef ref,
                                  uint32_t depth) {
  if (uint64_t{node.first} + node.childCount > page.children.size()) {
    return absl::DataLossError(
        fmt::format("gather: page {} node {} names children {}..{} of {}", ref.page, ref.index,
                    node.first, uint64_t{node.first} + node.childCount, page.children.size()));
  }
  if (depth + 1 > kMaxGatherDepth) {
    return absl::DataLossError(
        fmt::format("gather: tree deeper than {} levels at page {} node {} (a reference cycle?)",
                    kMaxGatherDepth, ref.page, ref.index));
  }
  return absl::OkStatus();
}

// The near-field options both gathers have, checked the same way; `what` names the options
// in the message.
inline absl::Status validateNearField(const char* what, float nearFieldFactor,
                                      float selfSkipRadius) {
  if (!(nearFieldFactor >= 0.0f && nearFieldFactor <= 1e3f)) {
    return absl::InvalidArgumentError(fmt::format(
        "{}: nearFieldFactor must be in [0, 1000], got {}", what, nearFieldFactor));
  }
  if (!(selfSkipRadius >= 0.0f && selfSkipRadius <= 100.0f)) {
    return absl::InvalidArgumentError(
        fmt::format("{}: selfSkipRadius must be in [0, 100], got {}", what, selfSkipRadius));
  }
  return absl::OkStatus();
}

// A buffer's resolution, once its options are known to be valid: invalid options reaching a
// gatherer are a caller bug (users' options go through validate()).
template <typename Options>
int checkedResolution(const Options& options) {
  if (absl::Status s = options.validate(); !s.ok()) {
    detail::checkFailed(__FILE__, __LINE__, std::string(s.message()));
  }
  return options.resolution;
}

// Page `id` from the pages a traversal holds (at most kMaxHeldPages, the least recently used
// evicted), fetched from the source when not held, so that gathers after the first allocate
// nothing. `Held` is any struct with fields id, page (shared_ptr) and lastUse; `clock`
// counts uses.
template <typename Held>
absl::StatusOr<const TreePage*> holdPage(std::vector<Held>& held, uint64_t& clock,
                                         TreePageSource& tree, uint32_t id, GatherStats* stats) {
  ++clock;
  for (Held& h : held) {
    if (h.id == id) {
      h.lastUse = clock;
      return h.page.get();
    }
  }
  ++stats->pagesTouched;
  absl::StatusOr<std::shared_ptr<const TreePage>> page = tree.page(id);
  if (!page.ok()) return page.status();
  PBGI_CHECK(*page != nullptr);  // a source returns a page or an error
  Held* slot;
  if (held.size() < kMaxHeldPages) {
    slot = &held.emplace_back();
  } else {
    slot = &*std::min_element(held.begin(), held.end(),
                              [](const Held& a, const Held& b) { return a.lastUse < b.lastUse; });
  }
  slot->id = id;
  slot->page = *std::move(page);
  slot->lastUse = clock;
  return slot->page.get();
}

}  // namespace pbgi::gather_internal

namespace pbgi {

namespace gather_internal {

// One node of a walk (TreeWalk's and SweptWalk's): culled behind the receiver's tangent plane,
// taken whole by splat(attributes, bounds, wavelet), handed to leaf(page, node), or refined, each child
// going to push(child, depth) last child first, so that they come off a stack in Morton order.
template <typename Splat, typename Leaf, typename Push>
absl::Status visitNode(const TreePage& page, NodeRef ref, uint32_t depth, const Vec3f& p,
                       const Vec3f& n, float planeSlack, GatherStats* stats, Splat&& splat,
                       Leaf&& leaf, Push&& push) {
  absl::StatusOr<const TreeNode*> nodeOr = nodeAt(page, ref);
  if (!nodeOr.ok()) return nodeOr.status();
  const TreeNode& node = **nodeOr;
  ++stats->nodesVisited;
  NodeBounds bounds;
  if (cullNode(node.attributes, p, n, planeSlack, &bounds) != NodeCull::kNone) {
    ++stats->nodesCulledPlane;
    return absl::OkStatus();
  }
  if (bounds.outside() && splat(node.attributes, bounds, page.waveletOf(node))) {
    return absl::OkStatus();
  }
  if (node.leaf()) {
    if (absl::Status s = checkLeaf(page, node, ref); !s.ok()) return s;
    leaf(page, node);
    return absl::OkStatus();
  }
  if (absl::Status s = checkInterior(page, node, ref, depth); !s.ok()) return s;
  const std::span<const NodeRef> children = page.childrenOf(node);
  for (size_t i = children.size(); i-- > 0;) push(children[i], depth + 1);
  return absl::OkStatus();
}

}  // namespace gather_internal

template <typename Splat, typename Leaf>
absl::Status TreeWalk::run(TreePageSource& tree, const Vec3f& p, const Vec3f& n,
                           GatherStats* stats, Splat&& splat, Leaf&& leaf) {
  const StackEntry root{tree.root(), 0};
  return runFrom(tree, std::span<const StackEntry>(&root, 1), p, n, stats, splat, leaf);
}

template <typename Splat, typename Leaf>
absl::Status TreeWalk::runFrom(TreePageSource& tree, std::span<const StackEntry> starts,
                               const Vec3f& p, const Vec3f& n, GatherStats* stats, Splat&& splat,
                               Leaf&& leaf) {
  using namespace gather_internal;
  const float planeSlack = 1e-6f * maxAbsComponent(p);  // float rounding of coplanar positions
  stack_.assign(starts.rbegin(), starts.rend());
  absl::Status status;
  while (!stack_.empty() && status.ok()) {
    const StackEntry entry = stack_.back();
    stack_.pop_back();
    current_ = entry;
    absl::StatusOr<const TreePage*> pageOr = holdPage(held_, useClock_, tree, entry.ref.page, stats);
    if (!pageOr.ok()) {
      status = pageOr.status();
      break;
    }
    status = visitNode(**pageOr, entry.ref, entry.depth, p, n, planeSlack, stats, splat, leaf,
                       [&](NodeRef child, uint32_t depth) { stack_.push_back({child, depth}); });
  }
  held_.clear();  // pages live no longer than the walk that used them
  return status;
}

inline void SweptWalk::begin(NodeRef root, const Vec3f& p, const Vec3f& n) {
  p_ = p;
  n_ = n;
  for (auto& [id, bucket] : buckets_) bucket.clear();
  pages_ = {};
  stack_.clear();
  push({root, 0});
}

inline void SweptWalk::push(const Entry& e) {
  std::vector<Entry>& bucket = buckets_[e.ref.page];
  if (bucket.empty()) pages_.push(e.ref.page);
  bucket.push_back(e);
}

template <typename Splat, typename Leaf>
absl::Status SweptWalk::sweep(TreePageSource& tree, uint32_t lowest, GatherStats* stats,
                              Splat&& splat, Leaf&& leaf) {
  using namespace gather_internal;
  const float planeSlack = 1e-6f * maxAbsComponent(p_);  // float rounding of coplanar positions
  while (!pages_.empty() && pages_.top() >= lowest) {
    const uint32_t id = pages_.top();
    pages_.pop();
    // Reversed, so that the bucket's nodes come off the stack in the order they arrived.
    std::vector<Entry>& bucket = buckets_[id];
    stack_.assign(bucket.rbegin(), bucket.rend());
    bucket.clear();
    ++stats->pagesTouched;
    absl::StatusOr<std::shared_ptr<const TreePage>> held = tree.page(id);
    if (!held.ok()) return held.status();
    PBGI_CHECK(*held != nullptr);  // a source returns a page or an error
    while (!stack_.empty()) {
      const Entry entry = stack_.back();
      stack_.pop_back();
      if (absl::Status s = visitNode(**held, entry.ref, entry.depth, p_, n_, planeSlack, stats,
                                     splat, leaf,
                                     [&](NodeRef child, uint32_t depth) {
                                       if (child.page == id) {
                                         stack_.push_back({child, depth});
                                       } else {
                                         push({child, depth});
                                       }
                                     });
          !s.ok()) {
        return s;
      }
    }
  }
  return absl::OkStatus();
}

}  // namespace pbgi
