// The PBGI integrator's accuracy on the dev scenes (the Cornell box and Sponza of
// ../shared/scenes), at a small size: the default preset through the bidirectional cut (the
// product's default) against the path tracer at high spp, on the image and on its indirect
// light alone, the layer PBGI computes. The bounds hold the bias that matters (the mean
// indirect light, which the tail estimate and two-sided surfels exist to get right) and the
// error as a whole; the same image without its indirect light fails them, so the test can tell.

#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <string>

#include "formats/image/compare.h"
#include "formats/image/image_io.h"
#include "formats/shot/shot_file.h"
#include "services/render/frame_render.h"
#include "tests/support/params.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

struct Case {
  const char* shot;     // under the shared scenes
  int width, height;
  uint64_t bakePoints;
  int bakeBounces;
  double indirectBias;  // |mean indirect / reference's - 1|, each channel
  double relMse;        // of the whole image
};

Image render(const ShotDesc& shot, FrameRenderRequest r) {
  auto report = renderShotFrame(shot, r);
  EXPECT_TRUE(report.ok()) << report.status();
  if (!report.ok()) return Image();
  auto image = readImage(r.outPath);
  EXPECT_TRUE(image.ok()) << image.status();
  return image.ok() ? *image : Image();
}

void expectAccurate(const Case& c) {
  PBGI_REQUIRE_SHARED_SCENES(scenes);
  auto loaded = loadShotFile((scenes / c.shot).string());
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  ShotDesc shot = *loaded;
  shot.width = c.width;
  shot.height = c.height;
  const fs::path dir = testing::makeTempDir("pbgi-accuracy");

  FrameRenderRequest p;
  p.frame = shot.firstFrame;
  p.integrator = "path";
  p.spp = 1024;
  p.preview = false;
  p.outPath = (dir / "path.exr").string();
  const Image path = render(shot, p);

  FrameRenderRequest g = p;
  g.integrator = "pbgi";
  g.spp = 16;
  g.outPath = (dir / "pbgi.exr").string();
  g.bakeDir = (dir / "bake").string();
  g.params = IntegratorParams();
  testing::setParam(g.params, "gather", "bidirectional");
  testing::setParam(g.params, "quality", "default");
  testing::setParam(g.params, "bake_points", std::to_string(c.bakePoints));
  testing::setParam(g.params, "bake_bounces", std::to_string(c.bakeBounces));
  const Image pbgi = render(shot, g);
  ASSERT_GT(path.width(), 0);
  ASSERT_GT(pbgi.width(), 0);

  const auto mp = meanRgb(pbgi, "indirect.R"), mr = meanRgb(path, "indirect.R");
  for (int ch = 0; ch < 3; ++ch) {
    EXPECT_NEAR(mp[ch] / mr[ch], 1.0, c.indirectBias)
        << c.shot << " mean indirect, channel " << ch << ": " << mp[ch] << " against " << mr[ch];
  }
  auto m = compareImages(pbgi, path);
  ASSERT_TRUE(m.ok()) << m.status();
  std::printf("%s %dx%d, %llu surfels: relMSE %.4g, mean indirect / reference %.4f %.4f %.4f\n",
              c.shot, c.width, c.height, static_cast<unsigned long long>(c.bakePoints), m->relMse,
              mp[0] / mr[0], mp[1] / mr[1], mp[2] / mr[2]);
  EXPECT_LT(m->relMse, c.relMse);

  // Without its indirect light the image fails the bound: the bound can tell.
  Image directOnly = pbgi;
  const int r0 = pbgi.channelIndex("R"), d0 = pbgi.channelIndex("direct.R");
  for (int y = 0; y < pbgi.height(); ++y)
    for (int x = 0; x < pbgi.width(); ++x)
      for (int ch = 0; ch < 3; ++ch) directOnly.at(x, y, r0 + ch) = pbgi.at(x, y, d0 + ch);
  auto without = compareImages(directOnly, path);
  ASSERT_TRUE(without.ok());
  EXPECT_GT(without->relMse, c.relMse);
  fs::remove_all(dir);
}

// Measured: mean indirect 0.964 / 0.967 / 0.978 of the path tracer's, relMSE 8.7e-4.
TEST(PbgiAccuracy, CornellBoxDefaultPresetMatchesThePathTracer) {
  expectAccurate({"cornell-box/cornell.shot.toml", 64, 64, 60000, 3, 0.04, 0.01});
}

// 100,000 surfels are coarse for Sponza (a radius of 15 cm): its mean indirect light measured
// 0.876 / 0.887 / 0.899 of the path tracer's here, relMSE 0.01155 (0.863 / 0.881 / 0.901 and
// 0.01135 before stop 22 changed how the cut treats near surfels and light no surfel sends:
// transfer_bench shows each change; at the dev shot's 1M surfels they lowered the indirect
// light's relMSE by 12 %). What is left is lost where surfels pass light to surfels one to
// four radii from other geometry (transfer_bench --light bounce --brute); 250,000 surfels
// lose less. The bound holds this bake's bias; accuracy_bench reports the product's.
TEST(PbgiAccuracy, SponzaDefaultPresetMatchesThePathTracer) {
  expectAccurate({"sponza/sponza.shot.toml", 80, 45, 100000, 3, 0.14, 0.05});
}

}  // namespace
}  // namespace pbgi
