// pbgi render SHOT [--frame N | --frames LIST] [--integrator NAME] [--spp N] [--threads N]
//                  [--out FILE.exr] [--crop X0,Y0,X1,Y1] [--aovs LIST] [--exr-compression C]
//                  [--json]

#include <algorithm>
#include <charconv>
#include <cmath>
#include <cstdio>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include "core/render/integrators.h"
#include "core/util/status.h"
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
  std::string frames;  // --frames 1-3,7
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
  ImageFlags image;  // --resolution / --scale, --seed, --aovs, --exr-compression
  bool json = false;
};

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

// The frames asked for: --frames, --frame, or the shot's first.
absl::StatusOr<std::vector<int>> renderFrames(const RenderOptions& o, const ShotDesc& shot) {
  std::vector<int> frames = {o.frame.value_or(shot.firstFrame)};
  if (!o.frames.empty()) {
    PBGI_ASSIGN_OR_RETURN(frames, parseFrameList(o.frames));
  }
  for (const int f : frames) PBGI_RETURN_IF_ERROR(checkShotFrame(shot, f));
  if (frames.size() > 1 && !o.out.empty() && o.out.find('#') == std::string::npos) {
    return absl::InvalidArgumentError(
        fmt::format("--out {}: {} frames would write one file; put #### in it for the frame number",
                    o.out, frames.size()));
  }
  return frames;
}

absl::StatusOr<FrameRenderRequest> baseRequest(const RenderOptions& o, const ShotDesc& shot) {
  FrameRenderRequest request;
  request.overrides.integrator = o.integrator;
  request.overrides.integratorWhere = {"--integrator"};
  request.overrides.spp = o.spp;
  request.threads = o.threads;
  request.tileSize = o.tileSize;
  request.preview = !o.noPreview;
  PBGI_RETURN_IF_ERROR(integratorParamFlags(o.set,
                                            {{"gather", o.gather},
                                             {"quality", o.quality},
                                             {"max_solid_angle", o.maxSolidAngle},
                                             {"microbuffer_resolution", o.resolution},
                                             {"cache_mb", o.cacheMb}},
                                            &request.overrides.params));
  request.treePath = o.tree;
  request.bakeDir = o.bakeDir;
  request.rebake = o.rebake;
  if (!o.crop.empty()) {
    PBGI_ASSIGN_OR_RETURN(const TileRect crop, parseCrop(o.crop));
    const int width = shot.width * shot.camera.views.x;
    const int height = shot.height * shot.camera.views.y;
    if (absl::Status s = checkRegions({crop}, width, height); !s.ok()) {
      return absl::OutOfRangeError(fmt::format("--crop {}: {} (the frame of {})", o.crop,
                                               std::string(s.message()), shot.path));
    }
    request.regions = {crop};
  }
  return request;
}

void printReport(const FrameRenderReport& report) {
  for (const std::string& w : report.warnings)
    std::fprintf(stderr, "pbgi: warning: %s\n", w.c_str());
  std::printf("wrote %s\n", report.imagePath.c_str());
  if (!report.previewPath.empty()) std::printf("preview %s\n", report.previewPath.c_str());
  std::printf("%s", formatStages(report.stages).c_str());
  if (report.tree) printTreeReport(*report.tree);
  std::printf("%s", formatCounters(report).c_str());
  const RenderCounters& c = report.counters;
  std::printf("  samples %llu, discarded (NaN/Inf) %llu, pixels that see nothing %llu\n",
              static_cast<unsigned long long>(c.cameraSamples),
              static_cast<unsigned long long>(c.discardedSamples),
              static_cast<unsigned long long>(c.pixelsWithoutHit));
  std::printf("wall time %.3f s\n", report.wallSeconds);
}

// One frame's statistics for --json: every field always present (null where it does not
// apply), integers as numbers.
nlohmann::ordered_json reportJson(int frame, const FrameRenderReport& report) {
  nlohmann::ordered_json stages = nlohmann::ordered_json::object();
  for (const StageTime& st : report.stages) stages[st.stage] = st.seconds;
  nlohmann::ordered_json counters = nlohmann::ordered_json::object();
  for (size_t i = 0; i < report.counterSpecs.size() && i < report.counters.values.size(); ++i) {
    counters[std::string(report.counterSpecs[i].name)] = report.counters.values[i];
  }
  nlohmann::ordered_json tree = nullptr;
  if (report.tree) {
    const TreeReadReport& t = *report.tree;
    tree = {{"path", t.treePath},
            {"baked", t.baked},
            {"gather", t.integratorDescription},
            {"cache_budget_bytes", t.cacheBudget},
            {"cache_hits", t.cache.hits},
            {"cache_misses", t.cache.misses},
            {"pages_read", t.pagesRead},
            {"pages_in_file", t.pagesInFile},
            {"file_bytes", t.fileBytes}};
  }
  return {{"frame", frame},
          {"integrator", report.integrator},
          {"image", report.imagePath},
          {"preview", report.previewPath.empty() ? nlohmann::ordered_json(nullptr)
                                                 : nlohmann::ordered_json(report.previewPath)},
          {"wall_seconds", report.wallSeconds},
          {"stages", stages},
          {"samples", report.counters.cameraSamples},
          {"discarded_samples", report.counters.discardedSamples},
          {"pixels_without_hit", report.counters.pixelsWithoutHit},
          {"counters", counters},
          {"tree", tree},
          {"warnings", report.warnings}};
}

int runRender(const RenderOptions& o) {
  auto shot = loadShotFile(o.shot);
  if (!shot.ok()) return reportError(shot.status());
  // The image's size, seed and output options become the shot's, as a farm job's do.
  RenderOverrides image;
  if (absl::Status s = imageOverrides(o.image, *shot, &image); !s.ok()) return reportError(s);
  if (absl::Status s = applyShotOverrides(*shot, image); !s.ok()) return reportError(s);
  const absl::StatusOr<std::vector<int>> frames = renderFrames(o, *shot);
  if (!frames.ok()) return reportError(frames.status());
  absl::StatusOr<FrameRenderRequest> base = baseRequest(o, *shot);
  if (!base.ok()) return reportError(base.status());
  nlohmann::ordered_json json = {{"shot", shot->path}, {"frames", nlohmann::ordered_json::array()}};
  for (const int frame : *frames) {
    FrameRenderRequest request = *base;
    request.frame = frame;
    if (!o.out.empty()) request.outPath = outputPathForFrame(o.out, frame, frames->size() > 1);
    Progress progress(fmt::format("render {} frame {}", shot->name, frame));
    Progress bakeProgress(fmt::format("bake {} frame {}", shot->name, frame));
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
    if (o.json) {
      json["frames"].push_back(reportJson(frame, *report));
    } else {
      printReport(*report);
    }
  }
  if (o.json) std::printf("%s\n", json.dump(2).c_str());
  return kExitOk;
}

}  // namespace

void registerRenderCommand(CLI::App& app, CommandAction& action) {
  auto options = std::make_shared<RenderOptions>();
  CLI::App* cmd = app.add_subcommand(
      "render", "Render one frame of a shot in this process and write an OpenEXR");
  cmd->add_option("SHOT", options->shot, "Shot file (TOML)")->required();
  auto* frame =
      cmd->add_option("--frame", options->frame, "Frame to render (default: the shot's first)");
  cmd->add_option("--frames", options->frames,
                  "Frames to render one after another, e.g. 1-3,7 (--out then needs ####)")
      ->excludes(frame);
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
  cmd->add_flag("--json", options->json,
                "Print each frame's statistics (stages, counters, tree, cache) as JSON");
  addImageFlags(*cmd, options->image);
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
