#pragma once
// Warps from the unit square to the shapes the renderer samples, and tabulated
// distributions (1-D and 2-D piecewise constant) for importance sampling.

#include <span>
#include <vector>

#include "core/math/vec.h"

namespace pbgi {

Vec2f sampleUniformDiskConcentric(const Vec2f& u);
Vec3f sampleCosineHemisphere(const Vec2f& u);  // local frame, z up
inline float cosineHemispherePdf(float cosTheta) { return cosTheta > 0.0f ? cosTheta * kInvPi : 0.0f; }
Vec3f sampleUniformSphere(const Vec2f& u);
inline float uniformSpherePdf() { return kInv4Pi; }
// Directions inside a cone around +z with cos(half-angle) = cosThetaMax.
Vec3f sampleUniformCone(const Vec2f& u, float cosThetaMax);
inline float uniformConePdf(float cosThetaMax) { return 1.0f / (2.0f * kPi * (1.0f - cosThetaMax)); }
// Barycentrics (b0, b1) of a uniformly distributed point on a triangle (b2 = 1 - b0 - b1).
Vec2f sampleUniformTriangle(const Vec2f& u);

// The power heuristic with beta = 2 (Veach 1997) for one sample from each strategy.
inline float powerHeuristic(float pdfA, float pdfB) {
  const float a = pdfA * pdfA;
  const float b = pdfB * pdfB;
  if (a == 0.0f) return 0.0f;
  if (!std::isfinite(a)) return 1.0f;
  return a / (a + b);
}

// A piecewise-constant distribution on [0, 1) with n equal cells.
class Distribution1D {
 public:
  Distribution1D() = default;
  explicit Distribution1D(std::span<const float> weights);

  // Returns a continuous position in [0, 1); pdf is the density with respect to that
  // position; cell (optional) receives the cell index.
  float sampleContinuous(float u, float* pdf, int* cell = nullptr) const;
  // Picks a cell with probability weight / total.
  int sampleDiscrete(float u, float* probability = nullptr) const;
  float discreteProbability(int cell) const;
  float density(float x) const;  // continuous density at x in [0, 1)
  int size() const { return static_cast<int>(func_.size()); }
  float total() const { return total_; }

 private:
  std::vector<float> func_;
  std::vector<float> cdf_;  // size n + 1
  float total_ = 0.0f;      // integral of func over [0, 1)
};

// A piecewise-constant distribution on [0, 1)^2 given as rows (v) of columns (u).
class Distribution2D {
 public:
  Distribution2D() = default;
  Distribution2D(std::span<const float> weights, int width, int height);

  Vec2f sampleContinuous(const Vec2f& u, float* pdf) const;
  float density(const Vec2f& p) const;
  bool empty() const { return rows_.empty(); }

 private:
  std::vector<Distribution1D> rows_;
  Distribution1D marginal_;
};

}  // namespace pbgi
