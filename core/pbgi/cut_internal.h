#pragma once
// The bidirectional cut's parts that its files share (bidirectional_cut.cpp, and the surfel
// light, near field, descent and brute-force reference beside it): not an interface.
#include <cstdint>
#include <span>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/pbgi/bidirectional_cut.h"
#include "core/pbgi/gather_internal.h"
#include "core/sampling/rng.h"
#include "core/scene/scene.h"

namespace pbgi::cut_internal {

using namespace gather_internal;

// Shadow rays stop this fraction of their length short of their target.
constexpr float kShortFraction = 1e-4f;

// Whether the segment from a receiver to a surfel's centre is free: from off the receiver's
// surface to off the surfel's, on the sides that face each other (Scene::spawnSegment), stopping
// just short of it. Glass does not block it (Scene::occludedByOpaque): a floor beside a glass
// object gathers the room behind the glass, which no surfel of the glass carries (its light is
// what it brings from the lights). Light from surfels of glass is blocked by other glass, as
// the glass's own surfels stand for the light that crosses it.
bool visibleSurfel(const Scene& scene, const CutReceiver& from, const Surfel& s, CutStats* stats);

// The light one surfel sends one receiver, into `light` (cut_surfel_light.cpp): as a virtual
// spherical light far off, as its disk near. False for a surfel on or behind the receiver's
// tangent plane on whose disk the receiver lies, a dark one, or one whose centre lies within
// `nearRadius` (the near field's rays take its light).
bool surfelLight(const Surfel& s, const CutReceiver& r, float selfSkipRadius, float nearRadius,
                 Rgb* light);

// What a node sends a receiver at p facing n, as the cut would evaluate it alone: its SH
// intensity towards p times the cosine at p over the squared distance (0 behind p).
float nodeContribution(const NodeAttributes& a, const WaveletRadiance* wavelet, const Vec3f& p,
                       const Vec3f& n);

// Where a shadow ray towards a cluster goes (cut_descent.cpp): one of its surfels, or the child
// in another page to go on from, or nothing.
struct Descent {
  enum class Kind { kSurfel, kNothing, kElsewhere };
  Kind kind = Kind::kNothing;  // kNothing: by the estimates, the node sends the receiver nothing
  Surfel surfel;               // kSurfel
  NodeRef next;                // kElsewhere: the child to go on from, in another page
  uint32_t depth = 0;          // of `next`
  float estimate = 0.0f;       // kElsewhere: what `next` sends the receiver, by its estimate
  float scale = 1.0f;          // the corrections' product on the way (kSurfel, kElsewhere)
};
absl::StatusOr<Descent> descend(const TreePage& page, NodeRef ref, uint32_t depth, float estimate,
                                float scale, const CutReceiver& to, bool cones, Rng& rng);

// The near field (bidirectional_cut.h, CutOptions::nearRays; cut_near_field.cpp).

// A near-field ray's hit: the surface point it met, that surface's normal (by its winding),
// the ray's direction, and the radiance read there so far (a weighted sum of surfels).
struct NearHit {
  Vec3f x{0.0f};
  Vec3f n{0.0f};
  Vec3f w{0.0f};
  uint32_t receiver = 0;
  Rgb sum{0.0f};
  float weight = 0.0f;
};

// A hit's reading going on from a node of the light tree.
struct NearStep {
  NodeRef at;
  uint32_t depth = 0;
  uint32_t hit = 0;
};

// The near field (bidirectional_cut.h, CutOptions::nearRays).

// Surfels are read within this many mean radii of a near-field hit: a few of them on a
// surface they cover evenly.
constexpr float kNearReadRadii = 2.0f;
// ... on the hit's surface: off its plane by at most this fraction of the reading radius (a
// curved surface bends away from its tangent plane by d^2 / 2 rho, and the other face of a
// wall lies a wall's thickness away), its normal within 60 degrees of the hit's either way
// (surfels are two-sided, and a mesh's winding says nothing of which side is out).
constexpr float kNearPlaneFraction = 0.5f;
constexpr float kNearSurfaceCos = 0.5f;
// ... and seen from the hit along the surface: a ray from the hit, lifted off the surface on
// the side the near-field ray came from by this fraction of their distance d, to the surfel,
// lifted by kNearEndLift of it. A chord of length d over a convex surface of radius rho lies
// d^2 / 8 rho inside it at its middle, so it clears surfaces curved less than d / 2; a surfel
// of the far face of a thin wall stays behind the near face, and one below a floor that meets
// its wall stays below the floor.
constexpr float kNearLiftFraction = 0.25f;
constexpr float kNearEndLift = 0.02f;

// The tree's mean surfel radius, from its root node in `page`.
absl::StatusOr<float> rootSurfelRadius(const TreePage& page, NodeRef root);
// The squared gap between a box and another box around `center` (half-size `halfExtent`).
float boxGap2(const Bounds3f& b, const Vec3f& center, const Vec3f& halfExtent);
// Each receiver's near-field rays, `rays` of them cosine-weighted about its normal and as long
// as `radius`, and the hits (on surfaces that are not lights'). A ray below the receiver's
// geometric surface sees nothing.
void traceNearField(const Scene& scene, std::span<const CutReceiver> receivers, int rays,
                    float radius, std::vector<NearHit>* hits, CutStats* stats);
// Reads into `hit` the surfels of the tree around it from `root` down (readNearSurface, page by
// page as the source gives them).
absl::Status readHit(TreePageSource& tree, const Scene& scene, NodeRef root, float radius,
                     NearHit& hit, CutStats* stats);
// Adds each hit's radiance, pi / rays of it (a cosine-weighted estimate), to its receiver. A hit
// where no surfel was read takes the mean of its receiver's other hits, or nothing when it has
// none. Hits come grouped by receiver (traceNearField).
void addNearLight(std::span<const NearHit> hits, int rays, std::span<Rgb> out, CutStats* stats);

// Reads into `hit` the surfels of `page` on the hit's surface within `radius` of it that the
// hit sees along that surface (a wall's surfels below a floor that meets it, in the dark, are
// not the wall's light above it), from node `step.at` down (children whose ghosts lie farther
// are skipped), weighted (1 - d^2/R^2)^2 and taken on the side the ray sees; children in other
// pages go to `elsewhere`.
template <typename Elsewhere>
absl::Status readNearSurface(const Scene& scene, const TreePage& page, const NearStep& from,
                             float radius, NearHit& hit, std::vector<NearStep>& stack,
                             Elsewhere&& elsewhere, CutStats* stats) {
  const float r2 = radius * radius;
  const Vec3f side = dot(hit.n, hit.w) < 0.0f ? hit.n : -hit.n;  // towards the receiver
  const auto seen = [&](const Vec3f& to) {
    const float apart = length(to - hit.x);
    const Vec3f start = hit.x + side * (kNearLiftFraction * apart);
    const Vec3f v = to + side * (kNearEndLift * apart) - start;
    const float d = length(v);
    if (!(d > 0.0f)) return true;
    Ray ray{.origin = start, .dir = v / d};
    ray.tMax = d;
    ++stats->shadowRays;
    if (!scene.occluded(ray)) return true;
    ++stats->occluded;
    return false;
  };
  const auto reaches = [&](const NodeAttributes& a) {
    return boxGap2(a.bounds, hit.x, Vec3f(0.0f)) <= r2;
  };
  stack.clear();
  stack.push_back(from);
  while (!stack.empty()) {
    const NearStep step = stack.back();
    stack.pop_back();
    absl::StatusOr<const TreeNode*> nodeOr = nodeAt(page, step.at);
    if (!nodeOr.ok()) return nodeOr.status();
    const TreeNode& node = **nodeOr;
    if (!reaches(node.attributes)) continue;
    if (node.leaf()) {
      if (absl::Status s = checkLeaf(page, node, step.at); !s.ok()) return s;
      for (const Surfel& sf : page.surfelsOf(node)) {
        const Vec3f v = sf.position - hit.x;
        const float d2 = v.length2();
        if (d2 >= r2 || std::abs(dot(v, hit.n)) > kNearPlaneFraction * radius ||
            std::abs(dot(sf.normal, hit.n)) < kNearSurfaceCos || !seen(sf.position)) {
          continue;
        }
        const float w = sqr(1.0f - d2 / r2);
        hit.sum += facingSide(sf, hit.w).radiance * w;
        hit.weight += w;
      }
      continue;
    }
    if (absl::Status s = checkInterior(page, node, step.at, step.depth); !s.ok()) return s;
    for (uint32_t c = 0; c < node.childCount; ++c) {
      const NodeRef child = page.children[node.first + c];
      const NearStep next{.at = child, .depth = step.depth + 1, .hit = step.hit};
      if (child.page == page.id) {
        stack.push_back(next);
      } else if (const NodeAttributes* ghost = page.childAttributes(node, c);
                 ghost == nullptr || reaches(*ghost)) {
        elsewhere(next);
      }
    }
  }
  return absl::OkStatus();
}

}  // namespace pbgi::cut_internal
