// The bake's surfel direct light against closed forms: the analytic cases of the path
// tracer's suite (tests/core/render/analytic.h), each receiver a stack of surfels whose light
// samples together estimate its irradiance, in three units; and a surfel on the inside of a
// closed emitting sphere, which receives pi Le from every side it faces inwards.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "core/bake/surfel_shading.h"
#include "tests/core/render/analytic.h"

namespace pbgi {
namespace {

using analytic::AnalyticCase;
using analytic::Estimate;
using analytic::Receiver;

constexpr int kLightSamples = 16;

// Irradiance at each receiver from `samples` surfel light samples: surfels of albedo
// kReceiverAlbedo facing n on triangle 0 (a receiver's, in every case), shaded by
// shadeSurfelsDirect, their front radiance times pi / albedo. Each surfel is an independent
// mean of kLightSamples samples (its own stream), so one sample's deviation is the surfels'
// times sqrt(kLightSamples).
std::vector<Estimate> surfelIrradiance(const AnalyticCase& c, int samples, uint64_t seed) {
  const int perReceiver = (samples + kLightSamples - 1) / kLightSamples;
  std::vector<Surfel> surfels;
  for (const Receiver& r : c.receivers) {
    Surfel s;
    s.position = r.p;
    s.normal = r.n;
    s.radius = 1e-4f * std::max(maxAbsComponent(r.p), 1e-30f);
    s.albedo = Rgb(analytic::kReceiverAlbedo);
    s.triangle = 0;
    surfels.insert(surfels.end(), perReceiver, s);
  }
  SurfelShadingOptions options;
  options.lightSamples = kLightSamples;
  options.seed = seed;
  const SurfelShadingStats stats = shadeSurfelsDirect(*c.scene, surfels, 0, options);
  EXPECT_EQ(stats.discardedSamples, 0u) << c.name;
  std::vector<Estimate> out;
  const double toIrradiance = kPi / analytic::kReceiverAlbedo;
  for (size_t i = 0; i < c.receivers.size(); ++i) {
    double sum = 0.0, sum2 = 0.0;
    for (int k = 0; k < perReceiver; ++k) {
      const double e = surfels[i * perReceiver + k].radiance.x * toIrradiance;
      sum += e;
      sum2 += e * e;
    }
    Estimate e = analytic::estimateOf(sum, sum2, perReceiver, c.receivers[i].exact);
    e.relStd *= std::sqrt(static_cast<double>(kLightSamples));
    out.push_back(e);
  }
  return out;
}

void expectMatchesClosedForm(const AnalyticCase& c, double bound, uint64_t seed) {
  ASSERT_NE(c.scene, nullptr) << c.name;
  const int n = analytic::samplesFor(c.sigmaSurfel, bound);
  const std::vector<Estimate> estimates = surfelIrradiance(c, n, seed);
  analytic::expectWithinBounds(c, estimates, n, bound, c.sigmaSurfel, "surfels");
}

class SurfelDirectLightAnalytic : public ::testing::TestWithParam<analytic::CaseGroup> {};

TEST_P(SurfelDirectLightAnalytic, IrradianceMatchesTheClosedForm) {
  const analytic::CaseGroup& group = GetParam();
  uint64_t seed = analytic::groupKey(group);
  for (const AnalyticCase& c : group.cases()) expectMatchesClosedForm(c, group.bound, seed++);
}

INSTANTIATE_TEST_SUITE_P(Lights, SurfelDirectLightAnalytic,
                         ::testing::ValuesIn(analytic::caseGroups()), analytic::caseGroupName);

// Surfels at the centres of a closed emitting sphere's faces (flat, albedo a, inside emitting
// Le on both sides as MTL Ke does): the inner side receives pi Le from the rest of the sphere,
// the outer side nothing, so the inner radiance is Le (1 + a) and the outer Le.
TEST(SurfelDirectLightFurnace, InsideAClosedEmittingSphereEveryFaceReceivesPiLe) {
  for (const float scale : analytic::kScales) {
    SceneBuilder b;
    Material m;
    m.albedo = Rgb(0.5f);
    m.radiance = Rgb(1.5f);
    MeshData sphere = testing::makeSphereMesh(3.0f * scale, b.addMaterial(m));
    sphere.normals.clear();
    std::vector<Surfel> surfels;
    for (uint32_t t = 0; t < sphere.triangleCount(); t += 7) {
      const Vec3f& p0 = sphere.positions[sphere.indices[3 * t]];
      const Vec3f& p1 = sphere.positions[sphere.indices[3 * t + 1]];
      const Vec3f& p2 = sphere.positions[sphere.indices[3 * t + 2]];
      Surfel s;
      s.position = (p0 + p1 + p2) / 3.0f;
      s.normal = normalize(cross(p1 - p0, p2 - p0));
      s.radius = 0.01f * scale;
      s.albedo = Rgb(0.5f);
      s.triangle = t;
      for (int k = 0; k < 16; ++k) surfels.push_back(s);
    }
    b.addMesh(std::move(sphere));
    auto scene = b.build();
    ASSERT_TRUE(scene.ok()) << scene.status();
    SurfelShadingOptions options;
    options.lightSamples = kLightSamples;
    shadeSurfelsDirect(**scene, surfels, 0, options);
    // Stated: a light sample's relative deviation of the irradiance is at most kSigma (1280
    // emitting triangles chosen by power and sampled by area), so the 16 x 16 samples of a
    // face bound its mean to 4 kSigma / 16, and all of them the mean over the faces.
    constexpr double kSigma = 0.12;
    constexpr int kPerFace = 16;
    const double exact = kPi * 1.5;
    const int faces = static_cast<int>(surfels.size()) / kPerFace;
    const double faceBound = 4.0 * kSigma / std::sqrt(kPerFace * kLightSamples);
    double sum = 0.0, sum2 = 0.0;
    for (int f = 0; f < faces; ++f) {
      double faceSum = 0.0;
      for (int k = 0; k < kPerFace; ++k) {
        const Surfel& s = surfels[f * kPerFace + k];
        const bool outward = dot(s.position, s.normal) > 0.0f;
        const Rgb inner = outward ? s.backRadiance : s.radiance;
        const Rgb outer = outward ? s.radiance : s.backRadiance;
        EXPECT_FLOAT_EQ(outer.x, 1.5f) << "the outside receives nothing";
        const double e = (inner.x - 1.5) * kPi / 0.5;
        faceSum += e;
        sum += e;
        sum2 += e * e;
      }
      EXPECT_NEAR(faceSum / kPerFace / exact, 1.0, faceBound)
          << "face " << f << ", scale " << scale;
    }
    const int n = faces * kPerFace;
    Estimate e = analytic::estimateOf(sum, sum2, n, exact);
    e.relStd *= std::sqrt(static_cast<double>(kLightSamples));
    const double bound = 4.0 * kSigma / std::sqrt(n * kLightSamples);
    EXPECT_NEAR(e.mean / exact, 1.0, bound) << "scale " << scale;
    EXPECT_LE(e.relStd, kSigma) << "scale " << scale;
    std::printf(
        "surfels inside an emitting sphere, scale %g: %d faces x %d samples, relative "
        "error of the mean %.2e (bound %.2e), sample deviation %.3f (stated %.3f)\n",
        scale, faces, kPerFace * kLightSamples, std::abs(e.mean / exact - 1.0), bound, e.relStd,
        kSigma);
  }
}

}  // namespace
}  // namespace pbgi
