// The PBGI integrator's accuracy on the dev scenes (the Cornell box and Sponza of
// ../shared/scenes), at a small size: the default preset through the bidirectional cut (the
// product's default) against the path tracer at high spp, on the image and on its indirect
// light alone, the layer PBGI computes. The bounds hold the bias that matters (the mean
// indirect light, which the tail estimate and two-sided surfels exist to get right) and the
// error as a whole; the same image without its indirect light fails them, so the test can tell.

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

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
  const char* shot;     // under the shared scenes, or under config/scenes when inRepo
  int width, height;
  uint64_t bakePoints;
  int bakeBounces;
  double indirectBias;  // |mean indirect / reference's - 1|, each channel
  double relMse;        // of the whole image
  bool inRepo = false;
  int referenceSpp = 1024;  // the path tracer's
};

Image render(const ShotDesc& shot, FrameRenderRequest r) {
  auto report = renderShotFrame(shot, r);
  EXPECT_TRUE(report.ok()) << report.status();
  if (!report.ok()) return Image();
  auto image = readImage(r.outPath);
  EXPECT_TRUE(image.ok()) << image.status();
  return image.ok() ? *image : Image();
}

Image renderPath(const ShotDesc& shot, const fs::path& dir, int spp) {
  FrameRenderRequest p;
  p.frame = shot.firstFrame;
  p.overrides.integrator = "path";
  p.overrides.spp = spp;
  p.preview = false;
  p.outPath = (dir / "path.exr").string();
  return render(shot, p);
}

Image renderPbgi(const ShotDesc& shot, const fs::path& dir, uint64_t bakePoints, int bounces) {
  FrameRenderRequest g;
  g.frame = shot.firstFrame;
  g.overrides.integrator = "pbgi";
  g.overrides.spp = 16;
  g.preview = false;
  g.outPath = (dir / "pbgi.exr").string();
  g.bakeDir = (dir / "bake").string();
  testing::setParam(g.overrides.params, "gather", "bidirectional");
  testing::setParam(g.overrides.params, "quality", "default");
  testing::setParam(g.overrides.params, "bake_points", std::to_string(bakePoints));
  testing::setParam(g.overrides.params, "bake_bounces", std::to_string(bounces));
  return render(shot, g);
}

void expectAccurate(const Case& c) {
  fs::path scenes = testing::sourceDir() / "config" / "scenes";
  if (!c.inRepo) {
    PBGI_REQUIRE_SHARED_SCENES(shared);
    scenes = shared;
  }
  auto loaded = loadShotFile((scenes / c.shot).string());
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  ShotDesc shot = *loaded;
  shot.width = c.width;
  shot.height = c.height;
  const fs::path dir = testing::makeTempDir("pbgi-accuracy");

  const Image path = renderPath(shot, dir, c.referenceSpp);
  const Image pbgi = renderPbgi(shot, dir, c.bakePoints, c.bakeBounces);
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

// The Cornell box at the default preset with its bake's bounces gathered at records: the mean
// indirect light within 3 % of the path tracer's, and the cut's descent corrections are what keep
// it inside (without them a coarse cluster drops light its children send).
TEST(PbgiAccuracy, CornellBoxDefaultPresetMatchesThePathTracer) {
  expectAccurate({"cornell-box/cornell.shot.toml", 64, 64, 60000, 3, 0.03, 0.01});
}

// 100,000 surfels are coarse for Sponza (a radius of 15 cm): light is lost where surfels pass it
// to surfels one to four radii from other geometry (transfer_bench --light bounce --brute shows
// it), so the bound on the mean indirect light is 12 %: it holds this small bake's bias, and
// accuracy_bench reports the product's at the shot's own bake. The path tracer's reference is
// 512 spp, its noise far inside the bounds.
TEST(PbgiAccuracy, SponzaDefaultPresetMatchesThePathTracer) {
  expectAccurate({"sponza/sponza.shot.toml", 80, 45, 100000, 3, 0.12, 0.05, false, 512});
}

// The glossy Cornell box: most of the light reaches the walls by way of the two GGX blocks, which
// the tree carries as wavelets; without them the walls get less than half their indirect light.
// A glossy leaf's estimate in the cut's descent stays its wavelet's (its surfels' diffuse
// estimates lose a seventh of the light).
TEST(PbgiAccuracy, GlossyCornellBoxCarriesTheBlocksLight) {
  // Against a 512-spp reference, whose noise is far inside the bounds.
  expectAccurate({"glossy-cornell/glossy-cornell.shot.toml", 64, 64, 60000, 3, 0.07,
                  0.05, true, 512});
}

// A glossy bounce: a glossy plate (GGX 0.15) tilted under a sphere light sends the
// light's reflection onto the wall in front of it, a spot that is all of the wall's indirect
// light (the floor is black). PBGI carries it through the plate's glossy surfels, whose light
// leaves as wavelets (their direct light, and each bounce's light they reflect), and the wall's
// gather: the wall's mean indirect light within 5 % of the path tracer's. Measured: 1.018,
// and the wall's lower two thirds 4.9 times as bright as its top third (path tracer: 4.3).
TEST(PbgiAccuracy, AGlossyPlateLightsTheWallInFrontOfIt) {
  const fs::path dir = testing::makeTempDir("pbgi-glossy-bounce");
  {
    std::ofstream obj(dir / "plate.obj");
    obj << "mtllib none.mtl\n"
           "usemtl floor\n"  // y = 0
           "v -3 0 -3\nv -3 0 3\nv 3 0 3\nv 3 0 -3\nf 1 2 3\nf 1 3 4\n"
           "usemtl wall\n"  // z = 2, facing the camera
           "v -3 0 2\nv -3 4 2\nv 3 4 2\nv 3 0 2\nf 5 6 7\nf 5 7 8\n"
           // A 1.4 m plate at 45 degrees, its top's normal (0, 1, 1) / sqrt 2: light from
           // straight above leaves it towards +z, onto the wall.
           "usemtl plate\n"
           "v -0.7 0.3 0.8\nv 0.7 0.3 0.8\nv 0.7 1.29 -0.19\nv -0.7 1.29 -0.19\n"
           "f 9 10 11\nf 9 11 12\n";
  }
  {
    std::ofstream toml(dir / "plate.shot.toml");
    toml << "version = 1\n"
            "[shot]\nname = \"glossy-bounce\"\nframes = [1, 1]\nresolution = [64, 48]\n"
            "output = \"out/plate.####.exr\"\n"
            "[camera]\nposition = [0.0, 3.5, -5.0]\nlook_at = [0.0, 1.2, 2.0]\n"
            "up = [0.0, 1.0, 0.0]\nfov_y_deg = 45.0\n"
            "[[geometry]]\nfile = \"plate.obj\"\n"
            "[[material]]\nname = \"floor\"\ntype = \"diffuse\"\nalbedo = [0.0, 0.0, 0.0]\n"
            "[[material]]\nname = \"wall\"\ntype = \"diffuse\"\nalbedo = [0.7, 0.7, 0.7]\n"
            "[[material]]\nname = \"plate\"\ntype = \"conductor\"\nroughness = 0.15\n"
            "specular = [0.95, 0.93, 0.88]\n"
            "[[light]]\ntype = \"sphere\"\ncenter = [0.0, 4.0, 0.3]\nradius = 0.2\n"
            "radiance = [60.0, 60.0, 60.0]\n";
  }
  auto loaded = loadShotFile((dir / "plate.shot.toml").string());
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  const ShotDesc shot = *loaded;
  const Image path = renderPath(shot, dir, 512);
  const Image pbgi = renderPbgi(shot, dir, 60000, 3);
  ASSERT_GT(path.width(), 0);
  ASSERT_GT(pbgi.width(), 0);
  // The wall's pixels (by their albedo), and their top third and the rest: the spot is low.
  const int a0 = pbgi.channelIndex("albedo.R"), i0 = pbgi.channelIndex("indirect.R");
  double got = 0.0, want = 0.0;
  std::array<double, 2> half = {0.0, 0.0}, pathHalf = {0.0, 0.0};
  std::array<int, 2> halfPixels = {0, 0};
  int pixels = 0;
  for (int y = 0; y < pbgi.height(); ++y) {
    for (int x = 0; x < pbgi.width(); ++x) {
      if (std::abs(pbgi.at(x, y, a0) - 0.7f) > 1e-4f || std::abs(path.at(x, y, a0) - 0.7f) > 1e-4f)
        continue;
      ++pixels;
      const int lower = y >= pbgi.height() / 3 ? 1 : 0;
      ++halfPixels[lower];
      for (int c = 0; c < 3; ++c) {
        got += pbgi.at(x, y, i0 + c);
        want += path.at(x, y, i0 + c);
        half[lower] += pbgi.at(x, y, i0 + c);
        pathHalf[lower] += path.at(x, y, i0 + c);
      }
    }
  }
  ASSERT_GT(pixels, 300);
  ASSERT_GT(halfPixels[0], 50);
  const double contrast = half[1] / half[0] * halfPixels[0] / halfPixels[1];
  const double pathContrast = pathHalf[1] / pathHalf[0] * halfPixels[0] / halfPixels[1];
  std::printf(
      "wall in front of a glossy plate (%d pixels): mean indirect %.4f of the path "
      "tracer's; its lower part %.1f times as bright as its top (path tracer %.1f)\n",
      pixels, got / want, contrast, pathContrast);
  EXPECT_GT(contrast, 3.0);  // the spot, in both
  EXPECT_GT(pathContrast, 3.0);
  EXPECT_NEAR(got / want, 1.0, 0.05);
  fs::remove_all(dir);
}

// The luminance-weighted centroid, in pixels, of the indirect light above 0.6 of its peak in
// a window (after a 3 x 3 box filter, which quiets the path tracer's caustic noise).
struct Blob {
  double x = 0.0, y = 0.0, peak = 0.0, inside = 0.0, outside = 0.0;
};

Blob brightBlob(const Image& image, int x0, int y0, int x1, int y1) {
  const int r = image.channelIndex("indirect.R");
  auto lum = [&](int x, int y) {
    return 0.2126 * image.at(x, y, r) + 0.7152 * image.at(x, y, r + 1) +
           0.0722 * image.at(x, y, r + 2);
  };
  std::vector<double> box;
  for (int y = y0; y < y1; ++y) {
    for (int x = x0; x < x1; ++x) {
      double sum = 0.0;
      int n = 0;
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int xx = x + dx, yy = y + dy;
          if (xx < 0 || yy < 0 || xx >= image.width() || yy >= image.height()) continue;
          sum += lum(xx, yy);
          ++n;
        }
      box.push_back(sum / n);
    }
  }
  Blob b;
  for (double v : box) b.peak = std::max(b.peak, v);
  double weight = 0.0;
  size_t in = 0, out = 0;
  for (int y = y0, k = 0; y < y1; ++y) {
    for (int x = x0; x < x1; ++x, ++k) {
      if (box[k] >= 0.6 * b.peak) {
        b.x += x * box[k];
        b.y += y * box[k];
        weight += box[k];
        b.inside += box[k];
        ++in;
      } else {
        b.outside += box[k];
        ++out;
      }
    }
  }
  b.x /= weight;
  b.y /= weight;
  b.inside /= std::max<size_t>(in, 1);
  b.outside /= std::max<size_t>(out, 1);
  return b;
}

// A smooth glass sphere's caustic: light the sphere focuses on the floor in its own shadow,
// which reaches the tree through the glass surfels' specular chains. PBGI puts it where the
// path tracer does, as bright. Measured: centroid (26.99, 29.98) against (28.98, 28.97).
TEST(PbgiAccuracy, ACausticUnderAGlassSphereLandsWhereThePathTracerPutsIt) {
  auto loaded =
      loadShotFile((testing::sourceDir() / "config/scenes/glass-caustic/caustic.shot.toml").string());
  ASSERT_TRUE(loaded.ok()) << loaded.status();
  ShotDesc shot = *loaded;
  shot.width = 64;
  shot.height = 48;
  const fs::path dir = testing::makeTempDir("pbgi-caustic");
  const Image path = renderPath(shot, dir, 4096);
  const Image pbgi = renderPbgi(shot, dir, 100000, 1);
  ASSERT_GT(path.width(), 0);
  ASSERT_GT(pbgi.width(), 0);
  // The floor in front of the sphere's foot, where the caustic lies (rows 28 to 39 of 48).
  const int x0 = 16, x1 = 48, y0 = 28, y1 = 40;
  const Blob want = brightBlob(path, x0, y0, x1, y1);
  const Blob got = brightBlob(pbgi, x0, y0, x1, y1);
  std::printf("caustic centroid: path tracer (%.2f, %.2f) peak %.3g contrast %.2f; PBGI (%.2f, "
              "%.2f) peak %.3g contrast %.2f\n",
              want.x, want.y, want.peak, want.inside / want.outside, got.x, got.y, got.peak,
              got.inside / got.outside);
  // The light on the floor where the path tracer's caustic is (rows 29 to 31, 7 pixels wide
  // around the pixel nearest its centroid; the rows above are the sphere itself, path traced
  // by both): without the glass's specular chains PBGI has 0.60 of the path tracer's light
  // there (measured), with them 1.83: the caustic is there, too concentrated at 64 x 48 (the
  // cube maps' 16 texels a face).
  auto around = [&](const Image& image) {
    const int r = image.channelIndex("indirect.R");
    double sum = 0.0;
    for (int y = 29; y <= 31; ++y)
      for (int x = static_cast<int>(std::lround(want.x)) - 3;
           x <= static_cast<int>(std::lround(want.x)) + 3; ++x)
        sum += 0.2126 * image.at(x, y, r) + 0.7152 * image.at(x, y, r + 1) +
               0.0722 * image.at(x, y, r + 2);
    return sum / 21.0;
  };
  std::printf("light at the caustic: PBGI %.4g, path tracer %.4g\n", around(pbgi), around(path));
  EXPECT_NEAR(got.x, want.x, 3.0);
  EXPECT_NEAR(got.y, want.y, 3.0);
  EXPECT_GT(around(pbgi), 0.75 * around(path));
  EXPECT_LT(around(pbgi), 2.0 * around(path));
  EXPECT_GT(got.inside / got.outside, 0.5 * want.inside / want.outside);
  // The image's mean indirect light, within 6 % of the path tracer's: the glass's chains bring
  // the lights alone, and the wall and floor behind the glass reach the floor's gathers through
  // it (Scene::occludedByOpaque), not through the glass's surfels.
  const auto meanIndirect = [](const Image& image) {
    const int r = image.channelIndex("indirect.R");
    double sum = 0.0;
    for (int y = 0; y < image.height(); ++y)
      for (int x = 0; x < image.width(); ++x)
        for (int c = 0; c < 3; ++c) sum += image.at(x, y, r + c);
    return sum;
  };
  const double indirect = meanIndirect(pbgi) / meanIndirect(path);
  std::printf("mean indirect light: %.3f of the path tracer's\n", indirect);
  EXPECT_NEAR(indirect, 1.0, 0.06);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace pbgi
