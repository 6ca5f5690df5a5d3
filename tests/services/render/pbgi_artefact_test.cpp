// PBGI's own artefacts at a real image size: patches, seams at the cut blocks' borders, and
// light missing where a room is lit by bounced light alone. The uplit room of the scene suite
// (config/scenes/uplit-room) at its 256 x 256, 16 spp, the default preset and the shot's own
// bake, so that the cut runs many blocks and receiver clusters as a user's render does.
//
// Patches and seams come from how the cut shares light between records (its receiver clusters,
// its blocks), not from the camera samples' noise, so they are measured without a converged
// reference: the same frame rendered with blocks of another size (48 pixels) has its receiver
// clusters elsewhere, and whatever the two disagree on at low frequency is the cut's structure
// showing; a seam is a step in the indirect light on the blocks' borders that the lines beside
// them do not have. The light's level is measured against the path tracer, over each half of
// the frame (its noise averages out over so many pixels).

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <tuple>
#include <vector>

#include "core/util/check.h"
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

// A shot of the scene suite (config/scenes/<name>), changed by `edit` when given, with its own
// bake (unless `bake` is false: path traced only), in a temporary folder.
class OwnBake {
 public:
  explicit OwnBake(const std::string& name, const std::function<void(ShotDesc&)>& edit = {},
                   bool bake = true)
      : dir_(testing::makeTempDir("pbgi-" + name)) {
    auto shot = loadShotFile(
        (testing::sourceDir() / "config/scenes" / name / (name + ".shot.toml")).string());
    if (!shot.ok()) {
      status_ = shot.status();
      return;
    }
    shot_ = *std::move(shot);
    if (edit) edit(shot_);
    if (!bake) return;
    // The shot's own bake: its surfels, bounces and bounce gathers.
    auto request = shotBakeRequest(shot_, 1);
    if (!request.ok()) {
      status_ = request.status();
      return;
    }
    request->outDir = (dir_ / "bake").string();
    request->pointCloud = PointCloudMode::kNever;
    auto report = bakeShotFrame(shot_, *request);
    if (!report.ok()) {
      status_ = report.status();
      return;
    }
    tree_ = report->treePath;
  }
  ~OwnBake() { fs::remove_all(dir_); }

  // Whether the shot loaded and baked.
  const absl::Status& status() const { return status_; }
  const ShotDesc& shot() const { return shot_; }

  // The shot as it stands (PBGI at its preset, or the path tracer), at `spp`, with `params` on
  // top.
  Image render(const std::string& name, const std::string& integrator, int spp,
               const std::vector<std::pair<std::string, std::string>>& params = {}) const {
    FrameRenderRequest r;
    r.frame = 1;
    r.overrides.integrator = integrator;
    r.overrides.spp = spp;
    for (const auto& [key, value] : params) testing::setParam(r.overrides.params, key, value);
    r.treePath = integrator == "pbgi" ? tree_ : std::string();
    r.preview = false;
    r.outPath = (dir_ / (name + ".exr")).string();
    auto report = renderShotFrame(shot_, r);
    EXPECT_TRUE(report.ok()) << report.status();
    if (!report.ok()) return Image();
    auto image = readImage(r.outPath);
    EXPECT_TRUE(image.ok()) << image.status();
    return image.ok() ? *image : Image();
  }

 private:
  fs::path dir_;
  absl::Status status_;
  ShotDesc shot_;
  std::string tree_;
};

// A room of the suite as PBGI renders it at 16 spp and the path tracer at 64 (its mean within
// 0.5 % of 256 spp's in these rooms).
struct PbgiAndPath {
  Image pbgi, path;
};
PbgiAndPath renderPbgiAndPath(const OwnBake& room) {
  return {room.render("pbgi", "pbgi", 16), room.render("path", "path", 64)};
}

// Channel c's mean in PBGI over the path tracer's, over the pixels `keep` takes; `pixels`
// counts them.
double meanRatio(const PbgiAndPath& images, int c, const std::function<bool(int, int)>& keep,
                 int* pixels) {
  double a = 0.0, b = 0.0;
  *pixels = 0;
  for (int y = 0; y < images.path.height(); ++y) {
    for (int x = 0; x < images.path.width(); ++x) {
      if (!keep(x, y)) continue;
      a += images.pbgi.at(x, y, c);
      b += images.path.at(x, y, c);
      ++*pixels;
    }
  }
  return a / b;
}

class PbgiArtefacts : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    room_ = new OwnBake("uplit-room");
    ASSERT_TRUE(room_->status().ok()) << room_->status();
    ASSERT_EQ(room_->shot().width, 256);
    ASSERT_EQ(room_->shot().height, 256);
  }
  static void TearDownTestSuite() { delete room_; }

  static Image render(const std::string& name, const std::string& integrator, int spp,
                      const std::vector<std::pair<std::string, std::string>>& params = {}) {
    return room_->render(name, integrator, spp, params);
  }

  static OwnBake* room_;
};

OwnBake* PbgiArtefacts::room_ = nullptr;

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

// Steps at the cut blocks' borders in one image's indirect light: over the interiors of flat
// surfaces (the normal constant over 5 x 5 pixels), each pair of neighbouring pixels' step less
// the mean of the steps either side of it (what a smooth gradient or curve would give), each
// averaged over 7 pixels along the line between them and taken relative to the light there,
// squared; the mean on the lines across the blocks' borders over its mean on the 8 lines
// nearest each border (4 either side). Noise and the light's own shape show alike on both; a
// seam shows on the borders alone.
double borderStepRatio(const Image& image, int block) {
  const int w = image.width(), h = image.height();
  const int ind = image.channelIndex("indirect.R"), nrm = image.channelIndex("normal.X");
  PBGI_CHECK(ind >= 0 && nrm >= 0);
  std::vector<double> light(static_cast<size_t>(w) * h);
  std::vector<uint8_t> flat(light.size(), 0);
  const auto at = [&](int x, int y) { return static_cast<size_t>(y) * w + x; };
  for (int y = 0; y < h; ++y) {
    for (int x = 0; x < w; ++x) {
      light[at(x, y)] = 0.2126 * image.at(x, y, ind) + 0.7152 * image.at(x, y, ind + 1) +
                        0.0722 * image.at(x, y, ind + 2);
      if (x < 2 || y < 2 || x + 2 >= w || y + 2 >= h) continue;
      bool same = true;
      for (int dy = -2; dy <= 2 && same; ++dy) {
        for (int dx = -2; dx <= 2 && same; ++dx) {
          float d = 0.0f;
          for (int c = 0; c < 3; ++c) d += std::abs(image.at(x + dx, y + dy, nrm + c) - image.at(x, y, nrm + c));
          same = d < 1e-3f;
        }
      }
      flat[at(x, y)] = same;
    }
  }
  constexpr int kAlong = 3;  // 7 pixels along the line
  double border = 0.0, around = 0.0;
  uint64_t borderCount = 0, aroundCount = 0;
  for (const bool columns : {true, false}) {
    const int across = columns ? w : h, along = columns ? h : w;
    // Pixel k across the lines, v along them.
    const auto value = [&](int k, int v) { return columns ? light[at(k, v)] : light[at(v, k)]; };
    const auto isFlat = [&](int k, int v) { return columns ? flat[at(k, v)] : flat[at(v, k)]; };
    for (int k = 1; k + 2 < across; ++k) {
      // The line between pixels k and k + 1.
      const int offset = (k + 1) % block;
      const int distance = std::min(offset, block - offset);
      if (distance > 4) continue;
      for (int v = kAlong; v + kAlong < along; ++v) {
        double m[4] = {0.0, 0.0, 0.0, 0.0};  // k - 1 .. k + 2, averaged along
        bool ok = true;
        for (int j = 0; j < 4 && ok; ++j) {
          for (int t = v - kAlong; t <= v + kAlong && ok; ++t) {
            ok = isFlat(k - 1 + j, t);
            m[j] += value(k - 1 + j, t);
          }
        }
        if (!ok) continue;
        const double step = (m[2] - m[1]) - 0.5 * ((m[1] - m[0]) + (m[3] - m[2]));
        const double e = step / std::max(m[1], 1e-3 * (2 * kAlong + 1));
        if (distance == 0) {
          border += e * e;
          ++borderCount;
        } else {
          around += e * e;
          ++aroundCount;
        }
      }
    }
  }
  PBGI_CHECK(borderCount > 0 && aroundCount > 0 && around > 0.0);
  return (border / static_cast<double>(borderCount)) / (around / static_cast<double>(aroundCount));
}

// No patches, no seams. Patches: two renders whose receiver clusters and blocks lie
// differently agree at low frequency (7 x 7 blur) within 2e-4 in relMSE; a cut that decides a
// light cluster's visibility for a whole receiver cluster at once, by one ray, leaves patches
// the clusters' size, different in each. Seams: the indirect light steps across the 64-pixel
// borders within 1.5x of how it steps beside them (borderStepRatio); blocks whose border
// pixels copy their inner records, or whose clusters end at the border, step there.
TEST_F(PbgiArtefacts, RecordsShowNoPatchesOrSeamsWhereverTheBlocksLie) {
  const Image a = render("blocks64", "pbgi", 16);
  const Image b = render("blocks48", "pbgi", 16, {{"cut_block", "48"}});
  ASSERT_EQ(a.width(), 256);
  const absl::StatusOr<ImageMetrics> m = compareImages(a, b, nullptr, {.blockSize = 64});
  ASSERT_TRUE(m.ok()) << m.status();
  const double seams = borderStepRatio(a, 64);
  std::printf("[ measured ] 64- against 48-pixel blocks: relMSE %.3g, low-frequency relMSE %.3g; "
              "steps at the 64-pixel borders / beside them %.3f\n",
              m->relMse, m->lowFrequencyRelMse, seams);
  EXPECT_LT(m->lowFrequencyRelMse, 2e-4);
  EXPECT_LT(seams, 1.5);
}

// The light of a room lit by bounced light alone is all there, away from its light too: the
// half of the frame away from the torchiere (the sofa, the table, the shelf) within 4 % of the
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
  EXPECT_NEAR(away, 1.0, 0.04);
  EXPECT_NEAR(near, 1.0, 0.04);
}

// Glass and a mirror in the same room (config/scenes/glass-room), at its 256 x 256, 16 spp and
// own bake: what they show is lit by bounced light alone, which camera paths through them find
// by chance at 16 spp (black pixels with white specks). Paths that end on a diffuse surface
// after mirrors and glass take the light it sends back from the tree's surfels: the glass
// sphere's pixels and the mirror's match the path tracer's (256 spp) on average, and their
// error is a small part of what the path tracer's own 16 spp leave there.
TEST(PbgiGlassRoom, GlassAndAMirrorShowTheRoomTheyFace) {
  const OwnBake room("glass-room");
  ASSERT_TRUE(room.status().ok()) << room.status();
  const auto render = [&](const std::string& name, const std::string& integrator, int spp) {
    return room.render(name, integrator, spp);
  };
  const Image pbgi = render("pbgi", "pbgi", 16);
  const Image path16 = render("path16", "path", 16);
  const Image path = render("path256", "path", 256);
  ASSERT_EQ(pbgi.width(), path.width());
  const int albedo = path.channelIndex("albedo.R");
  ASSERT_GE(albedo, 0);
  // The glass's albedo AOV is white, the mirror's its reflectance, 0.9.
  for (const auto& [name, value, meanBound] :
       {std::tuple{"glass", 1.0f, 0.05}, std::tuple{"mirror", 0.9f, 0.1}}) {
    double sumPbgi = 0.0, sumPath = 0.0, errPbgi = 0.0, errPath16 = 0.0;
    int pixels = 0;
    for (int y = 0; y < path.height(); ++y) {
      for (int x = 0; x < path.width(); ++x) {
        bool in = true;
        for (int c = 0; c < 3; ++c) in = in && std::abs(path.at(x, y, albedo + c) - value) < 1e-3f;
        if (!in) continue;
        ++pixels;
        for (int c = 0; c < 3; ++c) {
          const double ref = path.at(x, y, c);
          sumPbgi += pbgi.at(x, y, c);
          sumPath += ref;
          errPbgi += std::pow(pbgi.at(x, y, c) - ref, 2) / (ref * ref + kRelMseEpsilon);
          errPath16 += std::pow(path16.at(x, y, c) - ref, 2) / (ref * ref + kRelMseEpsilon);
        }
      }
    }
    std::printf("[ measured ] %s: %d pixels, mean PBGI / path tracer %.4f; relMSE PBGI %.4f, the "
                "path tracer at 16 spp %.4f\n",
                name, pixels, sumPbgi / sumPath, errPbgi / (3.0 * pixels),
                errPath16 / (3.0 * pixels));
    ASSERT_GT(pixels, 200) << name;
    EXPECT_NEAR(sumPbgi / sumPath, 1.0, meanBound) << name;
    EXPECT_LT(errPbgi, 0.25 * errPath16) << name;
  }
}

// A room lit only through a door ajar (config/scenes/door-ajar), at its 256 x 256, 16 spp and
// own bake: everything in view gets the light that comes through the gap, most of it after
// several bounces in the room, which gets its light a bounce or more after the room next door.
// PBGI's light within 4 % of the path tracer's (64 spp: its mean is within 0.5 % of 256 spp's)
// on each channel. A tail that extrapolates the scene's geometric series from bounce 3 alone
// leaves out 10 % here, and shadow rays that graze the far room's wall through the gap, a fifth.
TEST(PbgiDoorAjar, TheRoomBehindTheDoorGetsAllItsLight) {
  const OwnBake room("door-ajar");
  ASSERT_TRUE(room.status().ok()) << room.status();
  const PbgiAndPath images = renderPbgiAndPath(room);
  ASSERT_EQ(images.pbgi.width(), 256);
  ASSERT_EQ(images.path.width(), 256);
  for (int c = 0; c < 3; ++c) {
    int pixels = 0;
    const double ratio = meanRatio(images, c, [](int, int) { return true; }, &pixels);
    std::printf("[ measured ] door ajar, channel %d: mean PBGI / path tracer %.4f\n", c, ratio);
    EXPECT_NEAR(ratio, 1.0, 0.04) << "channel " << c;
  }
}

// The same rooms with the doorway shut by a wall: the camera's room gets no light at all. A
// bounce's records stand for patches of surfels several surfel spacings wide, and the floor and
// ceiling run on under the dividing wall: a patch or a record read across the wall carried the
// lit room's light into the dark one, bounce after bounce (half the open room's light here).
// PBGI's mean, against the path tracer's of the open rooms, at most a thousandth.
TEST(PbgiDoorAjar, NoLightCrossesTheWallOfADoorwayShut) {
  const OwnBake open("door-ajar", {}, false);
  ASSERT_TRUE(open.status().ok()) << open.status();
  const Image lit = open.render("path", "path", 4);
  const OwnBake shut("door-ajar", [](ShotDesc& shot) {
    shot.geometry.push_back(
        {.file = (testing::sourceDir() / "tests/data/meshes/doorway_shut.obj").string()});
  });
  ASSERT_TRUE(shut.status().ok()) << shut.status();
  const Image pbgi = shut.render("pbgi", "pbgi", 16);
  ASSERT_EQ(pbgi.width(), 256);
  ASSERT_EQ(lit.width(), 256);
  double dark = 0.0, light = 0.0;
  for (int y = 0; y < pbgi.height(); ++y) {
    for (int x = 0; x < pbgi.width(); ++x) {
      for (int c = 0; c < 3; ++c) dark += pbgi.at(x, y, c), light += lit.at(x, y, c);
    }
  }
  std::printf("[ measured ] doorway shut: PBGI's mean / the open rooms' %.3g\n", dark / light);
  EXPECT_LT(dark, 1e-3 * light);
}

// The door-ajar rooms with a checkerboard floor of rough conductors (config/scenes/metal-floor:
// GGX 0.1, a complex index of refraction, tints 0.8 and 0.2), at its 256 x 256, 16 spp and own
// bake. The floor runs on under the dividing wall into the lit room, whose bright floor is in
// the same clusters as the dark room's. Everything the camera sees but the floor (walls,
// ceiling, door, furniture) within 4 % of the path tracer (64 spp) on each channel; the floor's
// own pixels, which the glossy gather shades, within 15 %.
TEST(PbgiMetalFloor, TheWallsGetWhatTheMetalFloorReflects) {
  const OwnBake room("metal-floor");
  ASSERT_TRUE(room.status().ok()) << room.status();
  const PbgiAndPath images = renderPbgiAndPath(room);
  ASSERT_EQ(images.pbgi.width(), 256);
  ASSERT_EQ(images.path.width(), 256);
  const Image& path = images.path;
  const int ny = path.channelIndex("normal.Y");
  ASSERT_GE(ny, 0);
  // The floor: level surfaces in the lower part of the frame (the ceiling is in the upper).
  const auto isFloor = [&](int x, int y) {
    return std::abs(path.at(x, y, ny)) > 0.99f && y > path.height() * 45 / 100;
  };
  for (const bool floor : {false, true}) {
    const char* name = floor ? "floor" : "rest of the room";
    for (int c = 0; c < 3; ++c) {
      int pixels = 0;
      const double ratio =
          meanRatio(images, c, [&](int x, int y) { return isFloor(x, y) == floor; }, &pixels);
      std::printf("[ measured ] metal floor, %s, channel %d: mean PBGI / path tracer %.4f\n",
                  name, c, ratio);
      ASSERT_GT(pixels, 5000) << name;
      EXPECT_NEAR(ratio, 1.0, floor ? 0.15 : 0.04) << name << ", channel " << c;
    }
  }
}

}  // namespace
}  // namespace pbgi
