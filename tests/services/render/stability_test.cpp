// The numerical-stability stress suite: scenes built here to break the pipeline (scales from
// 1e-6 to 1e6, degenerate, sliver, zero-area and huge triangles, NaN and Inf vertices and
// normals, coincident surfaces, a light a million times brighter than another, a single
// triangle, an empty scene, a camera inside a closed box), each rendered by `pbgi render` with
// the path tracer and with PBGI through both gathers (a bake each). Every run either writes an
// image with no NaN or Inf pixel and its discards counted, or is refused with exit 2 and a
// message naming the input; no crash. Where the scene is sane, PBGI's mean is within stated
// error of the path tracer's, and the same scene at every scale gives the same picture.
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include <fmt/format.h>

#include "formats/image/image_io.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/stress_scenes.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
using testing::runPbgi;
using testing::shellQuote;

using testing::defaultCamera;
using testing::defaultLight;
using testing::roomObj;
using testing::writeStressShot;
using Case = testing::StressCase;

struct Outcome {
  bool refused = false;
  std::string message;  // stderr: the refusal, or the warnings
  std::string report;   // stdout: counters, discards among them
  double mean = 0.0;    // of R, G and B over the image
};

// Renders the case (`args`: more words for `pbgi render`); fails the test on a crash, a
// non-finite pixel or a refusal that does not name the input.
Outcome render(const fs::path& dir, const Case& c, const std::string& integrator,
               const std::string& gather = {}, const std::string& args = {}) {
  const fs::path shot = writeStressShot(dir, c, integrator, gather);
  const testing::RunResult r =
      runPbgi("render " + shellQuote(shot.string()) + " --no-preview" + args);
  Outcome o;
  const std::string what = c.name + " / " + integrator + (gather.empty() ? "" : " " + gather);
  if (r.exitCode == 2) {
    o.refused = true;
    o.message = r.err;
    EXPECT_TRUE(r.err.find("scene.obj") != std::string::npos ||
                r.err.find(shot.filename().string()) != std::string::npos)
        << what << ": a refusal that names no input:\n"
        << r.err;
    return o;
  }
  EXPECT_EQ(r.exitCode, 0) << what << ":\n" << r.output();
  o.message = r.err;
  o.report = r.out;
  if (r.exitCode != 0) return o;
  auto image = readImage((dir / (integrator + gather + ".exr")).string());
  EXPECT_TRUE(image.ok()) << what << ": " << image.status();
  if (!image.ok()) return o;
  double sum = 0.0;
  int nonFinite = 0;
  for (int y = 0; y < image->height(); ++y) {
    for (int x = 0; x < image->width(); ++x) {
      for (int ch = 0; ch < 3; ++ch) {
        const float v = image->at(x, y, ch);
        if (!std::isfinite(v)) ++nonFinite;
        sum += std::isfinite(v) ? v : 0.0;
      }
    }
  }
  EXPECT_EQ(nonFinite, 0) << what;
  o.mean = sum / (3.0 * image->width() * image->height());
  return o;
}

struct AllIntegrators {
  Outcome path, cut, perPixel;
};

// `dir`: where the case's files go (a fresh folder when empty); `pbgiArgs`: more words for
// the PBGI renders.
AllIntegrators renderAll(const Case& c, fs::path dir = {}, const std::string& pbgiArgs = {}) {
  if (dir.empty()) dir = testing::makeTempDir("stress-" + c.name);
  AllIntegrators a;
  a.path = render(dir, c, "path");
  a.cut = render(dir, c, "pbgi", "bidirectional", pbgiArgs);
  a.perPixel = render(dir, c, "pbgi", "per-pixel", pbgiArgs);
  std::printf("[ measured ] %-28s path %.5g  cut %.5g  per-pixel %.5g%s\n", c.name.c_str(),
              a.path.mean, a.cut.mean, a.perPixel.mean,
              a.path.refused || a.cut.refused ? "  (refused)" : "");
  return a;
}

// PBGI's mean light against the path tracer's, the two gathers each.
void expectClose(const Case& c, const AllIntegrators& a, double tolerance) {
  ASSERT_FALSE(a.path.refused || a.cut.refused || a.perPixel.refused) << c.name;
  ASSERT_GT(a.path.mean, 0.0) << c.name;
  EXPECT_NEAR(a.cut.mean / a.path.mean, 1.0, tolerance) << c.name << " bidirectional";
  EXPECT_NEAR(a.perPixel.mean / a.path.mean, 1.0, tolerance) << c.name << " per-pixel";
}

// The same room in units from 1e-6 to 1e6: the same picture, and PBGI within 15 % of the path
// tracer (an 8,000-surfel draft bake of a room whose light is a quarter of its ceiling).
TEST(Stability, AnyUnitGivesTheSamePicture) {
  std::map<double, AllIntegrators> at;
  for (const double s : {1.0, 1e-6, 1e-3, 1e3, 1e6}) {
    const Case c{fmt::format("room at scale {:g}", s), s, roomObj(s)};
    at[s] = renderAll(c);
    expectClose(c, at[s], 0.15);
    EXPECT_NEAR(at[s].path.mean / at[1.0].path.mean, 1.0, 1e-3)
        << c.name << ": the path tracer depends on the unit";
    EXPECT_NEAR(at[s].cut.mean / at[1.0].cut.mean, 1.0, 0.02)
        << c.name << ": PBGI depends on the unit";
  }
}

// Degenerate (collinear), zero-area (repeated vertices), sliver and huge triangles, NaN and
// Inf vertices and normals: dropped and counted by the loader, the rest renders.
TEST(Stability, HostileTrianglesAreDroppedAndTheRestRenders) {
  const Case c{"hostile triangles", 1.0, roomObj(1.0, testing::kHostileTriangles)};
  const AllIntegrators a = renderAll(c);
  ASSERT_FALSE(a.path.refused || a.cut.refused || a.perPixel.refused);
  for (const Outcome* o : {&a.path, &a.cut, &a.perPixel}) {
    // NaN, Inf and overflowing (the huge one) triangles; collinear and one-point ones. The
    // sliver renders (it has an area), and so does the triangle of NaN normals (face normal).
    EXPECT_NE(o->message.find(testing::kHostileTrianglesDropped), std::string::npos) << o->message;
  }
  expectClose(c, a, 0.15);
}

// Two copies of every surface in the same place: coincident surfels, doubled density.
TEST(Stability, CoincidentSurfacesRenderAsOne) {
  const std::string room = roomObj(1.0);
  std::string doubled = room;
  // The same faces again, over the same vertices' copies.
  int vertices = 0;
  for (size_t at = room.find("\nv "); at != std::string::npos; at = room.find("\nv ", at + 1))
    ++vertices;
  for (size_t at = 0, next; (next = room.find('\n', at)) != std::string::npos; at = next + 1) {
    const std::string line = room.substr(at, next - at);
    if (line.starts_with("f ")) {
      int a, b, cc;
      if (std::sscanf(line.c_str(), "f %d %d %d", &a, &b, &cc) == 3) {
        doubled += fmt::format("f {} {} {}\n", a, b, cc);
      }
    } else if (line.starts_with("usemtl")) {
      doubled += line + "\n";
    }
  }
  const Case single{"single surfaces", 1.0, room};
  const Case twice{"coincident surfaces", 1.0, doubled};
  const AllIntegrators a = renderAll(single);
  const AllIntegrators b = renderAll(twice);
  expectClose(twice, b, 0.15);
  EXPECT_NEAR(b.cut.mean / a.cut.mean, 1.0, 0.05);
}

// A light a million times brighter than the other, both in view of the room.
TEST(Stability, ALightAMillionTimesBrighterStaysFinite) {
  const Case c{"a million times brighter", 1.0, roomObj(1.0),
               testing::millionTimesBrighterLights()};
  const AllIntegrators a = renderAll(c);
  expectClose(c, a, 0.25);
}

// The smallest scenes: one triangle (a handful of surfels), and nothing at all.
TEST(Stability, OneTriangleRendersAndAnEmptySceneIsRefusedByName) {
  const Case one{"one triangle",
                 1.0,
                 "mtllib none.mtl\nusemtl white\nv -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n",
                 "",
                 "",
                 1000};  // bake_points' least
  const AllIntegrators a = renderAll(one);
  EXPECT_FALSE(a.path.refused);
  EXPECT_FALSE(a.cut.refused);
  const Case empty{"empty scene", 1.0, "# vertices, no faces\nv 0 0 0\nv 1 0 0\n"};
  const fs::path dir = testing::makeTempDir("stress-empty");
  const Outcome o = render(dir, empty, "pbgi", "bidirectional");
  EXPECT_TRUE(o.refused);  // naming scene.obj (render() checks)
}

// A camera inside a closed box, the light outside: the path tracer's image is black, PBGI's
// nearly so, and neither has a NaN.
TEST(Stability, ACameraInsideAClosedBoxSeesFiniteDark) {
  std::string box = "mtllib none.mtl\nusemtl white\n";
  const double p[8][3] = {{-1, -1, -1}, {1, -1, -1}, {1, 1, -1}, {-1, 1, -1},
                          {-1, -1, 1},  {1, -1, 1},  {1, 1, 1},  {-1, 1, 1}};
  for (const auto& v : p) box += fmt::format("v {} {} {}\n", v[0], v[1], v[2]);
  box +=
      "f 1 2 3\nf 1 3 4\nf 5 8 7\nf 5 7 6\nf 1 5 6\nf 1 6 2\nf 4 3 7\nf 4 7 8\n"
      "f 1 4 8\nf 1 8 5\nf 2 6 7\nf 2 7 3\n";
  const Case inside{"camera inside a box", 1.0, box, defaultLight(3.0),
                    "position = [0.0, 0.0, 0.0]\nlook_at = [0.0, 0.0, 1.0]\n"};
  const AllIntegrators a = renderAll(inside);
  EXPECT_FALSE(a.path.refused || a.cut.refused || a.perPixel.refused);
  EXPECT_EQ(a.path.mean, 0.0);
  // What PBGI lets through a wall (surfels of the lit outside seen past the inside's own):
  // under a thousandth of the room's brightness (0.17) in the room test.
  EXPECT_LT(a.cut.mean, 1e-3);
  EXPECT_LT(a.perPixel.mean, 1e-3);
}

// Light past float's headroom (kMaxEmission, 1e20 per component): a quad light, a shot's
// emissive material, an MTL's emission and an environment map's texels of radiance 3e38, which
// PBGI's clusters and irradiance overflowed (a render that failed on non-finite irradiance,
// and the path tracer's pixels that saw the light summed to Inf), each refused naming the
// file; at the limit itself, the room (2,000 surfels) renders finite and PBGI stays within 3 %
// of the path tracer (measured 0.992 of its mean with either gather, as at radiance 8; 0.90 and
// 0.92 when quantized surfel radiance was stored absolute, clamped at half floats' 65504).
TEST(Stability, EmissionPastFloatsHeadroomIsRefusedByNameAndAtItRenders) {
  const fs::path dir = testing::makeTempDir("stress-emission");
  const std::string hot = "3e38";
  Image sky(4, 2, {"R", "G", "B"});
  for (float& v : sky.pixels()) v = 3e38f;
  ASSERT_TRUE(writeExr(sky, (dir / "sky.exr").string()).ok());
  std::ofstream(dir / "hot.mtl") << "newmtl hot\nKe " << hot << " " << hot << " " << hot << "\n";
  const std::vector<std::pair<Case, std::string>> refused = {
      {{.name = "a quad light of radiance 3e38",
        .obj = roomObj(1.0),
        .lights = defaultLight(1.0, hot)},
       "radiance"},
      {{.name = "an emissive material of radiance 3e38",
        .obj =
            roomObj(1.0, "usemtl lamp\nv -0.2 0.9 -0.2\nv 0.2 0.9 -0.2\nv 0 0.9 0.2\nf -3 -2 -1\n"),
        .materials = "[[material]]\nname = \"lamp\"\ntype = \"emissive\"\nradiance = [" + hot +
                     ", " + hot + ", " + hot + "]\n"},
       "radiance"},
      {{.name = "an MTL's emission of 3e38",
        .obj = "mtllib hot.mtl\n" + roomObj(1.0,
                                            "usemtl hot\nv -0.2 0.9 -0.2\nv 0.2 0.9 -0.2\nv 0 "
                                            "0.9 0.2\nf -3 -2 -1\n")},
       "material 'hot' emits radiance"},
      {{.name = "an environment map of radiance 3e38",
        .obj = roomObj(1.0),
        .lights = "[[light]]\ntype = \"environment\"\nfile = \"sky.exr\"\n"},
       "sky.exr': texels of radiance up to 3e+38"},
  };
  for (const auto& [c, says] : refused) {
    for (const auto& [integrator, gather] :
         {std::pair<std::string, std::string>{"path", ""}, {"pbgi", "bidirectional"}}) {
      const Outcome o = render(dir, c, integrator, gather);  // naming the shot or scene.obj
      EXPECT_TRUE(o.refused) << c.name << " / " << integrator;
      EXPECT_NE(o.message.find(says), std::string::npos) << c.name << ":\n" << o.message;
    }
  }
  const Case limit{.name = "a light of radiance 1e20",
                   .obj = roomObj(1.0),
                   .lights = defaultLight(1.0, "1e20"),
                   .bakePoints = 2000};
  const AllIntegrators a = renderAll(limit);  // render() fails on a non-finite pixel
  expectClose(limit, a, 0.03);
}

// A geometry's transform can make what its file holds unusable: scaled by 1e-6, a triangle of
// 1e-17 units has an area below float's least (dropped and counted, and the room renders as
// the room of 1e-6 units does); scaled by 1e-30 or 1e30, every triangle goes (refused, naming
// the file and the transform). Both once passed silently: the path tracer rendered an empty
// scene, and PBGI's bake said only that the scene had no surface.
TEST(Stability, TrianglesATransformMakesUnusableAreCountedOrRefusedByName) {
  const std::string speck = "usemtl white\nv 0 0 0\nv 1e-17 0 0\nv 0 1e-17 0\nf -3 -2 -1\n";
  const Case shrunk{.name = "room and speck scaled by 1e-6",
                    .scale = 1e-6,
                    .obj = roomObj(1.0, speck),
                    .bakePoints = 2000,
                    .geometry = "scale = 1e-6\n"};
  const AllIntegrators a = renderAll(shrunk);
  ASSERT_FALSE(a.path.refused || a.cut.refused || a.perPixel.refused);
  for (const Outcome* o : {&a.path, &a.cut, &a.perPixel}) {
    EXPECT_NE(o->message.find("scene.obj: under the transform at frame 1 (scale 1e-06, "),
              std::string::npos)
        << o->message;
    EXPECT_NE(o->message.find("mesh 'white': dropped 1 degenerate (zero-area) triangle"),
              std::string::npos)
        << o->message;
  }
  expectClose(shrunk, a, 0.15);
  for (const char* scale : {"1e-30", "1e30"}) {
    const Case gone{.name = fmt::format("room scaled by {}", scale),
                    .obj = roomObj(1.0),
                    .geometry = fmt::format("scale = {}\n", scale)};
    const fs::path dir = testing::makeTempDir("stress-gone");
    for (const auto& [integrator, gather] :
         {std::pair<std::string, std::string>{"path", ""}, {"pbgi", "bidirectional"}}) {
      const Outcome o = render(dir, gone, integrator, gather);  // naming scene.obj
      EXPECT_TRUE(o.refused) << gone.name << " / " << integrator;
      EXPECT_NE(o.message.find("no usable triangles under the transform at frame 1 (scale "),
                std::string::npos)
          << o.message;
    }
  }
}

// The fewest surfels a bake makes. A shot's bake_points starts at 1,000, but `pbgi bake
// --points` takes any positive count and `pbgi render --tree` renders from the tree it wrote:
// one surfel is a tree of one node (a leaf, on one page), two at --leaf-size 1 a root over two
// leaves; the one surfel may emit, or be glossy (a wavelet vector of one leaf), or stand for a
// room of 1e-6 units. Every bake succeeds and both gathers from it are finite, their
// discards counted, and PBGI's mean within 25 % of the path tracer's: the direct light is exact
// at every receiver, and one or two surfels carry only the indirect (measured 0.84 to 0.90 of
// the path tracer's mean in the room at every scale, 1.00 under the lamp and on the metal floor,
// where nothing else bounces light).
TEST(Stability, ASingleSurfelBakesAndBothGathersFromItAreFinite) {
  struct Tiny {
    Case scene;
    int points;
    int leafSize;
    std::string bakeSays;  // in the bake's report
  };
  // A floor under an emissive quad of 10,000 times its area: the one surfel lands on the lamp
  // and emits (there is no other light).
  const Case lamp{
      .name = "one emissive surfel",
      .obj =
          "mtllib none.mtl\nusemtl lamp\n"
          "v -100 1 -100\nv -100 1 100\nv 100 1 100\nv 100 1 -100\nf 1 2 3\nf 1 3 4\n"
          "usemtl white\nv -1 -1 -1\nv 1 -1 -1\nv 1 -1 1\nv -1 -1 1\nf 5 6 7\nf 5 7 8\n",
      .lights = "# no [[light]]: the lamp is the light\n",
      .camera = "position = [0.0, 0.0, -3.4]\nlook_at = [0.0, -1.0, 0.0]\n",
      .materials =
          "[[material]]\nname = \"lamp\"\ntype = \"emissive\"\nradiance = [1.0, 1.0, 1.0]\n"};
  // A rough metal floor (wavelets, not SH) under the room's light.
  const Case metal{.name = "one glossy surfel",
                   .obj =
                       "mtllib none.mtl\nusemtl metal\n"
                       "v -1 -1 -1\nv 1 -1 -1\nv 1 -1 1\nv -1 -1 1\nf 1 2 3\nf 1 3 4\n",
                   .materials =
                       "[[material]]\nname = \"metal\"\ntype = \"conductor\"\nroughness = 0.05\n"
                       "specular = [0.9, 0.9, 0.9]\n"};
  const auto room = [](const std::string& name, double scale) {
    return Case{.name = name, .scale = scale, .obj = roomObj(scale)};
  };
  const std::vector<Tiny> cases = {
      {room("room, one surfel", 1.0), 1, 16, "tree: 1 nodes, 1 leaves, 1 pages"},
      {room("room, two leaves of one", 1.0), 2, 1, "tree: 3 nodes, 2 leaves, 1 pages"},
      {room("room at 1e-6, one surfel", 1e-6), 1, 16, "tree: 1 nodes, 1 leaves"},
      {lamp, 1, 16, "emissive 1,"},
      {metal, 1, 16, "wavelets (glossy light): 1 leaves baked, 1 nodes"},
  };
  for (const Tiny& t : cases) {
    SCOPED_TRACE(t.scene.name);
    const fs::path dir = testing::makeTempDir("stress-tiny");
    const fs::path shot = writeStressShot(dir, t.scene, "pbgi", "bidirectional");
    const testing::RunResult bake = runPbgi(
        fmt::format("bake {} --points {} --leaf-size {} --out {}", shellQuote(shot.string()),
                    t.points, t.leafSize, shellQuote((dir / "bake").string())));
    ASSERT_EQ(bake.exitCode, 0) << bake.output();
    EXPECT_NE(bake.out.find(fmt::format("surfels {} (", t.points)), std::string::npos) << bake.out;
    EXPECT_NE(bake.out.find(t.bakeSays), std::string::npos) << bake.out;
    const AllIntegrators a = renderAll(
        t.scene, dir, " --tree " + shellQuote((dir / "bake" / "pbgibidirectional.pbgi").string()));
    ASSERT_FALSE(a.path.refused || a.cut.refused || a.perPixel.refused);
    for (const Outcome* o : {&a.cut, &a.perPixel}) {
      EXPECT_NE(o->report.find("discarded (NaN/Inf) "), std::string::npos) << o->report;
    }
    expectClose(t.scene, a, 0.25);
  }
}

}  // namespace
}  // namespace pbgi
