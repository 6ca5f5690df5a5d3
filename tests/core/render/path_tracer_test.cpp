#include "core/render/path_tracer.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>

#include "core/render/renderer.h"
#include "tests/core/render/test_scenes.h"

namespace pbgi {
namespace {

using testing::makeBoxScene;
using testing::makeSphereMesh;

Rgb meanRgb(const Image& image) {
  double s[3] = {0, 0, 0};
  for (int y = 0; y < image.height(); ++y)
    for (int x = 0; x < image.width(); ++x)
      for (int c = 0; c < 3; ++c) s[c] += image.at(x, y, c);
  const double n = static_cast<double>(image.width()) * image.height();
  return Rgb(static_cast<float>(s[0] / n), static_cast<float>(s[1] / n), static_cast<float>(s[2] / n));
}

// Looks into makeBoxScene()'s open side.
Camera boxCamera(int width, int height) {
  CameraParams cp;
  cp.position = {0.5f, 0.5f, -1.4f};
  cp.lookAt = {0.5f, 0.5f, 0.0f};
  cp.fovYDeg = 40.0f;
  return Camera(cp, width, height);
}

// A closed sphere whose inside both emits Le and reflects diffusely with albedo rho: the
// radiance everywhere inside is Le / (1 - rho), whatever the geometry.
TEST(PathTracerTest, WhiteFurnaceClosedEmissiveSphere) {
  SceneBuilder b;
  Material m;
  m.type = MaterialType::kDiffuse;
  m.albedo = Rgb(0.5f);
  m.radiance = Rgb(1.0f, 2.0f, 0.5f);
  b.addMesh(makeSphereMesh(3.0f, b.addMaterial(m)));
  auto scene = b.build();
  ASSERT_TRUE(scene.ok()) << scene.status();
  const PathIntegrator integrator(**scene, PathTracerSettings{64, 3});
  CameraParams cp;
  cp.position = {0.3f, -0.2f, 0.1f};
  cp.lookAt = {1.0f, 0.5f, 0.2f};
  cp.fovYDeg = 90.0f;
  const Camera camera(cp, 16, 16);
  RenderSettings settings;
  settings.spp = 256;
  RenderCounters counters;
  const Image image = *renderFrame(integrator, camera, settings, 1, {}, &counters);
  const Rgb mean = meanRgb(image);
  EXPECT_NEAR(mean.x, 2.0f, 0.02f);
  EXPECT_NEAR(mean.y, 4.0f, 0.04f);
  EXPECT_NEAR(mean.z, 1.0f, 0.01f);
  EXPECT_EQ(counters.discardedSamples, 0u);
}

// With albedo 0 the furnace shows the emission alone: exercises emission without bounces.
TEST(PathTracerTest, BlackFurnaceShowsEmissionOnly) {
  SceneBuilder b;
  Material m;
  m.albedo = Rgb(0.0f);
  m.radiance = Rgb(0.7f);
  b.addMesh(makeSphereMesh(1.0f, b.addMaterial(m), 2));
  auto scene = b.build();
  ASSERT_TRUE(scene.ok());
  const PathIntegrator integrator(**scene, PathTracerSettings{});
  const Camera camera(CameraParams{}, 8, 8);
  RenderSettings settings;
  settings.spp = 4;
  const Image image = *renderFrame(integrator, camera, settings, 1, {}, nullptr);
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 8; ++x) EXPECT_FLOAT_EQ(image.at(x, y, 0), 0.7f);
}

TEST(PathTracerTest, TileAndThreadInvarianceBitForBit) {
  auto scene = makeBoxScene();
  ASSERT_NE(scene, nullptr);
  const PathIntegrator integrator(*scene, PathTracerSettings{});
  const Camera camera = boxCamera(72, 56);
  RenderSettings settings;
  settings.spp = 8;
  settings.filter = FilterType::kGaussian;
  settings.filterWidth = 2.0f;
  FrameRenderOptions a;
  a.threads = 1;
  a.tileSize = 16;
  FrameRenderOptions b;
  b.threads = 2;
  b.tileSize = 64;
  const Image ia = *renderFrame(integrator, camera, settings, 3, a, nullptr);
  const Image ib = *renderFrame(integrator, camera, settings, 3, b, nullptr);
  ASSERT_EQ(ia.pixels().size(), ib.pixels().size());
  EXPECT_EQ(0, std::memcmp(ia.pixels().data(), ib.pixels().data(), ia.pixels().size() * sizeof(float)));
  // And the image is not trivially black: the test would pass vacuously otherwise.
  EXPECT_GT(meanRgb(ia).x, 0.01f);
  // A different frame number draws different random numbers.
  const Image ic = *renderFrame(integrator, camera, settings, 4, a, nullptr);
  EXPECT_NE(0, std::memcmp(ia.pixels().data(), ic.pixels().data(), ia.pixels().size() * sizeof(float)));
}

TEST(PathTracerTest, DirectPlusIndirectIsTotalAndMaxDepthOneHasNoIndirect) {
  auto scene = makeBoxScene();
  ASSERT_NE(scene, nullptr);
  const Camera camera = boxCamera(24, 24);
  RenderSettings settings;
  settings.spp = 16;
  const PathIntegrator full(*scene, PathTracerSettings{64, 3});
  const Image image = *renderFrame(full, camera, settings, 1, {}, nullptr);
  const int direct = image.channelIndex("direct.R"), indirect = image.channelIndex("indirect.R");
  double indirectSum = 0.0;
  for (int y = 0; y < 24; ++y) {
    for (int x = 0; x < 24; ++x) {
      EXPECT_NEAR(image.at(x, y, 0), image.at(x, y, direct) + image.at(x, y, indirect),
                  1e-4f * std::max(1.0f, image.at(x, y, 0)));
      indirectSum += image.at(x, y, indirect);
    }
  }
  EXPECT_GT(indirectSum, 0.0);
  const PathIntegrator directOnly(*scene, PathTracerSettings{1, 3});
  const Image d = *renderFrame(directOnly, camera, settings, 1, {}, nullptr);
  for (int y = 0; y < 24; ++y)
    for (int x = 0; x < 24; ++x) EXPECT_EQ(d.at(x, y, indirect), 0.0f);
}

// More light samples at the first hit (PBGI's direct light) estimate the same light with less
// noise, and leave the rest of the path to the same random numbers.
TEST(PathTracerTest, FirstHitLightSamplesKeepTheMeanAndCutTheNoise) {
  auto scene = makeBoxScene();
  ASSERT_NE(scene, nullptr);
  const Camera camera = boxCamera(24, 24);
  RenderSettings settings;
  settings.spp = 4;
  const auto direct = [&](int lightSamples, int spp) {
    RenderSettings s = settings;
    s.spp = spp;
    const PathIntegrator i(*scene, PathTracerSettings{.maxDepth = 1, .rouletteDepth = 3,
                                                      .firstHitLightSamples = lightSamples});
    return *renderFrame(i, camera, s, 1, {}, nullptr);
  };
  // The camera samples are the same whatever the light samples (the path's own stream is
  // untouched), so against many light samples the error is the light sampling's alone.
  const Image reference = direct(256, 4);
  const Image one = direct(1, 4), many = direct(16, 4);
  const auto squaredError = [&](const Image& a) {
    double e = 0.0;
    for (int y = 0; y < 24; ++y)
      for (int x = 0; x < 24; ++x)
        for (int c = 0; c < 3; ++c) e += std::pow(a.at(x, y, c) - reference.at(x, y, c), 2.0);
    return e;
  };
  EXPECT_GT(squaredError(one), 0.0);
  EXPECT_LT(squaredError(many), 0.2 * squaredError(one));
  // The same light: means over many samples agree.
  const auto m1 = meanRgb(direct(1, 256), "R"), m16 = meanRgb(direct(16, 256), "R");
  for (int c = 0; c < 3; ++c) EXPECT_NEAR(m16[c] / m1[c], 1.0, 0.01) << "channel " << c;
  // The rest of the path draws the same random numbers: its indirect light is unchanged.
  const PathIntegrator a(*scene, PathTracerSettings{64, 3});
  const PathIntegrator b(*scene, PathTracerSettings{.maxDepth = 64, .rouletteDepth = 3,
                                                    .firstHitLightSamples = 8});
  const Image fa = *renderFrame(a, camera, settings, 1, {}, nullptr);
  const Image fb = *renderFrame(b, camera, settings, 1, {}, nullptr);
  const int indirect = fa.channelIndex("indirect.R");
  bool sameDirect = true;
  for (int y = 0; y < 24; ++y) {
    for (int x = 0; x < 24; ++x) {
      for (int c = 0; c < 3; ++c) EXPECT_EQ(fa.at(x, y, indirect + c), fb.at(x, y, indirect + c));
      sameDirect = sameDirect && fa.at(x, y, 0) == fb.at(x, y, 0);
    }
  }
  EXPECT_FALSE(sameDirect);  // while the direct light did change
}

// A near-mirror metal floor (GGX 0.05) reflecting a small sphere light towards the camera:
// light samples almost never find the lobe, so its BSDF samples carry the reflection. Extra
// BSDF samples at the first hit keep the mean and cut the noise; 1 leaves every bit as it was,
// and a diffuse floor is not touched (rough conductors only).
TEST(PathTracerTest, FirstHitBsdfSamplesOnAGlossyFloorKeepTheMeanAndCutTheNoise) {
  for (const bool metal : {true, false}) {
    SceneBuilder b;
    Material floor;
    if (metal) {
      floor.type = MaterialType::kConductor;
      floor.roughness = 0.05f;
      floor.specular = Rgb(0.9f, 0.8f, 0.7f);
    } else {
      floor.albedo = Rgb(0.5f);
    }
    b.addMesh(testing::makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, b.addMaterial(floor)));
    LightDesc sphere;
    sphere.type = LightType::kSphere;
    sphere.center = {0.0f, 0.6f, 0.8f};
    sphere.radius = 0.05f;
    sphere.radiance = Rgb(40.0f);
    b.addLight(sphere);
    auto built = b.build();
    ASSERT_TRUE(built.ok()) << built.status();
    const Scene& scene = **built;
    CameraParams cp;
    cp.position = {0.0f, 0.6f, -0.8f};
    cp.lookAt = {0.0f, 0.0f, 0.0f};
    cp.fovYDeg = 20.0f;
    const Camera camera(cp, 16, 16);
    const auto direct = [&](int bsdfSamples, int spp, uint64_t seed) {
      RenderSettings s;
      s.spp = spp;
      s.seed = seed;
      const PathIntegrator i(scene, PathTracerSettings{.maxDepth = 1,
                                                       .rouletteDepth = 3,
                                                       .firstHitLightSamples = 16,
                                                       .firstHitBsdfSamples = bsdfSamples});
      return *renderFrame(i, camera, s, 1, {}, nullptr);
    };
    const Image reference = direct(1, 256, 99);
    const auto squaredError = [&](const Image& a) {
      double e = 0.0;
      for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x)
          for (int c = 0; c < 3; ++c) e += std::pow(a.at(x, y, c) - reference.at(x, y, c), 2.0);
      return e;
    };
    const Image one = direct(1, 4, 1), many = direct(16, 4, 1);
    if (!metal) {
      for (int y = 0; y < 16; ++y)
        for (int x = 0; x < 16; ++x) ASSERT_EQ(one.at(x, y, 0), many.at(x, y, 0));
      continue;
    }
    std::printf(
        "[ measured ] glossy floor, 4 spp: squared error %.4g with 1 BSDF sample, %.4g "
        "with 16\n",
        squaredError(one), squaredError(many));
    EXPECT_GT(squaredError(one), 0.0);
    // What is left is mostly the camera samples' (where in its pixel each lands on the
    // reflection's edge), which only more of them cut: measured 0.40 of the error.
    EXPECT_LT(squaredError(many), 0.6 * squaredError(one));
    const Rgb m1 = meanRgb(reference), m16 = meanRgb(direct(16, 64, 7));
    std::printf("[ measured ] means, 16 BSDF samples over 1: %.4f %.4f %.4f\n", m16.x / m1.x,
                m16.y / m1.y, m16.z / m1.z);
    EXPECT_GT(m1.x, 0.05f);  // the light's reflection is in the picture
    for (int c = 0; c < 3; ++c) EXPECT_NEAR(m16[c] / m1[c], 1.0, 0.02) << "channel " << c;
  }
}

// Geometry with NaN vertices and zero-area triangles loads (cleaned) and renders with no
// NaN pixel and no discarded sample.
TEST(PathTracerTest, HostileGeometryRendersWithoutNaN) {
  SceneBuilder b;
  Material m;
  m.albedo = Rgb(0.6f);
  const uint32_t mat = b.addMaterial(m);
  MeshData mesh;
  const float nan = std::numeric_limits<float>::quiet_NaN();
  const float inf = std::numeric_limits<float>::infinity();
  mesh.positions = {{-1, 0, -1}, {1, 0, -1}, {1, 0, 1}, {-1, 0, 1}, {nan, 0, 0}, {0, inf, 0},
                    {0.5f, 0, 0.5f}};
  mesh.normals = {{0, 1, 0}, {0, 1, 0}, {nan, nan, nan}, {0, 0, 0}, {0, 1, 0}, {0, 1, 0}, {0, 1, 0}};
  mesh.indices = {0, 2, 1, 0, 3, 2, 0, 4, 1, 5, 2, 3, 6, 6, 6, 0, 1, 1};
  mesh.materials.assign(6, mat);
  b.addMesh(mesh);
  LightDesc sun;
  sun.type = LightType::kDirectional;
  sun.direction = {0.2f, -1.0f, 0.1f};
  sun.irradiance = Rgb(3.0f);
  b.addLight(sun);
  auto scene = b.build();
  ASSERT_TRUE(scene.ok());
  EXPECT_EQ((*scene)->stats().triangles, 2u);
  CameraParams cp;
  cp.position = {0.0f, 2.0f, -2.0f};
  cp.lookAt = {0.0f, 0.0f, 0.0f};
  const Camera camera(cp, 16, 16);
  const PathIntegrator integrator(**scene, PathTracerSettings{});
  RenderSettings settings;
  settings.spp = 4;
  RenderCounters counters;
  const Image image = *renderFrame(integrator, camera, settings, 1, {}, &counters);
  for (float v : image.pixels()) ASSERT_TRUE(std::isfinite(v));
  EXPECT_EQ(counters.discardedSamples, 0u);
  // The floor is lit: cos-weighted sun on albedo 0.6 gives 3 * 0.6/pi * cos.
  const float expected = 3.0f * 0.6f / kPi * (1.0f / std::sqrt(1.05f));
  EXPECT_NEAR(image.at(8, 8, 0), expected, 1e-3f);
}

}  // namespace
}  // namespace pbgi

namespace pbgi {
namespace {

// Irradiance on an open plane under a uniform sky L is pi L; under a sun it is E cos.
TEST(PathTracerTest, SampleIrradianceMatchesAnalytic) {
  SceneBuilder b;
  Material m;
  b.addMesh(testing::makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, b.addMaterial(m)));
  b.addLight(makeUniformEnvironmentLight(Rgb(0.5f)));
  auto scene = b.build();
  ASSERT_TRUE(scene.ok());
  Rng rng(4);
  const Vec3f n(0.0f, 1.0f, 0.0f);
  double sum = 0.0;
  const int count = 200000;
  for (int i = 0; i < count; ++i) sum += sampleIrradiance(**scene, Vec3f(0.0f), n, n, rng).x;
  EXPECT_NEAR(sum / count, kPi * 0.5, 0.01 * kPi * 0.5);
  // Inside a closed sphere nothing of the sky arrives.
  SceneBuilder closed;
  closed.addMesh(testing::makeSphereMesh(2.0f, closed.addMaterial(m), 2));
  closed.addLight(makeUniformEnvironmentLight(Rgb(0.5f)));
  auto inside = closed.build();
  ASSERT_TRUE(inside.ok());
  for (int i = 0; i < 1000; ++i) ASSERT_EQ(sampleIrradiance(**inside, Vec3f(0.0f), n, n, rng).x, 0.0f);
}

}  // namespace
}  // namespace pbgi

namespace pbgi {
namespace {

// PBGI's first hits take several light samples and leave the sky to the records. Where every
// light those samples could pick is a delta light, each is taken once, exactly: the direct
// light is their sum, the same whatever the random numbers, at a shadow ray a light. An area
// light or the sky among them keeps sampling.
TEST(PathTracerTest, SeveralDeltaLightsAreSummedExactlyWhereOnlyTheyCanBePicked) {
  SceneBuilder b;
  Material m;
  m.albedo = Rgb(0.6f);
  b.addMesh(testing::makeQuadMesh({-4, 0, -4}, {0, 0, 8}, {8, 0, 0}, b.addMaterial(m)));
  const Vec3f at[2] = {{0.3f, 1.0f, 0.0f}, {-0.5f, 2.0f, 0.2f}};
  const float intensity[2] = {2.0f, 5.0f};
  for (int i = 0; i < 2; ++i) {
    LightDesc point;
    point.type = LightType::kPoint;
    point.position = at[i];
    point.intensity = Rgb(intensity[i]);
    b.addLight(point);
  }
  b.addLight(makeUniformEnvironmentLight(Rgb(0.5f)));
  auto scene = b.build();
  ASSERT_TRUE(scene.ok());
  EXPECT_TRUE((*scene)->deltaLightsOnly(false).empty());  // the sky can be picked
  EXPECT_EQ((*scene)->deltaLightsOnly(true), (std::vector<int>{0, 1}));

  // Straight down onto the origin: E = sum of I cos / d^2, reflected at 0.6 / pi.
  double expected = 0.0;
  for (int i = 0; i < 2; ++i) {
    const float d2 = at[i].length2();
    expected += intensity[i] * (at[i].y / std::sqrt(d2)) / d2 * 0.6 / kPi;
  }
  const PathTracerSettings settings{
      .maxDepth = 1, .firstHitLightSamples = 16, .skyAtDiffuseFirstHit = false};
  const Ray down(Vec3f(0.0f, 3.0f, 0.0f), Vec3f(0.0f, -1.0f, 0.0f));
  for (uint64_t seed = 0; seed < 8; ++seed) {
    Rng rng(seed);
    const PathSample s = tracePath(**scene, down, rng, settings, nullptr);
    EXPECT_NEAR(s.direct.x, expected, 1e-5 * expected) << "seed " << seed;
  }

  // With an area light among them, the samples pick among all: no exact sum.
  LightDesc quad;
  quad.type = LightType::kQuad;
  quad.corner = {2.0f, 3.0f, 2.0f};
  quad.edgeU = {0.0f, 0.0f, 0.5f};
  quad.edgeV = {0.5f, 0.0f, 0.0f};
  quad.radiance = Rgb(1.0f);
  b.addLight(quad);
  auto withArea = b.build();
  ASSERT_TRUE(withArea.ok());
  EXPECT_TRUE((*withArea)->deltaLightsOnly(true).empty());
}

}  // namespace
}  // namespace pbgi
