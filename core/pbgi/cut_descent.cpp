// The cut's shadow-ray descents: from a cluster to the surfel its ray goes to.
#include "core/pbgi/cut_internal.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <optional>

namespace pbgi::cut_internal {

namespace {

using namespace gather_internal;

// A node's centroid seen from a receiver at p facing n: the unit direction to it, its squared
// distance and the cosine at p; nullopt when it lies at p or behind p's horizon.
struct Sight {
  Vec3f dir{0.0f};
  float d2 = 0.0f;
  float cosR = 0.0f;
};
std::optional<Sight> sightOf(const NodeAttributes& a, const Vec3f& p, const Vec3f& n) {
  const Vec3f v = a.centroid - p;
  const float d2 = v.length2();
  if (!(d2 > 0.0f)) return std::nullopt;
  const Vec3f dir = v / std::sqrt(d2);
  const float cosR = dot(n, dir);
  if (!(cosR > 0.0f)) return std::nullopt;
  return Sight{.dir = dir, .d2 = d2, .cosR = cosR};
}

// Where a shadow ray towards a cluster goes: one of its surfels, picked by descending from the
// cluster and choosing each child in proportion to what it sends the receiver `to` and the
// surfel in proportion to its own share, so that the fraction of rays to such surfels that
// arrive estimates the fraction of the cluster's light that reaches the receiver. The descent
// stays in one page: children in other pages are weighed by their ghosts (tree_page.h), and
// when the one picked is in another page the descent stops there and goes on when the sweep
// reaches that page (a Probe), so a cut asks for no page outside its sweep.
//
// The estimates do not add up: a node's children together send the receiver more or less than
// the node's own estimate says (its SH and its centroid's cosine and distance stand for all of
// its surfels). Each level of the descent therefore weighs the cluster's light by what the
// children send over what their parent's estimate said (Descent::scale). The product over the
// path telescopes: the expected light is then the sum over the cluster's surfels of what each
// sends as a point (the brute force's sum), not the cluster's own estimate, whatever the
// cluster's size. Without it, coarse clusters lost light: a descent that reached a node whose
// children send the receiver nothing dropped the cluster's whole light, and nothing made up for
// children that send more than their parent's estimate. transfer_bench (Sponza, 300k surfels,
// direct light, cut / brute force) measured 0.979, 0.989 and 0.941 for the draft and default
// presets and the bake's later bounces' cut (the draft's thresholds times 4); 0.995, 0.997 and
// 0.989 with the corrections, and each receiver's RMS error fell too.
//
// A cluster's SH can send a receiver light that none of its children's estimates, or none of a
// leaf's surfels, does (SH ringing past a face that looks away: a wall's two faces, the lit one
// turned from the receiver). The descent then finds nothing (kNothing) and the light is
// dropped, the finer estimate being the better one (the correction is 0). Deposited unseen
// instead, it would give a receiver facing into a wall (each surfel gathers on both sides) the
// light of the room beyond it: on Sponza a third of a bounce's light would go into the insides
// of walls, and camera points would gather 3 % more than the sum over every surfel
// (transfer_bench --light bounce, --light direct --brute).
//
// The product is held below kMaxDescentCorrection: a child its parent all but missed is
// picked rarely, and would be weighed by a spike. What the cap cuts off is light lost, most
// where light reaches a room through a gap a few clusters wide, whose clusters' estimates
// differ most from their children's; a higher cap loses less and spreads the light more.
//
// With CutOptions::coneDescent the children are weighed by coneContribution instead: their
// power and normal cones, no SH (a quarter less time in a Sponza bake's first bounce, as
// `pbgi bake` prints its stages). What the descent is worth in expectation does not change,
// since the estimates between the cluster and the surfel cancel in the product; only its
// spread does. Those estimates are in
// other units than the cluster's own, which starts the product, and the surfels', which ends
// it, so the product is held only at the end, below kMaxConeDescentCorrection: it runs wider
// (transfer_bench, Sponza 300k, direct light, cut / brute force at the bake's first-bounce
// thresholds: 0.9953 by SH; by cones held at 4, 16 and 64: 0.9908, 0.9951 and 0.9959).
inline constexpr float kMaxDescentCorrection = 8.0f;
inline constexpr float kMaxConeDescentCorrection = 64.0f;

// What a node sends a receiver at p facing n by its power and normal cone alone: its front
// sides as a disk of the power's radiance times area (exact for a flat cluster) seen at the
// largest cosine its cone allows towards p, its back sides' power likewise, times the cosine
// at p over the squared distance (0 behind p).
float coneContribution(const NodeAttributes& a, const Vec3f& p, const Vec3f& n) {
  const std::optional<Sight> sight = sightOf(a, p, n);
  if (!sight) return 0.0f;
  const float cosT = -dot(a.cone.axis, sight->dir);  // the cone's axis against the way to p
  const float sinT = safeSqrt(1.0f - cosT * cosT);
  const float cosG = a.cone.cosAngle, sinG = safeSqrt(1.0f - cosG * cosG);
  const auto largestCosine = [&](float c) {
    return c >= cosG ? 1.0f : std::max(0.0f, c * cosG + sinT * sinG);
  };
  // A Lambertian disk of radiance L and area A sends intensity L A cos: its SH's constant
  // term is Y00 pi L A.
  constexpr float kDiskOverDc = 1.0f / (kPi * static_cast<float>(kY00));
  const float front = std::max(0.0f, luminance(a.powerSh.c[0])) * kDiskOverDc * largestCosine(cosT);
  const float back = std::max(0.0f, luminance(a.backPower)) * largestCosine(-cosT);
  return (front + back) * sight->cosR / sight->d2;
}

}  // namespace

// What a node sends a receiver at p facing n, as the cut would evaluate it alone: its SH
// intensity towards p times the cosine at p over the squared distance (0 behind p).
float nodeContribution(const NodeAttributes& a, const WaveletRadiance* wavelet, const Vec3f& p,
                       const Vec3f& n) {
  const std::optional<Sight> sight = sightOf(a, p, n);
  if (!sight) return 0.0f;
  ClusterView view;
  viewCluster(a, sight->dir, &view);
  return std::max(0.0f, luminance(clusterRadiance(a, view, wavelet))) * view.coverage() *
         sight->cosR / sight->d2;
}

absl::StatusOr<Descent> descend(const TreePage& page, NodeRef ref, uint32_t depth, float estimate,
                                float scale, const CutReceiver& to, bool cones, Rng& rng) {
  // One level's correction: what the children send by their own estimates (`total`) over what
  // their parent's estimate said. By cones, held only at the surfel (`last`).
  const float cap = cones ? kMaxConeDescentCorrection : kMaxDescentCorrection;
  const auto correct = [&](float total, bool last) {
    const float next = estimate > 0.0f ? scale * (total / estimate) : cap;
    // Within the cap, NaN too (an infinite total over an infinite estimate).
    scale = next <= cap || (cones && !last && std::isfinite(next)) ? next : cap;
  };
  for (;;) {
    absl::StatusOr<const TreeNode*> nodeOr = nodeAt(page, ref);
    if (!nodeOr.ok()) return nodeOr.status();
    const TreeNode& node = **nodeOr;
    const float u = rng.uniform();
    if (node.leaf()) {
      if (absl::Status s = checkLeaf(page, node, ref); !s.ok()) return s;
      const std::span<const Surfel> surfels = page.surfelsOf(node);
      float weights[kMaxLeafSize + 1];
      float total = 0.0f;
      for (size_t k = 0; k < surfels.size(); ++k) {
        const Surfel& s = surfels[k];
        const Vec3f v = s.position - to.p;
        const float d2 = v.length2();
        const FacingSide side = facingSide(s, v);
        const float w = d2 > 0.0f ? std::max(0.0f, luminance(side.radiance)) * s.area() *
                                        std::max(0.0f, -dot(side.normal, v)) *
                                        std::max(0.0f, dot(to.n, v)) / (d2 * d2)
                                  : 0.0f;
        weights[k] = w;
        total += w;
      }
      if (!(total > 0.0f)) return Descent{};
      // A leaf with a wavelet (glossy surfels) sends the receiver what the wavelet says,
      // which its surfels' own estimates (their diffuse radiance) do not hold: its estimate
      // stands (by cones, its estimate by SH and wavelet, in the cluster's units).
      const WaveletRadiance* wavelet = page.wavelets.empty() ? nullptr : page.waveletOf(node);
      if (wavelet == nullptr) {
        correct(total, true);
      } else if (cones) {
        correct(nodeContribution(node.attributes, wavelet, to.p, to.n), true);
      }
      float x = u * total;
      size_t pick = surfels.size() - 1;
      for (size_t k = 0; k < surfels.size(); ++k) {
        x -= weights[k];
        if (x < 0.0f) {
          pick = k;
          break;
        }
      }
      return Descent{.kind = Descent::Kind::kSurfel, .surfel = surfels[pick], .scale = scale};
    }
    if (absl::Status s = checkInterior(page, node, ref, depth); !s.ok()) return s;
    float weights[8] = {};
    float total = 0.0f;
    for (uint32_t c = 0; c < node.childCount && c < 8; ++c) {
      const NodeAttributes* child = page.childAttributes(node, c);
      if (child == nullptr) {
        return absl::DataLossError(fmt::format(
            "cut: page {} node {}: child {} is in page {} and has no ghost here (a tree of an "
            "older payload, or damaged)",
            ref.page, ref.index, c, page.children[node.first + c].page));
      }
      // (A page without wavelets, every page of a diffuse scene's tree, skips the lookup.)
      // By cones, a child with a wavelet still by its SH and wavelet: glossy surfels' light
      // is in the wavelet, which the cone does not see (nor, then, picks).
      const WaveletRadiance* wavelet = page.wavelets.empty() ? nullptr : page.childWavelet(node, c);
      weights[c] = cones && wavelet == nullptr ? coneContribution(*child, to.p, to.n)
                                               : nodeContribution(*child, wavelet, to.p, to.n);
      total += weights[c];
    }
    if (!(total > 0.0f)) return Descent{};
    correct(total, false);
    float x = u * total;
    uint32_t pick = node.childCount - 1;
    for (uint32_t c = 0; c < node.childCount && c < 8; ++c) {
      x -= weights[c];
      if (x < 0.0f) {
        pick = c;
        break;
      }
    }
    ref = page.children[node.first + pick];
    estimate = weights[pick];
    ++depth;
    if (ref.page != page.id) {
      return Descent{.kind = Descent::Kind::kElsewhere,
                     .next = ref,
                     .depth = depth,
                     .estimate = estimate,
                     .scale = scale};
    }
  }
}

}  // namespace pbgi::cut_internal
