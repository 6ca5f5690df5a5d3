#include "services/render/frame_render.h"


#include <fmt/format.h>

#include <filesystem>

#include "core/render/integrator.h"
#include "core/render/pbgi_integrator.h"
#include "formats/pbgi/tree_file.h"
#include "services/bake/frame_bake.h"
#include "services/render/frame_assembly.h"
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

// The tree a PBGI render reads: request.treePath, else the frame's bake when one made from
// the same shot bytes and bake settings is on disk, else a new bake.
absl::StatusOr<std::unique_ptr<TreeFile>> frameTree(const ShotDesc& shot,
                                                    const FrameRenderRequest& request,
                                                    const Scene& scene, TreeReadReport* report) {
  if (!request.treePath.empty()) {
    report->treePath = request.treePath;
    return TreeFile::open(request.treePath);
  }
  auto bake = shotBakeRequest(shot, request.frame);
  if (!bake.ok()) return bake.status();
  bake->outDir = request.bakeDir;
  bake->threads = request.threads;
  bake->progress = request.bakeProgress;
  report->treePath = bakeTreePath(shot, *bake);
  if (!request.rebake && std::filesystem::exists(report->treePath)) {
    auto existing = TreeFile::open(report->treePath);
    if (existing.ok() && (*existing)->container().info().sceneHash == bakeHash(shot, *bake)) {
      return existing;
    }
  }
  auto baked = bakeShotFrame(shot, *bake, &scene);
  if (!baked.ok()) return baked.status();
  report->baked = true;
  report->bakeStages = baked->stages;
  return TreeFile::open(report->treePath);
}

}  // namespace

std::string writePreviewBeside(const Image& image, const std::string& exrPath,
                               const std::string& ocioConfig, std::vector<std::string>* warnings) {
  const std::string path = previewPathFor(exrPath);
  const std::string config = ocioConfig.empty() ? defaultOcioConfigPath() : ocioConfig;
  if (absl::Status s = writePreviewPng(image, path, config); !s.ok()) {
    warnings->push_back(fmt::format("no preview: {}", s.message()));
    return {};
  }
  return path;
}

const std::vector<std::string>& availableIntegrators() {
  static const std::vector<std::string> names = {"path", "pbgi"};
  return names;
}

absl::StatusOr<GatherOptions> pbgiGatherOptions(const RenderSettings& settings,
                                                const FrameRenderRequest& request) {
  auto options = gatherPreset(request.quality.empty() ? settings.quality : request.quality);
  if (!options.ok()) return options.status();
  const float solidAngle =
      request.maxSolidAngle > 0.0f ? request.maxSolidAngle : settings.maxSolidAngle;
  if (solidAngle > 0.0f) options->maxSolidAngle = solidAngle;
  const int resolution = request.microbufferResolution > 0 ? request.microbufferResolution
                                                           : settings.microbufferResolution;
  if (resolution > 0) options->resolution = resolution;
  if (absl::Status s = options->validate(); !s.ok()) return s;
  return *options;
}

absl::StatusOr<FrameRenderReport> renderShotFrame(const ShotDesc& shot,
                                                  const FrameRenderRequest& request) {
  FrameRenderReport report;
  StageClock clock(&report.stages);
  if (absl::Status s = checkShotFrame(shot, request.frame); !s.ok()) return s;
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
  FrameRenderOptions options;
  options.threads = request.threads;
  options.tileSize = request.tileSize;
  options.progress = request.progress;
  options.region = request.region;

  // The PBGI integrator reads its frame's tree through a page cache; both outlive the render.
  std::unique_ptr<TreeFile> treeFile;
  std::optional<PageCache> cache;
  std::unique_ptr<Integrator> integrator;
  if (settings.integrator == "pbgi") {
    auto gather = pbgiGatherOptions(settings, request);
    if (!gather.ok()) return gather.status();
    TreeReadReport& tree = report.tree.emplace();
    tree.gather = gather->toString();
    auto file = frameTree(shot, request, *frameScene->scene, &tree);
    if (!file.ok()) return file.status();
    treeFile = *std::move(file);
    clock.lap(tree.baked ? "bake" : "tree");
    tree.cacheBudget = request.cacheBytes > 0 ? request.cacheBytes
                                              : static_cast<size_t>(settings.cacheMb) << 20;
    cache.emplace(*treeFile, PageCacheOptions{.budgetBytes = tree.cacheBudget});
    integrator = std::make_unique<PbgiIntegrator>(
        *frameScene->scene, *cache,
        PbgiIntegratorSettings{.gather = *gather,
                               .glossy = glossyGatherOptions(*gather),
                               .maxGathersPerPixel = settings.gathersPerPixel,
                               .pathTracer = pt});
  } else {
    integrator = std::make_unique<PathIntegrator>(*frameScene->scene, pt);
  }
  auto image = renderFrame(*integrator, frameScene->camera, settings, request.frame, options,
                           &report.counters);
  if (!image.ok()) return image.status();
  if (cache) {
    report.tree->cache = cache->counters();
    report.tree->pagesRead = cache->distinctPagesLoaded();
    report.tree->pagesInFile = treeFile->container().directory().size();
  }
  if (request.region) {
    absl::StatusOr<Image> cropped = cropImage(*image, *request.region);
    if (!cropped.ok()) return cropped.status();
    image = std::move(cropped);
  }
  clock.lap("render");
  const double renderSeconds = report.stages.back().seconds;

  image->setMetadata("pbgi/shot", shot.name);
  image->setMetadata("pbgi/shotFile", shot.path);
  image->setMetadata("pbgi/frame", request.frame);
  image->setMetadata("pbgi/integrator", settings.integrator);
  image->setMetadata("pbgi/spp", settings.spp);
  image->setMetadata("pbgi/seed", std::to_string(settings.seed));
  image->setMetadata("pbgi/maxDepth", settings.maxDepth);
  image->setMetadata("pbgi/renderSeconds", static_cast<float>(renderSeconds));
  image->setMetadata("pbgi/discardedSamples", static_cast<int>(report.counters.discardedSamples));
  image->setMetadata("pbgi/version", std::string(PBGI_VERSION));
  if (request.region) image->setMetadata("pbgi/region", regionText(*request.region));
  if (report.tree) {
    image->setMetadata("pbgi/tree", report.tree->treePath);
    image->setMetadata("pbgi/gather", report.tree->gather);
  }

  report.exrPath = request.outPath.empty()
                       ? outputPathForFrame(shot.output, request.frame,
                                            shot.lastFrame > shot.firstFrame)
                       : request.outPath;
  if (absl::Status s = writeExr(*image, report.exrPath); !s.ok()) return s;
  if (request.preview) {
    report.previewPath =
        writePreviewBeside(*image, report.exrPath, request.ocioConfig, &report.warnings);
  }
  clock.lap("write");
  report.wallSeconds = clock.totalSeconds();
  return report;
}

}  // namespace pbgi
