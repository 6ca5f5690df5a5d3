// What the coordinator and workers agree on without asking: here, which tiles a frame's
// accuracy audit path traces.

#include <gtest/gtest.h>

#include <set>

#include "services/farm/job_rules.h"

namespace pbgi::farm {
namespace {

TEST(AuditTiles, TheSeededRuleIsStableDistinctInRangeAndSpreadsOverFrames) {
  const std::vector<int> a = chooseAuditTiles("sponza", 12, 64, 3);
  EXPECT_EQ(a, chooseAuditTiles("sponza", 12, 64, 3));  // the same wherever it is asked
  ASSERT_EQ(a.size(), 3u);
  EXPECT_TRUE(std::is_sorted(a.begin(), a.end()));
  EXPECT_EQ(std::set<int>(a.begin(), a.end()).size(), 3u);
  for (const int t : a) EXPECT_TRUE(t >= 0 && t < 64) << t;
  // Other frames and shots audit other tiles: over 40 frames, most of a 64-tile frame is seen.
  std::set<int> seen;
  for (int f = 1; f <= 40; ++f) {
    for (const int t : chooseAuditTiles("sponza", f, 64, 2)) seen.insert(t);
  }
  EXPECT_GT(seen.size(), 40u);
  EXPECT_NE(chooseAuditTiles("other", 12, 64, 3), a);
  // As many tiles as the frame has, or more: all of them; none asked: none.
  EXPECT_EQ(chooseAuditTiles("sponza", 1, 4, 9), (std::vector<int>{0, 1, 2, 3}));
  EXPECT_TRUE(chooseAuditTiles("sponza", 1, 4, 0).empty());
}

TEST(AuditTiles, AnAuditRendersTheCentralWindowOfEachOfATilesRectangles) {
  // A 256-pixel tile in two views, and a ragged 40x20 one: the centre 64x64, or all of it.
  EXPECT_EQ(auditWindows({{0, 0, 256, 256}, {512, 0, 768, 256}}),
            (std::vector<TileRect>{{96, 96, 160, 160}, {608, 96, 672, 160}}));
  EXPECT_EQ(auditWindows({{256, 512, 296, 532}}), (std::vector<TileRect>{{256, 512, 296, 532}}));
}

}  // namespace
}  // namespace pbgi::farm
