#include "core/pbgi/wavelet.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <limits>
#include <vector>

#include "core/sampling/rng.h"

namespace pbgi {
namespace {

// A glossy lobe around `axis`: exp(sharpness (cos - 1)), coloured.
Rgb lobe(const Vec3f& dir, const Vec3f& axis, float sharpness) {
  const float v = std::exp(sharpness * (dot(normalize(dir), axis) - 1.0f));
  return Rgb(v, 0.5f * v, 0.25f * v);
}

// The texel centre of an n x n cube map (the microbuffer's layout).
Vec3f texelDirection(int n, int face, int x, int y) {
  return microbufferTables(n)->directions[(static_cast<size_t>(face) * n + y) * n + x];
}

// The wavelets' cube is the microbuffer's: every texel centre looks up its own texel, a random
// direction lands in the texel whose centre is nearest in angle to within a texel, and the
// texels cover the sphere.
TEST(Wavelet, CubeTexelsRoundTripAndCoverTheSphere) {
  Rng rng(1);
  for (int n : {1, 4, 32}) {
    const auto cube = microbufferTables(n);
    double sum = 0.0;
    for (size_t k = 0; k < cube->directions.size(); ++k) {
      ASSERT_EQ(cubePixelIndex(cube->directions[k], n), static_cast<int>(k)) << "n = " << n;
      sum += cube->solidAngles[k];
    }
    EXPECT_NEAR(sum, 4.0 * kPi, 1e-4) << "n = " << n;
    for (int i = 0; i < 1000; ++i) {
      const Vec3f d =
          normalize(Vec3f(rng.uniform() - 0.5f, rng.uniform() - 0.5f, rng.uniform() - 0.5f));
      const int k = cubePixelIndex(d, n);
      ASSERT_GE(k, 0);
      ASSERT_LT(k, static_cast<int>(cube->directions.size()));
      EXPECT_GT(dot(cube->directions[k], d), std::cos(cube->maxWidth)) << "direction " << i;
    }
  }
}

TEST(Wavelet, HaarTransformAndInverseAreExactAndKeepEnergy) {
  for (int n : {1, 2, 8, 32}) {
    Rng rng(n);
    std::vector<float> image(static_cast<size_t>(n) * n);
    double energy = 0.0;
    for (float& v : image) {
      v = 10.0f * rng.uniform() - 3.0f;
      energy += double{v} * v;
    }
    std::vector<float> t = image;
    haarForward(t, n);
    double transformed = 0.0;
    for (float v : t) transformed += double{v} * v;
    EXPECT_NEAR(transformed, energy, 1e-4 * energy) << "n = " << n;  // orthonormal
    haarInverse(t, n);
    for (size_t i = 0; i < image.size(); ++i) {
      ASSERT_NEAR(t[i], image[i], 1e-4f * std::max(1.0f, std::abs(image[i]))) << "n " << n << " i " << i;
    }
  }
}

TEST(Wavelet, ConstantAndStepImagesLandWhereTheLayoutSays) {
  const int n = 8;
  std::vector<float> constant(n * n, 2.0f);
  haarForward(constant, n);
  EXPECT_NEAR(constant[0], 2.0f * n, 1e-5f);  // the sum over n^2 pixels / n
  for (int i = 1; i < n * n; ++i) EXPECT_NEAR(constant[i], 0.0f, 1e-5f) << i;
  // Brighter on the left half: the level-0 horizontal detail alone, positive.
  std::vector<float> step(n * n);
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) step[y * n + x] = x < n / 2 ? 3.0f : 1.0f;
  }
  haarForward(step, n);
  EXPECT_NEAR(step[0], 2.0f * n, 1e-4f);
  EXPECT_NEAR(step[1], 1.0f * n, 1e-4f);  // (3 - 1) / 2 times the node's n pixels a side
  for (int i = 2; i < n * n; ++i) EXPECT_NEAR(step[i], 0.0f, 1e-4f) << i;
}

TEST(Wavelet, KeepingEveryNodeReconstructsEveryTexel) {
  const Vec3f axis = normalize(Vec3f(0.3f, 0.8f, -0.5f));
  const int n = 16;
  const WaveletRadiance w =
      WaveletRadiance::project([&](const Vec3f& d) { return lobe(d, axis, 20.0f); }, n, 0.0f);
  EXPECT_EQ(w.rmsError(), 0.0f);
  for (int face = 0; face < 6; ++face) {
    const std::vector<Rgb> decoded = w.reconstructFace(face);
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        const Vec3f d = texelDirection(n, face, x, y);
        const Rgb expected = lobe(d, axis, 20.0f);
        const Rgb got = w.evaluate(d);
        for (int c = 0; c < 3; ++c) {
          ASSERT_NEAR(got[c], expected[c], 1e-5f + 1e-4f * expected[c]) << face << " " << x << " " << y;
          ASSERT_NEAR(decoded[y * n + x][c], got[c], 1e-5f + 1e-4f * expected[c]);
        }
      }
    }
  }
}

// A sharp highlight keeps few nodes for a small error, and the error reported is the error
// the reconstruction has.
TEST(Wavelet, AThresholdKeepsAHighlightInFewCoefficientsAndReportsItsErrorExactly) {
  const Vec3f axis = normalize(Vec3f(-0.2f, 0.1f, 1.0f));
  const int n = 32;
  const size_t allNodes = 6 * (n * n - 1) / 3;
  float lastError = -1.0f;
  size_t lastKept = allNodes + 1;
  for (float threshold : {1e-3f, 1e-2f, 1e-1f}) {
    const WaveletRadiance w = WaveletRadiance::project(
        [&](const Vec3f& d) { return lobe(d, axis, 200.0f); }, n, threshold);
    double sq = 0.0;
    for (int face = 0; face < 6; ++face) {
      const std::vector<Rgb> decoded = w.reconstructFace(face);
      for (int y = 0; y < n; ++y) {
        for (int x = 0; x < n; ++x) {
          const Rgb e = lobe(texelDirection(n, face, x, y), axis, 200.0f);
          sq += (decoded[y * n + x] - e).length2();
        }
      }
    }
    const double measured = std::sqrt(sq / (6.0 * 3.0 * n * n));
    std::printf("[ measured ] highlight, threshold %g: %zu of %zu nodes, rms error %.3g "
                "(reconstructed %.3g)\n",
                threshold, w.keptNodes(), allNodes, w.rmsError(), measured);
    EXPECT_NEAR(w.rmsError(), measured, 1e-3 * measured + 1e-7);
    EXPECT_LT(w.keptNodes(), allNodes / 20);
    EXPECT_LE(w.keptNodes(), lastKept);
    EXPECT_GE(w.rmsError(), lastError);
    lastKept = w.keptNodes();
    lastError = w.rmsError();
  }
  EXPECT_LT(lastError, 0.01f);  // of a peak of 1
}

TEST(Wavelet, ConstantRadianceKeepsNoDetailAndBrokenSamplesAreCounted) {
  const WaveletRadiance flat =
      WaveletRadiance::project([](const Vec3f&) { return Rgb(0.7f, 0.2f, 0.1f); }, 8, 1e-6f);
  EXPECT_TRUE(flat.isConstantPerFace());
  EXPECT_EQ(flat.keptCoefficients(), 18u);
  EXPECT_NEAR(flat.evaluate(Vec3f(0.3f, -1.0f, 0.2f)).x, 0.7f, 1e-5f);
  const WaveletRadiance broken = WaveletRadiance::project(
      [](const Vec3f& d) {
        return d.z > 0.9f ? Rgb(std::numeric_limits<float>::quiet_NaN()) : Rgb(1.0f);
      },
      8, 0.0f);
  EXPECT_GT(broken.nonFiniteSamples(), 0u);
  EXPECT_TRUE(isFinite(broken.evaluate(Vec3f(0.0f, 0.0f, 1.0f))));
  EXPECT_NEAR(broken.evaluate(Vec3f(0.0f, 0.0f, 1.0f)).x, 0.0f, 1e-5f);  // black where broken
}

}  // namespace
}  // namespace pbgi
