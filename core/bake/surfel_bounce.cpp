#include "core/bake/surfel_bounce.h"

#include <algorithm>

#include "core/sampling/rng.h"
#include "core/util/check.h"

namespace pbgi {

bool reflectsLight(const Surfel& s) {
  return s.materialClass == MaterialClass::kDiffuse && !isBlack(s.albedo);
}

CutOptions bounceCutOptions(const CutOptions& first, int bounce) {
  if (bounce <= 1) return first;
  CutOptions o = first;
  const float hi = 4.0f * kPi;
  o.lightSolidAngle = std::min(hi, o.lightSolidAngle * kLaterBounceCoarsening);
  o.lightBound = std::min(hi, o.lightBound * kLaterBounceCoarsening);
  o.receiverBound = std::min(hi, o.receiverBound * kLaterBounceCoarsening);
  return o;
}

SurfelBouncer::SurfelBouncer(const CutOptions& options) : options_(options) {}

absl::Status SurfelBouncer::gather(TreePageSource& tree, const Scene& scene,
                                   std::span<const Surfel> surfels, size_t groupSize,
                                   std::span<const uint64_t> keys, size_t groupsTogether,
                                   std::span<SurfelIrradiance> irradiance, CutStats* stats) {
  PBGI_CHECK_GT(groupSize, size_t{0});
  PBGI_CHECK_EQ(irradiance.size(), surfels.size());
  const size_t groups = (surfels.size() + groupSize - 1) / groupSize;
  PBGI_CHECK_EQ(keys.size(), groups);
  std::fill(irradiance.begin(), irradiance.end(), SurfelIrradiance{});
  while (sides_.size() < 2 * groups) sides_.emplace_back(options_);
  // One cut per side: a receiver tree of both sides would pair every receiver with its
  // opposite in each node, whose normals no cone narrower than a hemisphere holds, and share
  // nothing.
  PBGI_CHECK_GT(groupsTogether, size_t{0});
  std::vector<BidirectionalCut*> cuts;
  std::vector<CutJob> jobs;
  for (size_t batch = 0; batch < groups; batch += groupsTogether) {
    const size_t batchEnd = std::min(groups, batch + groupsTogether);
    cuts.clear();
    jobs.clear();
    for (size_t g = batch; g < batchEnd; ++g) {
      const size_t first = g * groupSize, end = std::min(surfels.size(), first + groupSize);
      for (const int side : {0, 1}) {
        Side& c = sides_[2 * g + side];
        c.receivers.clear();
        c.of.clear();
        for (size_t i = first; i < end; ++i) {
          const Surfel& s = surfels[i];
          if (!reflectsLight(s)) continue;
          // A surfel lies on its triangle: its shadow rays leave from its centre along the
          // side's normal.
          const Vec3f n = side == 0 ? s.normal : -s.normal;
          c.receivers.push_back({.p = s.position, .n = n, .ng = n});
          c.of.push_back(static_cast<uint32_t>(i));
        }
        c.gathered.resize(c.receivers.size());
        cuts.push_back(&c.cut);
        jobs.push_back(
            {.receivers = c.receivers, .key = hashKeys(keys[g], side), .out = c.gathered});
      }
    }
    if (absl::Status s = cutTogether(tree, scene, cuts, jobs, stats); !s.ok()) return s;
    for (size_t k = 2 * batch; k < 2 * batchEnd; ++k) {
      const Side& c = sides_[k];
      for (size_t r = 0; r < c.receivers.size(); ++r) {
        (k % 2 == 0 ? irradiance[c.of[r]].front : irradiance[c.of[r]].back) = c.gathered[r];
      }
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
