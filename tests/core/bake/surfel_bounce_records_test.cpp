// The bake's bounce records (BounceGatherer with receiverSpacing > 1): a record stands for a
// patch of surfels on one surface, and no surfel reads light from a surface facing another way.

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <vector>

#include "core/bake/surfel_bounce.h"
#include "core/bake/surfel_sampler.h"
#include "core/bake/surfel_shading.h"
#include "tests/core/render/test_scenes.h"
#include "tests/support/memory_tree.h"

namespace pbgi {
namespace {

// The two rooms' surfels (20,000) lit directly, their tree, and the bounce's groups of 4,096
// keyed by their index.
class SurfelBounceRecords : public ::testing::Test {
 protected:
  void SetUp() override {
    scene = testing::makeTwoRoomsScene();
    ASSERT_NE(scene, nullptr);
    SurfelSamplingOptions sampling;
    sampling.targetCount = 20000;
    auto collected = collectSurfels(*scene, sampling);
    ASSERT_TRUE(collected.ok()) << collected.status();
    surfels = *std::move(collected);
    shadeSurfelsDirect(*scene, surfels, 0, {});
    auto built = testing::memoryTree(surfels);
    ASSERT_TRUE(built.ok()) << built.status();
    tree = *std::move(built);
    n = surfels.size();
    keys.resize((n + kGroupSize - 1) / kGroupSize);
    for (size_t g = 0; g < keys.size(); ++g) keys[g] = g;
  }
  static constexpr size_t kGroupSize = 4096;
  std::unique_ptr<Scene> scene;
  std::vector<Surfel> surfels;
  std::unique_ptr<testing::MemoryTreeSource> tree;
  size_t n = 0;
  std::vector<uint64_t> keys;
};

// Two closed rooms either side of a wall 1 cm thick, a light in one. The wall's two faces
// share the records' grid cells and face opposite ways; so do each face and the side of the
// surfels beside it that looks into the wall.
TEST_F(SurfelBounceRecords, StandForPatchesAndNeverReadAcrossAWall) {
  const auto bounce = [&](int spacing, CutStats* stats) {
    std::vector<SurfelIrradiance> e(n);
    BounceGatherer bouncer(CutOptions{}, spacing);
    EXPECT_TRUE(bouncer.gather(*tree, *scene, surfels, kGroupSize, keys, 2, e, stats).ok());
    return e;
  };
  CutStats everyStats, recordStats;
  const std::vector<SurfelIrradiance> every = bounce(1, &everyStats);
  const std::vector<SurfelIrradiance> records = bounce(kBounceReceiverSpacing, &recordStats);
  EXPECT_EQ(everyStats.receivers, 2 * n);
  const double perRecord =
      2.0 * static_cast<double>(n) / static_cast<double>(recordStats.receivers);
  std::printf("[ measured ] %zu surfels, %.1f a record\n", n, perRecord);
  EXPECT_GT(perRecord, kBounceReceiverSpacing / 2.0);

  // The dark room, and every side that looks into the wall or out of the rooms, stays black
  // as each surfel's own gather leaves it; the lit room's sides read what theirs gather.
  double litEvery = 0.0, litRecords = 0.0;
  std::vector<float> differences;
  for (size_t i = 0; i < n; ++i) {
    const Surfel& s = surfels[i];
    const bool litRoom = s.position.x > 1.005f;
    // The side facing into the lit room: towards its centre.
    const bool frontInside = dot(Vec3f(1.51f, 0.5f, 0.5f) - s.position, s.normal) > 0.0f;
    const Rgb& e1 = frontInside ? every[i].front : every[i].back;
    const Rgb& eR = frontInside ? records[i].front : records[i].back;
    const Rgb& o1 = frontInside ? every[i].back : every[i].front;
    const Rgb& oR = frontInside ? records[i].back : records[i].front;
    ASSERT_TRUE(isBlack(o1)) << "surfel " << i;
    ASSERT_TRUE(isBlack(oR)) << "surfel " << i << " at " << s.position.x << ", " << s.position.y
                             << ", " << s.position.z << " reads light from outside its room";
    if (!litRoom) {
      ASSERT_TRUE(isBlack(e1) && isBlack(eR)) << "surfel " << i << " in the dark room";
      continue;
    }
    litEvery += luminance(e1);
    litRecords += luminance(eR);
    differences.push_back(std::abs(luminance(eR) - luminance(e1)) /
                          std::max(luminance(e1), 1e-6f));
  }
  std::sort(differences.begin(), differences.end());
  const float median = differences[differences.size() / 2];
  const float p90 = differences[differences.size() * 9 / 10];
  std::printf("[ measured ] lit room: mean irradiance %.5g (records) / %.5g (every surfel), "
              "per surfel |difference| median %.3g, 90th percentile %.3g\n",
              litRecords, litEvery, median, p90);
  EXPECT_NEAR(litRecords / litEvery, 1.0, 0.02);
  EXPECT_LT(median, 0.05f);
  EXPECT_LT(p90, 0.15f);
}

// The same rooms, a second bounce: the sides that gathered nothing in the first (the dark
// room, the sides facing into the walls or out of the rooms) are shut and not gathered again,
// and the lit room gathers what it gathers with every side gathering.
TEST_F(SurfelBounceRecords, SidesThatGatheredNothingAreShutInLaterBounces) {
  BounceGatherer bouncer(CutOptions{});
  std::vector<SurfelIrradiance> first(n), open(n), shut(n);
  CutStats stats;
  ASSERT_TRUE(bouncer.gather(*tree, *scene, surfels, kGroupSize, keys, 2, first, &stats).ok());
  // The second bounce from the same tree (what it gathers does not matter here, only whom).
  CutStats openStats, shutStats;
  uint64_t shutSides = 0;
  ASSERT_TRUE(bouncer.gather(*tree, *scene, surfels, kGroupSize, keys, 2, open, &openStats).ok());
  ASSERT_TRUE(bouncer
                  .gather(*tree, *scene, surfels, kGroupSize, keys, 2, shut, &shutStats, first,
                          &shutSides)
                  .ok());
  std::printf("[ measured ] %llu of %llu records' sides shut; cut pairs %llu against %llu\n",
              static_cast<unsigned long long>(shutSides),
              static_cast<unsigned long long>(openStats.receivers),
              static_cast<unsigned long long>(shutStats.pairs),
              static_cast<unsigned long long>(openStats.pairs));
  // The dark room's records (both sides) and the lit room's outward sides: over half.
  EXPECT_GT(2 * shutSides, openStats.receivers);
  EXPECT_EQ(shutStats.receivers + shutSides, openStats.receivers);
  double openSum = 0.0, shutSum = 0.0;
  for (size_t i = 0; i < n; ++i) {
    for (const bool front : {true, false}) {
      const Rgb& o = front ? open[i].front : open[i].back;
      const Rgb& s = front ? shut[i].front : shut[i].back;
      const Rgb& f = front ? first[i].front : first[i].back;
      if (isBlack(f)) {
        ASSERT_TRUE(isBlack(o) && isBlack(s)) << "surfel " << i;
      }
      openSum += luminance(o);
      shutSum += luminance(s);
    }
  }
  EXPECT_NEAR(shutSum / openSum, 1.0, 0.01);
}

// The second bounce probes the sides that gathered nothing: those that see a surface gather
// (the dark room's, and the sides facing into the wall between the rooms, which the first bounce
// found dark), and only those that see none (facing out of the closed rooms) stay shut. The light
// gathered is what every side gathering gathers.
TEST_F(SurfelBounceRecords, ASideThatSeesASurfaceIsGatheredAgainInTheSecondBounce) {
  BounceGatherer bouncer(CutOptions{});
  std::vector<SurfelIrradiance> first(n), open(n), probed(n), shut(n);
  CutStats stats, openStats, probedStats, shutStats;
  ASSERT_TRUE(bouncer.gather(*tree, *scene, surfels, kGroupSize, keys, 2, first, &stats).ok());
  ASSERT_TRUE(bouncer.gather(*tree, *scene, surfels, kGroupSize, keys, 2, open, &openStats).ok());
  uint64_t probedShut = 0, allShut = 0;
  ASSERT_TRUE(bouncer
                  .gather(*tree, *scene, surfels, kGroupSize, keys, 2, probed, &probedStats, first,
                          &probedShut, /*probeBlackSides=*/true)
                  .ok());
  ASSERT_TRUE(bouncer
                  .gather(*tree, *scene, surfels, kGroupSize, keys, 2, shut, &shutStats, first,
                          &allShut)
                  .ok());
  std::printf("[ measured ] black records' sides shut: %llu probed, %llu without probing, of %llu\n",
              static_cast<unsigned long long>(probedShut),
              static_cast<unsigned long long>(allShut),
              static_cast<unsigned long long>(openStats.receivers));
  EXPECT_GT(probedShut, 0u);
  EXPECT_LT(probedShut, allShut);
  EXPECT_EQ(probedStats.receivers + probedShut, openStats.receivers);
  // The light as every side gathering has it: the shut sides see nothing to gather.
  double openSum = 0.0, probedSum = 0.0;
  for (size_t i = 0; i < n; ++i) {
    openSum += luminance(open[i].front) + luminance(open[i].back);
    probedSum += luminance(probed[i].front) + luminance(probed[i].back);
  }
  EXPECT_NEAR(probedSum / openSum, 1.0, 0.01);
}

}  // namespace
}  // namespace pbgi
