// pbgi check SHOT [--frames LIST] [--json]: the shot checked as submission and the workers
// will meet it, without rendering. Exit 0 when it can render, 2 (naming the file) when not.

#include <cstdio>

#include <fmt/format.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "formats/shot/shot_file.h"
#include "services/cli/cli.h"
#include "services/render/shot_check.h"

namespace pbgi::cli {

namespace {

struct CheckOptions {
  std::string shot;
  std::string frames;
  bool json = false;
};

nlohmann::ordered_json toJson(const ShotDesc& shot, const ShotCheck& check) {
  nlohmann::ordered_json frames = nlohmann::ordered_json::array();
  for (const FrameCheck& f : check.frames) {
    frames.push_back({{"frame", f.frame},
                      {"meshes", f.stats.meshes},
                      {"triangles", f.stats.triangles},
                      {"lights", f.stats.lights},
                      {"emissive_triangles", f.stats.emissiveTriangles},
                      {"materials", f.materials},
                      {"bounds",
                       {{f.bounds.min.x, f.bounds.min.y, f.bounds.min.z},
                        {f.bounds.max.x, f.bounds.max.y, f.bounds.max.z}}},
                      {"warnings", f.warnings}});
  }
  nlohmann::ordered_json glossy = nlohmann::ordered_json::array();
  for (const GlossyMaterialCheck& g : check.glossy) {
    glossy.push_back({{"material", g.name},
                      {"roughness", g.roughness},
                      {"wavelet_bsdf_coefficients", g.keptCoefficients},
                      {"wavelet_bsdf_dense_coefficients", g.denseCoefficients},
                      {"wavelet_bsdf_error", g.relativeError},
                      {"lobe_texels", {g.lobeTexelsMin, g.lobeTexelsMax}},
                      {"glossy_gather", g.gather}});
  }
  return {{"shot", shot.path},
          {"name", shot.name},
          {"resolution", {shot.width, shot.height}},
          {"views", {shot.camera.views.x, shot.camera.views.y}},
          {"integrator", check.integrator},
          {"spp", shot.render.spp},
          {"bakes_tree", check.needsTree},
          {"output", check.output},
          {"output_format", toString(check.format)},
          {"frames", frames},
          {"glossy_materials", glossy},
          {"slower_than_path_traced", check.slowerThanPathTraced}};
}

std::string counted(size_t n, const char* one, const char* many) {
  return fmt::format("{} {}", n, n == 1 ? one : many);
}

void printText(const ShotDesc& shot, const ShotCheck& check) {
  std::printf("%s: shot '%s', %dx%d", shot.path.c_str(), shot.name.c_str(), shot.width,
              shot.height);
  if (shot.camera.views.x * shot.camera.views.y > 1) {
    std::printf(" in %dx%d views", shot.camera.views.x, shot.camera.views.y);
  }
  std::printf(", %s at %d spp%s\n", check.integrator.c_str(), shot.render.spp,
              check.needsTree ? " (bakes a PBGI tree per frame)" : "");
  std::printf("output %s (%s)\n", check.output.c_str(), toString(check.format).c_str());
  for (const FrameCheck& f : check.frames) {
    std::printf(
        "frame %d: %s, %s, %s (%s), %s\n", f.frame,
        counted(f.stats.meshes, "mesh", "meshes").c_str(),
        counted(f.stats.triangles, "triangle", "triangles").c_str(),
        counted(f.stats.lights, "light", "lights").c_str(),
        counted(f.stats.emissiveTriangles, "emissive triangle", "emissive triangles").c_str(),
        counted(f.materials, "material", "materials").c_str());
    for (const std::string& w : f.warnings) {
      std::fprintf(stderr, "pbgi: warning: frame %d: %s\n", f.frame, w.c_str());
    }
  }
  for (const GlossyMaterialCheck& g : check.glossy) {
    std::printf("%s\n", describeGlossyMaterial(g).c_str());
  }
  for (const std::string& note : check.slowerThanPathTraced) {
    std::fprintf(stderr, "pbgi: note: %s\n", note.c_str());
  }
  std::printf("ok: %zu frame%s can render\n", check.frames.size(),
              check.frames.size() == 1 ? "" : "s");
}

int runCheck(const CheckOptions& o) {
  auto shot = loadShotFile(o.shot);
  if (!shot.ok()) return reportError(shot.status());
  std::vector<int> frames;
  if (!o.frames.empty()) {
    auto parsed = parseFrameList(o.frames);
    if (!parsed.ok()) return reportError(parsed.status());
    frames = *std::move(parsed);
  }
  auto check = checkShot(*shot, frames);
  if (!check.ok()) return reportError(check.status());
  if (o.json) {
    std::printf("%s\n", toJson(*shot, *check).dump(2).c_str());
  } else {
    printText(*shot, *check);
  }
  return kExitOk;
}

}  // namespace

void registerCheckCommand(CLI::App& app, CommandAction& action) {
  auto options = std::make_shared<CheckOptions>();
  CLI::App* cmd = app.add_subcommand(
      "check",
      "Check a shot as submission and the workers will meet it, without rendering: its frames, "
      "integrator and output format, and each frame's geometry, materials, textures and "
      "environment loaded");
  cmd->add_option("SHOT", options->shot, "Shot file (TOML)")->required();
  cmd->add_option("--frames", options->frames,
                  "Frames to check, e.g. 1-3,7 (default: every frame)");
  cmd->add_flag("--json", options->json, "Print the check as JSON");
  cmd->callback([options, &action] { action = [options] { return runCheck(*options); }; });
}

}  // namespace pbgi::cli
