#include "services/render/frame_render.h"


#include <fmt/format.h>

#include <filesystem>

#include "core/render/integrator.h"
#include "core/render/integrators.h"
#include "formats/pbgi/tree_file.h"
#include "services/bake/frame_bake.h"
#include "services/render/frame_assembly.h"
#include "core/util/status.h"
#include "formats/image/image_io.h"
#include "formats/image/ocio_config.h"
#include "formats/scene/frame_scene.h"

namespace pbgi {

namespace {

std::string previewPathFor(const std::string& imagePath) {
  const size_t dot = imagePath.find_last_of('.');
  const size_t slash = imagePath.find_last_of('/');
  if (dot == std::string::npos || (slash != std::string::npos && dot < slash)) {
    return imagePath + ".png";
  }
  return imagePath.substr(0, dot) + ".png";
}

// The tree a PBGI render reads: request.treePath, else the frame's bake when one made from
// the same shot bytes and bake settings is on disk, else a new bake.
absl::StatusOr<std::shared_ptr<TreeFile>> frameTree(const ShotDesc& shot,
                                                    const RenderSettings& settings,
                                                    const FrameRenderRequest& request,
                                                    const Scene& scene, TreeReadReport* report) {
  if (request.openTree) {
    auto opened = request.openTree();
    if (opened.ok()) report->treePath = (*opened)->container().path();
    return opened;
  }
  if (!request.treePath.empty()) {
    report->treePath = request.treePath;
    return TreeFile::open(request.treePath);
  }
  ShotDesc baked = shot;
  baked.render = settings;
  auto bake = shotBakeRequest(baked, request.frame);
  if (!bake.ok()) return bake.status();
  bake->outDir = request.bakeDir;
  bake->threads = request.threads;
  bake->progress = request.bakeProgress;
  bake->cancel = request.cancel;
  report->treePath = bakeTreePath(baked, *bake);
  if (!request.rebake && std::filesystem::exists(report->treePath)) {
    auto existing = TreeFile::open(report->treePath);
    if (existing.ok() && (*existing)->container().info().sceneHash == bakeHash(baked, *bake)) {
      return existing;
    }
  }
  auto result = bakeShotFrame(baked, *bake, &scene);
  if (!result.ok()) return result.status();
  report->baked = true;
  report->bakeStages = result->stages;
  return TreeFile::open(report->treePath);
}

}  // namespace

std::string writePreviewBeside(const Image& image, const std::string& imagePath,
                               const std::string& ocioConfig, std::vector<std::string>* warnings) {
  const std::string path = previewPathFor(imagePath);
  if (path == imagePath) return {};  // the image is its own preview (a .png output)
  const std::string config = ocioConfig.empty() ? defaultOcioConfigPath() : ocioConfig;
  if (absl::Status s = writePreviewPng(image, path, config); !s.ok()) {
    warnings->push_back(fmt::format("no preview: {}", s.message()));
    return {};
  }
  return path;
}

std::string formatCounters(const FrameRenderReport& report) {
  std::string text;
  for (size_t i = 0; i < report.counterSpecs.size(); ++i) {
    if (report.counters[i] == 0) continue;
    text += fmt::format("  {} {}\n", report.counterSpecs[i].name, report.counters[i]);
  }
  return text;
}

absl::StatusOr<RenderSettings> requestSettings(const ShotDesc& shot,
                                               const FrameRenderRequest& request) {
  RenderSettings settings = shot.render;
  PBGI_RETURN_IF_ERROR(applyRenderOverrides(settings, request.overrides));
  return settings;
}

absl::StatusOr<FrameRenderReport> renderShotFrame(const ShotDesc& shot,
                                                  const FrameRenderRequest& request) {
  FrameRenderReport report;
  StageClock clock(&report.stages);
  PBGI_RETURN_IF_ERROR(checkShotFrame(shot, request.frame));
  // Before a bake: a region the frame cannot hold fails now, not minutes later.
  PBGI_RETURN_IF_ERROR(checkRegions(request.regions, shot.width * shot.camera.views.x,
                                    shot.height * shot.camera.views.y));
  const OutputOptions& output = request.output ? *request.output : shot.outputOptions;
  if (output.aovs) PBGI_RETURN_IF_ERROR(checkAovs(*output.aovs));
  PBGI_RETURN_IF_ERROR(checkExrCompression(output.exrCompression, "EXR compression"));
  report.imagePath = request.outPath.empty() ? outputPathForFrame(shot.output, request.frame,
                                                                  shot.lastFrame > shot.firstFrame)
                                             : request.outPath;
  PBGI_RETURN_IF_ERROR(outputFormatFor(report.imagePath).status());  // before the render's time
  PBGI_ASSIGN_OR_RETURN(const RenderSettings settings, requestSettings(shot, request));
  PBGI_ASSIGN_OR_RETURN(const IntegratorInfo* info, findIntegrator(settings.integrator));
  report.integrator = settings.integrator;
  report.counterSpecs.assign(info->counters.begin(), info->counters.end());

  std::optional<FrameScene> loaded;
  const FrameScene* frameScene = request.scene;
  if (frameScene == nullptr) {
    auto scene = loadFrameScene(shot, request.frame);
    if (!scene.ok()) return scene.status();
    loaded = std::move(*scene);
    frameScene = &*loaded;
  }
  report.warnings = frameScene->warnings;
  clock.lap("load");

  FrameRenderOptions options;
  options.threads = request.threads;
  options.tileSize = request.tileSize;
  options.progress = request.progress;
  options.cancel = request.cancel;
  options.regions = request.regions;

  // An integrator that needs the frame's tree reads it through a page cache; both outlive the
  // render.
  std::shared_ptr<TreeFile> treeFile;
  std::optional<PageCache> cache;
  if (info->needsTree) {
    const TreeSettings needs = info->treeSettings(settings);
    TreeReadReport& tree = report.tree.emplace();
    tree.integratorDescription = info->describe(settings);
    PBGI_ASSIGN_OR_RETURN(treeFile,
                          frameTree(shot, settings, request, *frameScene->scene, &tree));
    clock.lap(tree.baked ? "bake" : "tree");
    tree.cacheBudget = request.cacheBytes > 0 ? request.cacheBytes : needs.cacheBytes;
    cache.emplace(*treeFile, PageCacheOptions{.budgetBytes = tree.cacheBudget,
                                              .policy = needs.cachePolicy});
  }
  const std::unique_ptr<Integrator> integrator = info->create(
      {.scene = *frameScene->scene, .settings = settings, .tree = cache ? &*cache : nullptr});
  auto image = renderFrame(*integrator, frameScene->camera, settings, request.frame, options,
                           &report.counters);
  if (!image.ok()) return image.status();
  if (cache) {
    report.tree->cache = cache->counters();
    report.tree->pagesRead = cache->distinctPagesLoaded();
    report.tree->pagesInFile = treeFile->container().directory().size();
    report.tree->fileBytes = treeFile->container().info().fileSize;
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
  if (!request.regions.empty()) image->setMetadata("pbgi/regions", regionsText(request.regions));
  if (report.tree) {
    image->setMetadata("pbgi/tree", report.tree->treePath);
    image->setMetadata("pbgi/gather", report.tree->integratorDescription);
  }

  const std::string ocio =
      request.ocioConfig.empty() ? defaultOcioConfigPath() : request.ocioConfig;
  if (output.aovs) {
    PBGI_ASSIGN_OR_RETURN(*image, keepAovs(*image, *output.aovs));
  }
  PBGI_RETURN_IF_ERROR(
      writeRender(*image, report.imagePath, ocio, &report.warnings, output.exrCompression));
  if (request.preview) {
    report.previewPath =
        writePreviewBeside(*image, report.imagePath, request.ocioConfig, &report.warnings);
  }
  clock.lap("write");
  report.wallSeconds = clock.totalSeconds();
  return report;
}

}  // namespace pbgi
