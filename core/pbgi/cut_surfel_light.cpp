// The light of one surfel at one receiver, as the cut and its brute-force reference take it.
#include "core/pbgi/cut_internal.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <numbers>

#include "core/math/solid_angle.h"

namespace pbgi::cut_internal {

namespace {

using namespace gather_internal;

// Surfels nearer than this many radii are integrated over their disk, not taken as a point.
constexpr float kNearDiskRadii = 4.0f;
// A near disk is a regular polygon of this many edges, its circumradius scaled so that its
// area is the disk's: n/(2 pi) sin(2 pi/n) of the circle's area, inscribed.
constexpr int kDiskEdges = 16;
// ... spread to this many times its radius, at 1 / kNearDiskSpread^2 of its radiance (the same
// power): near a receiver, which disks happen to lie next to it (an overlap, a gap) would
// otherwise show as blotches that no number of samples averages out. Measured on the dev
// Sponza shot (1M surfels, draft, 4 spp): indirect relMSE 1.12e-2 unspread, 7.80e-3 at 2,
// 7.53e-3 at 3, and the mean indirect light 0.946, 0.938, 0.931 of the path tracer's (larger
// disks lose more past the edges of what they lie on).
constexpr float kNearDiskSpread = 2.0f;

// The near disk's polygon in its own plane: kDiskEdges points on a circle of the disk's area
// (circumradius 1 / sqrt(n / (2 pi) sin(2 pi / n)) for a unit disk), spread; computed once.
const std::array<Vec2f, kDiskEdges>& diskPolygon() {
  static const std::array<Vec2f, kDiskEdges> points = [] {
    std::array<Vec2f, kDiskEdges> p;
    const double scale = kNearDiskSpread / std::sqrt(kDiskEdges / (2.0 * std::numbers::pi) *
                                                     std::sin(2.0 * std::numbers::pi / kDiskEdges));
    for (int k = 0; k < kDiskEdges; ++k) {
      const double phi = k * (2.0 * std::numbers::pi / kDiskEdges);
      p[k] = Vec2f(static_cast<float>(scale * std::cos(phi)),
                   static_cast<float>(scale * std::sin(phi)));
    }
    return p;
  }();
  return points;
}

// A convex polygon clipped by a plane through the receiver: at most one vertex more.
struct ClippedPolygon {
  std::array<Vec3f, kDiskEdges + 1> v;
  int count = 0;
};

// Splits a convex polygon (vertices relative to the receiver) by the receiver's tangent plane
// (normal n) into its parts on and above it and on and below it.
void clipAtPlane(std::span<const Vec3f> polygon, const Vec3f& n, ClippedPolygon* above,
                 ClippedPolygon* below) {
  above->count = below->count = 0;
  const size_t count = polygon.size();
  for (size_t i = 0; i < count; ++i) {
    const Vec3f& a = polygon[i];
    const Vec3f& b = polygon[(i + 1) % count];
    const float ha = dot(n, a), hb = dot(n, b);
    if (ha >= 0.0f && above->count <= kDiskEdges) above->v[above->count++] = a;
    if (ha <= 0.0f && below->count <= kDiskEdges) below->v[below->count++] = a;
    if ((ha > 0.0f && hb < 0.0f) || (ha < 0.0f && hb > 0.0f)) {
      const Vec3f x = a + (b - a) * (ha / (ha - hb));
      if (above->count <= kDiskEdges) above->v[above->count++] = x;
      if (below->count <= kDiskEdges) below->v[below->count++] = x;
    }
  }
}

// The projected solid angle of a planar polygon on or above the horizon of a receiver with
// unit normal n (vertices relative to it): its vector solid angle's component along n
// (solid_angle.h, Lambert's formula). Exact however near the polygon is, where a point's
// 1/d^2 is not.
float projectedSolidAngle(const ClippedPolygon& polygon, const Vec3f& n) {
  if (polygon.count < 3) return 0.0f;
  std::array<Vec3d, kDiskEdges + 1> v;
  for (int i = 0; i < polygon.count; ++i) v[i] = {polygon.v[i].x, polygon.v[i].y, polygon.v[i].z};
  const Vec3d towards{n.x, n.y, n.z};
  const Vec3d vsa = vectorSolidAngle(std::span(v.data(), polygon.count), towards);
  return static_cast<float>(vsa[0] * towards[0] + vsa[1] * towards[1] + vsa[2] * towards[2]);
}

}  // namespace

bool visibleSurfel(const Scene& scene, const CutReceiver& from, const Surfel& s, CutStats* stats) {
  const float stop = kShortFraction * length(s.position - from.p) +
                     1e-5f * std::max(maxAbsComponent(s.position), 1e-20f);
  const Ray ray = scene.spawnSegment(from.p, from.ng, s.position, s.normal, stop);
  if (!(ray.tMax > 0.0f)) return true;
  ++stats->shadowRays;
  const bool blocked = s.materialClass == MaterialClass::kTransmissive ? scene.occluded(ray)
                                                                       : scene.occludedByOpaque(ray);
  if (blocked) ++stats->occluded;
  return !blocked;
}

// The light one surfel sends one receiver (the side facing it: surfels are two-sided). Far, a
// virtual spherical light: radiance times its disk area times both cosines over d^2 + r^2
// (exact on the disk's axis). Near (within kNearDiskRadii radii), the disk itself, spread
// (kNearDiskSpread), as a polygon whose projected solid angle is exact (Lambert's formula): 16
// points on the disk with a softened 1/d^2 each, as before, lost the peak of the light of a
// wall a fraction of a radius from a floor receiver (Sponza's surfels within half a radius of
// other geometry gathered 0.76 of what rays measure, transfer_bench --light bounce). (Softening
// the far formula to the spread radius as well measured no better: indirect relMSE 7.90e-3
// against 7.83e-3 on the dev shot.) The part of a disk below
// the receiver's horizon is folded back above it, within the disk's own plane: only surfels
// centred above the horizon are gathered, and near the horizon line their disks cover the
// surface above it as much less as they hang below it (disks of one size spread evenly over
// a surface cover half of it at the surface's edge), so dropping that part lost light in
// every concave corner (the unit-radiance closed box gathered 0.86-0.88 of pi within a radius
// of its edges). False for a surfel on or behind the receiver's tangent plane, on whose disk
// the receiver lies facing its way (its own surface: a wall whose disk reaches a floor
// receiver is gathered), or dark.
// Nor for a surfel whose centre lies within `nearRadius` (the near field's rays take its light).
bool surfelLight(const Surfel& s, const CutReceiver& r, float selfSkipRadius, float nearRadius,
                 Rgb* light) {
  Vec3f v;
  float dist2;
  if (skipSurfel(s, r.p, r.n, 1e-6f * maxAbsComponent(r.p), selfSkipRadius, &v, &dist2,
                 gather_internal::kOwnSurfaceCos) ||
      dist2 < nearRadius * nearRadius) {
    return false;
  }
  const FacingSide side = facingSide(s, v);
  if (isBlack(side.radiance)) return false;
  const float area = s.area();
  if (dist2 >= sqr(kNearDiskRadii * s.radius)) {
    const float dist = std::sqrt(dist2);
    const Vec3f w = v / dist;  // receiver to surfel
    const float cosS = -dot(side.normal, w);
    if (cosS <= 0.0f) return false;
    *light = side.radiance * (area * cosS * dot(r.n, w) / (dist2 + s.radius * s.radius));
    return true;
  }
  // The disk as a polygon of kDiskEdges edges (of the disk's area, spread), relative to the
  // receiver; the part above the horizon and the part below, folded, each integrated exactly.
  const Frame disk(side.normal);
  std::array<Vec3f, kDiskEdges> polygon;
  for (int k = 0; k < kDiskEdges; ++k) {
    const Vec2f& p = diskPolygon()[k];
    polygon[k] = v + disk.toWorld(Vec3f(s.radius * p.x, s.radius * p.y, 0.0f));
  }
  // Within the disk's plane the height above the receiver's tangent plane grows along `up`
  // (the receiver's normal projected on the disk) at rate |up|.
  const Vec3f up = r.n - side.normal * dot(r.n, side.normal);
  const float up2 = up.length2();
  ClippedPolygon above, below;
  clipAtPlane(polygon, r.n, &above, &below);
  float solidAngle = projectedSolidAngle(above, r.n);
  if (below.count >= 3 && up2 > 1e-6f) {
    for (int k = 0; k < below.count; ++k) {
      below.v[k] -= up * (2.0f * dot(r.n, below.v[k]) / up2);
    }
    solidAngle += projectedSolidAngle(below, r.n);
  }
  if (!(solidAngle > 0.0f)) return false;
  *light = side.radiance * (solidAngle / sqr(kNearDiskSpread));
  return true;
}

}  // namespace pbgi::cut_internal
