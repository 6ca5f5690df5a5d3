// Which glossy first hits take the diffuse gather (LambertianLobes): rough conductors whose
// lobe the tree's SH hold, reflecting by their directional albedo towards the camera.

#include "core/render/pbgi_receiver.h"

#include <gtest/gtest.h>

#include <cmath>

#include "core/bake/surfel_shading.h"
#include "tests/core/render/test_scenes.h"
#include "tests/support/bsdf_reference.h"

namespace pbgi {
namespace {

using testing::conductorMaterial;
using testing::dielectricMaterial;
using testing::diffuseMaterial;

TEST(LambertianLobes, RoughConductorsWhoseLobeTheShHoldReflectByTheirDirectionalAlbedo) {
  SceneBuilder b;
  const std::vector<Material> materials = {
      diffuseMaterial(Rgb(0.7f)),
      conductorMaterial(1.0f, Rgb(0.9f, 0.5f, 0.2f)),  // SH hold it: diffuse path
      conductorMaterial(0.2f, Rgb(0.9f, 0.5f, 0.2f)),  // a glossy lobe
      conductorMaterial(0.0f, Rgb(0.9f)),              // a mirror
      dielectricMaterial(1.0f),                        // the path tracer's
  };
  for (size_t i = 0; i < materials.size(); ++i) {
    const uint32_t m = b.addMaterial(materials[i]);
    b.addMesh(testing::makeQuadMesh({float(i), 0, 0}, {1, 0, 0}, {0, 0, 1}, m));
  }
  auto scene = b.build();
  ASSERT_TRUE(scene.ok()) << scene.status();
  ASSERT_FALSE(needsWavelets(materials[1]));
  ASSERT_TRUE(needsWavelets(materials[2]));
  const LambertianLobes lobes(**scene);
  EXPECT_FALSE(lobes.has(0));
  EXPECT_TRUE(lobes.has(1));
  EXPECT_FALSE(lobes.has(2));
  EXPECT_FALSE(lobes.has(3));
  EXPECT_FALSE(lobes.has(4));
  EXPECT_FALSE(lobes.has(99));  // no such material

  // Against brute force at views between the table's bins, grazing to head-on: within 1.5 %.
  const Bsdf bsdf(materials[1], untexturedAlbedo(materials[1]));
  float worst = 0.0f;
  for (const float c : {0.08f, 0.3f, 0.55f, 0.81f, 0.99f}) {
    const Vec3f wo(std::sqrt(1.0f - c * c), 0.0f, c);
    const Rgb expected = testing::directionalAlbedo(bsdf, wo);
    const Rgb got = lobes.albedo(1, c);
    for (int ch = 0; ch < 3; ++ch) {
      const float e = testing::relativeError(got[ch], expected[ch]);
      worst = std::max(worst, e);
      EXPECT_LT(e, 0.015f) << "cos " << c << " channel " << ch;
    }
  }
  std::printf("[ measured ] GGX 1.0 directional albedo table: worst relative error %.4f\n", worst);
  // The table holds what one Lambertian albedo cannot: GGX alpha 1 reflects far more at a
  // grazing view than head-on (measured, red: 0.716 at cosine 0.08, 0.278 at 0.99; its
  // shadowing-masking loses most head-on), so the view's own albedo is what scales E / pi.
  const float grazing = lobes.albedo(1, 0.08f).x, headOn = lobes.albedo(1, 0.99f).x;
  std::printf("[ measured ] GGX 1.0 albedo, red: %.3f grazing, %.3f head-on\n", grazing, headOn);
  EXPECT_GT(std::abs(grazing - headOn), 0.3f * std::max(grazing, headOn));
}

}  // namespace
}  // namespace pbgi
