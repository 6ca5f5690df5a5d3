// The bake's bounce rules that need no scene: how each bounce gathers, what a surfel reflects,
// and the tail that stands in for the bounces not baked.

#include "core/bake/surfel_bounce.h"

#include <gtest/gtest.h>

#include <array>
#include <span>
#include <vector>

#include "tests/core/render/test_scenes.h"

namespace pbgi {
namespace {

TEST(SurfelBounce, LaterBouncesGatherAtCoarserSolidAnglesThanTheFirst) {
  const CutOptions first = *cutPreset("draft");
  // The first bounce's thresholds, its descents by cones; the later bounces' by SH.
  CutOptions byCones = first;
  byCones.coneDescent = true;
  EXPECT_EQ(bounceCutOptions(first, 1), byCones);
  for (int bounce : {2, 3, 16}) {
    const CutOptions later = bounceCutOptions(first, bounce);
    EXPECT_FALSE(later.coneDescent);
    EXPECT_FLOAT_EQ(later.lightSolidAngle, first.lightSolidAngle * kLaterBounceCoarsening);
    EXPECT_FLOAT_EQ(later.lightBound, first.lightBound * kLaterBounceCoarsening);
    EXPECT_FLOAT_EQ(later.receiverBound, first.receiverBound * kLaterBounceCoarsening);
    EXPECT_EQ(later.normalAngle, first.normalAngle);
    EXPECT_EQ(later.selfSkipRadius, first.selfSkipRadius);
    EXPECT_TRUE(later.validate().ok());
  }
  // Thresholds near the top of their range stay valid.
  CutOptions wide = first;
  wide.lightSolidAngle = wide.lightBound = wide.receiverBound = 10.0f;
  EXPECT_TRUE(bounceCutOptions(wide, 2).validate().ok()) << bounceCutOptions(wide, 2).toString();
  // Zero thresholds (every surfel against every receiver) stay exact.
  CutOptions exact = first;
  exact.lightSolidAngle = exact.lightBound = exact.receiverBound = 0.0f;
  EXPECT_EQ(bounceCutOptions(exact, 3), exact);
}

TEST(SurfelBounce, LaterBouncesStandForMoreSurfelsARecord) {
  EXPECT_EQ(bounceReceiverSpacing(16, 1), 16);
  EXPECT_EQ(bounceReceiverSpacing(16, 2), 16 * kLaterBounceSpacing);
  EXPECT_EQ(bounceReceiverSpacing(16, 3), 32 * kLaterBounceSpacing);
  EXPECT_EQ(bounceReceiverSpacing(16, 4), 64 * kLaterBounceSpacing);
  EXPECT_EQ(bounceReceiverSpacing(16, 16), kMaxBounceSpacing);
  EXPECT_EQ(bounceReceiverSpacing(2, 2), 2 * kLaterBounceSpacing);
  EXPECT_EQ(bounceReceiverSpacing(1, 3), 1);  // every surfel its own, in every bounce
  EXPECT_EQ(bounceReceiverSpacing(kMaxBounceSpacing, 2), kMaxBounceSpacing);
}

TEST(SurfelBounce, OnlyDiffuseSurfelsReflectAndEachSideReflectsItsOwnLight) {
  Surfel s;
  s.radius = 0.5f;
  s.albedo = Rgb(0.5f, 0.25f, 0.0f);
  s.materialClass = MaterialClass::kDiffuse;
  s.radiance = Rgb(1.0f);
  const SurfelIrradiance e{.front = Rgb(kPi), .back = Rgb(2.0f * kPi)};
  const Rgb p = reflectedPower(s, e);
  EXPECT_FLOAT_EQ(p.x, 0.5f * 3.0f * s.area());
  EXPECT_FLOAT_EQ(p.z, 0.0f);
  Surfel lit = s;
  addReflected(lit, e);
  EXPECT_FLOAT_EQ(lit.radiance.x, 1.5f);
  EXPECT_FLOAT_EQ(lit.backRadiance.x, 1.0f);
  EXPECT_FLOAT_EQ(lit.backRadiance.y, 0.5f);
  for (MaterialClass c : {MaterialClass::kGlossy, MaterialClass::kTransmissive,
                          MaterialClass::kEmissive}) {
    Surfel other = s;
    other.materialClass = c;
    EXPECT_TRUE(isBlack(reflectedPower(other, e)));
    addReflected(other, e);
    EXPECT_EQ(other.radiance, s.radiance);
  }
}

TEST(SurfelBounce, TheTailIsAGeometricSeriesHeldBelowOne) {
  using Powers = std::vector<std::array<double, 3>>;
  // r = 0.5: the bounces past sum to the last one's power again.
  const Powers two = {{4.0, 4.0, 4.0}, {2.0, 2.0, 1.0}, {1.0, 2.0, 0.0}};
  const Rgb f = tailFactor(two);
  EXPECT_FLOAT_EQ(f.x, 1.0f);
  // r >= 1 (a bounce brighter than the last: noise, or a scene of white walls) is held.
  EXPECT_FLOAT_EQ(f.y, kMaxBounceRatio / (1.0f - kMaxBounceRatio));
  EXPECT_FLOAT_EQ(f.z, 0.0f);  // nothing reflected: no tail
  const Powers dark = {{1.0, 1.0, 1.0}, {0.0, -1.0, 1e300}, {1.0, 1.0, 1.0}};
  EXPECT_FLOAT_EQ(tailFactor(dark).x, 0.0f);
  EXPECT_FLOAT_EQ(tailFactor(Powers{{1.0, 1.0, 1.0}}).x, 0.0f);  // no bounce: no tail
}

// Bounces whose powers rise (the diffuse surfels of a room whose light reaches them by way of a
// metal floor gather more in the second bounce than in the first) are no geometric series: the
// tail holds their ratio to the scene's largest reflectance, not to kMaxBounceRatio's 19x.
TEST(SurfelBounce, TheTailIsHeldToTheLargestReflectance) {
  using Powers = std::vector<std::array<double, 3>>;
  const Powers rising = {{1.0, 1.0, 1.0}, {0.007, 0.007, 0.007}, {0.104, 0.104, 0.104},
                         {0.048, 0.048, 0.048}};
  EXPECT_FLOAT_EQ(tailFactor(rising).x, kMaxBounceRatio / (1.0f - kMaxBounceRatio));
  EXPECT_FLOAT_EQ(tailFactor(rising, 0.8f).x, 0.8f / (1.0f - 0.8f));
  EXPECT_FLOAT_EQ(tailFactor(rising, 2.0f).x, kMaxBounceRatio / (1.0f - kMaxBounceRatio));
  EXPECT_FLOAT_EQ(tailFactor(rising, -1.0f).x, 0.0f);
  // A ratio below the bound is the series' own.
  const Powers falling = {{1.0, 1.0, 1.0}, {0.5, 0.5, 0.5}};
  EXPECT_FLOAT_EQ(tailFactor(falling, 0.8f).x, 1.0f);

  // The scene's largest reflectance: its brightest channel of any material, emitters aside.
  SceneBuilder b;
  Material grey;
  grey.albedo = Rgb(0.5f, 0.7f, 0.3f);
  Material lamp;
  lamp.type = MaterialType::kEmissive;
  lamp.radiance = Rgb(10.0f);
  const uint32_t m = b.addMaterial(grey);
  const uint32_t l = b.addMaterial(lamp);
  b.addMesh(testing::makeQuadMesh({0, 0, 0}, {1, 0, 0}, {0, 1, 0}, m));
  b.addMesh(testing::makeQuadMesh({0, 0, 2}, {1, 0, 0}, {0, 1, 0}, l));
  auto scene = b.build();
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_FLOAT_EQ(largestBounceRatio(**scene), 0.7f);
}

// Ratios that swing about their limit (0.6, 0.5, 0.6, 0.5, ...: light passed back and forth
// between two surfaces): from the third bounce on the tail takes the ratio over two steps,
// sqrt(0.3), whose series sums what the swinging one does within 10 % whichever bounce it
// stops at; the last step alone counts 31 % too much after an odd bounce, 22 % too little
// after an even one.
TEST(SurfelBounce, TheTailTakesTheRatioOverTwoBouncesFromTheThird) {
  std::vector<std::array<double, 3>> power = {{1.0, 1.0, 1.0}};
  for (int k = 1; k <= 24; ++k) {
    const double r = k % 2 == 1 ? 0.6 : 0.5;
    const double p = power.back()[0] * r;
    power.push_back({p, p, p});
  }
  for (const size_t bounces : {3u, 4u, 5u}) {
    double rest = 0.0;
    for (size_t k = bounces + 1; k < power.size(); ++k) rest += power[k][0];
    const std::span<const std::array<double, 3>> baked(power.data(), bounces + 1);
    const double estimate = tailFactor(baked).x * power[bounces][0];
    EXPECT_NEAR(estimate / rest, 1.0, 0.1) << bounces << " bounces";
  }
  // Two bounces: the last step.
  const std::span<const std::array<double, 3>> two(power.data(), 3);
  EXPECT_FLOAT_EQ(tailFactor(two).x, 0.5f / 0.5f);
}

}  // namespace
}  // namespace pbgi
