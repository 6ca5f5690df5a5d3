#include "core/sampling/low_discrepancy.h"

#include <cmath>
#include <set>
#include <vector>

#include <gtest/gtest.h>

namespace pbgi {
namespace {

// Whether points are a (0, k, 2)-net: for every split of k into a + b, each of the 2^a x 2^b
// boxes holds exactly one point.
bool isNet(const std::vector<Vec2f>& points, int k) {
  for (int a = 0; a <= k; ++a) {
    const int nx = 1 << a, ny = 1 << (k - a);
    std::vector<int> count(static_cast<size_t>(nx) * ny, 0);
    for (const Vec2f& p : points) {
      const int x = static_cast<int>(p.x * static_cast<float>(nx));
      const int y = static_cast<int>(p.y * static_cast<float>(ny));
      if (x < 0 || x >= nx || y < 0 || y >= ny) return false;
      ++count[static_cast<size_t>(y) * nx + x];
    }
    for (const int c : count) {
      if (c != 1) return false;
    }
  }
  return true;
}

TEST(LowDiscrepancy, APixelsFirstPowerOfTwoSamplesAreANet) {
  for (uint64_t seed = 0; seed < 50; ++seed) {
    for (int k = 0; k <= 8; ++k) {
      std::vector<Vec2f> pixel, lens;
      for (uint32_t i = 0; i < (1u << k); ++i) {
        pixel.push_back(owenSobol2D(i, seed));
        lens.push_back(owenSobol2D(shuffledIndex(i, seed), seed + 1));
      }
      EXPECT_TRUE(isNet(pixel, k)) << "seed " << seed << ", 2^" << k << " points";
      EXPECT_TRUE(isNet(lens, k)) << "seed " << seed << ", 2^" << k << " shuffled points";
    }
  }
}

TEST(LowDiscrepancy, EachPointIsUniformOverSeedsAndSeedsDiffer) {
  // Point 3 of 4,096 scrambles, binned 8 x 8: each bin near 64.
  std::vector<int> bins(64, 0);
  std::set<std::pair<float, float>> distinct;
  for (uint64_t seed = 0; seed < 4096; ++seed) {
    const Vec2f p = owenSobol2D(3, seed);
    ++bins[static_cast<size_t>(static_cast<int>(p.y * 8.0f) * 8 + static_cast<int>(p.x * 8.0f))];
    distinct.insert({p.x, p.y});
  }
  double chi2 = 0.0;
  for (const int b : bins) chi2 += (b - 64.0) * (b - 64.0) / 64.0;
  EXPECT_LT(chi2, 110.0);  // 63 degrees of freedom: p < 0.001 above about 103
  EXPECT_GT(distinct.size(), 4000u);
}

TEST(LowDiscrepancy, AnEdgeAcrossAPixelIsEstimatedFarBetterThanByIndependentPoints) {
  // The covered share of a pixel under the edge y < 0.3 + 0.37 x (exactly 0.485), from 16
  // samples, over 2,000 pixels: independent points err by sqrt(p (1 - p) / 16) = 0.125 RMS.
  const auto covered = [](const Vec2f& p) { return p.y < 0.3f + 0.37f * p.x ? 1.0 : 0.0; };
  const double exact = 0.3 + 0.37 / 2.0;
  double stratified = 0.0, independent = 0.0;
  const int pixels = 2000;
  for (int px = 0; px < pixels; ++px) {
    Rng rng(static_cast<uint64_t>(px));
    double a = 0.0, b = 0.0;
    for (uint32_t i = 0; i < 16; ++i) {
      a += covered(owenSobol2D(i, static_cast<uint64_t>(px)));
      b += covered(Vec2f(rng.uniform(), rng.uniform()));
    }
    stratified += (a / 16.0 - exact) * (a / 16.0 - exact);
    independent += (b / 16.0 - exact) * (b / 16.0 - exact);
  }
  stratified = std::sqrt(stratified / pixels);
  independent = std::sqrt(independent / pixels);
  EXPECT_NEAR(independent, 0.125, 0.01);
  EXPECT_LT(stratified, 0.4 * independent) << stratified << " against " << independent;
}

}  // namespace
}  // namespace pbgi
