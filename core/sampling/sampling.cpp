#include "core/sampling/sampling.h"

#include <algorithm>
#include <numeric>

#include "core/util/check.h"

namespace pbgi {

Vec2f sampleUniformDiskConcentric(const Vec2f& u) {
  const Vec2f o(2.0f * u.x - 1.0f, 2.0f * u.y - 1.0f);
  if (o.x == 0.0f && o.y == 0.0f) return {0.0f, 0.0f};
  float r, theta;
  if (std::abs(o.x) > std::abs(o.y)) {
    r = o.x;
    theta = (kPi / 4.0f) * (o.y / o.x);
  } else {
    r = o.y;
    theta = kPi / 2.0f - (kPi / 4.0f) * (o.x / o.y);
  }
  return {r * std::cos(theta), r * std::sin(theta)};
}

Vec3f sampleCosineHemisphere(const Vec2f& u) {
  const Vec2f d = sampleUniformDiskConcentric(u);
  const float z = safeSqrt(1.0f - d.x * d.x - d.y * d.y);
  return {d.x, d.y, z};
}

Vec3f sampleUniformSphere(const Vec2f& u) {
  const float z = 1.0f - 2.0f * u.x;
  const float r = safeSqrt(1.0f - z * z);
  const float phi = 2.0f * kPi * u.y;
  return {r * std::cos(phi), r * std::sin(phi), z};
}

Vec3f sampleUniformCone(const Vec2f& u, float cosThetaMax) {
  const float cosTheta = (1.0f - u.x) + u.x * cosThetaMax;
  const float sinTheta = safeSqrt(1.0f - cosTheta * cosTheta);
  const float phi = 2.0f * kPi * u.y;
  return {std::cos(phi) * sinTheta, std::sin(phi) * sinTheta, cosTheta};
}

Vec2f sampleUniformTriangle(const Vec2f& u) {
  // Heitz 2019: area-preserving and low distortion.
  float b0, b1;
  if (u.x < u.y) {
    b0 = u.x / 2.0f;
    b1 = u.y - b0;
  } else {
    b1 = u.y / 2.0f;
    b0 = u.x - b1;
  }
  return {b0, b1};
}

Distribution1D::Distribution1D(std::span<const float> weights)
    : func_(weights.begin(), weights.end()), cdf_(weights.size() + 1) {
  PBGI_CHECK(!weights.empty());
  const size_t n = func_.size();
  for (float& f : func_) f = std::isfinite(f) ? std::max(f, 0.0f) : 0.0f;
  cdf_[0] = 0.0f;
  // Accumulate in double: large tables lose precision in float.
  double acc = 0.0;
  std::vector<double> cdf(n + 1, 0.0);
  for (size_t i = 0; i < n; ++i) {
    acc += func_[i] / static_cast<double>(n);
    cdf[i + 1] = acc;
  }
  total_ = static_cast<float>(acc);
  if (acc == 0.0) {
    for (size_t i = 1; i <= n; ++i) cdf_[i] = static_cast<float>(i) / static_cast<float>(n);
  } else {
    for (size_t i = 1; i <= n; ++i) cdf_[i] = static_cast<float>(cdf[i] / acc);
  }
  cdf_[n] = 1.0f;
}

float Distribution1D::sampleContinuous(float u, float* pdf, int* cell) const {
  // Last cdf_ entry <= u.
  const auto it = std::upper_bound(cdf_.begin(), cdf_.end(), u);
  const int n = size();
  int i = std::clamp(static_cast<int>(it - cdf_.begin()) - 1, 0, n - 1);
  // Skip cells of zero probability that upper_bound can land on when cdf is flat.
  while (i < n - 1 && cdf_[i + 1] == cdf_[i]) ++i;
  if (cell) *cell = i;
  const float width = cdf_[i + 1] - cdf_[i];
  float du = width > 0.0f ? (u - cdf_[i]) / width : 0.5f;
  du = std::clamp(du, 0.0f, 0x1.fffffep-1f);
  if (pdf) *pdf = total_ > 0.0f ? func_[i] / total_ : 1.0f;
  return std::min((static_cast<float>(i) + du) / static_cast<float>(n), 0x1.fffffep-1f);
}

int Distribution1D::sampleDiscrete(float u, float* probability) const {
  int cell = 0;
  sampleContinuous(u, nullptr, &cell);
  if (probability) *probability = discreteProbability(cell);
  return cell;
}

float Distribution1D::discreteProbability(int cell) const {
  if (cell < 0 || cell >= size()) return 0.0f;
  return cdf_[cell + 1] - cdf_[cell];
}

float Distribution1D::density(float x) const {
  const int n = size();
  const int i = std::clamp(static_cast<int>(x * static_cast<float>(n)), 0, n - 1);
  return total_ > 0.0f ? func_[i] / total_ : 1.0f;
}

Distribution2D::Distribution2D(std::span<const float> weights, int width, int height) {
  PBGI_CHECK_GT(width, 0);
  PBGI_CHECK_GT(height, 0);
  PBGI_CHECK_EQ(weights.size(), static_cast<size_t>(width) * static_cast<size_t>(height));
  rows_.reserve(height);
  std::vector<float> rowTotals(height);
  for (int v = 0; v < height; ++v) {
    rows_.emplace_back(weights.subspan(static_cast<size_t>(v) * width, width));
    rowTotals[v] = rows_.back().total();
  }
  marginal_ = Distribution1D(rowTotals);
}

Vec2f Distribution2D::sampleContinuous(const Vec2f& u, float* pdf) const {
  float pdfV = 0.0f, pdfU = 0.0f;
  int row = 0;
  const float v = marginal_.sampleContinuous(u.y, &pdfV, &row);
  const float x = rows_[row].sampleContinuous(u.x, &pdfU);
  if (pdf) *pdf = pdfV * pdfU;
  return {x, v};
}

float Distribution2D::density(const Vec2f& p) const {
  const int h = static_cast<int>(rows_.size());
  const int row = std::clamp(static_cast<int>(p.y * static_cast<float>(h)), 0, h - 1);
  return marginal_.density(p.y) * rows_[row].density(p.x);
}

}  // namespace pbgi
