#pragma once
// Renders one frame of a shot in this process and writes its EXR (and PNG preview). The CLI's
// `pbgi render` and, later, the farm's workers share this.

#include <atomic>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <absl/status/statusor.h>

#include "core/pbgi/page_cache.h"
#include "core/render/renderer.h"
#include "core/scene/shot.h"
#include "formats/pbgi/tree_file.h"
#include "formats/scene/frame_scene.h"
#include "services/util/stage_time.h"

namespace pbgi {

struct FrameRenderRequest {
  int frame = 0;
  // What the request changes of the shot's [render] settings (flags: --integrator, --spp,
  // --quality, --set key=value, ...).
  RenderOverrides overrides;
  int threads = 0;         // 0: all cores
  int tileSize = 0;        // 0: the shot's
  std::string outPath;     // empty: the shot's output pattern for this frame
  bool preview = true;     // write a PNG preview beside the EXR
  // The AOV layers and compression the image is written with; unset: the shot's. (A farm
  // tile keeps every layer, losslessly: the frame's assembly applies the job's.)
  std::optional<OutputOptions> output;
  std::string ocioConfig;  // empty: the shipped config
  std::function<void(int unitsDone, int unitsTotal)> progress;
  // Stops the render, and the bake before it, when set (a farm task whose lease was lost): the
  // request fails Cancelled.
  const std::atomic<bool>* cancel = nullptr;
  // Render and write only these rectangles of the (mosaic) frame: a farm tile, one rectangle
  // per view of a camera array. The EXR holds them stacked top to bottom, left-aligned, and
  // lists them in its metadata (pbgi/regions: "x0 y0 x1 y1;...").
  std::vector<TileRect> regions;

  size_t cacheBytes = 0;       // page cache budget; 0: the integrator's cache_mb
  std::string treePath;        // render from this tree; empty: the frame's bake (below)
  // Or from the tree this opens (a worker's remote tree, kept across tasks); takes precedence
  // over treePath.
  std::function<absl::StatusOr<std::shared_ptr<TreeFile>>()> openTree;
  std::string bakeDir;         // the frame's bake lives here; empty: beside the image
  bool rebake = false;         // bake even when a matching bake is on disk
  std::function<void(const std::string& stage, uint64_t done, uint64_t total)> bakeProgress;
  // The frame's scene, loaded before (a worker keeps it across a frame's tasks); null: load
  // it. Must be this shot's frame.
  const FrameScene* scene = nullptr;
};

// What a PBGI render read: its tree, its bake, its page cache.
struct TreeReadReport {
  std::string treePath;
  bool baked = false;          // false: a bake on disk was reused, or treePath was given
  std::vector<StageTime> bakeStages;
  size_t cacheBudget = 0;
  PageCacheCounters cache;
  uint64_t pagesRead = 0;      // distinct pages the render loaded
  uint64_t pagesInFile = 0;
  uint64_t fileBytes = 0;
  std::string integratorDescription;  // its gather and thresholds
};

struct FrameRenderReport {
  std::string integrator;
  std::vector<CounterSpec> counterSpecs;  // names of counters.values
  std::string imagePath;
  std::string previewPath;  // empty when none was written
  std::vector<StageTime> stages;
  double wallSeconds = 0.0;
  RenderCounters counters;
  std::optional<TreeReadReport> tree;  // PBGI renders only
  std::vector<std::string> warnings;
};

// Writes the image's OCIO preview beside `imagePath` (its extension replaced by .png) with
// `ocioConfig` (empty: the shipped config). Returns the PNG's path, or an empty string with a
// warning added: a missing preview never fails a frame.
std::string writePreviewBeside(const Image& image, const std::string& imagePath,
                               const std::string& ocioConfig, std::vector<std::string>* warnings);

// The settings a render uses: the shot's [render], the request's integrator, spp and
// parameters applied, checked by the integrator (errors name where a value was set).
absl::StatusOr<RenderSettings> requestSettings(const ShotDesc& shot,
                                               const FrameRenderRequest& request);

// The integrator's counters that are not zero, "  name value" a line.
std::string formatCounters(const FrameRenderReport& report);

// Renders one frame. For the PBGI integrator, bakes the frame's tree first unless a bake made
// from the same shot bytes and bake settings is already on disk (or request.treePath names
// one). Errors: the shot's, the bake's, and a tile's (a damaged tree page fails the frame
// naming the tile, the file and the page; nothing is written).
absl::StatusOr<FrameRenderReport> renderShotFrame(const ShotDesc& shot,
                                                  const FrameRenderRequest& request);

}  // namespace pbgi
