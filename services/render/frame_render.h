#pragma once
// Renders one frame of a shot in this process and writes its EXR (and PNG preview). The CLI's
// `pbgi render` and, later, the farm's workers share this.

#include <functional>
#include <string>
#include <vector>

#include <absl/status/statusor.h>

#include "core/render/renderer.h"
#include "core/scene/shot.h"
#include "services/util/stage_time.h"

namespace pbgi {

struct FrameRenderRequest {
  int frame = 0;
  std::string integrator;  // empty: the shot's
  int spp = 0;             // 0: the shot's
  int threads = 0;         // 0: all cores
  int tileSize = 0;        // 0: the shot's
  std::string outPath;     // empty: the shot's output pattern for this frame
  bool preview = true;     // write a PNG preview beside the EXR
  std::string ocioConfig;  // empty: the shipped config
  std::function<void(int tilesDone, int tilesTotal)> progress;
};

struct FrameRenderReport {
  std::string exrPath;
  std::string previewPath;  // empty when none was written
  std::vector<StageTime> stages;
  double wallSeconds = 0.0;
  RenderCounters counters;
  std::vector<std::string> warnings;
};

// The integrators this build can run, by name.
const std::vector<std::string>& availableIntegrators();

absl::StatusOr<FrameRenderReport> renderShotFrame(const ShotDesc& shot,
                                                  const FrameRenderRequest& request);

}  // namespace pbgi
