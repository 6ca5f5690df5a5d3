#include "core/bake/surfel_bounce.h"

#include <algorithm>

namespace pbgi {

bool reflectsLight(const Surfel& s) {
  return s.materialClass == MaterialClass::kDiffuse && !isBlack(s.albedo);
}

SurfelBouncer::SurfelBouncer(const CutOptions& options) : cut_(options) {}

absl::Status SurfelBouncer::gather(TreePageSource& tree, const Scene& scene,
                                   std::span<const Surfel> surfels, uint64_t key,
                                   std::span<Rgb> irradiance, CutStats* stats) {
  receivers_.clear();
  of_.clear();
  std::fill(irradiance.begin(), irradiance.end(), Rgb(0.0f));
  for (size_t i = 0; i < surfels.size(); ++i) {
    const Surfel& s = surfels[i];
    if (!reflectsLight(s)) continue;
    // A surfel lies on its triangle: shadow rays leave from its centre along its normal.
    receivers_.push_back({.p = s.position, .n = s.normal, .ng = s.normal});
    of_.push_back(static_cast<uint32_t>(i));
  }
  gathered_.resize(receivers_.size());
  if (absl::Status s = cut_.irradiance(tree, scene, receivers_, key, gathered_, stats); !s.ok()) {
    return s;
  }
  for (size_t r = 0; r < receivers_.size(); ++r) irradiance[of_[r]] = gathered_[r];
  return absl::OkStatus();
}

Rgb reflectedPower(const Surfel& s, const Rgb& e) {
  return reflectsLight(s) ? s.albedo * e * (s.area() * kInvPi) : Rgb(0.0f);
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
