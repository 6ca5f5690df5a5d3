#include "core/render/filter.h"

#include "core/util/check.h"

namespace pbgi {

namespace {
constexpr int kTableSize = 256;
}

FilterSampler::FilterSampler(FilterType type, float width) : type_(type), radius_(0.5f * width) {
  PBGI_CHECK_GT(width, 0.0f);
  if (type_ == FilterType::kBox) return;
  std::vector<float> values(kTableSize);
  for (int i = 0; i < kTableSize; ++i) {
    const float x = -radius_ + (static_cast<float>(i) + 0.5f) / kTableSize * 2.0f * radius_;
    values[i] = evaluate1D(x);
  }
  table_ = Distribution1D(values);
}

float FilterSampler::evaluate1D(float x) const {
  if (std::abs(x) > radius_) return 0.0f;
  switch (type_) {
    case FilterType::kBox:
      return 1.0f;
    case FilterType::kGaussian: {
      const float sigma = radius_ / 3.0f;
      return std::exp(-x * x / (2.0f * sigma * sigma));
    }
    case FilterType::kBlackmanHarris: {
      // The 4-term window over [-radius, radius], peak at 0.
      const float t = (x + radius_) / (2.0f * radius_);
      const float a = 2.0f * kPi * t;
      return 0.35875f - 0.48829f * std::cos(a) + 0.14128f * std::cos(2.0f * a) -
             0.01168f * std::cos(3.0f * a);
    }
  }
  return 0.0f;
}

Vec2f FilterSampler::sample(const Vec2f& u) const {
  if (type_ == FilterType::kBox) return {(u.x - 0.5f) * 2.0f * radius_, (u.y - 0.5f) * 2.0f * radius_};
  float pdf = 0.0f;
  const float x = table_.sampleContinuous(u.x, &pdf);
  const float y = table_.sampleContinuous(u.y, &pdf);
  return {(x - 0.5f) * 2.0f * radius_, (y - 0.5f) * 2.0f * radius_};
}

}  // namespace pbgi
