// A frame's bake as `pbgi bake` and `pbgi render` run it: the determinism the farm relies on,
// a tree whose bytes do not depend on the thread count.

#include <gtest/gtest.h>

#include <filesystem>

#include <fmt/format.h>
#include "formats/shot/shot_file.h"

#include "core/bake/multi_bounce.h"
#include "services/bake/frame_bake.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

// Enough surfels for two bounce batches (kBounceBatchSurfels) of many cut groups each, and a
// budget small enough that the groups sweeping together follow the thread count (one or two):
// what the batches hold, which cuts share a sweep and which thread runs them may change, the
// tree's bytes may not.
TEST(FrameBake, TheTreeIsByteIdenticalAtOneAndTwoThreads) {
  const fs::path dir = testing::makeTempDir("bake-threads");
  auto shot =
      loadShotFile((testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml").string());
  ASSERT_TRUE(shot.ok()) << shot.status();
  std::string trees[2];
  for (const int threads : {1, 2}) {
    auto request = shotBakeRequest(*shot, 1);
    ASSERT_TRUE(request.ok()) << request.status();
    request->outDir = (dir / fmt::format("threads{}", threads)).string();
    request->points = kBounceBatchSurfels + 12'000;
    request->bounces = 2;
    request->memoryBudget = size_t{128} << 20;
    request->threads = threads;
    request->pointCloud = PointCloudMode::kNever;
    auto report = bakeShotFrame(*shot, *request);
    ASSERT_TRUE(report.ok()) << report.status();
    trees[threads - 1] = testing::slurpFile(report->treePath);
  }
  ASSERT_FALSE(trees[0].empty());
  EXPECT_EQ(trees[0].size(), trees[1].size());
  EXPECT_TRUE(trees[0] == trees[1]) << "the trees differ";
  fs::remove_all(dir);
}

// Glossy leaves gather by pair refinement only when asked (bake --glossy-pairs): then the
// bounces' and the final tree's glossy leaves share splats in groups, the same tree at one and
// two threads, and the bake's hash tells the two bakes apart. A threshold out of range is
// refused before any work.
TEST(FrameBake, GlossyPairsAreAskedForAndDeterministic) {
  const fs::path dir = testing::makeTempDir("bake-glossy-pairs");
  auto shot = loadShotFile(
      (testing::sourceDir() / "config/scenes/glossy-cornell/glossy-cornell.shot.toml").string());
  ASSERT_TRUE(shot.ok()) << shot.status();
  auto request = shotBakeRequest(*shot, 1);
  ASSERT_TRUE(request.ok()) << request.status();
  request->points = 20'000;
  request->bounces = 1;
  request->pointCloud = PointCloudMode::kNever;
  const uint64_t aloneHash = bakeHash(*shot, *request);
  request->outDir = (dir / "alone").string();
  auto alone = bakeShotFrame(*shot, *request);
  ASSERT_TRUE(alone.ok()) << alone.status();
  EXPECT_EQ(alone->glossyPairs.receivers, 0u);
  request->glossyPairThreshold = 0.004f;
  EXPECT_NE(bakeHash(*shot, *request), aloneHash);
  std::string trees[2];
  for (const int threads : {1, 2}) {
    request->threads = threads;
    request->outDir = (dir / fmt::format("pairs{}", threads)).string();
    auto report = bakeShotFrame(*shot, *request);
    ASSERT_TRUE(report.ok()) << report.status();
    EXPECT_GT(report->glossyPairs.receivers, 0u);
    EXPECT_GT(report->glossyPairs.groupSplats, 0u);
    EXPECT_GT(report->glossyPairs.splatsServed, report->glossyPairs.groupSplats);
    trees[threads - 1] = testing::slurpFile(report->treePath);
  }
  ASSERT_FALSE(trees[0].empty());
  EXPECT_TRUE(trees[0] == trees[1]) << "the trees differ";
  request->glossyPairThreshold = -1.0f;
  auto bad = bakeShotFrame(*shot, *request);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(bad.status().message().find("glossy pairs"), std::string_view::npos) << bad.status();
  fs::remove_all(dir);
}

}  // namespace
}  // namespace pbgi
