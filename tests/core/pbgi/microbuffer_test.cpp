#include "core/pbgi/microbuffer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"

namespace pbgi {
namespace {

Vec3f randomDirection(Rng& rng) {
  const float u = rng.uniform();
  return sampleUniformSphere(Vec2f(u, rng.uniform()));
}

TEST(MicrobufferTables, SolidAnglesSumToFourPi) {
  for (int n : {1, 2, 3, 8, 12, 17, 32, 64}) {
    const auto tables = microbufferTables(n);
    ASSERT_EQ(tables->solidAngles.size(), static_cast<size_t>(6 * n * n));
    double sum = 0.0;
    for (float w : tables->solidAngles) {
      ASSERT_GT(w, 0.0f);
      sum += w;
    }
    EXPECT_NEAR(sum, 4.0 * std::numbers::pi, 1e-4) << "N = " << n;
    for (const Vec3f& d : tables->directions) ASSERT_NEAR(length(d), 1.0f, 1e-6f);
  }
}

TEST(MicrobufferTables, SharedPerResolution) {
  EXPECT_EQ(microbufferTables(12).get(), microbufferTables(12).get());
  EXPECT_NE(microbufferTables(12).get(), microbufferTables(13).get());
}

// The closed forms against an independent quadrature over the pixel's square of
// dA / |p|^3 (solid angle) and p / |p| dA / |p|^3 (vector solid angle), p = (u, v, 1) in the
// face's axes. Corner pixels are about 5 times smaller than centre ones at large N.
TEST(MicrobufferTables, SolidAngleMatchesQuadrature) {
  const int n = 8;
  const auto tables = microbufferTables(n);
  for (int f : {0, 3, 5}) {
    const int a = f / 2, b = (a + 1) % 3, c = (a + 2) % 3;
    const double sign = f % 2 == 0 ? 1.0 : -1.0;
    for (int j : {0, 3, 7}) {
      for (int i : {0, 4, 7}) {
        const int m = 200;
        double sum = 0.0, vec[3] = {0.0, 0.0, 0.0};
        const double step = 2.0 / n / m;
        for (int y = 0; y < m; ++y) {
          for (int x = 0; x < m; ++x) {
            double p[3];
            p[a] = sign;
            p[b] = -1.0 + 2.0 * i / n + (x + 0.5) * step;
            p[c] = -1.0 + 2.0 * j / n + (y + 0.5) * step;
            const double len = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
            const double w = step * step / (len * len * len);
            sum += w;
            for (int e = 0; e < 3; ++e) vec[e] += w * p[e] / len;
          }
        }
        const int k = (f * n + j) * n + i;
        EXPECT_NEAR(tables->solidAngles[k], sum, 1e-6 * sum + 1e-8) << "pixel " << k;
        for (int e = 0; e < 3; ++e) {
          EXPECT_NEAR(tables->vectorSolidAngles[k][e], vec[e], 1e-5 * sum) << "pixel " << k;
        }
        EXPECT_NEAR(tables->widths[k], std::sqrt(sum), 1e-6);
      }
    }
  }
}

TEST(Microbuffer, PixelIndexOfEveryPixelDirectionIsThatPixel) {
  for (int n : {1, 5, 12, 32}) {
    Microbuffer buffer(n);
    for (int k = 0; k < buffer.pixelCount(); ++k) {
      ASSERT_EQ(buffer.pixelIndex(buffer.direction(k)), k) << "N = " << n;
      ASSERT_EQ(buffer.pixelIndex(3.0f * buffer.direction(k)), k) << "N = " << n;
    }
  }
}

// A footprint covers exactly its solid angle, wherever it falls and whatever its size (the
// rim's fractions make up what the pixel centres inside lack or exceed), only near its
// direction, and the pixels well inside it fully.
TEST(Microbuffer, FootprintCoversExactlyItsSolidAngle) {
  Rng rng(11);
  for (int n : {8, 24}) {
    Microbuffer buffer(n);
    const float maxWidth = microbufferTables(n)->maxWidth;
    std::vector<Vec3f> dirs = {normalize(Vec3f(0, 0, 1)), normalize(Vec3f(1, 1, 0)),
                               normalize(Vec3f(1, 1, 1)), normalize(Vec3f(-1, 0.2f, 0.9f))};
    for (int i = 0; i < 20; ++i) dirs.push_back(randomDirection(rng));
    for (float omega : {1e-4f, 0.005f, 0.02f, 0.1f, 0.5f, 2.0f, 7.0f}) {
      const float rimChord = std::sqrt(omega / kPi);
      for (const Vec3f& d : dirs) {
        buffer.clear(Vec3f(0.0f));
        const int reached = buffer.splatFootprint(d, 2.0f, omega, Rgb(1.0f), 0.0f);
        EXPECT_EQ(reached, buffer.coveredPixels());
        EXPECT_NEAR(buffer.coveredSolidAngle(), omega, 2e-5f * omega + 1e-7f)
            << "N " << n << " omega " << omega << " dir " << fmt::format("{}", d);
        if (omega >= 0.02f) {
          EXPECT_TRUE(buffer.covered(buffer.pixelIndex(d)));
        }
        for (int k = 0; k < buffer.pixelCount(); ++k) {
          const float chord = length(buffer.direction(k) - d);
          if (buffer.covered(k)) {
            // Half a diagonal: the pixel of a tiny footprint's direction.
            ASSERT_LE(chord, rimChord + 0.75f * maxWidth) << "omega " << omega;
            EXPECT_EQ(buffer.depth(k), 2.0f);
          }
          if (omega >= 0.1f && chord < rimChord - maxWidth) {
            ASSERT_EQ(buffer.coverage(k), 1.0f) << "N " << n << " omega " << omega;
          }
        }
      }
    }
  }
}

// Splats of one surface (overlapping depth ranges) add their coverage: pieces side by side
// fill a pixel, and overlapping pieces keep their energy (coverage past 1).
TEST(Microbuffer, PiecesOfOneSurfaceAddUp) {
  Microbuffer buffer(8);
  buffer.clear(Vec3f(0.0f));
  const int k = 6 * 8 + 3 + 2 * 64;  // a pixel of face 2 (+z)
  const Vec3f d = buffer.direction(k);
  const float pixel = buffer.solidAngle(k);
  // A quarter of a pixel, centred on it, stays in it.
  EXPECT_EQ(buffer.splatFootprint(d, 3.0f, 0.25f * pixel, Rgb(4, 0, 0), 0.1f), 1);
  EXPECT_EQ(buffer.splatFootprint(d, 3.05f, 0.25f * pixel, Rgb(0, 4, 0), 0.1f), 1);
  EXPECT_NEAR(buffer.coverage(k), 0.5f, 1e-6f);
  EXPECT_NEAR(buffer.radiance(k).x, 1.0f, 1e-6f);  // coverage-weighted
  EXPECT_NEAR(buffer.radiance(k).y, 1.0f, 1e-6f);
  EXPECT_EQ(buffer.depth(k), 3.0f);
  buffer.splatFootprint(d, 3.0f, 0.5f * pixel, Rgb(0, 0, 4), 0.1f);
  EXPECT_NEAR(buffer.coverage(k), 1.0f, 1e-6f);
  EXPECT_NEAR(buffer.radiance(k).z, 2.0f, 1e-5f);
  buffer.splatFootprint(d, 3.0f, 0.25f * pixel, Rgb(0, 0, 4), 0.1f);
  EXPECT_NEAR(buffer.coverage(k), 1.25f, 1e-6f);
  EXPECT_NEAR(buffer.radiance(k).z, 3.0f, 1e-5f);
  EXPECT_EQ(buffer.coveredPixels(), 1);
}

TEST(Microbuffer, DepthTestKeepsTheNearerSplat) {
  Microbuffer buffer(12);
  const Vec3f d = normalize(Vec3f(0.3f, -0.2f, 1.0f));
  const int k = buffer.pixelIndex(d);
  buffer.clear(Vec3f(0.0f));
  EXPECT_GT(buffer.splatFootprint(d, 5.0f, 0.2f, Rgb(1, 0, 0), 0.0f), 0);
  ASSERT_EQ(buffer.coverage(k), 1.0f);
  EXPECT_GT(buffer.splatFootprint(d, 2.0f, 0.2f, Rgb(0, 1, 0), 0.0f), 0);  // nearer: wins
  EXPECT_EQ(buffer.radiance(k), Rgb(0, 1, 0));
  EXPECT_EQ(buffer.depth(k), 2.0f);
  buffer.splatFootprint(d, 3.0f, 0.2f, Rgb(0, 0, 1), 0.0f);  // farther: hidden
  EXPECT_EQ(buffer.radiance(k), Rgb(0, 1, 0));
  EXPECT_EQ(buffer.depth(k), 2.0f);
  EXPECT_EQ(buffer.coverage(k), 1.0f);

  // Solid layers give the same picture in either order.
  Microbuffer other(12);
  other.clear(Vec3f(0.0f));
  other.splatFootprint(d, 2.0f, 0.2f, Rgb(0, 1, 0), 0.0f);
  other.splatFootprint(d, 5.0f, 0.2f, Rgb(1, 0, 0), 0.0f);
  other.splatFootprint(d, 3.0f, 0.2f, Rgb(0, 0, 1), 0.0f);
  int solid = 0;
  for (int i = 0; i < buffer.pixelCount(); ++i) {
    if (buffer.coverage(i) == 1.0f && other.coverage(i) == 1.0f) {
      ASSERT_EQ(other.radiance(i), buffer.radiance(i));
      ++solid;
    }
  }
  EXPECT_GT(solid, 3);
}

// A splat covering a quarter of a pixel in front of a solid one: the mix by coverage; and a
// solid one far behind a half-covered pixel shows in the open half only.
TEST(Microbuffer, PartlyCoveredPixelsMixByCoverage) {
  Microbuffer buffer(8);
  buffer.clear(Vec3f(0.0f));
  const int k = 4 * 8 + 5;  // face 0 (+x)
  const Vec3f d = buffer.direction(k);
  const float pixel = buffer.solidAngle(k);
  buffer.splatFootprint(d, 2.0f, 1.0f, Rgb(0, 1, 0), 0.0f);
  buffer.splatFootprint(d, 1.0f, 0.25f * pixel, Rgb(0, 0, 8), 0.0f);
  EXPECT_NEAR(buffer.radiance(k).z, 2.0f, 1e-5f);
  EXPECT_NEAR(buffer.radiance(k).y, 0.75f, 1e-5f);
  EXPECT_EQ(buffer.depth(k), 1.0f);
  EXPECT_NEAR(buffer.coverage(k), 1.0f, 1e-6f);

  buffer.clear(Vec3f(0.0f));
  buffer.splatFootprint(d, 1.0f, 0.5f * pixel, Rgb(2, 0, 0), 0.0f);
  buffer.splatFootprint(d, 10.0f, 1.0f, Rgb(0, 2, 0), 0.0f);
  EXPECT_NEAR(buffer.coverage(k), 1.0f, 1e-6f);
  EXPECT_NEAR(buffer.radiance(k).x, 1.0f, 1e-6f);
  EXPECT_NEAR(buffer.radiance(k).y, 1.0f, 1e-6f);
  EXPECT_EQ(buffer.depth(k), 1.0f);
  // Two pieces of that far surface, each half a pixel: together they fill the open half, they
  // do not hide each other.
  buffer.clear(Vec3f(0.0f));
  buffer.splatFootprint(d, 1.0f, 0.5f * pixel, Rgb(2, 0, 0), 0.0f);
  buffer.splatFootprint(d, 10.0f, 0.5f * pixel, Rgb(0, 2, 0), 0.5f);
  buffer.splatFootprint(d, 10.2f, 0.5f * pixel, Rgb(0, 2, 0), 0.5f);
  EXPECT_NEAR(buffer.radiance(k).y, 1.0f, 1e-6f);
  EXPECT_NEAR(buffer.coverage(k), 1.0f, 1e-6f);
}

TEST(Microbuffer, HemisphereSkipsWhatIsBelowTheNormal) {
  const int n = 12;
  Microbuffer buffer(n);
  buffer.clear(Vec3f(0.0f), Vec3f(0, 0, 1));
  EXPECT_EQ(buffer.skippedFaces(), 1);           // -z
  EXPECT_EQ(buffer.skippedPixels(), 3 * n * n);  // -z and the lower halves of the side faces
  // Below the horizon nothing is written, even by a footprint that would cover it.
  EXPECT_EQ(buffer.splatFootprint(Vec3f(0, 0, -1), 1.0f, 1.0f, Rgb(1.0f), 0.0f), 0);
  EXPECT_EQ(buffer.coveredPixels(), 0);

  Rng rng(3);
  for (int i = 0; i < 20; ++i) {
    const Vec3f normal = randomDirection(rng);
    buffer.clear(Vec3f(1.0f), normal);
    int inactive = 0;
    for (int k = 0; k < buffer.pixelCount(); ++k) {
      const bool above = dot(buffer.direction(k), normal) > 0.0f;
      EXPECT_EQ(buffer.active(k), above);
      inactive += above ? 0 : 1;
    }
    EXPECT_EQ(buffer.skippedPixels(), inactive);
    // A face lies entirely below when |n_a| >= |n_b| + |n_c| for its axis a.
    int below = 0;
    for (int a = 0; a < 3; ++a) {
      below += std::abs(normal[a]) >= std::abs(normal[(a + 1) % 3]) + std::abs(normal[(a + 2) % 3])
                   ? 1
                   : 0;
    }
    EXPECT_EQ(buffer.skippedFaces(), below);
  }
}

// A uniform sky of radiance L gives pi L. The cosine is integrated exactly over pixels above
// the horizon; what remains is the pixels the horizon cuts, which the test measures.
TEST(Microbuffer, UniformSkyIrradianceIsPiL) {
  Rng rng(8);
  for (int n : {8, 12, 32}) {
    Microbuffer buffer(n);
    float worst = 0.0f;
    for (int i = 0; i < 20; ++i) {
      const Vec3f normal = i == 0 ? Vec3f(0, 0, 1) : randomDirection(rng);
      buffer.clear(Vec3f(0.0f), normal);
      buffer.splatFootprint(normal, 1.0f, 4.0f * kPi, Rgb(2.0f), 0.0f);  // the whole sphere
      const Rgb e = buffer.irradiance(normal);
      if (i == 0) {
        EXPECT_NEAR(e.x, 2.0f * kPi, 2e-5f);  // the horizon on pixel edges: exact
      }
      worst = std::max(worst, std::abs(e.x / (2.0f * kPi) - 1.0f));
      EXPECT_EQ(e.x, e.y);
    }
    std::printf("[ measured ] uniform sky, N = %d: worst relative error %.2e\n", n, worst);
    EXPECT_LT(worst, 24.0f / (n * n * n)) << "N = " << n;
  }
}

TEST(Microbuffer, ConvolutionsOfTheSamePicture) {
  Microbuffer buffer(16);
  const Vec3f normal = normalize(Vec3f(0.2f, 0.4f, 1.0f));
  buffer.clear(Vec3f(0.0f), normal);
  Rng rng(1);
  for (int i = 0; i < 30; ++i) {
    const Vec3f d = randomDirection(rng);
    buffer.splatFootprint(d, 1.0f + rng.uniform(), 0.3f * rng.uniform(),
                          Rgb(rng.uniform(), rng.uniform(), rng.uniform()), 0.0f);
  }
  // The midpoint rule against the exact per-pixel cosine.
  const Rgb e = buffer.irradiance(normal);
  const Rgb c = buffer.convolve([&](const Vec3f& w) { return std::max(0.0f, dot(w, normal)); });
  EXPECT_GT(e.x, 0.1f);
  EXPECT_NEAR(c.x / e.x, 1.0f, 0.01f);
  EXPECT_NEAR(c.z / e.z, 1.0f, 0.01f);
  // Weight 1 is the radiance integrated over the covered solid angle.
  buffer.clear(Vec3f(0.0f));
  buffer.splatFootprint(Vec3f(1, 0, 0), 1.0f, 4.0f * kPi, Rgb(1.0f), 0.0f);
  EXPECT_NEAR(buffer.convolve([](const Vec3f&) { return 1.0f; }).x, 4.0f * kPi, 1e-4f);
}

// The solid angle of a one-sided disk seen at distance d from its axis direction tilted by
// `facing` (cosine): exact face-on, the projected approximation otherwise.
float diskSolidAngle(float d, float r, float facing) {
  return 2.0f * kPi * (1.0f - d / std::sqrt(d * d + r * r)) * facing;
}

// Ray casting covers exactly the pixels whose centre ray hits the disk's front, at the hit
// distance, whether the origin is far from the disk or inside its bounding sphere.
TEST(Microbuffer, RayCastCoversExactlyTheDisk) {
  Rng rng(21);
  Microbuffer buffer(16);
  int hits = 0;
  for (int i = 0; i < 300; ++i) {
    const Vec3f origin(rng.uniform(), rng.uniform(), rng.uniform());
    const float radius = 0.05f + 1.5f * rng.uniform();
    const Vec3f center = origin + randomDirection(rng) * (0.2f + 5.0f * rng.uniform());
    Vec3f normal = randomDirection(rng);
    if (dot(normal, center - origin) > 0.0f) normal = -normal;
    buffer.clear(origin);
    buffer.rayCastDisk(center, normal, radius, Rgb(1.0f));
    for (int k = 0; k < buffer.pixelCount(); ++k) {
      const Vec3f& w = buffer.direction(k);
      const float t = dot(center - origin, normal) / dot(w, normal);
      const bool hit =
          dot(w, normal) < 0.0f && (origin + w * t - center).length2() <= radius * radius;
      ASSERT_EQ(buffer.covered(k), hit) << "disk " << i << " pixel " << k;
      if (hit) {
        ASSERT_EQ(buffer.coverage(k), 1.0f);
        ASSERT_NEAR(buffer.depth(k), t, 1e-5f * t);
        ++hits;
      }
    }
  }
  EXPECT_GT(hits, 1000);
}

TEST(Microbuffer, DisksCoverTheirSolidAngle) {
  const int n = 32;
  Microbuffer buffer(n);
  for (float h : {0.3f, 1.0f, 3.0f, 30.0f}) {
    const float r = 1.0f;
    const float exact = diskSolidAngle(h, r, 1.0f);
    // Ray-cast: the pixels the disk holds, up to the band of pixels along its rim.
    buffer.clear(Vec3f(0.0f));
    buffer.rayCastDisk(Vec3f(0, 0, h), Vec3f(0, 0, -1), r, Rgb(1.0f));
    const float sinAngle = r / std::sqrt(h * h + r * r);
    EXPECT_NEAR(buffer.coveredSolidAngle(), exact, 2.0f * kPi * sinAngle * (2.0f / n)) << h;
    for (int k = 0; k < buffer.pixelCount(); ++k) {
      if (buffer.covered(k)) {
        ASSERT_NEAR(buffer.depth(k), h / buffer.direction(k).z, 1e-4f * h);
      }
    }
    // Splatted: exactly its solid angle, tilted or not.
    for (const Vec3f& normal : {Vec3f(0, 0, -1), normalize(Vec3f(0.5f, 0.2f, -1.0f))}) {
      buffer.clear(Vec3f(0.0f));
      EXPECT_GT(buffer.splatDisk(Vec3f(0, 0, h), normal, r, Rgb(1.0f), r), 0);
      const float expected = diskSolidAngle(h, r, -normal.z);
      EXPECT_NEAR(buffer.coveredSolidAngle(), expected, 1e-4f * expected) << h;
    }
  }
}

TEST(Microbuffer, DiskSeenFromBehindIsTransparent) {
  Microbuffer buffer(12);
  buffer.clear(Vec3f(0.0f));
  EXPECT_EQ(buffer.splatDisk(Vec3f(0, 0, 2), Vec3f(0, 0, 1), 1.0f, Rgb(1.0f), 1.0f), 0);
  EXPECT_EQ(buffer.rayCastDisk(Vec3f(0, 0, 2), Vec3f(0, 0, 1), 1.0f, Rgb(1.0f)), 0);
  EXPECT_EQ(buffer.coveredPixels(), 0);
  // The same disk turned around is seen.
  EXPECT_GT(buffer.splatDisk(Vec3f(0, 0, 2), Vec3f(0, 0, -1), 1.0f, Rgb(1.0f), 1.0f), 0);
  EXPECT_GT(buffer.rayCastDisk(Vec3f(0, 0, 2), Vec3f(0, 0, -1), 1.0f, Rgb(1.0f)), 0);
}

TEST(Microbuffer, RayCastSeesADiskThatHoldsTheOrigin) {
  // The origin 0.01 below a big disk facing it: the disk fills almost the whole upper
  // hemisphere, which no bounding cone could describe.
  Microbuffer buffer(16);
  buffer.clear(Vec3f(0.0f));
  buffer.rayCastDisk(Vec3f(0.2f, 0, 0.01f), Vec3f(0, 0, -1), 5.0f, Rgb(1.0f));
  EXPECT_NEAR(buffer.coveredSolidAngle(), 2.0f * kPi, 0.05f);
}

}  // namespace
}  // namespace pbgi
