#pragma once
// Bakes one frame of a shot: surfels sampled on every triangle and lit by the path tracer's
// own light sampling, written as an OpenVDB point cloud, then sorted by Morton key in a
// memory budget and swept into the paged, quantized PBGI tree (`.pbgi`). `pbgi bake` runs
// it; the renderer and the farm's bake tasks share it.
//
// The tree holds reflected light only: emitters are lights, sampled directly by the renderer
// and by the bounces, so emissive surfels enter the tree black (they still occlude) while
// the point cloud shows their emission.
//
// Bounces (Christensen's multi-pass): the sorted surfels are kept in a spill with their
// direct light; each bounce gathers irradiance for every diffuse surfel from the previous
// bounce's tree (read through a page cache of a quarter of the budget), chunk by chunk of the
// sorted stream through the bidirectional cut (core/bake/surfel_bounce.h), and builds the
// next. Each surfel's irradiance is kept in a spill too, so that after the last bounce the
// light of the bounces not baked is estimated from the last two (a geometric tail) and added
// as the final tree is built.
//
// Memory: surfels stream through in chunks; the external sort gets half the budget, the
// tree's spill and page buffers a few MiB. The point cloud is the one part OpenVDB builds in
// memory; in `auto` mode it is written only when it fits in a quarter of the budget, and
// skipped with a warning otherwise.
#include <atomic>
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <absl/status/statusor.h>

#include "core/bake/surfel_bounce.h"
#include "core/bake/surfel_sampler.h"
#include "core/bake/surfel_shading.h"
#include "core/pbgi/external_sort.h"
#include "core/pbgi/bidirectional_cut.h"
#include "core/pbgi/tree_writer.h"
#include "core/scene/shot.h"
#include "services/util/stage_time.h"

namespace pbgi {

enum class PointCloudMode { kAuto, kAlways, kNever };

struct FrameBakeRequest {
  int frame = 0;
  std::string outDir;        // empty: beside the frame's output image
  uint64_t points = 0;       // 0: kDefaultBakePoints
  size_t memoryBudget = size_t{1} << 30;
  int bounces = 0;           // indirect bounces gathered over the tree itself
  CutOptions bounceCut;      // how those bounces gather
  bool bounceTail = true;    // estimate the bounces past the last (see above)
  int bounceSpacing = kBounceReceiverSpacing;  // surfels a bounce record stands for (1: each its own)
  int lightSamples = 16;     // per surfel, for direct light
  int threads = 0;           // 0: all cores
  TreeWriteOptions tree;     // encoding, leaf size, page size, codebook sizes, wavelet error
                             // (seed: the shot's; its wavelets' leaf: the bake's)
  int waveletResolution = 16;  // n x n texels a face of glossy surfels' cube maps
  // Glossy leaves gather the light of the trees before them by pair refinement with this
  // receiver threshold (sr; pair_gather.h), or each alone (0, the default).
  float glossyPairThreshold = 0.0f;
  PointCloudMode pointCloud = PointCloudMode::kAuto;
  std::string tempDir;       // spill files; empty: the system's temporary folder
  std::string pbgiVersion;
  std::function<void(const std::string& stage, uint64_t done, uint64_t total)> progress;
  // Stops the bake when set (a farm task whose lease was lost), between chunks of surfels in
  // every stage: the bake fails Cancelled and writes no tree.
  const std::atomic<bool>* cancel = nullptr;
};

inline constexpr uint64_t kDefaultBakePoints = 1'000'000;
inline constexpr int kMaxBakeBounces = 16;

struct FrameBakeReport {
  std::string treePath;
  std::string pointCloudPath;  // empty when none was written
  SurfelSamplingStats sampling;
  SurfelShadingStats shading;
  SortStats sort;
  TreeWriteResult tree;
  CutStats bounceCut;  // the bounces' cuts
  PairGatherStats glossyPairs;  // glossy leaves' gathers of the light of the trees before
  // The bounces' page caches (a quarter of the budget each): loads against the pages of the
  // trees they read.
  uint64_t bounceCacheHits = 0, bounceCacheLoads = 0, bounceTreePages = 0;
  uint64_t bounceShutSides = 0;  // records' sides the later bounces did not gather: shut
  std::vector<Rgb> bouncePower;  // reflected power of the direct light (0), then each bounce
  Rgb tail{0.0f};      // r / (1 - r) per channel: the last bounce's light scaled by 1 + this
  uint64_t treeFileBytes = 0;
  std::vector<StageTime> stages;
  std::vector<std::string> warnings;
  double wallSeconds = 0.0;
};

// The bake a shot's [render] settings ask for (bake_points, bake_bounces, bake_quality) of
// `frame`, as `pbgi bake` and the PBGI renderer both start from it, so that one reuses the
// other's bake. InvalidArgument for an unknown bake_quality.
absl::StatusOr<FrameBakeRequest> shotBakeRequest(const ShotDesc& shot, int frame);

// Where a frame's bake goes: `<outDir or the image's folder>/<image stem>.pbgi` and `.vdb`.
std::string bakeTreePath(const ShotDesc& shot, const FrameBakeRequest& request);

// What a bake is made from: the shot file's bytes and every request field that changes the
// tree (the requested point count, not the count sampled). The tree file's header keeps it,
// so a renderer can tell whether a bake on disk is the one it would make.
uint64_t bakeHash(const ShotDesc& shot, const FrameBakeRequest& request);

// `loadedScene`, when given, is the frame's scene already loaded (a render that bakes first);
// otherwise the bake loads it.
absl::StatusOr<FrameBakeReport> bakeShotFrame(const ShotDesc& shot,
                                              const FrameBakeRequest& request,
                                              const Scene* loadedScene = nullptr);

}  // namespace pbgi
