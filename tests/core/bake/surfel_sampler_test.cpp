#include "core/bake/surfel_sampler.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <string>
#include <vector>

#include "tests/core/render/test_scenes.h"

namespace pbgi {
namespace {

using testing::makeQuadMesh;
using testing::makeSphereMesh;

std::unique_ptr<Scene> buildScene(SceneBuilder& b) {
  auto scene = b.build();
  EXPECT_TRUE(scene.ok()) << scene.status();
  return scene.ok() ? std::move(*scene) : nullptr;
}

std::vector<Surfel> collect(const Scene& scene, const SurfelSamplingOptions& options,
                            SurfelSamplingStats* stats = nullptr) {
  auto out = collectSurfels(scene, options, stats);
  EXPECT_TRUE(out.ok()) << out.status();
  return out.ok() ? std::move(*out) : std::vector<Surfel>{};
}

SurfelSamplingOptions byCount(uint64_t n, uint64_t seed = 1, int frame = 0) {
  SurfelSamplingOptions o;
  o.targetCount = n;
  o.seed = seed;
  o.frame = frame;
  return o;
}

// Field by field, so that padding never takes part in a comparison.
std::string surfelBytes(const std::vector<Surfel>& surfels) {
  std::string bytes;
  auto put = [&bytes](const void* p, size_t n) { bytes.append(static_cast<const char*>(p), n); };
  for (const Surfel& s : surfels) {
    put(&s.position, sizeof s.position);
    put(&s.normal, sizeof s.normal);
    put(&s.radius, sizeof s.radius);
    put(&s.albedo, sizeof s.albedo);
    put(&s.radiance, sizeof s.radiance);
    put(&s.materialClass, sizeof s.materialClass);
    put(&s.triangle, sizeof s.triangle);
    put(&s.barycentric, sizeof s.barycentric);
  }
  return bytes;
}

// Two parallel quads, of areas 1 and 3.
std::unique_ptr<Scene> twoQuadScene() {
  SceneBuilder b;
  const uint32_t m = b.addMaterial(Material{});
  b.addMesh(makeQuadMesh({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, m));
  b.addMesh(makeQuadMesh({0, 0, 2}, {3, 0, 0}, {0, 1, 0}, m));
  return buildScene(b);
}

TEST(SurfelSamplerTest, CountsFollowAreaAndTotalIsExact) {
  auto scene = twoQuadScene();
  ASSERT_NE(scene, nullptr);
  for (const uint64_t n : {1ull, 2ull, 7ull, 1000ull, 1001ull, 4099ull}) {
    SurfelSamplingStats stats;
    const std::vector<Surfel> surfels = collect(*scene, byCount(n, 3), &stats);
    ASSERT_EQ(surfels.size(), n);
    EXPECT_EQ(stats.surfels, n);
    EXPECT_EQ(stats.triangles, 4u);
    EXPECT_DOUBLE_EQ(stats.totalArea, 4.0);
    // Per triangle (areas 0.5, 0.5, 1.5, 1.5 of 4): floor or ceil of the share.
    uint64_t perTriangle[4] = {0, 0, 0, 0};
    for (const Surfel& s : surfels) ++perTriangle[s.triangle];
    const double share[4] = {0.125, 0.125, 0.375, 0.375};
    for (int t = 0; t < 4; ++t) {
      EXPECT_LE(std::abs(static_cast<double>(perTriangle[t]) - share[t] * n), 1.0)
          << "n " << n << " triangle " << t << " got " << perTriangle[t];
    }
    // Per quad, 1 : 3 within a surfel.
    const double small = perTriangle[0] + perTriangle[1], large = perTriangle[2] + perTriangle[3];
    EXPECT_LE(std::abs(small - 0.25 * n), 1.0) << n;
    EXPECT_LE(std::abs(large - 0.75 * n), 1.0) << n;
  }
}

TEST(SurfelSamplerTest, SmallTrianglesShareSurfelsAndTheTotalStaysExact) {
  SceneBuilder b;
  b.addMesh(makeSphereMesh(1.0f, b.addMaterial(Material{}), 3));  // 1280 triangles
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  for (const uint64_t n : {1ull, 100ull, 1279ull, 5000ull}) {
    SurfelSamplingStats stats;
    const std::vector<Surfel> surfels = collect(*scene, byCount(n, 9), &stats);
    ASSERT_EQ(surfels.size(), n);
    std::vector<uint64_t> perTriangle(1280, 0);
    for (const Surfel& s : surfels) ++perTriangle[s.triangle];
    uint64_t empty = 0;
    for (uint64_t c : perTriangle) empty += c == 0;
    EXPECT_EQ(stats.trianglesWithoutSurfel, empty) << n;
    if (n < 1280) {
      EXPECT_GE(empty, 1280 - n) << n;
    }
    if (n == 5000) {
      EXPECT_EQ(empty, 0u);  // every triangle is larger than 1/5000 of the sphere
    }
  }
}

TEST(SurfelSamplerTest, DeterministicPerSeedAndFrame) {
  auto scene = twoQuadScene();
  ASSERT_NE(scene, nullptr);
  const std::string a = surfelBytes(collect(*scene, byCount(500, 42, 7)));
  const std::string again = surfelBytes(collect(*scene, byCount(500, 42, 7)));
  EXPECT_EQ(a, again);
  EXPECT_NE(a, surfelBytes(collect(*scene, byCount(500, 42, 8))));
  EXPECT_NE(a, surfelBytes(collect(*scene, byCount(500, 43, 7))));
}

TEST(SurfelSamplerTest, SurfelsLieOnTheirTrianglesWithGeometricNormals) {
  SceneBuilder b;
  const uint32_t m = b.addMaterial(Material{});
  MeshData sphere = makeSphereMesh(2.0f, m, 2);
  for (Vec3f& p : sphere.positions) p += Vec3f(1.0f, -3.0f, 0.5f);
  b.addMesh(makeQuadMesh({-4, -5, -4}, {0, 0, 8}, {8, 0, 0}, m));
  b.addMesh(std::move(sphere));
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  SurfelSamplingStats stats;
  const std::vector<Surfel> surfels = collect(*scene, byCount(3000, 5), &stats);
  ASSERT_EQ(surfels.size(), 3000u);
  const std::vector<MeshData>& meshes = scene->meshes();
  ASSERT_EQ(meshes.size(), 2u);
  float largestShadingTilt = 0.0f;
  uint32_t previousTriangle = 0;
  for (const Surfel& s : surfels) {
    EXPECT_GE(s.triangle, previousTriangle) << "stream order is triangle order";
    previousTriangle = s.triangle;
    const size_t mesh = s.triangle >= scene->triangleIdBase(1) ? 1 : 0;
    const MeshData& md = meshes[mesh];
    const uint64_t t = s.triangle - scene->triangleIdBase(mesh);
    ASSERT_LT(t, md.triangleCount());
    const uint32_t i0 = md.indices[3 * t], i1 = md.indices[3 * t + 1], i2 = md.indices[3 * t + 2];
    const float b1 = s.barycentric.x, b2 = s.barycentric.y;
    ASSERT_GE(b1, 0.0f);
    ASSERT_GE(b2, 0.0f);
    ASSERT_LE(b1 + b2, 1.0f + 1e-6f);
    const Vec3f p =
        md.positions[i0] * (1.0f - b1 - b2) + md.positions[i1] * b1 + md.positions[i2] * b2;
    EXPECT_LT(length(p - s.position), 1e-5f);
    const Vec3f ng =
        normalize(cross(md.positions[i1] - md.positions[i0], md.positions[i2] - md.positions[i0]));
    EXPECT_LT(length(ng - s.normal), 1e-6f);
    EXPECT_NEAR(s.radius, stats.radius, 0.0f);
    if (!md.normals.empty()) {
      const Vec3f ns =
          normalize(md.normals[i0] * (1.0f - b1 - b2) + md.normals[i1] * b1 + md.normals[i2] * b2);
      largestShadingTilt = std::max(largestShadingTilt, length(ns - s.normal));
    }
  }
  // The sphere's smooth vertex normals differ from its faces: the test would see a surfel
  // that took the shading normal.
  EXPECT_GT(largestShadingTilt, 0.05f);
  // The disks' areas add up to the surface's.
  EXPECT_NEAR(3000.0 * surfels[0].area(), stats.totalArea, 1e-4 * stats.totalArea);
}

TEST(SurfelSamplerTest, TargetRadiusSetsTheCount) {
  auto scene = twoQuadScene();
  ASSERT_NE(scene, nullptr);
  SurfelSamplingOptions o;
  o.targetRadius = 0.02f;
  SurfelSamplingStats stats;
  const std::vector<Surfel> surfels = collect(*scene, o, &stats);
  const double expected = 4.0 / (std::numbers::pi * 0.02 * 0.02);  // 3183.1
  EXPECT_EQ(surfels.size(), static_cast<size_t>(std::llround(expected)));
  EXPECT_NEAR(stats.radius, 0.02f, 0.02f * 1e-3f);
  // A radius larger than the scene still gives one surfel.
  o.targetRadius = 100.0f;
  EXPECT_EQ(collect(*scene, o).size(), 1u);
}

// A low-discrepancy set is far more even than independent points: count per cell of an
// 8 x 8 grid over one quad of 4096 surfels (64 a cell). Independent uniform points would
// scatter with a standard deviation of 8 and stray by 15 to 25 somewhere in the grid; this
// set strays by 2.
TEST(SurfelSamplerTest, PointsWithinATriangleAreStratified) {
  SceneBuilder b;
  const uint32_t m = b.addMaterial(Material{});
  b.addMesh(makeQuadMesh({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, m));
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  const std::vector<Surfel> surfels = collect(*scene, byCount(4096, 11));
  int cells[8][8] = {};
  for (const Surfel& s : surfels) {
    const int x = std::min(7, static_cast<int>(s.position.x * 8.0f));
    const int y = std::min(7, static_cast<int>(s.position.y * 8.0f));
    ++cells[y][x];
  }
  int worst = 0;
  for (auto& row : cells)
    for (int c : row) worst = std::max(worst, std::abs(c - 64));
  EXPECT_LE(worst, 6) << "cells should hold 64 +- a few surfels";
}

class UvTexture final : public Texture {
 public:
  Rgb evaluate(const Vec2f& uv) const override { return Rgb(uv.x, uv.y, 0.25f); }
};

TEST(SurfelSamplerTest, AlbedoIsTheTextureAtTheSurfelsUv) {
  SceneBuilder b;
  Material textured;
  textured.albedoTexture = std::make_shared<UvTexture>();
  MeshData quad = makeQuadMesh({0, 0, 0}, {2, 0, 0}, {0, 1, 0}, b.addMaterial(textured));
  quad.uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  b.addMesh(std::move(quad));
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  const std::vector<Surfel> surfels = collect(*scene, byCount(200, 2));
  for (const Surfel& s : surfels) {
    EXPECT_NEAR(s.albedo.x, s.position.x / 2.0f, 1e-5f);
    EXPECT_NEAR(s.albedo.y, s.position.y, 1e-5f);
    EXPECT_EQ(s.albedo.z, 0.25f);
  }
}

TEST(SurfelSamplerTest, MaterialClasses) {
  SceneBuilder b;
  Material diffuse, conductor, dielectric, emissive, glowing;
  conductor.type = MaterialType::kConductor;
  dielectric.type = MaterialType::kDielectric;
  emissive.type = MaterialType::kEmissive;
  emissive.radiance = Rgb(1.0f);
  glowing.radiance = Rgb(0.5f);  // diffuse, but it emits, so the scene lights with it
  const uint32_t ids[5] = {b.addMaterial(diffuse), b.addMaterial(conductor),
                           b.addMaterial(dielectric), b.addMaterial(emissive),
                           b.addMaterial(glowing)};
  for (int i = 0; i < 5; ++i)
    b.addMesh(makeQuadMesh({0, 0, float(i)}, {1, 0, 0}, {0, 1, 0}, ids[i]));
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  const MaterialClass expected[5] = {MaterialClass::kDiffuse, MaterialClass::kGlossy,
                                     MaterialClass::kTransmissive, MaterialClass::kEmissive,
                                     MaterialClass::kEmissive};
  const std::vector<Surfel> surfels = collect(*scene, byCount(100, 1));
  ASSERT_EQ(surfels.size(), 100u);
  for (const Surfel& s : surfels) {
    EXPECT_EQ(s.materialClass, expected[s.triangle / 2]) << "triangle " << s.triangle;
  }
}

// A conductor so rough that the tree's SH hold its lobes (GGX alpha 1: shLobeError 0.27) is
// sampled as a diffuse surface of its hemispherical albedo; a glossy one (alpha 0.25) is not.
TEST(SurfelSamplerTest, ARoughConductorIsDiffuseOfItsHemisphericalAlbedo) {
  SceneBuilder b;
  Material rough, glossy;
  rough.type = glossy.type = MaterialType::kConductor;
  rough.roughness = 1.0f;
  glossy.roughness = 0.25f;
  rough.specular = glossy.specular = Rgb(0.9f, 0.6f, 0.3f);
  const uint32_t ids[2] = {b.addMaterial(rough), b.addMaterial(glossy)};
  for (int i = 0; i < 2; ++i) {
    b.addMesh(makeQuadMesh({0, 0, float(i)}, {1, 0, 0}, {0, 1, 0}, ids[i]));
  }
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  const Rgb albedo = hemisphericalAlbedo(rough);
  std::printf("[ measured ] GGX alpha 1, specular (0.9, 0.6, 0.3): hemispherical albedo "
              "(%.3f, %.3f, %.3f)\n", albedo.x, albedo.y, albedo.z);
  // Below the Fresnel colour (a rough lobe loses light to masking), in its order.
  for (int c = 0; c < 3; ++c) {
    EXPECT_GT(albedo[c], 0.3f * rough.specular[c]);
    EXPECT_LT(albedo[c], rough.specular[c] + 0.05f);
  }
  EXPECT_GT(albedo.x, albedo.y);
  EXPECT_GT(albedo.y, albedo.z);
  const std::vector<Surfel> surfels = collect(*scene, byCount(100, 1));
  ASSERT_EQ(surfels.size(), 100u);
  for (const Surfel& s : surfels) {
    if (s.triangle / 2 == 0) {
      EXPECT_EQ(s.materialClass, MaterialClass::kDiffuse);
      EXPECT_EQ(s.albedo, albedo);
    } else {
      EXPECT_EQ(s.materialClass, MaterialClass::kGlossy);
    }
  }
}

TEST(SurfelSamplerTest, BadOptionsAndEmptyScenesAreErrors) {
  auto scene = twoQuadScene();
  ASSERT_NE(scene, nullptr);
  auto sink = [](const Surfel&) { return absl::OkStatus(); };
  SurfelSamplingOptions none;
  EXPECT_EQ(sampleSurfels(*scene, none, sink, nullptr).code(), absl::StatusCode::kInvalidArgument);
  SurfelSamplingOptions both;
  both.targetCount = 10;
  both.targetRadius = 0.1f;
  EXPECT_EQ(sampleSurfels(*scene, both, sink, nullptr).code(), absl::StatusCode::kInvalidArgument);
  SurfelSamplingOptions infinite;
  infinite.targetRadius = std::numeric_limits<float>::infinity();
  EXPECT_EQ(sampleSurfels(*scene, infinite, sink, nullptr).code(),
            absl::StatusCode::kInvalidArgument);
  SurfelSamplingOptions tiny;
  tiny.targetRadius = 1e-9f;  // 1.3e18 surfels
  EXPECT_EQ(sampleSurfels(*scene, tiny, sink, nullptr).code(), absl::StatusCode::kInvalidArgument);

  SceneBuilder lightsOnly;
  lightsOnly.addLight(makeUniformEnvironmentLight(Rgb(1.0f)));
  auto empty = buildScene(lightsOnly);
  ASSERT_NE(empty, nullptr);
  const absl::Status s = sampleSurfels(*empty, byCount(10), sink, nullptr);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("no surface"), absl::string_view::npos) << s;
}

TEST(SurfelSamplerTest, SinkErrorStopsTheStream) {
  auto scene = twoQuadScene();
  ASSERT_NE(scene, nullptr);
  int calls = 0;
  SurfelSamplingStats stats;
  const absl::Status s = sampleSurfels(
      *scene, byCount(100),
      [&](const Surfel&) {
        return ++calls == 11 ? absl::DataLossError("disk full") : absl::OkStatus();
      },
      &stats);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(s.message().find("surfel 10: disk full"), absl::string_view::npos) << s;
  EXPECT_EQ(calls, 11);
  EXPECT_EQ(stats.surfels, 10u);
}

TEST(SurfelSamplerTest, PlanMatchesTheStream) {
  auto scene = twoQuadScene();
  ASSERT_NE(scene, nullptr);
  SurfelSamplingOptions o;
  o.targetRadius = 0.05f;
  SurfelSamplingStats plan, done;
  ASSERT_TRUE(planSurfels(*scene, o, &plan).ok());
  EXPECT_EQ(collect(*scene, o, &done).size(), plan.surfels);
  EXPECT_EQ(done.surfels, plan.surfels);
  EXPECT_EQ(done.radius, plan.radius);
}

}  // namespace
}  // namespace pbgi
