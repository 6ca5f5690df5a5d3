#pragma once
// Pixel reconstruction filters, applied by filter importance sampling (pbrt-v4): each camera
// sample's position in the pixel is drawn from the filter itself and weighs 1. A pixel then
// depends on its own samples only, which keeps tiles independent and bit-identical whatever
// the tiling. All three filters are separable.

#include <vector>

#include "core/math/vec.h"
#include "core/sampling/sampling.h"
#include "core/scene/shot.h"

namespace pbgi {

class FilterSampler {
 public:
  // width: full width of the support in pixels. The Gaussian's sigma is width / 6 (the
  // support spans +-3 sigma); Blackman-Harris spans the whole width.
  FilterSampler(FilterType type, float width);

  // Offset from the pixel centre, in pixels.
  Vec2f sample(const Vec2f& u) const;
  // The filter's 1-D profile at x (unnormalised), for tests.
  float evaluate1D(float x) const;
  float radius() const { return radius_; }

 private:
  FilterType type_;
  float radius_;
  Distribution1D table_;  // over [-radius, radius) for the non-box filters
};

}  // namespace pbgi
