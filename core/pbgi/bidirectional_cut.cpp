#include "core/pbgi/bidirectional_cut.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <numbers>
#include <optional>
#include <queue>
#include <unordered_map>

#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <fmt/format.h>

#include "core/math/solid_angle.h"
#include "core/pbgi/cut_internal.h"
#include "core/pbgi/gather_internal.h"
#include "core/sampling/low_discrepancy.h"
#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"
#include "core/scene/scene.h"

namespace pbgi {

namespace {

using namespace gather_internal;

using namespace cut_internal;

// Receiver items of a pair: a receiver-tree node by index, or a single receiver with this bit.
constexpr uint32_t kReceiverBit = 0x80000000u;
constexpr uint32_t kNoParent = std::numeric_limits<uint32_t>::max();
constexpr float kHalfPi = 0.5f * kPi;
constexpr float kInfinity = std::numeric_limits<float>::infinity();

// A criterion's value within its threshold; a threshold of 0 accepts nothing, so that zero
// thresholds refine every pair down to surfels against single receivers.
bool within(float value, float threshold) { return threshold > 0.0f && value <= threshold; }

// The light arriving at a receiver node as a linear field around the node's centre: a receiver
// at centre + delta with normal n gets irradiance n . (v[c] + j[c] delta) in channel c (j[c]
// by rows). Fields of nodes along a path add up, each re-centred on the child.
struct LinearField {
  // Imath's vectors do not initialise themselves.
  LinearField() {
    for (int c = 0; c < 3; ++c) {
      v[c] = Vec3f(0.0f);
      for (int r = 0; r < 3; ++r) j[c][r] = Vec3f(0.0f);
    }
  }
  std::array<Vec3f, 3> v;
  std::array<std::array<Vec3f, 3>, 3> j;

  Vec3f at(int c, const Vec3f& delta) const {
    return v[c] + Vec3f(dot(j[c][0], delta), dot(j[c][1], delta), dot(j[c][2], delta));
  }
  // Adds `o`, a field around a centre `offset` away from this one's (offset = this centre
  // minus o's centre).
  void add(const LinearField& o, const Vec3f& offset) {
    for (int c = 0; c < 3; ++c) {
      v[c] += o.at(c, offset);
      for (int r = 0; r < 3; ++r) j[c][r] += o.j[c][r];
    }
  }
};

struct ReceiverNode {
  Bounds3f bounds;
  Vec3f center{0.0f};
  float radius = 0.0f;
  Vec3f axis{0.0f, 0.0f, 1.0f};
  float angle = 0.0f;  // half-angle of the normal cone (radians)
  float cosAngle = 1.0f, sinAngle = 0.0f;
  uint32_t first = 0, count = 0;  // receivers, in the tree's order
  uint32_t firstChild = 0, childCount = 0;
  uint32_t parent = kNoParent;
  LinearField field;
};

struct Pair {
  NodeRef light;
  uint32_t receiver = 0;  // receiver node, or kReceiverBit | receiver index
  uint32_t depth = 0;     // of the light node, against reference cycles
};

// The receiver side of a pair as the criteria see it.
struct ReceiverView {
  Vec3f center{0.0f};
  Vec3f halfExtent{0.0f};  // half the bounds' diagonal
  float radius = 0.0f;
  Vec3f axis{0.0f, 0.0f, 1.0f};
  float angle = 0.0f;
  float cosAngle = 1.0f, sinAngle = 0.0f;
  float chord = 0.0f;  // 2 sin(angle / 2): the farthest a normal of the cone is from its axis
  bool single = false;
};

// Light leaving a point towards the receivers: radiant intensity (per channel) in the direction
// of the receivers' centre, its gradient with respect to that direction (3D, per channel), and
// a softening radius^2 added to the squared distance (a surfel's own radius: the virtual
// spherical light's bound on the 1/d^2 spike).
struct PointSource {
  Vec3f position{0.0f};
  Rgb intensity{0.0f};
  std::array<Vec3f, 3> gradient{Vec3f(0.0f), Vec3f(0.0f), Vec3f(0.0f)};
  float softening2 = 0.0f;
};

// Light from a cluster waiting for its shadow ray's target, picked below the cluster in a
// lower page (see descend()).
struct Probe {
  NodeRef at;             // the node the descent goes on from
  uint32_t depth = 0;     // of `at`
  uint32_t receiver = 0;  // the receiver item the light goes to
  uint32_t origin = 0;    // the receiver the ray leaves from
  float estimate = 0.0f;  // what `at` sends the origin, as its parent estimated it
  float scale = 1.0f;     // the descent's corrections so far (see descend())
  Rng rng{0};
  PointSource src;
};

struct Bucket {
  std::vector<Pair> pairs;
  std::vector<Probe> probes;
  std::vector<NearStep> near;
  bool queued = false;
};

uint64_t lightId(NodeRef ref) { return (uint64_t{ref.page} << 32) | ref.index; }

// A surfel as a point source towards direction w (unit, from the surfel to the receivers): the
// side facing w (two-sided), or false when that side sends nothing.
bool surfelSource(const Surfel& s, const Vec3f& w, PointSource* src) {
  const FacingSide side = facingSide(s, -w);
  const float cosS = dot(side.normal, w);
  if (!(cosS > 0.0f) || isBlack(side.radiance)) return false;
  const float area = s.area();
  src->position = s.position;
  src->intensity = side.radiance * (area * cosS);
  for (int c = 0; c < 3; ++c) src->gradient[c] = side.normal * (side.radiance[c] * area);
  src->softening2 = s.radius * s.radius;
  return true;
}

// A cluster as a point source at its centroid towards w (unit, from it to the receivers): its
// intensity (radiance times the area it shows, both sides, as the gathers see it), and the
// front sides' SH power's gradient scaling their part.
PointSource clusterSource(const NodeAttributes& a, const WaveletRadiance* wavelet,
                          const ClusterView& view, const Vec3f& w) {
  PointSource src;
  src.position = a.centroid;
  src.intensity = clusterRadiance(a, view, wavelet) * view.coverage();
  if (!(view.shArea > 0.0f)) return src;
  // The front's I = P(w) area / shArea: the SH power's gradient, scaled alike, and held to
  // 4 I per radian (a Lambertian patch changes by at most its whole intensity per radian; the
  // band-2 SH of a flat cluster can ring steeper near grazing). The back's mean radiance is
  // taken as constant across directions.
  Vec3f grad[kShCoefficients];
  evalShBasisGradient(w, grad);
  const float scale = view.area / view.shArea;
  for (int c = 0; c < 3; ++c) {
    Vec3f g(0.0f);
    for (int i = 0; i < kShCoefficients; ++i) g += grad[i] * a.powerSh.c[i][c];
    g *= scale;
    const float len = length(g), cap = 4.0f * src.intensity[c];
    src.gradient[c] = len > cap ? g * (cap / len) : g;
  }
  return src;
}

absl::Status checkReceiver(const CutReceiver& r, size_t i) {
  const float len = length(r.n);
  if (!isFinite(r.p) || !isFinite(r.n) || !isFinite(r.ng) || !(std::abs(len - 1.0f) < 1e-3f)) {
    return absl::InvalidArgumentError(fmt::format(
        "bidirectional cut: receiver {} needs a finite position and unit normals, got "
        "position {} normal {} geometric normal {}",
        i, r.p, r.n, r.ng));
  }
  return absl::OkStatus();
}

// The receivers of one cut as an octree (leaves of the cut's receiverLeafSize, each node with
// its bounds and normal cone), and the light the cut deposits on them: a linear field per
// node, an exact sum per receiver. An item is a node's index or kReceiverBit | a receiver's.
struct ReceiverTree {
  std::span<const CutReceiver> receivers;
  std::vector<ReceiverNode> nodes;
  std::vector<uint32_t> order;  // receiver indices, grouped by tree node
  std::vector<Rgb> single;      // per receiver: light from pairs with it alone

  void build(std::span<const CutReceiver> cutReceivers, int leafSize);
  ReceiverView view(uint32_t item) const {
    ReceiverView v;
    if (item & kReceiverBit) {
      const CutReceiver& r = receivers[item & ~kReceiverBit];
      v.center = r.p;
      v.axis = r.n;
      v.single = true;
    } else {
      const ReceiverNode& n = nodes[item];
      v.center = n.center;
      v.halfExtent = n.bounds.diagonal() * 0.5f;
      v.radius = n.radius;
      v.axis = n.axis;
      v.angle = n.angle;
      v.cosAngle = n.cosAngle;
      v.sinAngle = n.sinAngle;
      v.chord = n.angle >= kPi ? 2.0f : 2.0f * std::sin(0.5f * n.angle);
    }
    return v;
  }

  // Adds a point source's light, times `weight` (what of it arrives: the descent's corrections
  // when its shadow ray did), to a receiver item: exactly at a
  // single receiver, as a linear field around a node's centre (first order in the offset from
  // it: the source's distance and direction, and its intensity's change with direction).
  void deposit(uint32_t item, const PointSource& src, float weight) {
    if (item & kReceiverBit) {
      const uint32_t r = item & ~kReceiverBit;
      const Vec3f v = src.position - receivers[r].p;
      const float d2 = v.length2();
      const float cosR = dot(receivers[r].n, v);
      if (cosR > 0.0f && d2 > 0.0f) {
        single[r] += src.intensity * (weight * cosR / (std::sqrt(d2) * (d2 + src.softening2)));
      }
      return;
    }
    ReceiverNode& n = nodes[item];
    const Vec3f u = src.position - n.center;
    const float d2 = u.length2();
    if (!(d2 > 0.0f)) return;
    const float d = std::sqrt(d2);
    const Vec3f w = u / d;  // towards the source
    const float inv2 = weight / (d2 + src.softening2);
    const float inv3 = inv2 / d;
    for (int c = 0; c < 3; ++c) {
      const float i = src.intensity[c];
      // The gradient is with respect to the emission direction, -w: only its part across w.
      const Vec3f g = src.gradient[c] - w * dot(w, src.gradient[c]);
      n.field.v[c] += w * (i * inv2);
      for (int row = 0; row < 3; ++row) {
        Vec3f e(0.0f);
        e[row] = 1.0f;
        n.field.j[c][row] += (w * (3.0f * w[row]) - e) * (i * inv3) + g * (w[row] * inv3);
      }
    }
  }

  // A source's light, times `weight`, at receiver r of node `node` alone: the source's
  // intensity towards the node's centre, changed by its gradient for r's place, at r's own
  // distance and cosine.
  void depositAt(uint32_t r, uint32_t node, const PointSource& src, float weight) {
    const Vec3f v = src.position - receivers[r].p;
    const float d2 = v.length2();
    const float cosR = dot(receivers[r].n, v);
    if (!(cosR > 0.0f) || !(d2 > 0.0f)) return;
    const Vec3f u = src.position - nodes[node].center;
    const float dc2 = u.length2();
    Rgb intensity = src.intensity;
    if (dc2 > 0.0f) {
      const float dc = std::sqrt(dc2);
      const Vec3f w = u / dc;
      const Vec3f delta = receivers[r].p - nodes[node].center;
      for (int c = 0; c < 3; ++c) {
        const Vec3f g = src.gradient[c] - w * dot(w, src.gradient[c]);
        intensity[c] = std::max(0.0f, intensity[c] + dot(g, delta) / dc);
      }
    }
    single[r] += intensity * (weight * cosR / (std::sqrt(d2) * (d2 + src.softening2)));
  }

  // A random receiver of an item: where its shadow rays leave from; with `strata` > 1, of the
  // `stratum`th of that many equal runs of its receivers in the tree's order (octants in turn,
  // so the runs spread over the node).
  uint32_t originOf(uint32_t item, Rng& rng, uint32_t stratum = 0, uint32_t strata = 1) const {
    if (item & kReceiverBit) return item & ~kReceiverBit;
    const ReceiverNode& n = nodes[item];
    const uint32_t begin = static_cast<uint32_t>(uint64_t{stratum} * n.count / strata);
    const uint32_t end = static_cast<uint32_t>(uint64_t{stratum + 1} * n.count / strata);
    const uint32_t size = std::max(end - begin, 1u);
    const uint32_t k = std::min(size - 1, static_cast<uint32_t>(rng.uniform() * size));
    return order[n.first + std::min(begin + k, n.count - 1)];
  }
  uint64_t served(uint32_t item) const { return (item & kReceiverBit) ? 1 : nodes[item].count; }
  // Each node's field pushed down to its children (re-centred), then read at each receiver,
  // plus its own light: the cut's irradiance, in the receivers' order.
  absl::Status read(std::span<Rgb> out);

 private:
  ReceiverNode makeNode(uint32_t first, uint32_t count, uint32_t parent) const;
  std::vector<uint32_t> scratch;
};

ReceiverNode ReceiverTree::makeNode(uint32_t first, uint32_t count, uint32_t parent) const {
  ReceiverNode node;
  node.first = first;
  node.count = count;
  node.parent = parent;
  Vec3f normalSum(0.0f);
  for (uint32_t i = first; i < first + count; ++i) {
    const CutReceiver& r = receivers[order[i]];
    node.bounds.extend(r.p);
    normalSum += r.n;
  }
  node.center = node.bounds.center();
  node.radius = node.bounds.radius();
  const float len = length(normalSum);
  if (!(len > 1e-6f)) {
    node.axis = Vec3f(0.0f, 0.0f, 1.0f);
    node.angle = kPi;
    node.cosAngle = -1.0f;
    node.sinAngle = 0.0f;
    return node;
  }
  node.axis = normalSum / len;
  float minCos = 1.0f;
  for (uint32_t i = first; i < first + count; ++i) {
    minCos = std::min(minCos, dot(node.axis, receivers[order[i]].n));
  }
  node.angle = safeAcos(minCos);
  node.cosAngle = std::cos(node.angle);
  node.sinAngle = std::sin(node.angle);
  return node;
}

void ReceiverTree::build(std::span<const CutReceiver> cutReceivers, int leafSize) {
  receivers = cutReceivers;
  single.assign(receivers.size(), Rgb(0.0f));
  nodes.clear();
  order.resize(receivers.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<uint32_t>(i);
  if (receivers.empty()) return;
  nodes.push_back(makeNode(0, static_cast<uint32_t>(receivers.size()), kNoParent));
  // Breadth first: children follow their parents, so one forward pass pushes light down.
  for (size_t i = 0; i < nodes.size(); ++i) {
    const uint32_t first = nodes[i].first, count = nodes[i].count;
    if (count <= static_cast<uint32_t>(leafSize)) continue;
    const Vec3f mid = nodes[i].center;
    std::array<uint32_t, 9> start{};
    auto octant = [&](uint32_t r) {
      const Vec3f& p = receivers[r].p;
      return (p.x > mid.x ? 1 : 0) | (p.y > mid.y ? 2 : 0) | (p.z > mid.z ? 4 : 0);
    };
    for (uint32_t k = first; k < first + count; ++k) ++start[octant(order[k]) + 1];
    int groups = 0;
    for (int o = 0; o < 8; ++o) groups += start[o + 1] > 0 ? 1 : 0;
    std::vector<std::pair<uint32_t, uint32_t>> ranges;  // (first, count) per child
    if (groups >= 2) {
      for (int o = 0; o < 8; ++o) start[o + 1] += start[o];
      scratch.resize(count);
      std::array<uint32_t, 8> fill{};
      for (int o = 0; o < 8; ++o) fill[o] = start[o];
      for (uint32_t k = first; k < first + count; ++k) scratch[fill[octant(order[k])]++] = order[k];
      std::copy(scratch.begin(), scratch.begin() + count, order.begin() + first);
      for (int o = 0; o < 8; ++o) {
        if (start[o + 1] > start[o]) ranges.push_back({first + start[o], start[o + 1] - start[o]});
      }
    } else {
      // Every receiver in one place (or one float step apart): halves, in the given order.
      ranges.push_back({first, count / 2});
      ranges.push_back({first + count / 2, count - count / 2});
    }
    nodes[i].firstChild = static_cast<uint32_t>(nodes.size());
    nodes[i].childCount = static_cast<uint32_t>(ranges.size());
    for (const auto& [f, c] : ranges) {
      nodes.push_back(makeNode(f, c, static_cast<uint32_t>(i)));
    }
  }
}

absl::Status ReceiverTree::read(std::span<Rgb> out) {
  for (size_t i = 1; i < nodes.size(); ++i) {
    ReceiverNode& n = nodes[i];
    const ReceiverNode& parent = nodes[n.parent];
    n.field.add(parent.field, n.center - parent.center);
  }
  for (const ReceiverNode& n : nodes) {
    if (n.childCount > 0) continue;
    for (uint32_t k = n.first; k < n.first + n.count; ++k) {
      const uint32_t r = order[k];
      const CutReceiver& rec = receivers[r];
      const Vec3f delta = rec.p - n.center;
      Rgb e;
      for (int c = 0; c < 3; ++c) e[c] = std::max(0.0f, dot(rec.n, n.field.at(c, delta)));
      out[r] = e + single[r];
      if (!isFinite(out[r])) {
        return absl::DataLossError(fmt::format(
            "cut: irradiance {} at {} is not finite: the tree holds non-finite radiance", out[r],
            rec.p));
      }
    }
  }
  return absl::OkStatus();
}

}  // namespace

struct BidirectionalCut::State {
  ReceiverTree tree;
  std::unordered_map<uint32_t, Bucket> buckets;
  std::priority_queue<uint32_t> pages;
  std::vector<Pair> stack;
  std::vector<Probe> probes;        // the page's being resolved
  std::vector<uint8_t> lit;         // a leaf's surfels that send light
  std::vector<Rgb> leafLight;       // and what each sends a single receiver
  std::vector<NearHit> nearHits;    // the near field's
  std::vector<NearStep> nearSteps;  // the page's readings under way
  std::vector<NearStep> nearStack;
  uint64_t pending = 0;
  NodeRef root;
  bool nearTraced = false;  // the near field's rays are traced when the root's page is read
  float nearRadius = 0.0f;  // 0 without a near field, or before the root's page
  float readRadius = 0.0f;

  // The cut under way (begin() to finish()).
  CutOptions opts;
  TreePageSource* source = nullptr;
  const Scene* scn = nullptr;
  uint64_t key = 0;
  std::optional<uint64_t> lightKey;
  CutStats stats;

  // The random numbers of a pair's evaluation (CutJob::lightKey).
  Rng rngFor(const Pair& pair) const {
    return lightKey ? Rng::forKeys(*lightKey, lightId(pair.light))
                    : Rng::forKeys(key, lightId(pair.light), pair.receiver);
  }

  absl::Status begin(TreePageSource& treeSource, const Scene& scene,
                     std::span<const CutReceiver> cutReceivers, uint64_t cutKey,
                     const CutOptions& options, std::optional<uint64_t> cutLightKey);
  // The highest page with pairs waiting; nullopt when the cut is done.
  std::optional<uint32_t> nextPage() const {
    if (pages.empty()) return std::nullopt;
    return pages.top();
  }
  // Evaluates the pairs waiting on pages `lowest` and up, highest first, with those that
  // their refinement sends to those pages.
  absl::Status sweep(uint32_t lowest);
  absl::Status finish(std::span<Rgb> out, CutStats* statsOut);

  // A pair to evaluate: now when its light is in the page at hand, else in its page's bucket.
  void push(const Pair& p, uint32_t currentPage) {
    if (p.light.page == currentPage) {
      stack.push_back(p);
      return;
    }
    waitOn(p.light.page).pairs.push_back(p);
  }
  // The bucket of page `id`, queued for the sweep, for one more waiting pair or descent.
  Bucket& waitOn(uint32_t id) {
    Bucket& b = buckets[id];
    if (!b.queued) {
      b.queued = true;
      pages.push(id);
    }
    ++pending;
    stats.peakPendingPairs = std::max(stats.peakPendingPairs, pending);
    return b;
  }

  // A cluster's light at a receiver item, once its shadow ray's target is known: deposited
  // when the ray arrives, else dropped (and dropped when no surfel sends the receiver
  // anything); or, when the target lies in another page, waiting there.
  void resolve(const Descent& d, uint32_t receiver, uint32_t origin, const Rng& rng,
               const PointSource& src) {
    switch (d.kind) {
      case Descent::Kind::kNothing:
        return;
      case Descent::Kind::kSurfel:
        if (opts.recordVisibility && !(receiver & kReceiverBit)) {
          // Each receiver of the node its own ray to the surfel the descent picked.
          const ReceiverNode& n = tree.nodes[receiver];
          for (uint32_t k = n.first; k < n.first + n.count; ++k) {
            const uint32_t r = tree.order[k];
            if (visibleSurfel(*scn, tree.receivers[r], d.surfel, &stats)) {
              tree.depositAt(r, receiver, src, d.scale);
            }
          }
          return;
        }
        if (visibleSurfel(*scn, tree.receivers[origin], d.surfel, &stats)) {
          tree.deposit(receiver, src, d.scale);
        }
        return;
      case Descent::Kind::kElsewhere:
        waitOn(d.next.page)
            .probes.push_back({.at = d.next,
                               .depth = d.depth,
                               .receiver = receiver,
                               .origin = origin,
                               .estimate = d.estimate,
                               .scale = d.scale,
                               .rng = rng,
                               .src = src});
        return;
    }
  }

  void refineReceiver(const Pair& pair, uint32_t page) {
    ++stats.refinedReceiver;
    const ReceiverNode& n = tree.nodes[pair.receiver];
    if (n.childCount > 0) {
      for (uint32_t c = 0; c < n.childCount; ++c) {
        push({pair.light, n.firstChild + c, pair.depth}, page);
      }
    } else {
      for (uint32_t k = n.first; k < n.first + n.count; ++k) {
        push({pair.light, kReceiverBit | tree.order[k], pair.depth}, page);
      }
    }
  }

  // A leaf of the light tree against a receiver item: every surfel's light exactly (as a
  // virtual spherical light at a single receiver, to first order at a node), visibility from
  // rays to surfels, one per stratum of the leaf: as many strata as the leaf's solid angle
  // holds eps_L, so that no ray decides more light than a cluster's (every surfel its own ray
  // when eps_L is 0).
  void evaluateLeaf(const Pair& pair, const TreePage& page, const TreeNode& leaf,
                    const ReceiverView& rv) {
    ++stats.leafPairs;
    const std::span<const Surfel> surfels = page.surfelsOf(leaf);
    const size_t n = surfels.size();
    lit.assign(n, 0);
    leafLight.resize(n);
    float solidAngle = 0.0f;
    size_t litCount = 0;
    for (size_t k = 0; k < n; ++k) {
      const Surfel& s = surfels[k];
      bool sends = false;
      if (rv.single) {
        sends = surfelLight(s, tree.receivers[pair.receiver & ~kReceiverBit], opts.selfSkipRadius,
                            nearRadius, &leafLight[k]);
      } else {
        sends = !isBlack(facingSide(s, s.position - rv.center).radiance);
      }
      if (!sends) continue;
      lit[k] = 1;
      ++litCount;
      const Vec3f v = s.position - rv.center;
      const float d2 = v.length2() + s.radius * s.radius;
      solidAngle += s.area() * std::abs(dot(s.normal, v)) / (std::sqrt(v.length2()) * d2);
    }
    stats.surfelTerms += n;
    stats.receiversServed += tree.served(pair.receiver) * n;
    if (litCount == 0) return;
    const size_t strata =
        opts.lightSolidAngle > 0.0f
            ? std::clamp<size_t>(static_cast<size_t>(std::ceil(solidAngle / opts.lightSolidAngle)), 1, n)
            : n;
    Rng rng = rngFor(pair);
    for (size_t g = 0; g < strata; ++g) {
      const size_t begin = g * n / strata, end = (g + 1) * n / strata;
      size_t candidates = 0;
      for (size_t k = begin; k < end; ++k) candidates += lit[k];
      if (candidates == 0) continue;
      // A random lit surfel of the stratum, as the target of the stratum's ray.
      size_t pick = std::min(candidates - 1, static_cast<size_t>(rng.uniform() * candidates));
      size_t target = begin;
      for (size_t k = begin; k < end; ++k) {
        if (!lit[k]) continue;
        if (pick-- == 0) {
          target = k;
          break;
        }
      }
      const CutReceiver& from = tree.receivers[tree.originOf(pair.receiver, rng)];
      if (!visibleSurfel(*scn, from, surfels[target], &stats)) continue;
      for (size_t k = begin; k < end; ++k) {
        if (!lit[k]) continue;
        if (rv.single) {
          tree.single[pair.receiver & ~kReceiverBit] += leafLight[k];
          continue;
        }
        PointSource src;
        if (surfelSource(surfels[k], normalize(rv.center - surfels[k].position), &src)) {
          tree.deposit(pair.receiver, src, 1.0f);
        }
      }
    }
  }

  // A pair small enough to evaluate whole (the light seen from the receivers' centre along
  // `dir`, at squared distance d2, as `view`): the cluster's light towards every receiver,
  // through a shadow ray descending to one of its surfels, when the centroid lies above every
  // receiver's horizon; dropped when below all of them; else the receivers are refined.
  absl::Status evaluateSmall(const Pair& pair, const TreePage& page, const TreeNode& node,
                             const ReceiverView& rv, const ClusterView& view, const Vec3f& dir,
                             float d2) {
    const NodeAttributes& a = node.attributes;
    // The centroid's direction against the normals' cone: gamma + angle < 90 degrees.
    const float cosGamma = dot(rv.axis, dir);
    const float sinGamma = safeSqrt(1.0f - cosGamma * cosGamma);
    if (cosGamma * rv.cosAngle - sinGamma * rv.sinAngle > 0.0f) {
      ++stats.clusterPairs;
      stats.receiversServed += tree.served(pair.receiver);
      PointSource src = clusterSource(a, page.waveletOf(node), view, -dir);
      if (isBlack(src.intensity)) return absl::OkStatus();
      Rng rng = rngFor(pair);
      const uint32_t rays =
          rv.single ? 1u
                    : std::min<uint32_t>(static_cast<uint32_t>(opts.clusterRays),
                                         static_cast<uint32_t>(tree.served(pair.receiver)));
      if (rays > 1) {
        // Each ray carries its share of the light.
        const float share = 1.0f / static_cast<float>(rays);
        src.intensity *= share;
        for (Vec3f& g : src.gradient) g *= share;
      }
      for (uint32_t ray = 0; ray < rays; ++ray) {
        if (absl::Status s = traceCluster(pair, page, node, rv, src, cosGamma, d2, ray, rays, rng);
            !s.ok()) {
          return s;
        }
      }
      return absl::OkStatus();
    }
    // cos(gamma - angle) < 0: the centroid is below the horizon of every receiver.
    if (rv.single || cosGamma * rv.cosAngle + sinGamma * rv.sinAngle < 0.0f) {
      ++stats.culled;  // dropped
      return absl::OkStatus();
    }
    refineReceiver(pair, page.id);  // some receivers see it above, some below
    return absl::OkStatus();
  }

  // One of a cluster pair's shadow rays (evaluateSmall), from a receiver of the `ray`th of
  // `rays` runs of the pair's receivers, with `src` its share of the light.
  absl::Status traceCluster(const Pair& pair, const TreePage& page, const TreeNode& node,
                            const ReceiverView& rv, const PointSource& src, float cosGamma,
                            float d2, uint32_t ray, uint32_t rays, Rng& rng) {
    const NodeAttributes& a = node.attributes;
    const uint32_t origin = tree.originOf(pair.receiver, rng, ray, rays);
    // Towards one of the cluster's surfels, picked in proportion to the light it sends:
    // the fraction of rays that arrive is then the fraction of the cluster's light that
    // does, wherever the light sits in the cluster (a floor cluster reaching under a block
    // has its centroid, or points of its bounds, where no light is). The descent starts
    // from the cluster's own estimate at the ray's origin, which its corrections divide: at
    // a single receiver, the source's, seen at the cosine and distance just measured.
    const CutReceiver& from = tree.receivers[origin];
    const float estimate = rv.single ? std::max(0.0f, luminance(src.intensity)) * cosGamma / d2
                                     : nodeContribution(a, page.waveletOf(node), from.p, from.n);
    absl::StatusOr<Descent> target =
        descend(page, pair.light, pair.depth, estimate, 1.0f, from, opts.coneDescent, rng);
    if (!target.ok()) return target.status();
    resolve(*target, pair.receiver, origin, rng, src);
    return absl::OkStatus();
  }

  absl::Status process(const Pair& pair, const TreePage& page) {
    ++stats.pairs;
    const ReceiverView rv = tree.view(pair.receiver);
    absl::StatusOr<const TreeNode*> nodeOr = nodeAt(page, pair.light);
    if (!nodeOr.ok()) return nodeOr.status();
    const TreeNode& node = **nodeOr;
    const NodeAttributes& a = node.attributes;
    const Bounds3f& lightBounds = a.bounds;
    const Vec3f lightCenter = lightBounds.center();
    const float lightRadius = lightBounds.radius();
    const Vec3f halfL = lightBounds.diagonal() * 0.5f;

    // Where the light lies against the receivers' tangent planes (every position in E's bounds,
    // every normal n in its cone around axis a): with v from a receiver to a light point,
    // a . v - |n - a| |v| <= n . v <= a . v + |n - a| |v|, and |n - a| <= 2 sin(angle / 2).
    const Vec3f toCenter = lightCenter - rv.center;
    const float centerDist2 = toCenter.length2();
    const float along = dot(toCenter, rv.axis);
    const float extent = absDotExtent(rv.axis, halfL) + absDotExtent(rv.axis, rv.halfExtent);
    const float reach = lightRadius + rv.radius;
    const float spread = rv.single ? 0.0f : rv.chord * (std::sqrt(centerDist2) + reach);
    const float slack = 1e-6f * maxAbsComponent(rv.center);
    if (lightBounds.empty() || along + extent + spread <= slack) {
      ++stats.culled;  // below every receiver's horizon
      return absl::OkStatus();
    }
    // Nothing to send (the insides of closed objects, unlit rooms): the power's constant term
    // is the integral of a non-negative intensity.
    if (!(luminance(a.powerSh.c[0]) > 0.0f) && !(luminance(a.backPower) > 0.0f) &&
        page.waveletOf(node) == nullptr) {
      ++stats.culled;
      return absl::OkStatus();
    }
    const bool aboveAll = along - extent - spread > slack;
    const bool separated = centerDist2 > reach * reach;
    // Light that may hold surfels within the near field of one of the receivers: taken surfel
    // by surfel at single receivers, whose near field's rays take the nearest. (Asked only of
    // pairs that could otherwise be evaluated whole.)
    const auto reachesNear = [&] {
      return nearRadius > 0.0f &&
             boxGap2(lightBounds, rv.center, rv.halfExtent) < sqr(nearRadius);
    };

    // The paper's criteria, the bounding spheres' first (no square root, no SH).
    const Vec3f toCentroid = a.centroid - rv.center;
    const float d2 = std::max(toCentroid.length2(), 1e-30f);
    const float boundL = kPi * lightRadius * lightRadius / d2;
    const float boundE = kPi * rv.radius * rv.radius / d2;
    const bool receiverSmall =
        rv.single || (within(boundE, opts.receiverBound) && rv.angle < opts.normalAngle);
    const bool boundsSmall = separated && within(boundL, opts.lightBound) && receiverSmall;
    const float hE = rv.single                   ? 0.0f
                     : rv.angle >= opts.normalAngle ? kInfinity
                     : opts.receiverBound > 0.0f    ? boundE / opts.receiverBound
                                                 : kInfinity;
    const float hBound = opts.lightBound > 0.0f ? boundL / opts.lightBound : kInfinity;
    // The SH projected solid angle, when it can still decide anything: the pair may be small,
    // or the light's refinement heuristic h_L may need it to beat the receiver's.
    float solidAngle = kInfinity;
    ClusterView view;
    const float d = std::sqrt(d2);
    const Vec3f dir = toCentroid / d;
    if (boundsSmall || (!node.leaf() && !rv.single && hBound <= hE)) {
      viewCluster(a, dir, &view);
      solidAngle = view.coverage() / d2;
    }
    const bool small =
        boundsSmall && within(solidAngle, opts.lightSolidAngle) && !reachesNear();
    if (small && !rv.single && page.waveletOf(node) != nullptr) {
      // Directional light (glossy surfels' wavelets) is taken receiver by receiver: a node's
      // receivers share the surfel one descent picks for their shadow rays, which stands for
      // the share of the light that arrives only where that share is the same across them. A
      // glossy cluster's surfels aim their lobes at some receivers and not at others, so a
      // shared pick sends a lobe's visible share to receivers the lobe misses: a metal floor
      // running under a wall into a lit room brightens the dark room's walls with it.
      refineReceiver(pair, page.id);
      return absl::OkStatus();
    }
    if (small) return evaluateSmall(pair, page, node, rv, view, dir, d2);

    if (node.leaf()) {
      // Too big to be a cluster: its surfels one by one, for a single receiver, and for a node
      // when the node is small from the leaf and the whole leaf lies above its horizon.
      if (absl::Status s = checkLeaf(page, node, pair.light); !s.ok()) return s;
      const float nearest = std::max(std::sqrt(centerDist2) - lightRadius, 1e-30f);
      if (rv.single ||
          (aboveAll &&
           within(kPi * rv.radius * rv.radius / (nearest * nearest), opts.receiverBound) &&
           !reachesNear())) {
        evaluateLeaf(pair, page, node, rv);
      } else {
        refineReceiver(pair, page.id);
      }
      return absl::OkStatus();
    }

    // Refine one side: the light side when h_L > h_E (a single receiver: always).
    bool refineLight = rv.single;
    if (!refineLight) {
      // Without the SH solid angle (not computed), h_L >= hBound > h_E already.
      float hL = hBound;
      if (solidAngle < kInfinity) {
        hL = std::max(hL, opts.lightSolidAngle > 0.0f ? solidAngle / opts.lightSolidAngle : kInfinity);
      }
      refineLight = hL > hE || (hL == hE && lightRadius >= rv.radius);
    }
    if (!refineLight) {
      refineReceiver(pair, page.id);
      return absl::OkStatus();
    }
    ++stats.refinedLight;
    if (absl::Status s = checkInterior(page, node, pair.light, pair.depth); !s.ok()) return s;
    for (const NodeRef& child : page.childrenOf(node)) {
      push({child, pair.receiver, pair.depth + 1}, page.id);
    }
    return absl::OkStatus();
  }
};

BidirectionalCut::BidirectionalCut(const CutOptions& options)
    : options_(options), state_(std::make_unique<State>()) {}
BidirectionalCut::~BidirectionalCut() = default;
BidirectionalCut::BidirectionalCut(BidirectionalCut&&) noexcept = default;

absl::Status BidirectionalCut::State::begin(TreePageSource& treeSource, const Scene& scene,
                                            std::span<const CutReceiver> cutReceivers,
                                            uint64_t cutKey, const CutOptions& options,
                                            std::optional<uint64_t> cutLightKey) {
  for (size_t i = 0; i < cutReceivers.size(); ++i) {
    if (absl::Status s = checkReceiver(cutReceivers[i], i); !s.ok()) return s;
  }
  opts = options;
  source = &treeSource;
  scn = &scene;
  key = cutKey;
  lightKey = cutLightKey;
  stats = CutStats{};
  stats.cuts = 1;
  stats.receivers = cutReceivers.size();
  tree.build(cutReceivers, opts.receiverLeafSize);
  stats.receiverNodes = tree.nodes.size();
  for (auto& [id, bucket] : buckets) {
    bucket.pairs.clear();
    bucket.probes.clear();
    bucket.near.clear();
    bucket.queued = false;
  }
  probes.clear();
  pages = {};
  stack.clear();
  pending = 0;
  nearHits.clear();
  nearSteps.clear();
  nearTraced = opts.nearRays == 0;
  nearRadius = readRadius = 0.0f;
  if (tree.receivers.empty()) return absl::OkStatus();
  root = treeSource.root();
  push({root, 0, 0}, ~root.page);
  return absl::OkStatus();
}

absl::Status BidirectionalCut::State::sweep(uint32_t lowest) {
  while (!pages.empty() && pages.top() >= lowest) {
    const uint32_t id = pages.top();
    pages.pop();
    {
      // The bucket's waiting work moves to the page's own buffers, and the bucket goes (work
      // for the page later gets a new one): a kept bucket would hold the capacity the buffers
      // had, and a cut's memory would grow with the pages it sweeps, not with what waits
      // (Sponza 1M, 64 groups of cuts together: 967 MB peak against 651 MB).
      auto it = buckets.find(id);
      PBGI_CHECK(it != buckets.end());
      Bucket& bucket = it->second;
      pending -= bucket.pairs.size() + bucket.probes.size() + bucket.near.size();
      std::swap(stack, bucket.pairs);
      std::swap(probes, bucket.probes);
      std::swap(nearSteps, bucket.near);
      buckets.erase(it);
    }
    if (stack.empty() && probes.empty() && nearSteps.empty()) continue;
    ++stats.pageRequests;
    absl::StatusOr<std::shared_ptr<const TreePage>> page = source->page(id);
    if (!page.ok()) return page.status();
    PBGI_CHECK(*page != nullptr);
    if (!nearTraced && id == root.page) {
      // The first page of the sweep: the near field's radius, its rays, their readings.
      nearTraced = true;
      absl::StatusOr<float> mean = rootSurfelRadius(**page, root);
      if (!mean.ok()) return mean.status();
      nearRadius = kNearFieldRadii * *mean;
      readRadius = kNearReadRadii * *mean;
      if (nearRadius > 0.0f) {
        traceNearField(*scn, tree.receivers, opts.nearRays, nearRadius, &nearHits, &stats);
        for (uint32_t i = 0; i < nearHits.size(); ++i) {
          nearSteps.push_back({.at = root, .depth = 0, .hit = i});
        }
      }
    }
    while (!stack.empty()) {
      const Pair pair = stack.back();
      stack.pop_back();
      if (absl::Status s = process(pair, **page); !s.ok()) return s;
    }
    // Descents that reached this page, in the order they arrived (pairs refined here go to
    // other pages: none arrive while these run).
    for (Probe& probe : probes) {
      absl::StatusOr<Descent> target =
          descend(**page, probe.at, probe.depth, probe.estimate, probe.scale,
                  tree.receivers[probe.origin], opts.coneDescent, probe.rng);
      if (!target.ok()) return target.status();
      resolve(*target, probe.receiver, probe.origin, probe.rng, probe.src);
    }
    probes.clear();
    for (const NearStep& step : nearSteps) {
      if (absl::Status s = readNearSurface(
              *scn, **page, step, readRadius, nearHits[step.hit], nearStack,
              [&](const NearStep& next) { waitOn(next.at.page).near.push_back(next); }, &stats);
          !s.ok()) {
        return s;
      }
    }
    nearSteps.clear();
  }
  return absl::OkStatus();
}

absl::Status BidirectionalCut::State::finish(std::span<Rgb> out, CutStats* statsOut) {
  PBGI_CHECK_EQ(out.size(), tree.receivers.size());
  std::fill(out.begin(), out.end(), Rgb(0.0f));
  addNearLight(nearHits, opts.nearRays, tree.single, &stats);
  if (absl::Status s = tree.read(out); !s.ok()) return s;
  if (statsOut) *statsOut += stats;
  // What waited for pages is gone: give the buckets' memory back (up to about a million
  // pairs and descents at a cut's peak), so that cuts kept for later do not hold it.
  std::unordered_map<uint32_t, Bucket>().swap(buckets);
  std::vector<Pair>().swap(stack);
  std::vector<Probe>().swap(probes);
  std::vector<NearHit>().swap(nearHits);
  return absl::OkStatus();
}

absl::Status BidirectionalCut::irradiance(TreePageSource& tree, const Scene& scene,
                                          std::span<const CutReceiver> receivers, uint64_t key,
                                          std::span<Rgb> out, CutStats* statsOut,
                                          std::optional<uint64_t> lightKey) {
  PBGI_CHECK_EQ(out.size(), receivers.size());
  State& st = *state_;
  if (absl::Status s = st.begin(tree, scene, receivers, key, options_, lightKey); !s.ok()) {
    return s;
  }
  if (absl::Status s = st.sweep(0); !s.ok()) return s;
  return st.finish(out, statsOut);
}

absl::Status cutTogether(TreePageSource& tree, const Scene& scene,
                         std::span<BidirectionalCut* const> cuts, std::span<const CutJob> jobs,
                         CutStats* statsOut) {
  PBGI_CHECK_EQ(cuts.size(), jobs.size());
  std::vector<absl::Status> errors(jobs.size());
  // Runs step(i) for each cut i of `which` in parallel; the first error in job order.
  std::vector<size_t> which(jobs.size());
  for (size_t i = 0; i < which.size(); ++i) which[i] = i;
  auto forEachCut = [&](auto&& step) {
    tbb::this_task_arena::isolate([&] {
      tbb::parallel_for(size_t{0}, which.size(), [&](size_t k) {
        if (errors[which[k]].ok()) errors[which[k]] = step(which[k]);
      });
    });
    for (const absl::Status& e : errors) {
      if (!e.ok()) return e;
    }
    return absl::OkStatus();
  };
  if (absl::Status s = forEachCut([&](size_t i) {
        PBGI_CHECK_EQ(jobs[i].out.size(), jobs[i].receivers.size());
        return cuts[i]->state_->begin(tree, scene, jobs[i].receivers, jobs[i].key,
                                      cuts[i]->options(), jobs[i].lightKey);
      });
      !s.ok()) {
    return s;
  }
  // A window of pages at a time, from the highest down, for the cuts waiting on it: every cut
  // sweeps its own pages in its own order, so the window changes no cut's result, only how
  // close in time the cuts ask for the same page.
  for (;;) {
    std::optional<uint32_t> high;
    for (BidirectionalCut* cut : cuts) {
      const std::optional<uint32_t> next = cut->state_->nextPage();
      if (next && (!high || *next > *high)) high = next;
    }
    if (!high) break;
    const uint32_t lowest = *high >= kCutWindowPages - 1 ? *high - (kCutWindowPages - 1) : 0;
    which.clear();
    for (size_t i = 0; i < cuts.size(); ++i) {
      const std::optional<uint32_t> next = cuts[i]->state_->nextPage();
      if (next && *next >= lowest) which.push_back(i);
    }
    if (absl::Status s = forEachCut([&](size_t i) { return cuts[i]->state_->sweep(lowest); });
        !s.ok()) {
      return s;
    }
  }
  for (size_t i = 0; i < jobs.size(); ++i) {
    if (absl::Status s = cuts[i]->state_->finish(jobs[i].out, statsOut); !s.ok()) return s;
  }
  return absl::OkStatus();
}

}  // namespace pbgi
