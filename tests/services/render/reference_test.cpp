// The path tracer against an independent renderer: Blender Cycles ground truths (4096 spp,
// box filter, 64 bounces) in ../shared/scenes. The image mean is the integral of radiance over
// the image plane, so a smaller image with more samples per pixel estimates the same number.

#include <gtest/gtest.h>

#include "formats/image/image_io.h"
#include "formats/shot/shot_file.h"
#include "services/render/frame_render.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

std::array<double, 3> channelMeans(const Image& image) {
  std::array<double, 3> sum{0, 0, 0};
  const int r = image.channelIndex("R");
  for (int y = 0; y < image.height(); ++y)
    for (int x = 0; x < image.width(); ++x)
      for (int c = 0; c < 3; ++c) sum[c] += image.at(x, y, r + c);
  for (double& s : sum) s /= static_cast<double>(image.width()) * image.height();
  return sum;
}

void expectMeansMatchCycles(const std::filesystem::path& shotPath,
                            const std::filesystem::path& referencePath, int width, int height,
                            int spp) {
  auto shot = loadShotFile(shotPath.string());
  ASSERT_TRUE(shot.ok()) << shot.status();
  shot->width = width;
  shot->height = height;
  const auto dir = testing::makeTempDir("reference");
  FrameRenderRequest request;
  request.frame = shot->firstFrame;
  request.overrides.integrator = "path";
  request.overrides.spp = spp;
  request.outPath = (dir / "render.exr").string();
  request.preview = false;
  auto report = renderShotFrame(*shot, request);
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_EQ(report->counters.discardedSamples, 0u);
  auto ours = readImage(request.outPath);
  ASSERT_TRUE(ours.ok()) << ours.status();
  auto reference = readImage(referencePath.string());
  ASSERT_TRUE(reference.ok()) << reference.status();
  const auto a = channelMeans(*ours);
  const auto b = channelMeans(*reference);
  for (int c = 0; c < 3; ++c) {
    EXPECT_NEAR(a[c], b[c], 0.01 * b[c]) << "channel " << c << ": ours " << a[c] << ", Cycles " << b[c];
  }
  std::filesystem::remove_all(dir);
}

TEST(ReferenceTest, CornellBoxMeansMatchCycles) {
  PBGI_REQUIRE_SHARED_SCENES(scenes);
  expectMeansMatchCycles(scenes / "cornell-box/cornell.shot.toml",
                         scenes / "cornell-box/cornell.cycles-4096spp.exr", 64, 64, 512);
}

TEST(ReferenceTest, SponzaMeansMatchCycles) {
  PBGI_REQUIRE_SHARED_SCENES(scenes);
  expectMeansMatchCycles(scenes / "sponza/sponza.shot.toml",
                         scenes / "sponza/sponza.cycles-4096spp.exr", 64, 36, 256);
}

}  // namespace
}  // namespace pbgi
