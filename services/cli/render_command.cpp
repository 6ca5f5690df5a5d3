// pbgi render SHOT [--frame N] [--integrator NAME] [--spp N] [--threads N] [--out FILE.exr]

#include <cstdio>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "formats/shot/shot_file.h"
#include "services/cli/cli.h"
#include "services/cli/progress.h"
#include "services/render/frame_render.h"

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
};

int runRender(const RenderOptions& o) {
  auto shot = loadShotFile(o.shot);
  if (!shot.ok()) return reportError(shot.status());
  FrameRenderRequest request;
  request.frame = o.frame.value_or(shot->firstFrame);
  request.integrator = o.integrator;
  request.spp = o.spp;
  request.threads = o.threads;
  request.tileSize = o.tileSize;
  request.outPath = o.out;
  request.preview = !o.noPreview;
  Progress progress(fmt::format("render {} frame {}", shot->name, request.frame));
  request.progress = [&](int done, int total) { progress.update(done, total); };
  auto report = renderShotFrame(*shot, request);
  progress.finish();
  if (!report.ok()) return reportError(report.status());
  for (const std::string& w : report->warnings) std::fprintf(stderr, "pbgi: warning: %s\n", w.c_str());
  std::printf("wrote %s\n", report->exrPath.c_str());
  if (!report->previewPath.empty()) std::printf("preview %s\n", report->previewPath.c_str());
  std::printf("%s", formatStages(report->stages).c_str());
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
      ->check(CLI::PositiveNumber);
  cmd->add_option("--threads", options->threads, "Worker threads (default: all cores)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--tile-size", options->tileSize, "Tile edge in pixels (default: the shot's)")
      ->check(CLI::Range(4, 1024));
  cmd->add_option("--out", options->out, "Output EXR (default: the shot's output pattern)");
  cmd->add_flag("--no-preview", options->noPreview, "Do not write the PNG preview");
  cmd->callback([options, &action] { action = [options] { return runRender(*options); }; });
}

}  // namespace pbgi::cli
