// pbgi render SHOT [--frame N] [--integrator NAME] [--spp N] [--threads N] [--out FILE.exr]
//                  [--crop X0,Y0,X1,Y1]

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>

#include <fmt/format.h>
#include <CLI/CLI.hpp>

#include "formats/shot/shot_file.h"
#include "services/cli/cli.h"
#include "services/cli/progress.h"
#include "services/render/frame_render.h"
#include "services/util/cli_checks.h"

namespace pbgi::cli {

namespace {

struct RenderOptions {
  std::string shot;
  std::optional<int> frame;
  std::string integrator;
  int spp = 0;
  int threads = 0;
  int tileSize = 0;
  std::string out;
  bool noPreview = false;
  std::string gather;
  std::string quality;
  std::string maxSolidAngle;
  std::string resolution;
  std::string cacheMb;
  std::vector<std::string> set;  // key=value
  std::string tree;
  std::string bakeDir;
  bool rebake = false;
  std::string crop;  // X0,Y0,X1,Y1
  std::string imageSize;  // --resolution W,H: each view's pixels
  double scale = 0;       // --scale: of the shot's resolution
  std::optional<uint64_t> seed;
};

constexpr int kMaxImageSide = 65536;

// --resolution W,H or --scale F (of each view: a camera array keeps its layout) and --seed:
// the shot as this render sees it. A bake does not depend on them.
absl::Status applyImageFlags(const RenderOptions& o, ShotDesc* shot) {
  if (!o.imageSize.empty()) {
    int w = 0, h = 0;
    const char* end = o.imageSize.data() + o.imageSize.size();
    const auto [comma, ec1] = std::from_chars(o.imageSize.data(), end, w);
    const bool parsed = ec1 == std::errc() && comma != end && *comma == ',' &&
                        std::from_chars(comma + 1, end, h).ptr == end;
    if (!parsed || w < 1 || h < 1 || w > kMaxImageSide || h > kMaxImageSide) {
      return absl::InvalidArgumentError(
          fmt::format("--resolution '{}': expected W,H (two whole numbers from 1 to {})",
                      o.imageSize, kMaxImageSide));
    }
    shot->width = w;
    shot->height = h;
  } else if (o.scale > 0) {
    const auto scaled = [&](int side) {
      return static_cast<int>(std::clamp<double>(std::lround(side * o.scale), 1, kMaxImageSide));
    };
    shot->width = scaled(shot->width);
    shot->height = scaled(shot->height);
  }
  if (o.seed) shot->render.seed = *o.seed;
  return absl::OkStatus();
}

// "X0,Y0,X1,Y1": pixels of the full frame, half-open, origin top left.
absl::StatusOr<TileRect> parseCrop(const std::string& text) {
  int v[4];
  const char* p = text.data();
  const char* end = text.data() + text.size();
  for (int i = 0; i < 4; ++i) {
    const auto [next, ec] = std::from_chars(p, end, v[i]);
    const bool separatorOk = i < 3 ? (next != end && *next == ',') : next == end;
    if (ec != std::errc() || !separatorOk) {
      return absl::InvalidArgumentError(fmt::format(
          "--crop '{}': expected X0,Y0,X1,Y1 (four whole numbers: pixels of the full frame, "
          "half-open, origin top left)",
          text));
    }
    p = next + 1;
  }
  return TileRect{v[0], v[1], v[2], v[3]};
}

std::string percent(uint64_t part, uint64_t whole) {
  return whole > 0 ? fmt::format("{:.1f} %", 100.0 * double(part) / double(whole)) : "-";
}

void printTreeReport(const TreeReadReport& t) {
  std::printf("tree %s (%s)\n", t.treePath.c_str(), t.baked ? "baked now" : "reused");
  if (t.baked) std::printf("%s", formatStages(t.bakeStages).c_str());
  std::printf("  gather: %s\n", t.integratorDescription.c_str());
  std::printf("  cache: budget %.1f MiB, %s\n", t.cacheBudget / 1048576.0,
              t.cache.toString().c_str());
  std::printf(
      "  pages read %llu of %llu in the file (%s)\n", static_cast<unsigned long long>(t.pagesRead),
      static_cast<unsigned long long>(t.pagesInFile), percent(t.pagesRead, t.pagesInFile).c_str());
}

int runRender(const RenderOptions& o) {
  auto shot = loadShotFile(o.shot);
  if (!shot.ok()) return reportError(shot.status());
  if (absl::Status s = applyImageFlags(o, &*shot); !s.ok()) return reportError(s);
  FrameRenderRequest request;
  request.frame = o.frame.value_or(shot->firstFrame);
  request.overrides.integrator = o.integrator;
  request.overrides.integratorWhere = {"--integrator"};
  request.overrides.spp = o.spp;
  request.threads = o.threads;
  request.tileSize = o.tileSize;
  request.outPath = o.out;
  request.preview = !o.noPreview;
  if (absl::Status s = integratorParamFlags(o.set,
                                            {{"gather", o.gather},
                                             {"quality", o.quality},
                                             {"max_solid_angle", o.maxSolidAngle},
                                             {"microbuffer_resolution", o.resolution},
                                             {"cache_mb", o.cacheMb}},
                                            &request.overrides.params);
      !s.ok()) {
    return reportError(s);
  }
  request.treePath = o.tree;
  request.bakeDir = o.bakeDir;
  request.rebake = o.rebake;
  if (!o.crop.empty()) {
    auto crop = parseCrop(o.crop);
    if (!crop.ok()) return reportError(crop.status());
    const int width = shot->width * shot->camera.views.x;
    const int height = shot->height * shot->camera.views.y;
    if (absl::Status s = checkRegions({*crop}, width, height); !s.ok()) {
      return reportError(absl::OutOfRangeError(fmt::format(
          "--crop {}: {} (the frame of {})", o.crop, std::string(s.message()), shot->path)));
    }
    request.regions = {*crop};
  }
  Progress progress(fmt::format("render {} frame {}", shot->name, request.frame));
  Progress bakeProgress(fmt::format("bake {} frame {}", shot->name, request.frame));
  request.bakeProgress = [&](const std::string& stage, uint64_t done, uint64_t total) {
    bakeProgress.update(stage, done, total);
  };
  request.progress = [&](int done, int total) {
    if (done == 1) bakeProgress.finish();
    progress.update("tiles", done, total);
  };

  auto report = renderShotFrame(*shot, request);
  progress.finish();
  if (!report.ok()) return reportError(report.status());
  for (const std::string& w : report->warnings)
    std::fprintf(stderr, "pbgi: warning: %s\n", w.c_str());
  std::printf("wrote %s\n", report->imagePath.c_str());
  if (!report->previewPath.empty()) std::printf("preview %s\n", report->previewPath.c_str());
  std::printf("%s", formatStages(report->stages).c_str());
  if (report->tree) printTreeReport(*report->tree);
  std::printf("%s", formatCounters(*report).c_str());
  const RenderCounters& c = report->counters;
  std::printf("  samples %llu, discarded (NaN/Inf) %llu, pixels that see nothing %llu\n",
              static_cast<unsigned long long>(c.cameraSamples),
              static_cast<unsigned long long>(c.discardedSamples),
              static_cast<unsigned long long>(c.pixelsWithoutHit));
  std::printf("wall time %.3f s\n", report->wallSeconds);
  return kExitOk;
}

}  // namespace

void registerRenderCommand(CLI::App& app, CommandAction& action) {
  auto options = std::make_shared<RenderOptions>();
  CLI::App* cmd = app.add_subcommand(
      "render", "Render one frame of a shot in this process and write an OpenEXR");
  cmd->add_option("SHOT", options->shot, "Shot file (TOML)")->required();
  cmd->add_option("--frame", options->frame, "Frame to render (default: the shot's first)");
  cmd->add_option("--integrator", options->integrator, "Integrator (default: the shot's)");
  cmd->add_option("--spp", options->spp, "Camera samples per pixel (default: the shot's)")
      ->check(positiveNumber());
  cmd->add_option("--threads", options->threads, "Worker threads (default: all cores)")
      ->check(positiveNumber());
  cmd->add_option("--tile-size", options->tileSize, "Tile edge in pixels (default: the shot's)")
      ->check(CLI::Range(4, 1024));
  cmd->add_option("--out", options->out,
                  "Output image, its format by extension: .exr (every AOV), .tif/.tiff/.hdr "
                  "(colour in float), .png/.jpg (8-bit through the OCIO view) (default: the "
                  "shot's output pattern)");
  cmd->add_flag("--no-preview", options->noPreview, "Do not write the PNG preview");
  auto* size = cmd->add_option("--resolution", options->imageSize,
                               "Image size W,H of each view (default: the shot's resolution)");
  cmd->add_option("--scale", options->scale,
                  "Scale the shot's resolution, e.g. 0.5 for a half-size check render")
      ->check(positiveNumber())
      ->excludes(size);
  cmd->add_option("--seed", options->seed,
                  "Sampling seed (default: the shot's seed); a render is a function of it");
  cmd->add_option("--crop", options->crop,
                  "Render only pixels X0,Y0,X1,Y1 of the full frame (half-open, origin top "
                  "left): the EXR's data window, in the frame's display window, bit for bit "
                  "the full render's pixels there");
  addIntegratorParamFlags(*cmd, options->set, options->gather, options->quality);
  cmd->add_option("--max-solid-angle", options->maxSolidAngle,
                  "PBGI per-pixel: largest solid angle (sr) splatted as one cluster (default: the "
                  "preset's)");
  cmd->add_option("--microbuffer-resolution", options->resolution,
                  "PBGI: microbuffer pixels per cube face side (default: the preset's)");
  cmd->add_option("--cache-mb", options->cacheMb,
                  "PBGI: tree page cache budget in MiB (default: the shot's cache_mb, 256)");
  cmd->add_option("--tree", options->tree,
                  "PBGI: render from this .pbgi tree instead of the frame's bake");
  cmd->add_option("--bake-dir", options->bakeDir,
                  "PBGI: where the frame's bake is found or written (default: beside the image)");
  cmd->add_flag("--rebake", options->rebake, "PBGI: bake again even when a matching bake exists");
  cmd->callback([options, &action] { action = [options] { return runRender(*options); }; });
}

}  // namespace pbgi::cli
