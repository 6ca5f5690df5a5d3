#include "core/scene/light.h"

#include <gtest/gtest.h>

#include "core/sampling/rng.h"

namespace pbgi {
namespace {

// Monte Carlo estimate of the irradiance at p (normal n) from light sampling.
Rgb estimateIrradiance(const Light& light, const Vec3f& p, const Vec3f& n, int count) {
  Rng rng(7);
  Rgb sum(0.0f);
  for (int i = 0; i < count; ++i) {
    const Vec2f u(rng.uniform(), rng.uniform());
    auto s = light.sample(p, u);
    if (!s) continue;
    const float cosTheta = std::max(0.0f, dot(s->wi, n));
    sum += s->radiance * (cosTheta / s->pdf);
  }
  return sum / static_cast<float>(count);
}

TEST(LightTest, SphereIrradianceMatchesAnalytic) {
  // A sphere of radius r at distance d straight above: E = pi L (r/d)^2.
  for (float d : {1.5f, 4.0f, 1000.0f}) {
    const auto light = makeSphereLight({0.0f, d, 0.0f}, 1.0f, Rgb(2.0f));
    const Rgb e = estimateIrradiance(*light, Vec3f(0.0f), Vec3f(0.0f, 1.0f, 0.0f), 200000);
    const float expected = kPi * 2.0f / (d * d);
    EXPECT_NEAR(e.x, expected, 0.01f * expected) << "distance " << d;
  }
}

TEST(LightTest, QuadIrradianceMatchesAnalyticAndIsOneSided) {
  // A unit square centred above the receiver at height h, facing down. Irradiance at the
  // centre below a square of half-side a at height h (Lambert's formula for a polygon):
  // E = L * 4 * (a / sqrt(a^2 + h^2)) * atan(a / sqrt(a^2 + h^2)).
  const float a = 0.5f, h = 1.0f;
  // edge_u x edge_v = (2a, 0, 0) x (0, 0, 2a) points down (-y).
  const auto down = makeQuadLight({-a, h, -a}, {2 * a, 0.0f, 0.0f}, {0.0f, 0.0f, 2 * a}, Rgb(1.0f));
  const Rgb e = estimateIrradiance(*down, Vec3f(0.0f), Vec3f(0.0f, 1.0f, 0.0f), 400000);
  const float k = a / std::sqrt(a * a + h * h);
  const float expected = 4.0f * k * std::atan(k);
  EXPECT_NEAR(e.x, expected, 0.01f * expected);
  // Flipped edges: the quad shines up and the receiver below gets nothing.
  const auto up = makeQuadLight({-a, h, -a}, {0.0f, 0.0f, 2 * a}, {2 * a, 0.0f, 0.0f}, Rgb(1.0f));
  EXPECT_EQ(estimateIrradiance(*up, Vec3f(0.0f), Vec3f(0.0f, 1.0f, 0.0f), 1000).x, 0.0f);
}

TEST(LightTest, SamplePdfMatchesPdfFunction) {
  const auto quad = makeQuadLight({-1, 2, -1}, {2, 0, 0}, {0, 0, 2}, Rgb(1.0f));
  const auto sphere = makeSphereLight({0.5f, 3.0f, 0.2f}, 0.7f, Rgb(1.0f));
  Rng rng(3);
  const Vec3f p(0.1f, 0.0f, -0.2f);
  for (const Light* light : {quad.get(), sphere.get()}) {
    for (int i = 0; i < 100; ++i) {
      auto s = light->sample(p, Vec2f(rng.uniform(), rng.uniform()));
      ASSERT_TRUE(s.has_value());
      const Vec3f hit = p + s->wi * s->distance;
      const Vec3f n = light == sphere.get() ? normalize(hit - Vec3f(0.5f, 3.0f, 0.2f))
                                            : Vec3f(0.0f, -1.0f, 0.0f);
      EXPECT_NEAR(light->pdf(p, s->wi, hit, n), s->pdf, 1e-3f * s->pdf);
      // The point and normal a shadow ray aims at are the sample's own.
      EXPECT_LT(length(s->point - hit), 1e-5f * s->distance);
      EXPECT_GT(dot(s->normal, n), 0.99999f);
    }
  }
}

TEST(LightTest, LatLongMappingFollowsTheSpec) {
  auto near = [](const Vec3f& a, const Vec3f& b) { return length(a - b) < 1e-5f; };
  EXPECT_TRUE(near(latLongToDirection({0.5f, 0.5f}), {1, 0, 0}));    // centre: +x
  EXPECT_TRUE(near(latLongToDirection({0.75f, 0.5f}), {0, 0, 1}));   // three quarters: +z
  EXPECT_TRUE(near(latLongToDirection({0.0f, 0.5f}), {-1, 0, 0}));   // left edge: -x
  EXPECT_TRUE(near(latLongToDirection({0.3f, 0.0f}), {0, 1, 0}));    // top row: +y
  for (const Vec2f uv : {Vec2f(0.1f, 0.2f), Vec2f(0.6f, 0.7f), Vec2f(0.9f, 0.45f)}) {
    const Vec2f back = directionToLatLong(latLongToDirection(uv));
    EXPECT_NEAR(back.x, uv.x, 1e-5f);
    EXPECT_NEAR(back.y, uv.y, 1e-5f);
  }
}

std::shared_ptr<LatLongImage> makeEnvironment() {
  auto image = std::make_shared<LatLongImage>();
  image->width = 16;
  image->height = 8;
  for (int y = 0; y < 8; ++y)
    for (int x = 0; x < 16; ++x) image->texels.push_back(Rgb(0.1f + x * 0.05f, 0.2f, y == 2 ? 5.0f : 0.1f));
  return image;
}

TEST(LightTest, EnvironmentRotationMovesTheCentreToMinusZ) {
  auto image = std::make_shared<LatLongImage>();
  image->width = 4;
  image->height = 2;
  image->texels.assign(8, Rgb(0.0f));
  image->texels[2] = Rgb(1.0f);  // row 0, column 2: the upper half around the centre (+x)
  const auto plain = makeEnvironmentLight(image, 1.0f, 0.0f);
  const auto turned = makeEnvironmentLight(image, 1.0f, 90.0f);
  const Vec3f dirX = normalize(Vec3f(1.0f, 0.3f, 0.1f));
  // Slightly towards +x of -z: after turning back by 90 degrees it lies just on the +z side
  // of +x, inside column 2.
  const Vec3f dirMinusZ = normalize(Vec3f(0.1f, 0.3f, -1.0f));
  EXPECT_EQ(plain->escaped(dirX).x, 1.0f);
  EXPECT_EQ(plain->escaped(dirMinusZ).x, 0.0f);
  EXPECT_EQ(turned->escaped(dirMinusZ).x, 1.0f);
  EXPECT_EQ(turned->escaped(dirX).x, 0.0f);
}

TEST(LightTest, EnvironmentSamplingIsConsistent) {
  const auto env = makeEnvironmentLight(makeEnvironment(), 2.0f, 30.0f);
  // E[L / pdf] over light samples is the integral of L over the sphere; compare with the
  // same integral by uniform sphere sampling.
  Rng rng(11);
  double viaLight = 0.0, viaUniform = 0.0;
  const int n = 400000;
  for (int i = 0; i < n; ++i) {
    auto s = env->sample(Vec3f(0.0f), Vec2f(rng.uniform(), rng.uniform()));
    if (s) {
      viaLight += s->radiance.z / s->pdf;
      EXPECT_NEAR(env->pdf(Vec3f(0.0f), s->wi, Vec3f(0.0f), Vec3f(0.0f)), s->pdf, 2e-3f * s->pdf);
    }
    const Vec3f d = sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform()));
    viaUniform += env->escaped(d).z / uniformSpherePdf();
  }
  EXPECT_NEAR(viaLight / n, viaUniform / n, 0.01 * viaUniform / n);
}

TEST(LightTest, DeltaLightsFollowInverseSquareAndCone) {
  const auto point = makePointLight({0, 2, 0}, Rgb(8.0f));
  auto s = point->sample(Vec3f(0.0f), Vec2f(0.5f));
  ASSERT_TRUE(s);
  EXPECT_TRUE(s->delta);
  EXPECT_FLOAT_EQ(s->radiance.x, 2.0f);
  const auto spot = makeSpotLight({0, 2, 0}, {0, -1, 0}, 20.0f, Rgb(8.0f));
  EXPECT_TRUE(spot->sample(Vec3f(0.0f), Vec2f(0.5f)).has_value());
  EXPECT_FALSE(spot->sample(Vec3f(2.0f, 0.0f, 0.0f), Vec2f(0.5f)).has_value());  // 45 degrees out
  const auto sun = makeDirectionalLight({0, -2, 0}, Rgb(3.0f));
  auto ss = sun->sample(Vec3f(0.0f), Vec2f(0.5f));
  ASSERT_TRUE(ss);
  EXPECT_FLOAT_EQ(ss->wi.y, 1.0f);
  EXPECT_TRUE(std::isinf(ss->distance));
}

}  // namespace
}  // namespace pbgi
