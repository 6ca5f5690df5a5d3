#pragma once
// Spherical functions as a PBGI tree's nodes hold them: sums of one to three Lambertian lobes
// of random normals, colours and areas, as 27-float vectors (Sh9Rgb::toFloats). Shared by the
// quantizer's tests and benchmarks so both measure the same data.

#include <vector>

#include "core/pbgi/sh.h"
#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"

namespace pbgi::testing {

inline std::vector<float> lambertianLobeVectors(size_t count, uint64_t seed = 9) {
  Rng rng(seed);
  std::vector<float> data(count * Sh9Rgb::kFloats);
  for (size_t i = 0; i < count; ++i) {
    Sh9Rgb sum;
    const int lobes = 1 + static_cast<int>(rng.uniform() * 3.0f);
    for (int l = 0; l < lobes; ++l) {
      const float u0 = rng.uniform();
      const Vec3f n = sampleUniformSphere(Vec2f(u0, rng.uniform()));
      const float r = rng.uniform(), g = rng.uniform(), b = rng.uniform();
      sum += lambertianIntensitySh(n, 0.5f + rng.uniform(), Rgb(r, g, b));
    }
    sum.toFloats(data.data() + i * Sh9Rgb::kFloats);
  }
  return data;
}

}  // namespace pbgi::testing
