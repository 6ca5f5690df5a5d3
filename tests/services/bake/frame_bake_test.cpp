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

}  // namespace
}  // namespace pbgi
