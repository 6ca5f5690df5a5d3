#include "core/bake/surfel_shading.h"

#include <gtest/gtest.h>

#include <cstring>
#include <vector>

#include <tbb/task_arena.h>

#include "core/bake/surfel_sampler.h"
#include "tests/core/render/test_scenes.h"
#include "tests/support/memory_tree.h"

namespace pbgi {
namespace {

using testing::makeQuadMesh;

std::unique_ptr<Scene> buildScene(SceneBuilder& b) {
  auto scene = b.build();
  EXPECT_TRUE(scene.ok()) << scene.status();
  return scene.ok() ? std::move(*scene) : nullptr;
}

std::vector<Surfel> sample(const Scene& scene, uint64_t n, uint64_t seed = 1) {
  SurfelSamplingOptions o;
  o.targetCount = n;
  o.seed = seed;
  auto out = collectSurfels(scene, o);
  EXPECT_TRUE(out.ok()) << out.status();
  return out.ok() ? std::move(*out) : std::vector<Surfel>{};
}

// A floor (facing +y) of albedo 0.5 under a uniform sky L: E = pi L, so the outgoing
// radiance is 0.5 / pi * pi L = 0.5 L. Averaged over 16384 surfels x 16 samples the
// estimator's relative standard deviation is about 0.3 %.
TEST(SurfelShadingTest, UniformSkyGivesAlbedoTimesSky) {
  SceneBuilder b;
  Material m;
  m.albedo = Rgb(0.5f);
  b.addMesh(makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, b.addMaterial(m)));
  const Rgb sky(0.8f, 0.4f, 0.2f);
  b.addLight(makeUniformEnvironmentLight(sky));
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  std::vector<Surfel> surfels = sample(*scene, 16384);
  SurfelShadingOptions o;
  o.seed = 3;
  const SurfelShadingStats stats = shadeSurfelsDirect(*scene, surfels, 0, o);
  EXPECT_EQ(stats.surfels, 16384u);
  EXPECT_EQ(stats.discardedSamples, 0u);
  double sum[3] = {0, 0, 0};
  for (const Surfel& s : surfels) {
    ASSERT_TRUE(isFinite(s.radiance));
    ASSERT_GE(minComponent(s.radiance), 0.0f);
    for (int c = 0; c < 3; ++c) sum[c] += s.radiance[c];
  }
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(sum[c] / surfels.size(), 0.5 * sky[c], 0.01 * 0.5 * sky[c]) << "channel " << c;
  }
}

// Under a sun (a delta light, one exact sample): L = albedo / pi * E cos(theta) on the
// blocker's top, and nothing at all on the floor it shades.
TEST(SurfelShadingTest, SunlitAndShadowedSurfels) {
  SceneBuilder b;
  Material m;
  m.albedo = Rgb(0.6f, 0.3f, 0.9f);
  const uint32_t id = b.addMaterial(m);
  b.addMesh(makeQuadMesh({0, 0, 0}, {0, 0, 1}, {1, 0, 0}, id));       // floor, faces +y
  b.addMesh(makeQuadMesh({-2, 0.5f, -2}, {0, 0, 5}, {5, 0, 0}, id));  // blocker above it
  const Vec3f toSun = normalize(Vec3f(0.3f, 1.0f, 0.2f));
  const Rgb sunIrradiance(3.0f, 2.0f, 1.0f);
  b.addLight(makeDirectionalLight(-toSun, sunIrradiance));
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  std::vector<Surfel> surfels = sample(*scene, 2600);
  shadeSurfelsDirect(*scene, surfels, 0, SurfelShadingOptions{});
  int floor = 0, top = 0;
  for (const Surfel& s : surfels) {
    if (s.triangle < 2) {
      ++floor;
      EXPECT_EQ(s.radiance, Rgb(0.0f)) << "floor surfel at " << s.position;
    } else {
      ++top;
      const Rgb expected = m.albedo * sunIrradiance * (dot(toSun, s.normal) / kPi);
      EXPECT_LT(length(s.radiance - expected), 1e-5f * length(expected)) << s.radiance;
    }
  }
  EXPECT_EQ(floor, 100);  // area 1 of 26
  EXPECT_EQ(top, 2500);
}

TEST(SurfelShadingTest, EmissiveSurfelsCarryTheirEmission) {
  SceneBuilder b;
  Material emitter, glowing;
  emitter.type = MaterialType::kEmissive;
  emitter.radiance = Rgb(2.0f, 1.0f, 0.5f);
  glowing.albedo = Rgb(0.5f);
  glowing.radiance = Rgb(0.25f);
  b.addMesh(makeQuadMesh({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, b.addMaterial(emitter)));
  b.addMesh(makeQuadMesh({0, 0, 3}, {1, 0, 0}, {0, 1, 0}, b.addMaterial(glowing)));
  b.addLight(makeUniformEnvironmentLight(Rgb(1.0f)));
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  std::vector<Surfel> surfels = sample(*scene, 4000);
  SurfelShadingOptions o;
  o.lightSamples = 64;
  const SurfelShadingStats stats = shadeSurfelsDirect(*scene, surfels, 0, o);
  EXPECT_EQ(stats.emissive, 4000u);
  double glowSum = 0.0;
  int glowCount = 0;
  for (const Surfel& s : surfels) {
    EXPECT_EQ(s.materialClass, MaterialClass::kEmissive);
    if (s.triangle < 2) {
      EXPECT_EQ(s.radiance, emitter.radiance);  // an emitter reflects nothing
    } else {
      // Its own emission plus what it reflects of the sky.
      EXPECT_GE(minComponent(s.radiance), 0.25f);
      glowSum += s.radiance.x;
      ++glowCount;
    }
  }
  // 0.25 + 0.5 / pi * pi * 1 = 0.75: the emitter quad lies behind the glowing one's front.
  EXPECT_NEAR(glowSum / glowCount, 0.75, 0.015);
}

// Glossy and transmissive materials have no Lambertian lobe: their surfels reflect nothing
// into the diffuse radiance, however bright their surroundings.
TEST(SurfelShadingTest, GlossyAndTransmissiveSurfelsStoreOnlyTheirDiffusePart) {
  SceneBuilder b;
  Material conductor, dielectric;
  conductor.type = MaterialType::kConductor;
  conductor.roughness = 0.3f;
  dielectric.type = MaterialType::kDielectric;
  b.addMesh(makeQuadMesh({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, b.addMaterial(conductor)));
  b.addMesh(makeQuadMesh({0, 0, 3}, {1, 0, 0}, {0, 1, 0}, b.addMaterial(dielectric)));
  b.addLight(makeUniformEnvironmentLight(Rgb(1.0f)));
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  std::vector<Surfel> surfels = sample(*scene, 100);
  shadeSurfelsDirect(*scene, surfels, 0, SurfelShadingOptions{});
  for (const Surfel& s : surfels) {
    EXPECT_FALSE(isBlack(s.albedo));  // the material's reflectance is still recorded
    EXPECT_EQ(s.radiance, Rgb(0.0f));
  }
}

class NanTexture final : public Texture {
 public:
  Rgb evaluate(const Vec2f& uv) const override {
    return Rgb(uv.x < 0.5f ? std::numeric_limits<float>::quiet_NaN() : 0.5f);
  }
};

// A texture that returns NaN on half the quad: those surfels come out black and counted.
TEST(SurfelShadingTest, NonFiniteRadianceIsCountedAndBlack) {
  SceneBuilder b;
  Material m;
  m.albedoTexture = std::make_shared<NanTexture>();
  MeshData quad = makeQuadMesh({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, b.addMaterial(m));
  quad.uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  b.addMesh(std::move(quad));
  b.addLight(makeDirectionalLight(Vec3f(0, 0, -1), Rgb(1.0f)));
  auto scene = buildScene(b);
  ASSERT_NE(scene, nullptr);
  std::vector<Surfel> surfels = sample(*scene, 1000);
  const SurfelShadingStats stats = shadeSurfelsDirect(*scene, surfels, 0, SurfelShadingOptions{});
  uint64_t bad = 0;
  for (const Surfel& s : surfels) {
    ASSERT_TRUE(isFinite(s.radiance));
    if (s.position.x < 0.5f) {
      ++bad;
      EXPECT_EQ(s.radiance, Rgb(0.0f));
    } else {
      EXPECT_NEAR(s.radiance.x, 0.5f / kPi, 1e-6f);
    }
  }
  EXPECT_EQ(stats.nonFiniteSurfels, bad);
  EXPECT_GT(bad, 400u);
}

// A surfel's radiance depends on its index in the stream, not on the chunk it was shaded in
// or on the number of threads.
TEST(SurfelShadingTest, IndependentOfChunkingAndThreads) {
  auto scene = testing::makeBoxScene();
  ASSERT_NE(scene, nullptr);
  const std::vector<Surfel> surfels = sample(*scene, 3000, 7);
  SurfelShadingOptions o;
  o.seed = 11;
  o.frame = 2;
  o.lightSamples = 4;
  std::vector<Surfel> whole = surfels;
  shadeSurfelsDirect(*scene, whole, 0, o);
  std::vector<Surfel> chunked = surfels;
  tbb::task_arena single(1);
  single.execute([&] {
    for (size_t first = 0; first < chunked.size(); first += 37) {
      const size_t n = std::min<size_t>(37, chunked.size() - first);
      shadeSurfelsDirect(*scene, std::span<Surfel>(chunked).subspan(first, n), first, o);
    }
  });
  size_t lit = 0;
  for (size_t i = 0; i < surfels.size(); ++i) {
    ASSERT_EQ(std::memcmp(&whole[i].radiance, &chunked[i].radiance, sizeof(Rgb)), 0) << i;
    lit += !isBlack(whole[i].radiance);
  }
  EXPECT_GT(lit, surfels.size() / 2);
  // And a different frame draws different light samples.
  std::vector<Surfel> other = surfels;
  o.frame = 3;
  shadeSurfelsDirect(*scene, other, 0, o);
  size_t differ = 0;
  for (size_t i = 0; i < surfels.size(); ++i) differ += !(other[i].radiance == whole[i].radiance);
  EXPECT_GT(differ, surfels.size() / 2);
}

// A rough conductor surfel under the sun: its wavelet radiance is the BSDF times the sun's
// irradiance towards every texel (one direction of light: exact, without a threshold), brightest
// near the mirror direction, and dark with the sun blocked.

struct SunCase {
  std::unique_ptr<Scene> scene;
  Material metal;
  Surfel surfel;
  Vec3f toSun;
  Rgb sun;
};

SunCase sunCase(bool blocked) {
  SunCase c;
  SceneBuilder b;
  Material floor;
  floor.albedo = Rgb(0.5f);
  b.addMesh(makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, b.addMaterial(floor)));
  if (blocked) b.addMesh(makeQuadMesh({-5, 1, -5}, {10, 0, 0}, {0, 0, 10}, b.addMaterial(floor)));
  c.toSun = normalize(Vec3f(0.4f, 1.0f, 0.2f));
  c.sun = Rgb(3.0f, 2.0f, 1.0f);
  LightDesc light;
  light.type = LightType::kDirectional;
  light.direction = -c.toSun;
  light.irradiance = c.sun;
  b.addLight(light);
  c.scene = buildScene(b);
  c.metal.type = MaterialType::kConductor;
  c.metal.roughness = 0.3f;
  c.metal.specular = Rgb(0.9f, 0.8f, 0.7f);
  c.surfel.position = {0.0f, 0.0f, 0.0f};
  c.surfel.normal = {0.0f, 1.0f, 0.0f};
  c.surfel.radius = 0.01f;
  return c;
}

TEST(SurfelShadingTest, AGlossySurfelSendsTheSunOutAsItsBsdfDoes) {
  SunCase c = sunCase(false);
  ASSERT_NE(c.scene, nullptr);
  Rng rng(4);
  const int n = 16;
  const WaveletRadiance w =
      glossyDirectRadiance(*c.scene, c.surfel, c.metal, Rgb(1.0f), n, 0.0f, 4, rng);
  const Frame frame(c.surfel.normal);
  const Bsdf bsdf(c.metal, Rgb(1.0f));
  const Vec3f wiLocal = frame.toLocal(c.toSun);
  float brightest = -1.0f;
  Vec3f brightestDir(0.0f);
  for (int face = 0; face < 6; ++face) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        const Vec3f wo = microbufferTables(n)->directions[(face * n + y) * n + x];
        const Rgb expected = bsdf.f(frame.toLocal(wo), wiLocal) * c.sun * wiLocal.z;
        const Rgb got = w.evaluate(wo);
        for (int ch = 0; ch < 3; ++ch) {
          ASSERT_NEAR(got[ch], expected[ch], 1e-4f + 1e-4f * expected[ch]) << face << " " << x << " " << y;
        }
        if (got.x > brightest) brightest = got.x, brightestDir = wo;
      }
    }
  }
  const Vec3f mirror = Vec3f(-c.toSun.x, c.toSun.y, -c.toSun.z);
  EXPECT_GT(dot(brightestDir, mirror), 0.95f) << "brightest towards " << brightestDir;
  EXPECT_GT(brightest, 0.0f);
  // Below the surface nothing: a conductor reflects on the side the light arrives on.
  EXPECT_NEAR(w.evaluate(Vec3f(0.1f, -1.0f, 0.0f)).x, 0.0f, 1e-5f);
}

TEST(SurfelShadingTest, AGlossySurfelInShadowSendsNothing) {
  SunCase c = sunCase(true);
  ASSERT_NE(c.scene, nullptr);
  Rng rng(4);
  const WaveletRadiance w =
      glossyDirectRadiance(*c.scene, c.surfel, c.metal, Rgb(1.0f), 8, 0.0f, 4, rng);
  EXPECT_TRUE(w.isConstantPerFace());
  EXPECT_NEAR(w.evaluate(Vec3f(-0.4f, 1.0f, -0.2f)).x, 0.0f, 1e-6f);
}

// Which materials pay for wavelets: lobes the tree's SH cannot hold. A diffuse surfel's clamped
// cosine is what SH are for; a mirror never fits; rough metal falls on one side or the other
// by its roughness.
Material microfacet(MaterialType type, float roughness) {
  Material m;
  m.type = type;
  m.roughness = roughness;
  return m;
}

TEST(SurfelShadingTest, OnlyLobesTheShCannotHoldNeedWavelets) {
  Material diffuse;
  EXPECT_EQ(shLobeError(diffuse), 0.0f);
  EXPECT_FALSE(needsWavelets(diffuse));
  EXPECT_TRUE(needsWavelets(microfacet(MaterialType::kConductor, 0.0f)));   // a mirror
  EXPECT_TRUE(needsWavelets(microfacet(MaterialType::kDielectric, 0.0f)));  // glass
  float last = 2.0f;
  for (float roughness : {0.05f, 0.15f, 0.35f, 0.6f, 1.0f}) {
    const float error = shLobeError(microfacet(MaterialType::kConductor, roughness));
    std::printf("[ measured ] GGX conductor alpha %.2f: SH (bands 0-2) error of its lobes %.3f\n",
                roughness, error);
    EXPECT_LT(error, last) << "rougher lobes are smoother";
    last = error;
  }
  EXPECT_TRUE(needsWavelets(microfacet(MaterialType::kConductor, 0.6f)));
  const Material rough = microfacet(MaterialType::kConductor, 1.0f);
  EXPECT_FALSE(needsWavelets(rough));
  EXPECT_TRUE(needsWavelets(rough, 0.2f));  // the tolerance is the user's
}

// The quadrature itself: a function in the SH's span has no error, a clamped cosine the
// analytic 0.0884 (sqrt(1 - (pi/4 + pi/3 + 5 pi/64) / (2 pi/3))), a narrow lobe a large one.
TEST(SurfelShadingTest, ShProjectionErrorIsZeroInsideTheShSpan) {
  EXPECT_LT(shProjectionError([](const Vec3f& d) { return 1.0f + 0.5f * d.z + 0.25f * d.x * d.y; }, 32),
            0.01f);
  EXPECT_GT(shProjectionError(
                [](const Vec3f& d) { return std::exp(100.0f * (normalize(d).z - 1.0f)); }, 32),
            0.5f);
  EXPECT_NEAR(shProjectionError([](const Vec3f& d) { return std::max(0.0f, normalize(d).z); }, 64),
              0.0884f, 0.002f);
  EXPECT_EQ(shProjectionError([](const Vec3f&) { return 0.0f; }, 8), 0.0f);
}

}  // namespace
}  // namespace pbgi

namespace pbgi {
namespace {

// A rough metal floor beside a sunlit diffuse wall, the wall's light gathered by the floor's
// glossy leaves (runs of 8 Morton-ordered surfels) from the tree of every surfel.
struct WallAndMetalFloor {
  std::unique_ptr<Scene> scene;
  std::unique_ptr<testing::MemoryTreeSource> tree;
  std::vector<Surfel> glossy;  // Morton order
};

WallAndMetalFloor wallAndMetalFloor() {
  WallAndMetalFloor c;
  SceneBuilder b;
  Material metal;
  metal.type = MaterialType::kConductor;
  metal.roughness = 0.2f;
  metal.specular = Rgb(0.9f, 0.8f, 0.7f);
  Material wall;
  wall.albedo = Rgb(0.7f, 0.3f, 0.2f);
  b.addMesh(makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, b.addMaterial(metal)));
  b.addMesh(makeQuadMesh({-1, 0, -1}, {0, 2, 0}, {0, 0, 2}, b.addMaterial(wall)));
  LightDesc sun;
  sun.type = LightType::kDirectional;
  sun.direction = -normalize(Vec3f(1.0f, 0.8f, 0.3f));
  sun.irradiance = Rgb(3.0f);
  b.addLight(sun);
  c.scene = buildScene(b);
  if (c.scene == nullptr) return c;
  std::vector<Surfel> surfels = sample(*c.scene, 12000, 5);
  SurfelShadingOptions o;
  o.seed = 2;
  shadeSurfelsDirect(*c.scene, surfels, 0, o);
  c.tree = testing::treeOf(surfels, 2);
  for (const SortedSurfel& s : testing::sortSurfels(surfels)) {
    if (s.surfel.materialClass == MaterialClass::kGlossy) c.glossy.push_back(s.surfel);
  }
  return c;
}

// Runs of 8 of `surfels` as a writer's batch of leaves.
std::vector<WaveletLeafJob> leafJobs(std::vector<Surfel>& surfels) {
  std::vector<WaveletLeafJob> jobs;
  for (size_t first = 0; first < surfels.size(); first += 8) {
    const size_t n = std::min<size_t>(8, surfels.size() - first);
    jobs.push_back({std::span<Surfel>(surfels).subspan(first, n), 1000 + first, {}});
  }
  return jobs;
}

// Pair refinement with the receiver threshold at zero is per-leaf evaluation: every leaf's
// vector and surfels' radiance are operator()'s, bit for bit. With a threshold of 0.004 sr the
// leaves share splats and reflect the same light within a few percent (relative L2 over every
// texel of every leaf).
TEST(GlossyLeafBakerTest, PairRefinementAtZeroIsPerLeafEvaluation) {
  WallAndMetalFloor c = wallAndMetalFloor();
  ASSERT_NE(c.scene, nullptr);
  ASSERT_GT(c.glossy.size(), 2000u);
  GlossyBakeOptions o;
  o.resolution = 8;
  o.directLight = false;
  o.indirectSamples = 4;
  o.pairReceiverSolidAngle = 0.0f;
  GlossyLeafBaker baker(*c.scene, o);
  baker.setIncoming(c.tree.get());
  std::vector<Surfel> alone = c.glossy, together = c.glossy;
  std::vector<WaveletLeafJob> aloneJobs = leafJobs(alone), jobs = leafJobs(together);
  for (WaveletLeafJob& j : aloneJobs) j.out = baker(j.surfels, j.key);
  PairGatherStats stats;
  baker.bakeLeaves(jobs, &stats);
  EXPECT_EQ(stats.receivers, jobs.size());
  EXPECT_EQ(stats.groupSplats, 0u);
  for (size_t j = 0; j < jobs.size(); ++j) {
    ASSERT_EQ(jobs[j].out.dense(), aloneJobs[j].out.dense()) << "leaf " << j;
  }
  double lit = 0.0;
  for (size_t i = 0; i < alone.size(); ++i) {
    ASSERT_EQ(alone[i].radiance, together[i].radiance) << i;
    ASSERT_EQ(alone[i].backRadiance, together[i].backRadiance) << i;
    lit += luminance(alone[i].radiance);
  }
  EXPECT_GT(lit, 0.0);  // the wall's light reaches the floor

  GlossyBakeOptions shared = o;
  shared.pairReceiverSolidAngle = 0.004f;
  GlossyLeafBaker sharing(*c.scene, shared);
  sharing.setIncoming(c.tree.get());
  std::vector<Surfel> grouped = c.glossy;
  std::vector<WaveletLeafJob> groupedJobs = leafJobs(grouped);
  PairGatherStats groupedStats;
  sharing.bakeLeaves(groupedJobs, &groupedStats);
  double d2 = 0.0, n2 = 0.0;
  for (size_t j = 0; j < jobs.size(); ++j) {
    const std::vector<float> a = aloneJobs[j].out.dense(), g = groupedJobs[j].out.dense();
    ASSERT_EQ(a.size(), g.size());
    for (size_t k = 0; k < a.size(); ++k) {
      d2 += double(g[k] - a[k]) * (g[k] - a[k]);
      n2 += double(a[k]) * a[k];
    }
  }
  std::printf(
      "[ measured ] %zu glossy leaves: pair refinement at %g against each alone, relative "
      "L2 %.4f\n  %s\n",
      jobs.size(), shared.pairReceiverSolidAngle, std::sqrt(d2 / n2),
      groupedStats.toString().c_str());
  EXPECT_GT(groupedStats.groupSplats, 0u);
  EXPECT_LT(std::sqrt(d2 / n2), 0.1);  // measured 0.065
}

}  // namespace
}  // namespace pbgi
