#pragma once
// Surfel clouds of simple shapes with known answers, for the gather tests: a closed sphere
// (Fibonacci lattice, facing inwards) and a flat disk (Vogel's sunflower), each with equal
// disks whose areas sum to the shape's.

#include <cmath>
#include <vector>

#include "core/math/vec.h"
#include "core/pbgi/surfel.h"

namespace pbgi::testing {

inline const float kGoldenAngle = kPi * (3.0f - std::sqrt(5.0f));

// Surfels on a sphere (a Fibonacci lattice, nearly uniform), facing inwards, with equal disks
// whose areas sum to the sphere's.
inline std::vector<Surfel> sphereSurfels(int n, float radius, const Rgb& radiance) {
  std::vector<Surfel> surfels(n);
  for (int i = 0; i < n; ++i) {
    const float z = 1.0f - (2.0f * i + 1.0f) / n;
    const float r = safeSqrt(1.0f - z * z);
    const float phi = i * kGoldenAngle;
    const Vec3f dir(r * std::cos(phi), r * std::sin(phi), z);
    surfels[i].position = radius * dir;
    surfels[i].normal = -dir;
    surfels[i].radius = 2.0f * radius / std::sqrt(static_cast<float>(n));
    surfels[i].radiance = radiance;
  }
  return surfels;
}

// Surfels on a disk (Vogel's sunflower), facing `normal`, with areas summing to the disk's.
inline std::vector<Surfel> diskSurfels(int n, const Vec3f& center, const Vec3f& normal, float radius,
                                const Rgb& radiance) {
  const Frame frame(normal);
  std::vector<Surfel> surfels(n);
  for (int i = 0; i < n; ++i) {
    const float r = radius * std::sqrt((i + 0.5f) / n);
    const float phi = i * kGoldenAngle;
    surfels[i].position = center + frame.toWorld(Vec3f(r * std::cos(phi), r * std::sin(phi), 0));
    surfels[i].normal = normal;
    surfels[i].radius = radius / std::sqrt(static_cast<float>(n));
    surfels[i].radiance = radiance;
  }
  return surfels;
}

}  // namespace pbgi::testing
