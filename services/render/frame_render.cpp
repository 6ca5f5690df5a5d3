#include "services/render/frame_render.h"


#include <fmt/format.h>

#include "core/render/integrator.h"
#include "core/util/status.h"
#include "formats/image/image_io.h"
#include "formats/image/ocio_config.h"
#include "formats/scene/frame_scene.h"

namespace pbgi {

namespace {

std::string previewPathFor(const std::string& exrPath) {
  const size_t dot = exrPath.find_last_of('.');
  const size_t slash = exrPath.find_last_of('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) {
    return exrPath + ".png";
  }
  return exrPath.substr(0, dot) + ".png";
}

}  // namespace

const std::vector<std::string>& availableIntegrators() {
  static const std::vector<std::string> names = {"path"};
  return names;
}

absl::StatusOr<FrameRenderReport> renderShotFrame(const ShotDesc& shot,
                                                  const FrameRenderRequest& request) {
  FrameRenderReport report;
  StageClock clock(&report.stages);
  if (request.frame < shot.firstFrame || request.frame > shot.lastFrame) {
    return absl::OutOfRangeError(fmt::format("{}: frame {} is outside the shot's frames [{}, {}]",
                                             shot.path, request.frame, shot.firstFrame,
                                             shot.lastFrame));
  }
  RenderSettings settings = shot.render;
  if (!request.integrator.empty()) settings.integrator = request.integrator;
  if (request.spp > 0) settings.spp = request.spp;
  const auto& names = availableIntegrators();
  if (std::find(names.begin(), names.end(), settings.integrator) == names.end()) {
    return absl::InvalidArgumentError(fmt::format(
        "integrator '{}' is not available in this build (available: {})", settings.integrator,
        fmt::join(names, ", ")));
  }

  auto frameScene = loadFrameScene(shot, request.frame);
  if (!frameScene.ok()) return frameScene.status();
  report.warnings = frameScene->warnings;
  clock.lap("load");

  PathTracerSettings pt;
  pt.maxDepth = settings.maxDepth;
  pt.rouletteDepth = settings.rouletteDepth;
  const PathIntegrator integrator(*frameScene->scene, pt);

  FrameRenderOptions options;
  options.threads = request.threads;
  options.tileSize = request.tileSize;
  options.progress = request.progress;
  Image image = renderFrame(integrator, frameScene->camera, settings, request.frame, options,
                            &report.counters);
  clock.lap("render");
  const double renderSeconds = report.stages.back().seconds;

  image.setMetadata("pbgi/shot", shot.name);
  image.setMetadata("pbgi/shotFile", shot.path);
  image.setMetadata("pbgi/frame", request.frame);
  image.setMetadata("pbgi/integrator", settings.integrator);
  image.setMetadata("pbgi/spp", settings.spp);
  image.setMetadata("pbgi/seed", std::to_string(settings.seed));
  image.setMetadata("pbgi/maxDepth", settings.maxDepth);
  image.setMetadata("pbgi/renderSeconds", static_cast<float>(renderSeconds));
  image.setMetadata("pbgi/discardedSamples", static_cast<int>(report.counters.discardedSamples));
  image.setMetadata("pbgi/version", std::string(PBGI_VERSION));

  report.exrPath = request.outPath.empty()
                       ? outputPathForFrame(shot.output, request.frame,
                                            shot.lastFrame > shot.firstFrame)
                       : request.outPath;
  if (absl::Status s = writeExr(image, report.exrPath); !s.ok()) return s;
  if (request.preview) {
    const std::string config =
        request.ocioConfig.empty() ? defaultOcioConfigPath() : request.ocioConfig;
    report.previewPath = previewPathFor(report.exrPath);
    if (absl::Status s = writePreviewPng(image, report.previewPath, config); !s.ok()) {
      report.warnings.push_back(fmt::format("no preview: {}", s.message()));
      report.previewPath.clear();
    }
  }
  clock.lap("write");
  report.wallSeconds = clock.totalSeconds();
  return report;
}

}  // namespace pbgi
