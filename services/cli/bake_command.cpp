// pbgi bake SHOT --frame N [--out DIR] [--points N] [--mem-budget SIZE] [--bounces K] ...

#include <cstdio>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "formats/pbgi/tree_file.h"
#include "formats/shot/shot_file.h"
#include "services/bake/frame_bake.h"
#include "services/cli/cli.h"
#include "services/cli/progress.h"
#include "services/util/cli_checks.h"

namespace pbgi::cli {

namespace {

struct BakeOptions {
  std::string shot;
  std::optional<int> frame;
  std::string out;
  std::optional<uint64_t> points;
  std::string memBudget = "1G";
  std::optional<int> bounces;
  int bounceSpacing = kBounceReceiverSpacing;
  int lightSamples = 16;
  int threads = 0;
  int leafSize = kDefaultLeafSize;
  std::string pageSize = "64K";
  std::string encoding = "quantized";
  int powerCentres = TreeWriteOptions{}.powerCentres;
  std::string pointCloud = "auto";
  std::string tempDir;
  std::optional<std::string> bounceQuality;
  bool noTail = false;
  std::optional<float> waveletError;
  std::optional<int> waveletResolution;
  float glossyPairs = 0.0f;
};

int runBake(const BakeOptions& o) {
  auto shot = loadShotFile(o.shot);
  if (!shot.ok()) return reportError(shot.status());
  // The shot's bake settings, then the flags over them.
  auto shotRequest = shotBakeRequest(*shot, o.frame.value_or(shot->firstFrame));
  if (!shotRequest.ok()) return reportError(shotRequest.status());
  FrameBakeRequest request = *shotRequest;
  request.outDir = o.out;
  if (o.points) request.points = *o.points;
  auto budget = parseByteSize(o.memBudget, "--mem-budget");
  if (!budget.ok()) return reportError(budget.status());
  request.memoryBudget = *budget;
  auto pageSize = parseByteSize(o.pageSize, "--page-size");
  if (!pageSize.ok()) return reportError(pageSize.status());
  if (*pageSize > kMaxPageSize || *pageSize < kMinPageSize || (*pageSize & (*pageSize - 1)) != 0) {
    return reportError(absl::InvalidArgumentError(fmt::format(
        "--page-size {}: expected a power of two from {} to {} bytes", o.pageSize, kMinPageSize,
        kMaxPageSize)));
  }
  request.tree.pageSize = static_cast<uint32_t>(*pageSize);
  request.tree.build.leafSize = o.leafSize;
  if (o.waveletError) request.tree.wavelets.relativeError = *o.waveletError;
  if (o.waveletResolution) request.waveletResolution = *o.waveletResolution;
  request.glossyPairThreshold = o.glossyPairs;
  request.tree.powerCentres = o.powerCentres;
  // CLI11 has already checked the name against the same list.
  request.tree.encoding = parseTreeEncoding(o.encoding).value_or(TreeEncoding::kQuantized);
  if (request.tree.encoding == TreeEncoding::kQuantized8) {
    request.tree.powerCentres =
        std::min(request.tree.powerCentres, maxCodebookEntries(TreeEncoding::kQuantized8) - 1);
  }
  request.pointCloud = o.pointCloud == "always"  ? PointCloudMode::kAlways
                       : o.pointCloud == "never" ? PointCloudMode::kNever
                                                 : PointCloudMode::kAuto;
  if (o.bounces) request.bounces = *o.bounces;
  if (o.bounceQuality) {
    auto cut = bounceCutPreset(*o.bounceQuality);
    if (!cut.ok()) return reportError(cut.status());
    request.bounceCut = *cut;
  }
  request.bounceTail = !o.noTail;
  request.bounceSpacing = o.bounceSpacing;
  request.lightSamples = o.lightSamples;
  request.threads = o.threads;
  request.tempDir = o.tempDir;
  Progress progress(fmt::format("bake {} frame {}", shot->name, request.frame));
  request.progress = [&](const std::string& stage, uint64_t done, uint64_t total) {
    progress.update(stage, done, total);
  };
  auto report = bakeShotFrame(*shot, request);
  progress.finish();
  if (!report.ok()) return reportError(report.status());
  for (const std::string& w : report->warnings) std::fprintf(stderr, "pbgi: warning: %s\n", w.c_str());
  const TreeWriteResult& t = report->tree;
  std::printf("wrote %s (%.1f MiB)\n", report->treePath.c_str(), report->treeFileBytes / 1048576.0);
  if (!report->pointCloudPath.empty()) std::printf("wrote %s\n", report->pointCloudPath.c_str());
  std::printf("  surfels %llu (radius %g), emissive %llu, light samples discarded %llu\n",
              static_cast<unsigned long long>(report->sampling.surfels), report->sampling.radius,
              static_cast<unsigned long long>(report->shading.emissive),
              static_cast<unsigned long long>(report->shading.discardedSamples));
  std::printf("  tree: %llu nodes, %llu leaves, %llu pages, %.1f bytes/node in the file\n",
              static_cast<unsigned long long>(t.build.nodes),
              static_cast<unsigned long long>(t.build.leaves),
              static_cast<unsigned long long>(t.pages.pages),
              t.build.nodes > 0 ? double(report->treeFileBytes) / double(t.build.nodes) : 0.0);
  if (quantized(request.tree.encoding)) {
    std::printf(
        "  codebooks: power %d entries, area %d entries; quantization error (relative RMS) "
        "power %.3g, area %.3g, worst node %.3g\n",
        t.codebooks.power.size(), t.codebooks.area.size(), t.quantization.power.relativeRms,
        t.quantization.area.relativeRms, t.quantization.power.maxRelative);
  }
  if (t.wavelets.nodes > 0) {
    std::printf(
        "  wavelets (glossy light): %llu leaves baked, %llu nodes, %llu vectors stored (%llu as "
        "differences from their parent's), %llu coefficients, %llu bytes (%.1f%% of the file), "
        "worst relative error %.3g\n",
        static_cast<unsigned long long>(t.wavelets.leaves),
        static_cast<unsigned long long>(t.wavelets.nodes),
        static_cast<unsigned long long>(t.wavelets.stored),
        static_cast<unsigned long long>(t.wavelets.differences),
        static_cast<unsigned long long>(t.wavelets.coefficients),
        static_cast<unsigned long long>(t.wavelets.bytes),
        report->treeFileBytes > 0 ? 100.0 * double(t.wavelets.bytes) / double(report->treeFileBytes)
                                  : 0.0,
        t.wavelets.maxRelativeError);
  } else {
    std::printf("  wavelets: none (no glossy or refractive material needs them)\n");
  }
  std::printf("  sort: %s\n", report->sort.toString().c_str());
  if (request.bounces > 0) {
    std::printf("  bounces: %s\n    cuts: %s\n", request.bounceCut.toString().c_str(),
                report->bounceCut.toString().c_str());
    std::printf("    page caches (%llu MiB each): %llu loads of %llu pages in the trees read, "
                "%llu hits\n",
                static_cast<unsigned long long>(request.memoryBudget / 4 >> 20),
                static_cast<unsigned long long>(report->bounceCacheLoads),
                static_cast<unsigned long long>(report->bounceTreePages),
                static_cast<unsigned long long>(report->bounceCacheHits));
    std::printf("    records' sides shut (nothing gathered in the bounces before): %llu, not "
                "gathered again\n",
                static_cast<unsigned long long>(report->bounceShutSides));
    std::printf("    reflected power per bounce (relative to the direct light's):");
    const Rgb& direct = report->bouncePower.front();
    for (size_t k = 1; k < report->bouncePower.size(); ++k) {
      std::printf(" %zu: %.3f", k, luminance(report->bouncePower[k]) / std::max(luminance(direct), 1e-30f));
    }
    std::printf("\n    bounces past the last: %s (the last bounce's light times 1 + (%.3f, %.3f, %.3f))\n",
                request.bounceTail ? "estimated" : "left out", report->tail.x, report->tail.y,
                report->tail.z);
  }
  if (report->glossyPairs.receivers > 0) {
    std::printf("  glossy leaves' incoming light, by pair refinement: %s\n",
                report->glossyPairs.toString().c_str());
  }
  std::printf("%s", formatStages(report->stages).c_str());
  std::printf("wall time %.3f s\n", report->wallSeconds);
  return kExitOk;
}

}  // namespace

void registerBakeCommand(CLI::App& app, CommandAction& action) {
  auto options = std::make_shared<BakeOptions>();
  CLI::App* cmd = app.add_subcommand(
      "bake", "Bake one frame: a surfel point cloud (OpenVDB) and its paged PBGI tree (.pbgi)");
  cmd->add_option("SHOT", options->shot, "Shot file (TOML)")->required();
  cmd->add_option("--frame", options->frame, "Frame to bake (default: the shot's first)");
  cmd->add_option("--out", options->out, "Output folder (default: beside the frame's image)");
  cmd->add_option(
         "--points", options->points,
         fmt::format("Surfel count (default: the shot's bake_points, else {})", kDefaultBakePoints))
      ->check(positiveNumber());
  cmd->add_option("--mem-budget", options->memBudget,
                  "Memory budget, e.g. 256M or 2G (default: 1G)");
  cmd->add_option("--bounces", options->bounces,
                  "Indirect bounces baked into the surfels (default: the shot's bake_bounces)")
      ->check(nonNegativeNumber());
  cmd->add_option("--bounce-quality", options->bounceQuality,
                  "Gather preset for the bounces: draft, default, high (default: the shot's "
                  "bake_quality)")
      ->check(CLI::IsMember({"draft", "default", "high"}));
  cmd->add_option("--bounce-spacing", options->bounceSpacing,
                  fmt::format("Surfels a bounce gather stands for: the bounces gather at one "
                              "surfel of each patch of about this many and the rest interpolate "
                              "(1: every surfel gathers; default: {})",
                              kBounceReceiverSpacing))
      ->check(CLI::Range(1, kMaxBounceSpacing));
  cmd->add_flag("--no-tail", options->noTail,
               "Leave out the light of the bounces past the last instead of estimating it");
  cmd->add_option("--light-samples", options->lightSamples,
                  "Light samples per surfel (default: 16)")
      ->check(positiveNumber());
  cmd->add_option("--threads", options->threads, "Worker threads (default: all cores)")
      ->check(positiveNumber());
  cmd->add_option("--leaf-size", options->leafSize, "Most surfels in a leaf (default: 16)")
      ->check(CLI::Range(1, kMaxLeafSize));
  cmd->add_option("--page-size", options->pageSize, "Tree page size (default: 64K)");
  cmd->add_option("--encoding", options->encoding,
                  "Node encoding: quantized (16-bit codebook indices), quantized8, or float")
      ->check(CLI::IsMember({"quantized", "quantized8", "float"}));
  cmd->add_option("--codebook", options->powerCentres,
                  "Radiance codebook centres, plus the black entry (default: 254)")
      ->check(CLI::Range(1, 65534));
  cmd->add_option("--point-cloud", options->pointCloud,
                  "Write the OpenVDB point cloud: auto (when it fits the budget), always, never")
      ->check(CLI::IsMember({"auto", "always", "never"}));
  cmd->add_option("--temp-dir", options->tempDir, "Folder for spill files (default: the system's)");
  cmd->add_option("--wavelet-error", options->waveletError,
                  "Glossy light: the relative L2 error each node's wavelet vector is coded within "
                  "(default: the shot's bake_wavelet_error, 0.2)");
  cmd->add_option("--wavelet-resolution", options->waveletResolution,
                  "Glossy light: texels a side of each cube-map face (a power of two; default: the "
                  "shot's bake_wavelet_resolution, 16)");
  cmd->add_option("--glossy-pairs", options->glossyPairs,
                  "Glossy leaves gather the bounces' light by pair refinement (Wang et al.'s "
                  "Algorithm 1): a group of leaves takes a cluster once when the group spans at "
                  "most this solid angle (sr) from it; 0, the default, gathers each leaf alone")
      ->check(CLI::Range(0.0f, 12.566f));
  cmd->callback([options, &action] { action = [options] { return runBake(*options); }; });
}

}  // namespace pbgi::cli
