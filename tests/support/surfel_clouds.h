#pragma once
// Sorted surfel clouds for the tree tests: a floor and a sphere, keyed by Morton code and
// numbered in input order, as the external sort delivers them.
#include <algorithm>
#include <cmath>
#include <vector>

#include "core/pbgi/external_sort.h"
#include "core/pbgi/morton.h"
#include "core/pbgi/tree_writer.h"
#include "core/sampling/rng.h"

namespace pbgi::testing {

// Small pages, leaves and codebooks: trees of a few thousand surfels span many pages.
inline TreeWriteOptions smallTreeOptions(TreeEncoding encoding, uint32_t pageSize = 4096) {
  TreeWriteOptions o;
  o.encoding = encoding;
  o.pageSize = pageSize;
  o.build.leafSize = 8;
  o.powerCentres = 64;
  o.areaCentres = 16;
  return o;
}

// Surfels on a few planes and a sphere, sorted by key, numbered in input order.
inline std::vector<SortedSurfel> makeSorted(size_t n, uint64_t seed, bool allSamePosition = false) {
  Rng rng = Rng::forKeys(seed);
  std::vector<SortedSurfel> points(n);
  Bounds3f bounds;
  bounds.extend(Vec3f(-1.0f));
  bounds.extend(Vec3f(1.0f));
  for (size_t i = 0; i < n; ++i) {
    Surfel& s = points[i].surfel;
    if (allSamePosition) {
      s.position = Vec3f(0.25f);
    } else if (i % 3 == 0) {
      s.position = Vec3f(rng.uniform() * 2 - 1, -1.0f, rng.uniform() * 2 - 1);
    } else {
      const float z = rng.uniform() * 2 - 1, phi = rng.uniform() * 2 * kPi;
      const float r = safeSqrt(1 - z * z);
      s.position = 0.5f * Vec3f(r * std::cos(phi), r * std::sin(phi), z);
    }
    s.normal = i % 3 == 0 ? Vec3f(0, 1, 0) : normalize(s.position + Vec3f(1e-3f, 0, 0));
    s.radius = 0.01f;
    s.radiance = Rgb(rng.uniform(), rng.uniform() * 0.5f, 0.25f);
    s.albedo = Rgb(0.5f, rng.uniform(), 0.2f);
    points[i].key = mortonKey(s.position, bounds);
    points[i].sequence = i;
  }
  std::sort(points.begin(), points.end(), [](const SortedSurfel& a, const SortedSurfel& b) {
    return a.key != b.key ? a.key < b.key : a.sequence < b.sequence;
  });
  return points;
}

}  // namespace pbgi::testing
