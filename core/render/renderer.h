#pragma once
// The tile renderer. A frame is cut into square tiles visited in Morton order; each pixel's
// samples draw their random numbers from (seed, frame, pixel, sample), so a tile is
// bit-identical whatever the tiling, the thread count or the machine.

#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include <absl/status/statusor.h>

#include "core/render/image.h"
#include "core/render/integrator.h"
#include "core/scene/camera.h"
#include "core/scene/shot.h"

namespace pbgi {

struct TileRect {
  int x0 = 0, y0 = 0, x1 = 0, y1 = 0;  // half-open pixel bounds in the (mosaic) image
  int width() const { return x1 - x0; }
  int height() const { return y1 - y0; }
};

struct FrameRenderOptions {
  int threads = 0;  // 0: all cores
  int tileSize = 0; // 0: the shot's render.tile_size
  std::function<void(int tilesDone, int tilesTotal)> progress;  // called from worker threads
  // Render only these pixels (a farm tile); the rest of the image stays 0. Pixels do not
  // depend on the tiling, so they come out as in a render of the whole frame.
  std::optional<TileRect> region;
};

// The channels of a rendered frame: RGBA, then the AOV layers.
const std::vector<std::string>& frameChannels();

// Tiles covering width x height, in Morton (Z) order of their grid positions.
std::vector<TileRect> makeTiles(int width, int height, int tileSize);
// The same over `region` (pixel bounds of the image).
std::vector<TileRect> makeTiles(const TileRect& region, int tileSize);

// Renders the pixels of `tile` into `image` (which has frameChannels() and the full size),
// pixel by pixel in Morton order, adding to `counters`. `scratch` is the integrator's
// (newScratch()) for this thread. The integrator's errors come back naming the tile.
absl::Status renderTile(const Integrator& integrator, IntegratorScratch* scratch,
                        const Camera& camera, const RenderSettings& settings, int frame,
                        const TileRect& tile, Image& image, RenderCounters* counters);

// Every tile, in parallel. The first tile that fails (in tile order) fails the frame; tiles
// not yet started are then skipped.
absl::StatusOr<Image> renderFrame(const Integrator& integrator, const Camera& camera,
                                  const RenderSettings& settings, int frame,
                                  const FrameRenderOptions& options, RenderCounters* counters);

}  // namespace pbgi
