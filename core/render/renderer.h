#pragma once
// The renderer: cuts a frame into render units, generates every unit's camera samples, hands
// them to the integrator and averages each pixel's samples into the image.
//
// Units. For an integrator whose pixels are independent (blockSize() 0), a unit is a square
// tile (Morton order over the frame, pixels in Morton order within). For one that shares work
// across pixels, a unit is up to blocksPerUnit() blocks of a fixed grid in view space
// (consecutive in Morton order), blockSize() pixels a side, each holding that square of every
// view of a camera array (views share one block, so a light field's nearly identical samples
// share the work). Blocks do not move with the tiling: a region asked for renders the whole
// blocks it touches and keeps its own pixels. A block's pixels depend on the block alone, not
// on the unit it came in (the unit's blocks share page loads, not results).
//
// Determinism: a sample's random stream is keyed (seed, frame, pixel, sample) and a unit's
// own (seed, frame, block), so a pixel is bit-identical whatever the tiling, the regions, the
// thread count or the machine.

#include <atomic>
#include <cstdint>
#include <functional>
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
  bool contains(int x, int y) const { return x >= x0 && x < x1 && y >= y0 && y < y1; }
  bool operator==(const TileRect&) const = default;
};

struct FrameRenderOptions {
  int threads = 0;  // 0: all cores
  int tileSize = 0; // 0: the shot's render.tile_size (pixel-independent integrators)
  std::function<void(int unitsDone, int unitsTotal)> progress;  // called from worker threads
  // Render only these pixels (a farm tile: rectangles of the mosaic image, each inside it);
  // empty: every pixel. The image returned then holds only them, stacked top to bottom and
  // left-aligned (stackedSize); a single region's image has its window at the region's corner
  // of the frame. Pixels come out as in a render of the whole frame.
  std::vector<TileRect> regions;
  // Stops the render when set (checked between pixels): renderFrame returns cancelledError().
  const std::atomic<bool>* cancel = nullptr;
};

// The channels of a rendered frame: RGBA, then the AOV layers.
const std::vector<std::string>& frameChannels();
// The AOV layers of a rendered frame, in order: albedo, normal, depth, direct, indirect.
const std::vector<std::string>& frameAovs();
// InvalidArgument naming the first of `aovs` that frameAovs() does not hold.
absl::Status checkAovs(const std::vector<std::string>& aovs);
// The image with RGBA and only the AOV layers named (each one of frameAovs()); the metadata
// and window kept. InvalidArgument naming an unknown layer.
absl::StatusOr<Image> keepAovs(const Image& image, const std::vector<std::string>& aovs);

// Tiles covering width x height, in Morton (Z) order of their grid positions.
std::vector<TileRect> makeTiles(int width, int height, int tileSize);
// The same over `region` (pixel bounds of the image).
std::vector<TileRect> makeTiles(const TileRect& region, int tileSize);

// The size of rectangles stacked top to bottom, left-aligned: the image a render of those
// regions returns (one region: its own size).
Vec2i stackedSize(const std::vector<TileRect>& regions);

// The cells of an nx x ny grid, in Morton (Z) order of their positions.
std::vector<Vec2i> mortonOrder(int nx, int ny);

// The random key of block (bx, by) of a frame: what an integrator's work across the block's
// pixels draws from.
uint64_t blockKey(uint64_t seed, int frame, int bx, int by);
// The random key every block of a frame shares (TileSamples::frameKey).
uint64_t frameKey(uint64_t seed, int frame);

// OutOfRange unless every region is non-empty and inside a width x height image; the error
// names the first that is not.
absl::Status checkRegions(const std::vector<TileRect>& regions, int width, int height);

// Every unit, in parallel. The first unit that fails (in unit order) fails the frame, its
// error naming the unit; units not yet started are then skipped. OutOfRange for a region that
// leaves the image. `counters` may be null.
absl::StatusOr<Image> renderFrame(const Integrator& integrator, const Camera& camera,
                                  const RenderSettings& settings, int frame,
                                  const FrameRenderOptions& options, RenderCounters* counters);

}  // namespace pbgi
