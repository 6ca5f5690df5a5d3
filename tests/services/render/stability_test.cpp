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
#include <vector>

#include <fmt/format.h>

#include "formats/image/image_io.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
using testing::runPbgi;
using testing::shellQuote;

// A closed-ish room (floor, ceiling, back and side walls) of side 2s around the origin with a
// block on the floor and a quad light under the ceiling: the Cornell box's shape in any unit.
std::string roomObj(double s, const std::string& extra = {}) {
  std::string obj = "mtllib none.mtl\n";
  int base = 0;
  auto quad = [&](const std::string& material, std::array<std::array<double, 3>, 4> p) {
    obj += "usemtl " + material + "\n";
    for (const auto& v : p) obj += fmt::format("v {:.9g} {:.9g} {:.9g}\n", v[0] * s, v[1] * s, v[2] * s);
    obj += fmt::format("f {} {} {}\nf {} {} {}\n", base + 1, base + 2, base + 3, base + 1,
                       base + 3, base + 4);
    base += 4;
  };
  quad("white", {{{-1, -1, -1}, {1, -1, -1}, {1, -1, 1}, {-1, -1, 1}}});   // floor
  quad("white", {{{-1, 1, -1}, {-1, 1, 1}, {1, 1, 1}, {1, 1, -1}}});       // ceiling
  quad("white", {{{-1, -1, 1}, {1, -1, 1}, {1, 1, 1}, {-1, 1, 1}}});       // back
  quad("red", {{{-1, -1, -1}, {-1, -1, 1}, {-1, 1, 1}, {-1, 1, -1}}});     // left
  quad("green", {{{1, -1, -1}, {1, 1, -1}, {1, 1, 1}, {1, -1, 1}}});       // right
  // A block: its top and two faces towards the camera.
  quad("white", {{{-0.5, -0.2, 0.0}, {0.1, -0.2, 0.0}, {0.1, -0.2, 0.6}, {-0.5, -0.2, 0.6}}});
  quad("white", {{{-0.5, -1, 0.0}, {0.1, -1, 0.0}, {0.1, -0.2, 0.0}, {-0.5, -0.2, 0.0}}});
  quad("white", {{{0.1, -1, 0.0}, {0.1, -1, 0.6}, {0.1, -0.2, 0.6}, {0.1, -0.2, 0.0}}});
  return obj + extra;
}

struct Case {
  std::string name;
  double scale = 1.0;
  std::string obj;             // the geometry file's text
  std::string lights;          // [[light]] tables (default: the room's quad light)
  std::string camera;          // position / look_at (default: looking into the room)
  int bakePoints = 8000;
};

std::string defaultLight(double s) {
  return fmt::format(
      "[[light]]\ntype = \"quad\"\ncorner = [{0:.9g}, {1:.9g}, {2:.9g}]\n"
      "edge_u = [0.0, 0.0, {3:.9g}]\nedge_v = [{4:.9g}, 0.0, 0.0]\nradiance = [8.0, 8.0, 8.0]\n",
      0.25 * s, 0.99 * s, -0.25 * s, 0.5 * s, -0.5 * s);
}

std::string defaultCamera(double s) {
  return fmt::format("position = [0.0, 0.0, {:.9g}]\nlook_at = [0.0, 0.0, 0.0]\n", -3.4 * s);
}

// Writes the case's OBJ and shot into `dir`; returns the shot's path.
fs::path writeCase(const fs::path& dir, const Case& c, const std::string& integrator,
                   const std::string& gather) {
  std::ofstream(dir / "scene.obj") << c.obj;
  const fs::path shot = dir / fmt::format("{}.shot.toml", integrator + gather);
  std::ofstream(shot) << fmt::format(
      "version = 1\n[shot]\nname = \"stress\"\nframes = [1, 1]\nresolution = [32, 32]\n"
      "output = \"{}.exr\"\n[camera]\n{}up = [0.0, 1.0, 0.0]\nfov_y_deg = 40.0\n"
      "[[geometry]]\nfile = \"scene.obj\"\n"
      "[[material]]\nname = \"white\"\ntype = \"diffuse\"\nalbedo = [0.7, 0.7, 0.7]\n"
      "[[material]]\nname = \"red\"\ntype = \"diffuse\"\nalbedo = [0.6, 0.1, 0.1]\n"
      "[[material]]\nname = \"green\"\ntype = \"diffuse\"\nalbedo = [0.1, 0.6, 0.1]\n"
      "{}[render]\nintegrator = \"{}\"\nspp = 16\n{}",
      integrator + gather, c.camera.empty() ? defaultCamera(c.scale) : c.camera,
      c.lights.empty() ? defaultLight(c.scale) : c.lights, integrator,
      integrator == "pbgi" ? fmt::format("gather = \"{}\"\nbake_points = {}\nquality = \"draft\"\n",
                                         gather, c.bakePoints)
                           : std::string());
  return shot;
}

struct Outcome {
  bool refused = false;
  std::string message;  // stderr: the refusal, or the warnings
  double mean = 0.0;  // of R, G and B over the image
};

// Renders the case; fails the test on a crash, a non-finite pixel or a refusal that does not
// name the input.
Outcome render(const fs::path& dir, const Case& c, const std::string& integrator,
               const std::string& gather = {}) {
  const fs::path shot = writeCase(dir, c, integrator, gather);
  const testing::RunResult r = runPbgi("render " + shellQuote(shot.string()) + " --no-preview");
  Outcome o;
  const std::string what = c.name + " / " + integrator + (gather.empty() ? "" : " " + gather);
  if (r.exitCode == 2) {
    o.refused = true;
    o.message = r.err;
    EXPECT_TRUE(r.err.find("scene.obj") != std::string::npos ||
                r.err.find(shot.filename().string()) != std::string::npos)
        << what << ": a refusal that names no input:\n" << r.err;
    return o;
  }
  EXPECT_EQ(r.exitCode, 0) << what << ":\n" << r.output();
  o.message = r.err;
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

AllIntegrators renderAll(const Case& c) {
  const fs::path dir = testing::makeTempDir("stress-" + c.name);
  AllIntegrators a;
  a.path = render(dir, c, "path");
  a.cut = render(dir, c, "pbgi", "bidirectional");
  a.perPixel = render(dir, c, "pbgi", "per-pixel");
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
  std::string extra =
      "usemtl white\n"
      "v 0 0 0\nv 0.5 0.5 0.5\nv 1 1 1\nf -3 -2 -1\n"            // collinear
      "v 0.2 0.2 0.2\nf -1 -1 -1\n"                             // one point thrice
      "v -0.9 -0.99 -0.9\nv 0.9 -0.99 -0.9\nv 0.9 -0.99 -0.8999999\nf -3 -2 -1\n"  // sliver
      "v nan 0 0\nv 0 1 0\nv 0 0 1\nf -3 -2 -1\n"               // NaN vertex
      "v inf 0 0\nv 0 -inf 0\nv 0 0 1\nf -3 -2 -1\n"             // Inf vertices
      "v 1e30 -1 1e30\nv -1e30 -1 1e30\nv 0 -1 -1e30\nf -3 -2 -1\n"  // huge, under the floor
      "vn nan nan nan\nv -0.4 -0.99 0.7\nv -0.3 -0.99 0.7\nv -0.3 -0.99 0.8\nf -3//1 -2//1 -1//1\n";
  const Case c{"hostile triangles", 1.0, roomObj(1.0, extra)};
  const AllIntegrators a = renderAll(c);
  ASSERT_FALSE(a.path.refused || a.cut.refused || a.perPixel.refused);
  for (const Outcome* o : {&a.path, &a.cut, &a.perPixel}) {
    // NaN, Inf and overflowing (the huge one) triangles; collinear and one-point ones. The
    // sliver renders (it has an area), and so does the triangle of NaN normals (face normal).
    EXPECT_NE(o->message.find("dropped 3 triangles with NaN/Inf vertices, 2 degenerate"),
              std::string::npos)
        << o->message;
  }
  expectClose(c, a, 0.15);
}

// Two copies of every surface in the same place: coincident surfels, doubled density.
TEST(Stability, CoincidentSurfacesRenderAsOne) {
  const std::string room = roomObj(1.0);
  std::string doubled = room;
  // The same faces again, over the same vertices' copies.
  int vertices = 0;
  for (size_t at = room.find("\nv "); at != std::string::npos; at = room.find("\nv ", at + 1)) ++vertices;
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
  const std::string lights =
      defaultLight(1.0) +
      "[[light]]\ntype = \"sphere\"\ncenter = [-0.6, 0.6, 0.5]\nradius = 0.001\n"
      "radiance = [8e6, 8e6, 8e6]\n";
  const Case c{"a million times brighter", 1.0, roomObj(1.0), lights};
  const AllIntegrators a = renderAll(c);
  expectClose(c, a, 0.25);
}

// The smallest scenes: one triangle (a handful of surfels), and nothing at all.
TEST(Stability, OneTriangleRendersAndAnEmptySceneIsRefusedByName) {
  const Case one{"one triangle", 1.0,
                 "mtllib none.mtl\nusemtl white\nv -1 -1 0\nv 1 -1 0\nv 0 1 0\nf 1 2 3\n", "",
                 "", 1000};  // bake_points' least
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
  box += "f 1 2 3\nf 1 3 4\nf 5 8 7\nf 5 7 6\nf 1 5 6\nf 1 6 2\nf 4 3 7\nf 4 7 8\n"
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

}  // namespace
}  // namespace pbgi
