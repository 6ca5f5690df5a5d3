// Farm tiles rendered as separate EXRs and assembled give the pixels of the frame rendered
// whole (what makes the farm's tiling invisible), and a missing or wrong tile fails the
// frame by name without writing it.

#include <gtest/gtest.h>

#include <filesystem>

#include "formats/image/image_io.h"
#include "formats/shot/shot_file.h"
#include "services/render/frame_assembly.h"
#include "services/render/frame_render.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

const fs::path kShot = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";

class FrameAssembly : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::makeTempDir("pbgi-assembly");
    auto shot = loadShotFile(kShot.string());
    ASSERT_TRUE(shot.ok()) << shot.status();
    shot_ = *shot;
    shot_.width = 40;
    shot_.height = 28;
  }
  void TearDown() override { fs::remove_all(dir_); }

  FrameRenderRequest request(const std::string& name) const {
    FrameRenderRequest r;
    r.frame = 1;
    r.overrides.integrator = "path";
    r.overrides.spp = 2;
    r.preview = false;
    r.outPath = (dir_ / (name + ".exr")).string();
    return r;
  }

  // Renders every farm tile of `tileSize` to its own EXR; returns the paths.
  std::vector<std::string> renderTiles(const std::vector<FarmTile>& tiles) {
    std::vector<std::string> paths;
    for (size_t i = 0; i < tiles.size(); ++i) {
      FrameRenderRequest r = request("tile" + std::to_string(i));
      r.regions = tiles[i];
      r.threads = 1;
      auto report = renderShotFrame(shot_, r);
      EXPECT_TRUE(report.ok()) << report.status();
      paths.push_back(r.outPath);
    }
    return paths;
  }

  // Renders the farm tiles of `tileSize`, swaps the files of tiles a and b and assembles them;
  // the frame must not be written. Returns the assembly's status.
  absl::Status assembleSwapped(int tileSize, size_t a, size_t b) {
    const std::vector<FarmTile> tiles = farmTiles(shot_, tileSize);
    std::vector<std::string> paths = renderTiles(tiles);
    std::swap(paths[a], paths[b]);
    const std::string out = (dir_ / "frame.exr").string();
    const absl::Status s = assembleFrame(paths, tiles, shot_.width, shot_.height, out).status();
    EXPECT_FALSE(fs::exists(out));
    return s;
  }

  fs::path dir_;
  ShotDesc shot_;
};

TEST_F(FrameAssembly, AssembledTilesAreTheWholeFrameBitForBit) {
  const FrameRenderRequest whole = request("whole");
  ASSERT_TRUE(renderShotFrame(shot_, whole).ok());
  const std::vector<FarmTile> tiles = farmTiles(shot_, 16);
  ASSERT_EQ(tiles.size(), 6u);  // 3 x 2, ragged at the right and bottom
  const std::vector<std::string> paths = renderTiles(tiles);
  auto tile0 = readImage(paths[0]);
  ASSERT_TRUE(tile0.ok()) << tile0.status();
  EXPECT_EQ(tile0->width(), 16);
  EXPECT_EQ(tile0->height(), 16);
  // Each tile is an image of its own size whose data window is its place in the frame.
  for (size_t i = 0; i < tiles.size(); ++i) {
    auto tile = readImage(paths[i]);
    ASSERT_TRUE(tile.ok()) << tile.status();
    const TileRect& r = tiles[i][0];
    EXPECT_EQ(tile->width(), r.width());
    EXPECT_EQ(tile->height(), r.height());
    EXPECT_EQ(tile->window(), (ImageWindow{r.x0, r.y0, shot_.width, shot_.height})) << i;
  }

  const std::string out = (dir_ / "assembled.exr").string();
  ASSERT_TRUE(assembleFrame(paths, tiles, shot_.width, shot_.height, out).ok());
  auto a = readImage(out);
  auto b = readImage(whole.outPath);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->channels(), b->channels());
  ASSERT_EQ(a->pixels().size(), b->pixels().size());
  EXPECT_TRUE(a->pixels() == b->pixels());
}

TEST_F(FrameAssembly, AMissingTileFailsTheFrameByName) {
  const std::vector<FarmTile> tiles = farmTiles(shot_, 20);
  std::vector<std::string> paths = renderTiles(tiles);
  fs::remove(paths[2]);
  const std::string out = (dir_ / "frame.exr").string();
  const absl::Status s = assembleFrame(paths, tiles, shot_.width, shot_.height, out).status();
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound) << s;
  EXPECT_NE(s.message().find("tile 2"), std::string::npos) << s;
  EXPECT_NE(s.message().find(paths[2]), std::string::npos) << s;
  EXPECT_FALSE(fs::exists(out));
}

TEST_F(FrameAssembly, ATileOfTheWrongSizeFailsTheFrame) {
  // 2 x 2 tiles in Morton order: 0 and 1 are 20 x 20, 2 and 3 are 20 x 8 (the bottom row).
  const absl::Status s = assembleSwapped(20, 0, 2);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
}

TEST_F(FrameAssembly, ATileOfTheRightSizeInTheWrongPlaceFailsTheFrame) {
  // Tiles 0 and 1 are both 16 x 16, at x 0 and x 16: only their data windows tell them apart.
  const absl::Status s = assembleSwapped(16, 0, 1);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_NE(s.message().find("tile 0"), std::string::npos) << s;
  EXPECT_NE(s.message().find("data window starts at (16, 0)"), std::string::npos) << s;
}

TEST(FarmRegion, TextRoundTripsAndBadTextIsRejected) {
  const TileRect r{16, 32, 48, 40};
  auto back = parseRegion(regionText(r));
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->x0, 16);
  EXPECT_EQ(back->y1, 40);
  for (const char* bad : {"", "1 2 3", "0 0 0 4", "4 0 2 8", "0 0 4 4 extra", "a b c d"}) {
    EXPECT_FALSE(parseRegion(bad).ok()) << bad;
  }
}

}  // namespace
}  // namespace pbgi

namespace pbgi {
namespace {

TEST_F(FrameAssembly, CroppingAFrameToATilesRegionsGivesTheTilesPixels) {
  // A camera array of 2x1 views: a farm tile is one square in each view, stacked in its EXR.
  shot_.camera.views = {2, 1};
  const FrameRenderRequest whole = request("whole");
  ASSERT_TRUE(renderShotFrame(shot_, whole).ok());
  auto frame = readImage(whole.outPath);
  ASSERT_TRUE(frame.ok()) << frame.status();
  const std::vector<FarmTile> tiles = farmTiles(shot_, 16);
  ASSERT_EQ(tiles[4].size(), 2u);
  const std::vector<std::string> paths = renderTiles({tiles[4]});
  auto tile = readImage(paths[0]);
  ASSERT_TRUE(tile.ok()) << tile.status();
  auto crop = cropRegions(*frame, tiles[4]);
  ASSERT_TRUE(crop.ok()) << crop.status();
  ASSERT_EQ(crop->width(), tile->width());
  ASSERT_EQ(crop->height(), tile->height());
  ASSERT_EQ(crop->channels(), tile->channels());
  EXPECT_EQ(crop->pixels(), tile->pixels());
  // A rectangle outside the frame is refused by name.
  auto outside = cropRegions(*frame, {TileRect{70, 0, 90, 8}});
  EXPECT_EQ(outside.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(outside.status().message().find("70 0 90 8"), std::string::npos) << outside.status();
}

}  // namespace
}  // namespace pbgi
