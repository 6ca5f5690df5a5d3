#include "core/pbgi/sh.h"

#include <gtest/gtest.h>

#include <cmath>

#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"

namespace pbgi {
namespace {

Vec3f randomDirection(Rng& rng) {
  const float u0 = rng.uniform();
  return sampleUniformSphere(Vec2f(u0, rng.uniform()));
}

// Sloan's table, written out independently of sh.cpp, at a direction off every axis.
TEST(ShTest, BasisMatchesSloanTable) {
  const Vec3f d = normalize(Vec3f(0.3f, -0.5f, 0.8f));
  const double x = d.x, y = d.y, z = d.z;
  const double pi = std::numbers::pi;
  const double expected[9] = {0.5 * std::sqrt(1.0 / pi),
                              -std::sqrt(3.0 / (4.0 * pi)) * y,
                              std::sqrt(3.0 / (4.0 * pi)) * z,
                              -std::sqrt(3.0 / (4.0 * pi)) * x,
                              0.5 * std::sqrt(15.0 / pi) * x * y,
                              -0.5 * std::sqrt(15.0 / pi) * y * z,
                              0.25 * std::sqrt(5.0 / pi) * (3.0 * z * z - 1.0),
                              -0.5 * std::sqrt(15.0 / pi) * x * z,
                              0.25 * std::sqrt(15.0 / pi) * (x * x - y * y)};
  float got[9];
  evalShBasis(d, got);
  for (int i = 0; i < 9; ++i) EXPECT_NEAR(got[i], expected[i], 1e-6) << "coefficient " << i;
}

// Projecting each basis function must give back the unit vector: integral Y_i Y_j = delta_ij.
// The quadrature is exact for these polynomials, so the only error is float rounding.
// The gradients agree with central differences of the basis (in 3D, off the sphere too: the
// basis is a polynomial).
TEST(ShTest, BasisGradientMatchesFiniteDifferences) {
  for (const Vec3f& dir : {Vec3f(0, 0, 1), normalize(Vec3f(0.3f, -0.5f, 0.8f)),
                           normalize(Vec3f(-1, 2, 0.5f))}) {
    Vec3f grad[kShCoefficients];
    evalShBasisGradient(dir, grad);
    const float h = 1e-3f;
    for (int axis = 0; axis < 3; ++axis) {
      Vec3f step(0.0f);
      step[axis] = h;
      float plus[kShCoefficients], minus[kShCoefficients];
      evalShBasis(dir + step, plus);
      evalShBasis(dir - step, minus);
      for (int i = 0; i < kShCoefficients; ++i) {
        EXPECT_NEAR(grad[i][axis], (plus[i] - minus[i]) / (2.0f * h), 1e-3f)
            << "basis " << i << " axis " << axis;
      }
    }
  }
}

TEST(ShTest, BasisIsOrthonormalByQuadrature) {
  for (int j = 0; j < kShCoefficients; ++j) {
    const Sh9 p = projectNumerically(
        [j](const Vec3f& w) {
          float y[kShCoefficients];
          evalShBasis(w, y);
          return y[j];
        },
        8, 16);
    for (int i = 0; i < kShCoefficients; ++i) {
      EXPECT_NEAR(p.c[i], i == j ? 1.0f : 0.0f, 1e-5f) << "<Y" << i << ", Y" << j << ">";
    }
  }
}

// For the normal +z only the zonal terms remain: pi Y00 = 0.886227, 2 pi / 3 Y10(z) =
// 1.023327 and pi / 4 Y20(z) = pi / 4 * 0.315392 * (3 - 1) = 0.495416 (Ramamoorthi and
// Hanrahan 2001 list 0.886227, 1.023328 and 0.247708 = pi / 4 * 0.315392).
TEST(ShTest, ClampedCosineAroundZHasKnownCoefficients) {
  const Sh9 sh = projectClampedCosine(Vec3f(0.0f, 0.0f, 1.0f));
  EXPECT_NEAR(sh.c[0], 0.886227f, 1e-5f);
  EXPECT_NEAR(sh.c[2], 1.023327f, 1e-5f);
  EXPECT_NEAR(sh.c[6], 0.495416f, 1e-5f);
  for (int i : {1, 3, 4, 5, 7, 8}) EXPECT_EQ(sh.c[i], 0.0f) << i;
}

TEST(ShTest, ClampedCosineMatchesNumericalProjection) {
  const Vec3f normals[] = {Vec3f(0, 0, 1),
                           Vec3f(0, 0, -1),
                           Vec3f(1, 0, 0),
                           Vec3f(0, -1, 0),
                           normalize(Vec3f(1, 1, 1)),
                           normalize(Vec3f(-0.2f, 0.7f, -0.4f)),
                           normalize(Vec3f(0.9f, -0.1f, 0.3f))};
  for (const Vec3f& n : normals) {
    // The kink at the horizon slows the quadrature to second order: many nodes.
    const Sh9 numeric =
        projectNumerically([n](const Vec3f& w) { return std::max(0.0f, dot(n, w)); }, 600, 1200);
    const Sh9 analytic = projectClampedCosine(n);
    for (int i = 0; i < kShCoefficients; ++i) {
      EXPECT_NEAR(numeric.c[i], analytic.c[i], 1e-3f) << "normal " << n << " coefficient " << i;
    }
  }
}

TEST(ShTest, ProjectThenEvaluateReproducesBandLimitedFunction) {
  Rng rng(17);
  Sh9 truth;
  for (float& c : truth.c) c = 2.0f * rng.uniform() - 1.0f;
  const auto f = [&truth](const Vec3f& w) { return evaluate(truth, w); };
  // The smallest exact rule: three Gauss-Legendre nodes (degree 5) and five in phi.
  const Sh9 projected = projectNumerically(f, 3, 5);
  for (int i = 0; i < kShCoefficients; ++i) EXPECT_NEAR(projected.c[i], truth.c[i], 1e-5f) << i;
  for (int k = 0; k < 100; ++k) {
    const Vec3f w = randomDirection(rng);
    EXPECT_NEAR(evaluate(projected, w), f(w), 1e-5f) << w;
  }
  // One node too few in phi aliases the m = +-2 terms: the test would notice a wrong rule.
  const Sh9 aliased = projectNumerically(f, 3, 2);
  float worst = 0.0f;
  for (int i = 0; i < kShCoefficients; ++i)
    worst = std::max(worst, std::abs(aliased.c[i] - truth.c[i]));
  EXPECT_GT(worst, 1e-2f);
}

// Integrating an SH function over the sphere leaves c0 * sqrt(4 pi). A disk of area A shows
// an integrated projected area of pi A, and a Lambertian emitter of radiance L sends out a
// power of pi L A.
TEST(ShTest, DiskAndEmitterLobesIntegrateToAreaAndPower) {
  const Vec3f n = normalize(Vec3f(0.2f, 0.9f, -0.4f));
  const float area = 0.37f;
  const Sh9 a = projectedAreaSh(n, area);
  EXPECT_NEAR(a.c[0] * std::sqrt(4.0f * kPi), kPi * area, 1e-5f);
  // Band-limited, the lobe peaks along n at 1.0625 A (0.25 + 0.5 + 0.3125), and behind the
  // disk it is small but not zero (the ringing of a three-band projection).
  EXPECT_NEAR(evaluate(a, n), 1.0625f * area, 1e-5f);
  EXPECT_NEAR(evaluate(a, -n), (0.25f - 0.5f + 0.3125f) * area, 1e-5f);

  const Rgb radiance(2.0f, 0.5f, 0.0f);
  const Sh9Rgb power = lambertianIntensitySh(n, area, radiance);
  const Rgb total = power.c[0] * std::sqrt(4.0f * kPi);
  EXPECT_NEAR(total.x, kPi * area * 2.0f, 1e-5f);
  EXPECT_NEAR(total.y, kPi * area * 0.5f, 1e-5f);
  EXPECT_EQ(total.z, 0.0f);
  // Intensity over projected area is the radiance in every direction the disk faces.
  const Vec3f w = normalize(n + Vec3f(0.1f, 0.0f, 0.2f));
  EXPECT_NEAR(evaluate(power, w).x / evaluate(a, w), radiance.x, 1e-5f);
}

TEST(ShTest, ArithmeticAndFlatLayout) {
  const Sh9 a = projectClampedCosine(Vec3f(0, 1, 0));
  const Sh9 b = projectClampedCosine(Vec3f(1, 0, 0));
  const Vec3f w = normalize(Vec3f(1, 2, 3));
  EXPECT_NEAR(evaluate(a + b * 2.0f, w), evaluate(a, w) + 2.0f * evaluate(b, w), 1e-6f);
  EXPECT_EQ(0.5f * a, a * 0.5f);

  Sh9Rgb rgb(a, Rgb(1.0f, 2.0f, 3.0f));
  rgb += Sh9Rgb(b, Rgb(0.5f));
  rgb *= 2.0f;
  const Rgb e = evaluate(rgb, w);
  EXPECT_NEAR(e.y, 2.0f * (2.0f * evaluate(a, w) + 0.5f * evaluate(b, w)), 1e-5f);
  float flat[Sh9Rgb::kFloats];
  rgb.toFloats(flat);
  EXPECT_EQ(flat[3 * 4 + 1], rgb.c[4].y);  // coefficient-major, then channel
  EXPECT_EQ(flat[26], rgb.c[8].z);
  EXPECT_EQ(Sh9Rgb::fromFloats(flat), rgb);
}

}  // namespace
}  // namespace pbgi

namespace pbgi {
namespace {

TEST(ShRotation, RotatesAClampedCosineOntoItsAxisAndBack) {
  const Vec3f n = normalize(Vec3f(0.3f, -0.8f, 0.5f));
  const Frame frame(n);
  const ShRotation r = ShRotation::toLocal(frame);
  const Sh9 world = projectClampedCosine(n);
  const Sh9 local = r.apply(world);
  const Sh9 expected = projectClampedCosine(Vec3f(0, 0, 1));
  for (int i = 0; i < kShCoefficients; ++i) EXPECT_NEAR(local.c[i], expected.c[i], 1e-5f) << i;
  const Sh9 back = r.applyInverse(local);
  for (int i = 0; i < kShCoefficients; ++i) EXPECT_NEAR(back.c[i], world.c[i], 1e-5f) << i;
  // A function evaluates the same in either frame.
  const Vec3f d = normalize(Vec3f(-0.2f, 0.4f, 0.9f));
  EXPECT_NEAR(evaluate(world, frame.toWorld(d)), evaluate(local, d), 1e-5f);
}

}  // namespace
}  // namespace pbgi
