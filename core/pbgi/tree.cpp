#include "core/pbgi/tree.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/util/check.h"

namespace pbgi {

namespace {

// The axis-aligned extent of a disk of radius r around normal n: r sqrt(1 - n_i^2) per axis.
Vec3f diskExtent(const Vec3f& n, float r) {
  return {r * safeSqrt(1.0f - n.x * n.x), r * safeSqrt(1.0f - n.y * n.y),
          r * safeSqrt(1.0f - n.z * n.z)};
}

Vec3f unitOrZ(const Vec3f& v) {
  const float len = length(v);
  // A sum that cancels (normals facing every way) gives no axis; +z is as good as any and
  // the angle then covers the sphere.
  if (!(len > 1e-20f) || !std::isfinite(len)) return {0.0f, 0.0f, 1.0f};
  return v / len;
}

// The cone around the weighted sum of the members' axes that holds every member's cone:
// each lies within (angle between the axes) + (its own half-angle) of the new axis, and
// angles add where cosines do not. A single normal is a cone of half-angle 0.
template <typename Range, typename Axis, typename CosAngle, typename Weight>
NormalCone coneAround(const Range& members, Axis axisOf, CosAngle cosAngleOf, Weight weightOf) {
  Vec3f sum(0.0f);
  for (const auto& m : members) sum += axisOf(m) * weightOf(m);
  NormalCone cone;
  cone.axis = unitOrZ(sum);
  if (!(length(sum) > 1e-20f)) {
    cone.cosAngle = -1.0f;
    return cone;
  }
  float halfAngle = 0.0f;
  for (const auto& m : members) {
    halfAngle = std::max(halfAngle, safeAcos(dot(axisOf(m), cone.axis)) + safeAcos(cosAngleOf(m)));
  }
  cone.cosAngle = halfAngle >= kPi ? -1.0f : std::cos(halfAngle);
  return cone;
}

}  // namespace

NodeAttributes leafAttributes(std::span<const Surfel> surfels) {
  NodeAttributes node;
  Vec3f weighted(0.0f);
  for (const Surfel& s : surfels) {
    const float a = s.area();
    const Vec3f e = diskExtent(s.normal, s.radius);
    node.bounds.extend(s.position - e);
    node.bounds.extend(s.position + e);
    node.area += a;
    weighted += s.position * a;
    node.areaSh += projectedAreaSh(s.normal, a);
    node.powerSh += lambertianIntensitySh(s.normal, a, s.radiance);
    node.backPower += s.backRadiance * a;
  }
  node.pointCount = surfels.size();
  node.centroid = node.area > 0.0f ? weighted / node.area
                  : surfels.empty() ? Vec3f(0.0f)
                                    : surfels.front().position;
  node.cone = coneAround(
      surfels, [](const Surfel& s) { return s.normal; }, [](const Surfel&) { return 1.0f; },
      [](const Surfel& s) { return s.area(); });
  return node;
}

NodeAttributes mergeAttributes(std::span<const NodeAttributes> children) {
  NodeAttributes node;
  Vec3f weighted(0.0f);
  for (const NodeAttributes& c : children) {
    node.bounds.extend(c.bounds.min);
    node.bounds.extend(c.bounds.max);
    node.area += c.area;
    node.pointCount += c.pointCount;
    weighted += c.centroid * c.area;
    node.areaSh += c.areaSh;
    node.powerSh += c.powerSh;
    node.backPower += c.backPower;
  }
  node.centroid = node.area > 0.0f ? weighted / node.area
                  : children.empty() ? Vec3f(0.0f)
                                     : children.front().centroid;
  node.cone = coneAround(
      children, [](const NodeAttributes& c) { return c.cone.axis; },
      [](const NodeAttributes& c) { return c.cone.cosAngle; },
      [](const NodeAttributes& c) { return c.area; });
  return node;
}

Rgb meanRadiance(const NodeAttributes& node, const Vec3f& w) {
  const float projected = evaluate(node.areaSh, w);
  if (!(projected > 0.0f)) return Rgb(0.0f);
  const Rgb intensity = evaluate(node.powerSh, w);
  return vmax(intensity, Rgb(0.0f)) / projected;
}

std::string NodeAttributes::toString() const {
  return fmt::format(
      "node(points={} area={:g} bounds=[{:g} {:g} {:g}]-[{:g} {:g} {:g}] centroid=({:g} {:g} "
      "{:g}) cone=({:g} {:g} {:g}; cos {:g}) power.dc=({:g} {:g} {:g}))",
      pointCount, area, bounds.min.x, bounds.min.y, bounds.min.z, bounds.max.x, bounds.max.y,
      bounds.max.z, centroid.x, centroid.y, centroid.z, cone.axis.x, cone.axis.y, cone.axis.z,
      cone.cosAngle, powerSh.c[0].x, powerSh.c[0].y, powerSh.c[0].z);
}

}  // namespace pbgi
