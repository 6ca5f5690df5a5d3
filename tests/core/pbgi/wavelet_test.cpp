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

// The relative L2 distance between two dense coefficient vectors (which, the basis being
// orthonormal, is that of the functions over the texels).
double relativeDistance(const std::vector<float>& given, const std::vector<float>& got) {
  double d2 = 0.0, n2 = 0.0;
  for (size_t k = 0; k < given.size(); ++k) {
    d2 += double(given[k] - got[k]) * (given[k] - got[k]);
    n2 += double(given[k]) * given[k];
  }
  return std::sqrt(d2 / n2);
}

// A highlight on a noisy floor: what a glossy surfel's Monte Carlo light looks like.
Rgb noisyHighlight(const Vec3f& d, const Vec3f& axis) {
  const uint64_t h = static_cast<uint64_t>(std::abs(d.x * 7919.0f + d.y * 104729.0f + d.z * 1299709.0f));
  const float noise = 0.05f * static_cast<float>(h % 1000) / 1000.0f;
  return lobe(d, axis, 80.0f) + Rgb(0.2f + noise);
}

TEST(Wavelet, KeepingTheFewestNodesHoldsTheRelativeErrorItIsGiven) {
  const Vec3f axis = normalize(Vec3f(0.3f, -0.5f, 0.8f));
  const int n = 16;
  const WaveletRadiance exact =
      WaveletRadiance::project([&](const Vec3f& d) { return noisyHighlight(d, axis); }, n, 0.0f);
  const std::vector<float> given = exact.dense();
  size_t lastKept = exact.keptNodes() + 1;
  for (float error : {0.01f, 0.05f, 0.1f, 0.3f}) {
    const WaveletRadiance kept = WaveletRadiance::fromDense(given, n, 0.0f, error);
    const double measured = relativeDistance(given, kept.dense());
    std::printf("[ measured ] relative error %g: %zu of %zu nodes, measured %.4f\n", error,
                kept.keptNodes(), exact.keptNodes(), measured);
    EXPECT_LE(measured, error * (1.0 + 1e-4));
    EXPECT_NEAR(kept.relativeError(), measured, 1e-4);
    EXPECT_LT(kept.keptNodes(), lastKept);
    lastKept = kept.keptNodes();
  }
  // A node budget keeps the largest nodes and reports what it cost.
  const WaveletRadiance capped = WaveletRadiance::fromDense(given, n, 0.0f, 0.0f, 5);
  EXPECT_EQ(capped.keptNodes(), 5u);
  EXPECT_NEAR(capped.relativeError(), relativeDistance(given, capped.dense()), 1e-4);
}

TEST(Wavelet, ASumIsTheSumOfItsParts) {
  const int n = 8;
  const WaveletRadiance a = WaveletRadiance::project(
      [](const Vec3f& d) { return lobe(d, Vec3f(0.0f, 0.0f, 1.0f), 30.0f); }, n, 0.0f);
  const WaveletRadiance b = WaveletRadiance::project(
      [](const Vec3f& d) { return lobe(d, normalize(Vec3f(1.0f, 1.0f, 0.0f)), 5.0f); }, n, 0.0f);
  const WaveletRadiance* parts[] = {&a, nullptr, &b};
  const WaveletRadiance sum = WaveletRadiance::sum(parts, 0.0f);
  Rng rng = Rng::forKeys(5, 6, 7, 8);
  for (int i = 0; i < 200; ++i) {
    const Vec3f d(rng.uniform() - 0.5f, rng.uniform() - 0.5f, rng.uniform() - 0.5f);
    if (d.length2() < 1e-4f) continue;
    const Rgb expected = a.evaluate(d) + b.evaluate(d);
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(sum.evaluate(d)[c], expected[c], 1e-5f);
  }
  EXPECT_TRUE(WaveletRadiance::sum(std::span<const WaveletRadiance* const>(), 0.0f).empty());
}

// The wavelet radiance product: a BSDF slice projected once with each texel's solid angle as
// weight, dotted with projected radiance, is the reflected radiance the texels integrate.
TEST(Wavelet, TheProductOfAProjectedBrdfAndRadianceIsTheSpatialIntegral) {
  const int n = 16;
  const auto cube = microbufferTables(n);
  const Vec3f normal(0.0f, 0.0f, 1.0f);
  const Vec3f mirror = normalize(Vec3f(0.4f, 0.2f, 1.0f));
  // A Phong-like lobe times the cosine, per unit solid angle.
  auto brdfCos = [&](const Vec3f& wi) {
    const float c = dot(wi, normal);
    return c > 0.0f ? 20.0f * std::pow(std::max(0.0f, dot(wi, mirror)), 30.0f) * c : 0.0f;
  };
  auto radiance = [&](const Vec3f& wi) { return noisyHighlight(wi, normalize(Vec3f(0.5f, 0.1f, 1.0f))); };
  double integral[3] = {0.0, 0.0, 0.0};
  for (size_t t = 0; t < cube->directions.size(); ++t) {
    const Rgb v = radiance(cube->directions[t]) * (brdfCos(cube->directions[t]) * cube->solidAngles[t]);
    for (int c = 0; c < 3; ++c) integral[c] += v[c];
  }
  const WaveletRadiance brdf = WaveletRadiance::project(
      [&](const Vec3f& wi) {
        return Rgb(brdfCos(wi) * cube->solidAngles[static_cast<size_t>(cubePixelIndex(wi, n))]);
      },
      n, 0.0f);
  const WaveletRadiance light = WaveletRadiance::project(radiance, n, 0.0f);
  const Rgb product = brdf.dot(light);
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(product[c], integral[c], 1e-4 * integral[c] + 1e-6);
  // Thresholded (each to 5 %), the product keeps within a few percent of the integral.
  const Rgb sparse = WaveletRadiance::fromDense(brdf.dense(), n, 0.0f, 0.05f)
                         .dot(WaveletRadiance::fromDense(light.dense(), n, 0.0f, 0.05f));
  std::printf("[ measured ] product %.5g, thresholded %.5g, integral %.5g\n", product.x,
              sparse.x, integral[0]);
  EXPECT_NEAR(sparse.x, integral[0], 0.05 * integral[0]);
}

TEST(Wavelet, StoredFacesAreCheckedByName) {
  const WaveletRadiance w = WaveletRadiance::project(
      [](const Vec3f& d) { return lobe(d, Vec3f(0.0f, 0.0f, 1.0f), 30.0f); }, 4, 0.0f);
  ASSERT_GE(w.faces()[4].nodes.size(), 2u);
  EXPECT_TRUE(WaveletRadiance::fromFaces(4, w.faces()).ok());
  EXPECT_NE(WaveletRadiance::fromFaces(3, w.faces()).status().message().find("power of two"),
            std::string::npos);
  auto broken = [&](auto&& change) {
    std::array<WaveletFace, 6> faces = w.faces();
    change(faces[4]);
    return std::string(WaveletRadiance::fromFaces(4, faces).status().message());
  };
  EXPECT_NE(broken([](WaveletFace& f) { f.nodes[0].level = 2; }).find("outside the 2 levels"),
            std::string::npos);
  EXPECT_NE(broken([](WaveletFace& f) { f.nodes[1].x = 7; }).find("outside"), std::string::npos);
  EXPECT_NE(broken([](WaveletFace& f) { std::swap(f.nodes[0], f.nodes[1]); }).find("order"),
            std::string::npos);
  EXPECT_NE(broken([](WaveletFace& f) { f.nodes[1].detail[2].y = std::nanf(""); })
                .find("not finite"),
            std::string::npos);
  EXPECT_NE(broken([](WaveletFace& f) { f.scaling.z = INFINITY; }).find("scaling not finite"),
            std::string::npos);
}

}  // namespace
}  // namespace pbgi
