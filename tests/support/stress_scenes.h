#pragma once
// The numerical-stability suite's scenes, shared by the in-process suite
// (tests/services/render/stability_test.cpp) and the same scenes through the farm
// (tests/services/worker/stability_farm_test.cpp): a room in any unit, hostile triangles, a
// light a million times brighter than another, and the shot that renders one of them.
#include <array>
#include <filesystem>
#include <fstream>
#include <string>

#include <fmt/format.h>

namespace pbgi::testing {

// A closed-ish room (floor, ceiling, back and side walls) of side 2s around the origin with a
// block on the floor and a quad light under the ceiling: the Cornell box's shape in any unit.
inline std::string roomObj(double s, const std::string& extra = {}) {
  std::string obj = "mtllib none.mtl\n";
  int base = 0;
  auto quad = [&](const std::string& material, std::array<std::array<double, 3>, 4> p) {
    obj += "usemtl " + material + "\n";
    for (const auto& v : p)
      obj += fmt::format("v {:.9g} {:.9g} {:.9g}\n", v[0] * s, v[1] * s, v[2] * s);
    obj += fmt::format("f {} {} {}\nf {} {} {}\n", base + 1, base + 2, base + 3, base + 1, base + 3,
                       base + 4);
    base += 4;
  };
  quad("white", {{{-1, -1, -1}, {1, -1, -1}, {1, -1, 1}, {-1, -1, 1}}});  // floor
  quad("white", {{{-1, 1, -1}, {-1, 1, 1}, {1, 1, 1}, {1, 1, -1}}});      // ceiling
  quad("white", {{{-1, -1, 1}, {1, -1, 1}, {1, 1, 1}, {-1, 1, 1}}});      // back
  quad("red", {{{-1, -1, -1}, {-1, -1, 1}, {-1, 1, 1}, {-1, 1, -1}}});    // left
  quad("green", {{{1, -1, -1}, {1, 1, -1}, {1, 1, 1}, {1, -1, 1}}});      // right
  // A block: its top and two faces towards the camera.
  quad("white", {{{-0.5, -0.2, 0.0}, {0.1, -0.2, 0.0}, {0.1, -0.2, 0.6}, {-0.5, -0.2, 0.6}}});
  quad("white", {{{-0.5, -1, 0.0}, {0.1, -1, 0.0}, {0.1, -0.2, 0.0}, {-0.5, -0.2, 0.0}}});
  quad("white", {{{0.1, -1, 0.0}, {0.1, -1, 0.6}, {0.1, -0.2, 0.6}, {0.1, -0.2, 0.0}}});
  return obj + extra;
}

// Triangles to append to roomObj(1): collinear, one point thrice, a sliver, NaN and Inf
// vertices, a huge one under the floor, and one of NaN normals. The loader drops the NaN, Inf
// and overflowing (huge) ones and the collinear and one-point ones, and says so as "dropped 3
// triangles with NaN/Inf vertices, 2 degenerate"; the sliver renders (it has an area), and so
// does the triangle of NaN normals (by its face normal).
inline const char* const kHostileTriangles =
    "usemtl white\n"
    "v 0 0 0\nv 0.5 0.5 0.5\nv 1 1 1\nf -3 -2 -1\n"                              // collinear
    "v 0.2 0.2 0.2\nf -1 -1 -1\n"                                                // one point thrice
    "v -0.9 -0.99 -0.9\nv 0.9 -0.99 -0.9\nv 0.9 -0.99 -0.8999999\nf -3 -2 -1\n"  // sliver
    "v nan 0 0\nv 0 1 0\nv 0 0 1\nf -3 -2 -1\n"                                  // NaN vertex
    "v inf 0 0\nv 0 -inf 0\nv 0 0 1\nf -3 -2 -1\n"                               // Inf vertices
    "v 1e30 -1 1e30\nv -1e30 -1 1e30\nv 0 -1 -1e30\nf -3 -2 -1\n"  // huge, under the floor
    "vn nan nan nan\nv -0.4 -0.99 0.7\nv -0.3 -0.99 0.7\nv -0.3 -0.99 0.8\nf -3//1 -2//1 -1//1\n";
inline const char* const kHostileTrianglesDropped =
    "dropped 3 triangles with NaN/Inf vertices, 2 degenerate";

struct StressCase {
  std::string name;
  double scale = 1.0;
  std::string obj;     // the geometry file's text
  std::string lights;  // [[light]] tables (default: the room's quad light)
  std::string camera;  // position / look_at (default: looking into the room)
  int bakePoints = 8000;
  int spp = 16;
  std::string materials;  // [[material]] tables beside white, red and green
  std::string geometry;   // more keys for [[geometry]] (a transform)
  int resolution = 32;    // pixels a side
};

// The room's quad light under its ceiling; `radiance` as TOML writes a float.
inline std::string defaultLight(double s, const std::string& radiance = "8.0") {
  return fmt::format(
      "[[light]]\ntype = \"quad\"\ncorner = [{0:.9g}, {1:.9g}, {2:.9g}]\n"
      "edge_u = [0.0, 0.0, {3:.9g}]\nedge_v = [{4:.9g}, 0.0, 0.0]\nradiance = [{5}, {5}, {5}]\n",
      0.25 * s, 0.99 * s, -0.25 * s, 0.5 * s, -0.5 * s, radiance);
}

// The room's light and, in view of the room, a sphere a million times brighter.
inline std::string millionTimesBrighterLights() {
  return defaultLight(1.0) +
         "[[light]]\ntype = \"sphere\"\ncenter = [-0.6, 0.6, 0.5]\nradius = 0.001\n"
         "radiance = [8e6, 8e6, 8e6]\n";
}

inline std::string defaultCamera(double s) {
  return fmt::format("position = [0.0, 0.0, {:.9g}]\nlook_at = [0.0, 0.0, 0.0]\n", -3.4 * s);
}

// Writes the case's OBJ (dir/scene.obj) and a square shot (32 x 32 unless said) of one frame
// rendered by
// `integrator` (and, for PBGI, `gather`, at the case's bake_points in the draft preset) into
// `dir`; returns the shot's path. The image goes to dir/INTEGRATORGATHER.exr.
inline std::filesystem::path writeStressShot(const std::filesystem::path& dir, const StressCase& c,
                                             const std::string& integrator,
                                             const std::string& gather) {
  std::ofstream(dir / "scene.obj") << c.obj;
  const std::filesystem::path shot = dir / fmt::format("{}.shot.toml", integrator + gather);
  std::ofstream(shot) << fmt::format(
      "version = 1\n[shot]\nname = \"stress\"\nframes = [1, 1]\nresolution = [{}, {}]\n"
      "output = \"{}.exr\"\n[camera]\n{}up = [0.0, 1.0, 0.0]\nfov_y_deg = 40.0\n"
      "[[geometry]]\nfile = \"scene.obj\"\n{}"
      "[[material]]\nname = \"white\"\ntype = \"diffuse\"\nalbedo = [0.7, 0.7, 0.7]\n"
      "[[material]]\nname = \"red\"\ntype = \"diffuse\"\nalbedo = [0.6, 0.1, 0.1]\n"
      "[[material]]\nname = \"green\"\ntype = \"diffuse\"\nalbedo = [0.1, 0.6, 0.1]\n"
      "{}{}[render]\nintegrator = \"{}\"\nspp = {}\n{}",
      c.resolution, c.resolution, integrator + gather,
      c.camera.empty() ? defaultCamera(c.scale) : c.camera, c.geometry,
      c.materials, c.lights.empty() ? defaultLight(c.scale) : c.lights, integrator, c.spp,
      integrator == "pbgi" ? fmt::format("gather = \"{}\"\nbake_points = {}\nquality = \"draft\"\n",
                                         gather, c.bakePoints)
                           : std::string());
  return shot;
}

}  // namespace pbgi::testing
