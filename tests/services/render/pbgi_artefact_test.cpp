// PBGI's own artefacts at a real image size: patches, seams at the cut blocks' borders, and
// light missing where a room is lit by bounced light alone. The uplit room of the scene suite
// (config/scenes/uplit-room) at its 256 x 256, 16 spp, the default preset and the shot's own
// bake, so that the cut runs many blocks and receiver clusters as a user's render does.
//
// Patches and seams come from how the cut shares light between records (its receiver clusters,
// its blocks), not from the camera samples' noise, so they are measured without a converged
// reference: the same frame rendered with blocks of another size (48 pixels) has its receiver
// clusters and its block borders elsewhere, and whatever the two disagree on at low frequency,
// or steps across the 64-pixel borders, is the cut's structure showing. The light's level is
// measured against the path tracer, over each half of the frame (its noise averages out over
// so many pixels).

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>

#include "formats/image/compare.h"
#include "formats/image/image_io.h"
#include "formats/shot/shot_file.h"
#include "services/bake/frame_bake.h"
#include "services/render/frame_render.h"
#include "tests/support/params.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

class PbgiArtefacts : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new fs::path(testing::makeTempDir("pbgi-artefacts"));
    auto shot = loadShotFile(
        (testing::sourceDir() / "config/scenes/uplit-room/uplit-room.shot.toml").string());
    ASSERT_TRUE(shot.ok()) << shot.status();
    shot_ = new ShotDesc(*shot);
    ASSERT_EQ(shot_->width, 256);
    ASSERT_EQ(shot_->height, 256);
    // The shot's own bake: its surfels, bounces and bounce gathers.
    auto request = shotBakeRequest(*shot_, 1);
    ASSERT_TRUE(request.ok()) << request.status();
    request->outDir = (*dir_ / "bake").string();
    request->pointCloud = PointCloudMode::kNever;
    auto report = bakeShotFrame(*shot_, *request);
    ASSERT_TRUE(report.ok()) << report.status();
    tree_ = new std::string(report->treePath);
  }
  static void TearDownTestSuite() {
    fs::remove_all(*dir_);
    delete dir_;
    delete shot_;
    delete tree_;
  }

  // The shot as it stands (PBGI, default preset, 16 spp), with `params` on top.
  static Image render(const std::string& name, const std::string& integrator, int spp,
                      const std::vector<std::pair<std::string, std::string>>& params = {}) {
    FrameRenderRequest r;
    r.frame = 1;
    r.overrides.integrator = integrator;
    r.overrides.spp = spp;
    for (const auto& [key, value] : params) testing::setParam(r.overrides.params, key, value);
    r.treePath = integrator == "pbgi" ? *tree_ : std::string();
    r.preview = false;
    r.outPath = (*dir_ / (name + ".exr")).string();
    auto report = renderShotFrame(*shot_, r);
    EXPECT_TRUE(report.ok()) << report.status();
    if (!report.ok()) return Image();
    auto image = readImage(r.outPath);
    EXPECT_TRUE(image.ok()) << image.status();
    return image.ok() ? *image : Image();
  }

  static fs::path* dir_;
  static ShotDesc* shot_;
  static std::string* tree_;
};

fs::path* PbgiArtefacts::dir_ = nullptr;
ShotDesc* PbgiArtefacts::shot_ = nullptr;
std::string* PbgiArtefacts::tree_ = nullptr;

// The mean of R, G and B over columns [x0, x1) of every row.
double meanOver(const Image& image, int x0, int x1) {
  double sum = 0.0;
  for (int y = 0; y < image.height(); ++y) {
    for (int x = x0; x < x1; ++x) {
      for (int c = 0; c < 3; ++c) sum += image.at(x, y, c);
    }
  }
  return sum / (3.0 * image.height() * (x1 - x0));
}

// No patches, no seams: two renders whose receiver clusters and blocks lie differently agree at
// low frequency (7 x 7 blur) within 2e-4, and their difference steps across the 64-pixel
// borders no more than elsewhere (1.2x). A cut that decides a cluster's light for a whole
// receiver cluster at once fails both: its patches are the clusters' size and its blocks'
// clusters end at their borders.
TEST_F(PbgiArtefacts, RecordsShowNoPatchesOrSeamsWhereverTheBlocksLie) {
  const Image a = render("blocks64", "pbgi", 16);
  const Image b = render("blocks48", "pbgi", 16, {{"cut_block", "48"}});
  ASSERT_EQ(a.width(), 256);
  const absl::StatusOr<ImageMetrics> m = compareImages(a, b, nullptr, {.blockSize = 64});
  ASSERT_TRUE(m.ok()) << m.status();
  std::printf("[ measured ] 64- against 48-pixel blocks: relMSE %.3g, low-frequency relMSE %.3g, "
              "seam step ratio %.3f\n",
              m->relMse, m->lowFrequencyRelMse, m->seamStepRatio);
  EXPECT_LT(m->lowFrequencyRelMse, 2e-4);
  EXPECT_LT(m->seamStepRatio, 1.2);
}

// The light of a room lit by bounced light alone is all there, away from its light too: the
// half of the frame away from the torchiere (the sofa, the table, the shelf) within 3 % of the
// path tracer's, as the half under it. A bake that stops gathering on the sides of surfels that
// saw no lit surface in its first bounce (under the table, behind the sofa) leaves the later
// bounces' light out there.
TEST_F(PbgiArtefacts, TheRoomAwayFromItsLightGetsAllItsBouncedLight) {
  const Image pbgi = render("pbgi", "pbgi", 16);
  const Image path = render("path", "path", 64);
  ASSERT_EQ(pbgi.width(), path.width());
  const int w = pbgi.width();
  const double away = meanOver(pbgi, 0, w / 2) / meanOver(path, 0, w / 2);
  const double near = meanOver(pbgi, w / 2, w) / meanOver(path, w / 2, w);
  std::printf("[ measured ] PBGI / path tracer: the half away from the light %.4f, the half "
              "under it %.4f\n",
              away, near);
  EXPECT_NEAR(away, 1.0, 0.03);
  EXPECT_NEAR(near, 1.0, 0.03);
}

}  // namespace
}  // namespace pbgi
