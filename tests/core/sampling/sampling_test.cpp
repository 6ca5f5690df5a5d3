#include "core/sampling/sampling.h"

#include <gtest/gtest.h>

#include "core/render/filter.h"
#include "core/render/renderer.h"
#include "core/sampling/rng.h"

namespace pbgi {
namespace {

TEST(RngTest, StreamsAreKeyedAndReproducible) {
  Rng a = Rng::forKeys(0, 1, 2, 3), b = Rng::forKeys(0, 1, 2, 3), c = Rng::forKeys(0, 1, 2, 4);
  int same = 0;
  for (int i = 0; i < 100; ++i) {
    const float x = a.uniform();
    EXPECT_EQ(x, b.uniform());
    same += x == c.uniform();
    EXPECT_GE(x, 0.0f);
    EXPECT_LT(x, 1.0f);
  }
  EXPECT_LT(same, 3);
}

TEST(Distribution1DTest, SamplesInProportionToWeights) {
  const std::vector<float> w = {1.0f, 0.0f, 3.0f, 4.0f};
  const Distribution1D d(w);
  std::vector<int> counts(4, 0);
  Rng rng(1);
  const int n = 80000;
  for (int i = 0; i < n; ++i) ++counts[d.sampleDiscrete(rng.uniform())];
  EXPECT_EQ(counts[1], 0);
  EXPECT_NEAR(counts[0] / double(n), 0.125, 0.005);
  EXPECT_NEAR(counts[3] / double(n), 0.5, 0.01);
  EXPECT_FLOAT_EQ(d.discreteProbability(2), 0.375f);
  float pdf = 0.0f;
  d.sampleContinuous(0.9f, &pdf);
  EXPECT_FLOAT_EQ(pdf, 4.0f / 2.0f);  // weight / (total / n)
}

TEST(Distribution2DTest, DensityIntegratesToOne) {
  std::vector<float> w(6 * 4);
  for (size_t i = 0; i < w.size(); ++i) w[i] = static_cast<float>((i * 7) % 5);
  const Distribution2D d(w, 6, 4);
  double integral = 0.0;
  const int n = 240;
  for (int y = 0; y < n; ++y)
    for (int x = 0; x < n; ++x) integral += d.density(Vec2f((x + 0.5f) / n, (y + 0.5f) / n));
  EXPECT_NEAR(integral / (n * n), 1.0, 1e-4);
  Rng rng(5);
  for (int i = 0; i < 1000; ++i) {
    float pdf = 0.0f;
    const Vec2f p = d.sampleContinuous(Vec2f(rng.uniform(), rng.uniform()), &pdf);
    EXPECT_NEAR(pdf, d.density(p), 1e-4f);
    EXPECT_GT(pdf, 0.0f);
  }
}

TEST(SamplingTest, WarpsStayOnTheirDomains) {
  Rng rng(9);
  for (int i = 0; i < 1000; ++i) {
    const Vec2f u(rng.uniform(), rng.uniform());
    EXPECT_NEAR(length(sampleUniformSphere(u)), 1.0f, 1e-5f);
    const Vec3f h = sampleCosineHemisphere(u);
    EXPECT_NEAR(length(h), 1.0f, 1e-5f);
    EXPECT_GE(h.z, 0.0f);
    EXPECT_GE(sampleUniformCone(u, 0.9f).z, 0.9f - 1e-6f);
    const Vec2f b = sampleUniformTriangle(u);
    EXPECT_GE(b.x, 0.0f);
    EXPECT_GE(b.y, 0.0f);
    EXPECT_LE(b.x + b.y, 1.0f + 1e-6f);
  }
}

TEST(FilterTest, SamplesStayInSupportAndFollowTheProfile) {
  for (FilterType type : {FilterType::kBox, FilterType::kGaussian, FilterType::kBlackmanHarris}) {
    const FilterSampler f(type, 3.0f);
    Rng rng(2);
    double centre = 0.0, edge = 0.0;
    for (int i = 0; i < 20000; ++i) {
      const Vec2f o = f.sample(Vec2f(rng.uniform(), rng.uniform()));
      ASSERT_LE(std::abs(o.x), 1.5f);
      ASSERT_LE(std::abs(o.y), 1.5f);
      centre += std::abs(o.x) < 0.25f;
      edge += std::abs(o.x) > 1.25f;
    }
    if (type == FilterType::kBox) {
      EXPECT_NEAR(centre / edge, 1.0, 0.15);
    } else {
      EXPECT_GT(centre, 5.0 * edge);
    }
  }
}

TEST(TilesTest, CoverTheImageOnceInMortonOrder) {
  const auto tiles = makeTiles(100, 70, 32);
  ASSERT_EQ(tiles.size(), 12u);
  std::vector<int> covered(100 * 70, 0);
  for (const auto& t : tiles)
    for (int y = t.y0; y < t.y1; ++y)
      for (int x = t.x0; x < t.x1; ++x) ++covered[y * 100 + x];
  for (int c : covered) ASSERT_EQ(c, 1);
  // Morton order: (0,0), (1,0), (0,1), (1,1), (2,0), ...
  EXPECT_EQ(tiles[1].x0, 32);
  EXPECT_EQ(tiles[2].y0, 32);
  EXPECT_EQ(tiles[3].x0, 32);
  EXPECT_EQ(tiles[3].y0, 32);
}

}  // namespace
}  // namespace pbgi
