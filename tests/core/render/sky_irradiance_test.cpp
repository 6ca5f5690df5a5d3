// The environment's light at PBGI's records (sky_irradiance.h), against closed forms, and the
// camera samples' direct light that leaves it to them.

#include "core/render/sky_irradiance.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "core/render/path_tracer.h"
#include "tests/core/render/analytic.h"
#include "tests/core/render/test_scenes.h"

namespace pbgi {
namespace {

using analytic::Vec3d;

constexpr float kSky = 0.7f;  // the sky's radiance

// A closed 2 x 1 x 2 room whose ceiling has a square opening of side `hole` at its centre
// (hole 0: no opening), under a uniform sky.
std::unique_ptr<Scene> roomUnderSky(float hole) {
  SceneBuilder b;
  Material white;
  white.albedo = Rgb(0.5f);
  const uint32_t w = b.addMaterial(white);
  b.addMesh(testing::makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, w));   // floor
  b.addMesh(testing::makeQuadMesh({-1, 0, -1}, {2, 0, 0}, {0, 1, 0}, w));   // z = -1
  b.addMesh(testing::makeQuadMesh({-1, 0, 1}, {0, 1, 0}, {2, 0, 0}, w));    // z = 1
  b.addMesh(testing::makeQuadMesh({-1, 0, -1}, {0, 1, 0}, {0, 0, 2}, w));   // x = -1
  b.addMesh(testing::makeQuadMesh({1, 0, -1}, {0, 0, 2}, {0, 1, 0}, w));    // x = 1
  // The ceiling, around the opening: four strips.
  const float h = 0.5f * hole;
  b.addMesh(testing::makeQuadMesh({-1, 1, -1}, {2, 0, 0}, {0, 0, 1 - h}, w));
  b.addMesh(testing::makeQuadMesh({-1, 1, h}, {2, 0, 0}, {0, 0, 1 - h}, w));
  if (hole > 0.0f) {
    b.addMesh(testing::makeQuadMesh({-1, 1, -h}, {1 - h, 0, 0}, {0, 0, hole}, w));
    b.addMesh(testing::makeQuadMesh({h, 1, -h}, {1 - h, 0, 0}, {0, 0, hole}, w));
  } else {
    b.addMesh(testing::makeQuadMesh({-1, 1, -h}, {2, 0, 0}, {0, 0, 1e-3f}, w));
  }
  b.addLight(makeUniformEnvironmentLight(Rgb(kSky)));
  return analytic::buildOrNull(b);
}

// Irradiance at floor point p from the sky through the opening: Lambert's formula over it.
double throughOpening(const Vec3f& p, const Vec3f& n, float hole) {
  const float h = 0.5f * hole;
  const std::vector<Vec3d> opening = {Vec3d(-h, 1, -h), Vec3d(h, 1, -h), Vec3d(h, 1, h),
                                      Vec3d(-h, 1, h)};
  return analytic::polygonIrradiance(Vec3d(p), Vec3d(n), opening, kSky);
}

TEST(SkyIrradiance, ARecordUnderAnOpeningGetsTheOpeningsIrradiance) {
  const float hole = 0.6f;
  auto scene = roomUnderSky(hole);
  ASSERT_NE(scene, nullptr);
  ASSERT_TRUE(hasSkyLight(*scene));
  const SkyIrradiance sky(*scene);
  ASSERT_FALSE(sky.empty());
  struct Point {
    Vec3f p, n;
  };
  const std::vector<Point> points = {
      {{0.0f, 0.0f, 0.0f}, {0, 1, 0}},      // under the opening's centre
      {{0.25f, 0.0f, -0.1f}, {0, 1, 0}},    // under its edge
      {{0.8f, 0.0f, 0.7f}, {0, 1, 0}},      // in a corner of the floor
      {{-0.999f, 0.5f, 0.2f}, {1, 0, 0}},   // on a wall
  };
  for (const Point& pt : points) {
    const double exact = throughOpening(pt.p, pt.n, hole);
    // Many records at the same point: the mean is the estimator's expectation; the spread is
    // what neighbouring records differ by.
    const int records = 1024;
    double sum = 0.0, sum2 = 0.0;
    uint64_t rays = 0;
    for (int k = 0; k < records; ++k) {
      const double e = sky.at(pt.p + pt.n * 1e-4f, pt.n, pt.n, hashKeys(uint64_t{7}, k), &rays).y;
      sum += e;
      sum2 += e * e;
    }
    const double mean = sum / records;
    const double spread = std::sqrt(std::max(0.0, sum2 / records - mean * mean));
    std::printf("[ measured ] (%g, %g, %g): exact %.5f, mean %.5f, one record's deviation %.2f %%, "
                "%.0f rays a record\n",
                pt.p.x, pt.p.y, pt.p.z, exact, mean, 100.0 * spread / exact,
                static_cast<double>(rays) / records);
    EXPECT_NEAR(mean, exact, 0.01 * exact) << pt.p.x << ", " << pt.p.z;
    // The noise is at the opening's edge alone (measured 3 to 11 %; a ray a cell and none
    // again at the edges: 19 to 36 %).
    EXPECT_LT(spread, 0.15 * exact) << pt.p.x << ", " << pt.p.z;
    // A ray a cell above the horizon (about half of them), and the edge cells again.
    EXPECT_LE(static_cast<double>(rays) / records, 500.0);
  }
  // The same room closed: no ray escapes.
  auto closed = roomUnderSky(0.0f);
  ASSERT_NE(closed, nullptr);
  const SkyIrradiance none(*closed);
  uint64_t rays = 0;
  for (int k = 0; k < 16; ++k) {
    EXPECT_EQ(none.at({0.1f, 1e-4f, 0.2f}, {0, 1, 0}, {0, 1, 0}, k, &rays), Rgb(0.0f));
  }
  // Under an open sky: pi L, noise only where cells straddle the horizon.
  SceneBuilder open;
  Material m;
  open.addMesh(testing::makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, open.addMaterial(m)));
  open.addLight(makeUniformEnvironmentLight(Rgb(kSky)));
  auto plane = open.build();
  ASSERT_TRUE(plane.ok());
  const SkyIrradiance full(**plane);
  for (uint64_t k = 0; k < 16; ++k) {
    EXPECT_NEAR(full.at({0, 1e-4f, 0}, {0, 1, 0}, {0, 1, 0}, k, &rays).x, kPi * kSky,
                0.02 * kPi * kSky);
  }
}

TEST(SkyIrradiance, AScenesWithoutAnEnvironmentHasNone) {
  SceneBuilder b;
  Material m;
  b.addMesh(testing::makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, b.addMaterial(m)));
  b.addLight(makeDirectionalLight(Vec3f(0, -1, 0), Rgb(1.0f)));
  auto scene = analytic::buildOrNull(b);
  ASSERT_NE(scene, nullptr);
  EXPECT_FALSE(hasSkyLight(*scene));
  EXPECT_TRUE(SkyIrradiance(*scene).empty());
}

// A diffuse floor under a sky and a sun: a camera sample that leaves the sky to its record
// takes the sun's light alone, exactly (one delta light: no sampling left), and a glossy
// floor keeps the sky.
TEST(SkyIrradiance, SamplesThatLeaveTheSkyToRecordsTakeTheOtherLightsAlone) {
  for (const bool glossy : {false, true}) {
    SceneBuilder b;
    Material m;
    m.albedo = Rgb(0.5f);
    if (glossy) {
      m.type = MaterialType::kConductor;
      m.roughness = 0.3f;
    }
    b.addMesh(testing::makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, b.addMaterial(m)));
    b.addLight(makeUniformEnvironmentLight(Rgb(kSky)));
    const Vec3f toSun = normalize(Vec3f(0.3f, 1.0f, 0.2f));
    b.addLight(makeDirectionalLight(-toSun, Rgb(2.0f)));
    auto scene = analytic::buildOrNull(b);
    ASSERT_NE(scene, nullptr);
    PathTracerSettings settings{.maxDepth = 1, .firstHitLightSamples = 4};
    settings.skyAtDiffuseFirstHit = false;
    const Ray ray{Vec3f(0.1f, 1.0f, -0.5f), normalize(Vec3f(0.0f, -1.0f, 0.6f))};
    PathTracerSettings withSky = settings;
    withSky.skyAtDiffuseFirstHit = true;
    for (int k = 0; k < 2000; ++k) {
      Rng rng(static_cast<uint64_t>(k)), same(static_cast<uint64_t>(k));
      const PathSample s = tracePath(*scene, ray, rng, settings);
      ASSERT_TRUE(s.hit);
      if (glossy) {
        // Not a record's receiver: the same light as the path tracer's, draw for draw.
        ASSERT_EQ(s.direct, tracePath(*scene, ray, same, withSky).direct) << "sample " << k;
      } else {
        ASSERT_NEAR(s.direct.x, 0.5f / kPi * 2.0f * toSun.y, 1e-5f) << "sample " << k;
      }
    }
  }
}

}  // namespace
}  // namespace pbgi
