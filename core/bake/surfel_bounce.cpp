#include "core/bake/surfel_bounce.h"

#include <algorithm>

#include "core/sampling/rng.h"

namespace pbgi {

bool reflectsLight(const Surfel& s) {
  return s.materialClass == MaterialClass::kDiffuse && !isBlack(s.albedo);
}

SurfelBouncer::SurfelBouncer(const CutOptions& options) : cut_(options) {}

absl::Status SurfelBouncer::gather(TreePageSource& tree, const Scene& scene,
                                   std::span<const Surfel> surfels, uint64_t key,
                                   std::span<SurfelIrradiance> irradiance, CutStats* stats) {
  std::fill(irradiance.begin(), irradiance.end(), SurfelIrradiance{});
  // One cut per side: a receiver tree of both sides would pair every receiver with its
  // opposite in each node, whose normals no cone narrower than a hemisphere holds, and share
  // nothing.
  for (const int side : {0, 1}) {
    receivers_.clear();
    of_.clear();
    for (size_t i = 0; i < surfels.size(); ++i) {
      const Surfel& s = surfels[i];
      if (!reflectsLight(s)) continue;
      // A surfel lies on its triangle: its shadow rays leave from its centre along the side's
      // normal.
      const Vec3f n = side == 0 ? s.normal : -s.normal;
      receivers_.push_back({.p = s.position, .n = n, .ng = n});
      of_.push_back(static_cast<uint32_t>(i));
    }
    gathered_.resize(receivers_.size());
    if (absl::Status s = cut_.irradiance(tree, scene, receivers_, hashKeys(key, side), gathered_,
                                         stats);
        !s.ok()) {
      return s;
    }
    for (size_t r = 0; r < receivers_.size(); ++r) {
      (side == 0 ? irradiance[of_[r]].front : irradiance[of_[r]].back) = gathered_[r];
    }
  }
  return absl::OkStatus();
}

Rgb reflectedPower(const Surfel& s, const SurfelIrradiance& e) {
  return reflectsLight(s) ? s.albedo * (e.front + e.back) * (s.area() * kInvPi) : Rgb(0.0f);
}

void addReflected(Surfel& s, const SurfelIrradiance& e) {
  if (!reflectsLight(s)) return;
  s.radiance += s.albedo * kInvPi * e.front;
  s.backRadiance += s.albedo * kInvPi * e.back;
}

Rgb tailFactor(const std::array<double, 3>& last, const std::array<double, 3>& previous) {
  Rgb f(0.0f);
  for (int c = 0; c < 3; ++c) {
    if (!(last[c] > 0.0) || !(previous[c] > 0.0)) continue;
    const double r = std::min<double>(last[c] / previous[c], kMaxBounceRatio);
    f[c] = static_cast<float>(r / (1.0 - r));
  }
  return f;
}

}  // namespace pbgi
