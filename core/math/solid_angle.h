#pragma once
// The vector solid angle of a polygon seen from the origin (Arvo 1995, "Applications of
// Irradiance Tensors to the Simulation of Non-Lambertian Phenomena"): the integral of the unit
// direction over the spherical polygon the polygon projects to, half the sum over its edges of
// the angle each subtends times the unit normal of the plane through it and the origin. Its dot
// product with a unit normal n is the polygon's projected solid angle for a receiver at the
// origin facing n, where the polygon lies on or above n's horizon (Lambert's formula): exact
// however near the polygon is. In double: the microbuffer's exact texel tables and the cut's
// near disks use it.
#include <array>
#include <cmath>
#include <span>

namespace pbgi {

using Vec3d = std::array<double, 3>;

// Vertices in order, relative to the viewpoint, any lengths but 0; edges through the viewpoint
// or seen end-on add nothing. The result is turned to point to `towards`' side.
inline Vec3d vectorSolidAngle(std::span<const Vec3d> v, const Vec3d& towards) {
  Vec3d sum{0.0, 0.0, 0.0};
  const size_t count = v.size();
  for (size_t e = 0; e < count; ++e) {
    const Vec3d& a = v[e];
    const Vec3d& b = v[(e + 1) % count];
    const Vec3d c{a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
    const double len = std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]);
    if (!(len > 0.0)) continue;
    const double angle = std::atan2(len, a[0] * b[0] + a[1] * b[1] + a[2] * b[2]);
    for (int i = 0; i < 3; ++i) sum[i] += 0.5 * angle * c[i] / len;
  }
  const double side = sum[0] * towards[0] + sum[1] * towards[1] + sum[2] * towards[2];
  if (side < 0.0) {
    for (double& x : sum) x = -x;
  }
  return sum;
}

}  // namespace pbgi
