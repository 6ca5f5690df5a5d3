#pragma once
// Integrators, at the level the renderer drives them (pbrt-v4's split between an integrator
// that renders an image tile and one that shades rays one pixel at a time). The renderer hands
// an integrator every camera sample of a render unit at once: the pixels of a tile, or, for an
// integrator that shares work across pixels (the bidirectional cut), every pixel of a few
// blocks of a fixed grid in all views of a camera array. Integrators that shade pixel by pixel (the path
// tracer, the per-pixel PBGI gather) derive from PixelIntegrator, which walks the unit's
// pixels for them. A failure an integrator cannot recover from (a damaged tree page) fails the
// unit instead of being rendered.
//
// Which integrators exist, their parameters, counters and needs: core/render/integrators.h.
#include <atomic>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/status.h>

#include "core/math/vec.h"
#include "core/render/path_tracer.h"
#include "core/sampling/rng.h"

namespace pbgi {

// A counter an integrator keeps, by name (printed by the CLI and the workers' logs).
struct CounterSpec {
  std::string_view name;
  std::string_view help;
};

// What the renderer counts, and the integrator's own counters (by index in its
// counterSpecs()).
struct RenderCounters {
  uint64_t cameraSamples = 0;
  uint64_t discardedSamples = 0;  // NaN or Inf radiance, dropped from the pixel's average
  uint64_t pixelsWithoutHit = 0;  // primary rays found no geometry in any sample
  std::vector<uint64_t> values;   // the integrator's, sized by the renderer

  uint64_t& operator[](size_t i) { return values[i]; }
  uint64_t operator[](size_t i) const { return i < values.size() ? values[i] : 0; }
  void add(const RenderCounters& o);
};

// A block of a render unit: its pixels [firstPixel, firstPixel + pixelCount) of the unit's
// list, and the key of its own random numbers, (seed, frame, block): the block being one of the
// fixed grid, neither depends on the tiling.
struct UnitBlock {
  size_t firstPixel = 0;
  size_t pixelCount = 0;
  // Pixels just past the block's far borders (Integrator::blockHalo) that follow its own in
  // the unit's pixels: the integrator may use their samples, and the renderer writes none.
  size_t haloCount = 0;
  uint64_t key = 0;
};

// The camera samples of one render unit. Pixels are listed in the order the renderer chose
// (Morton order within a tile, views one after another within a block); pixel i owns samples
// [i * spp, (i + 1) * spp). Rays and random streams are keyed (seed, frame, pixel, sample),
// so a sample's value does not depend on the unit it came in.
struct TileSamples {
  int spp = 1;
  std::span<const Vec2i> pixels;  // image (mosaic) coordinates
  std::span<const Ray> rays;
  std::span<Rng> rngs;
  // For an integrator with blocks (blockSize() > 0): the unit's blocks, whose pixels follow
  // one another in `pixels`. Work that spans pixels stays within a block. Empty for a tile.
  std::span<const UnitBlock> blocks;
  // Keyed (seed, frame) alone: random numbers that every block of the frame shares.
  uint64_t frameKey = 0;
  // Set while the unit renders when its render is to stop (a cancelled farm task); an
  // integrator checks it between pixels and returns cancelledError().
  const std::atomic<bool>* cancel = nullptr;

  size_t pixelCount() const { return pixels.size(); }
  bool cancelled() const { return cancel && cancel->load(std::memory_order_relaxed); }
};

// What a render stopped by its cancel flag returns.
absl::Status cancelledError();

// Scratch an integrator keeps per thread between units (buffers, traversal state).
class IntegratorScratch {
 public:
  virtual ~IntegratorScratch() = default;
};

class Integrator {
 public:
  virtual ~Integrator() = default;
  virtual std::string name() const = 0;
  virtual std::span<const CounterSpec> counterSpecs() const { return {}; }
  // One per rendering thread; null when the integrator needs none.
  virtual std::unique_ptr<IntegratorScratch> newScratch() const { return nullptr; }
  // 0: pixels are independent of one another, and the renderer may cut the image into any
  // tiles. > 0: a pixel's value depends on the other pixels of its block, the square of
  // blockSize() view pixels of a fixed grid, in every view: the renderer then renders whole
  // blocks (all views), so that a pixel is the same whatever the tiling or region asked for.
  virtual int blockSize() const { return 0; }
  // How many blocks (consecutive in Morton order over the grid) a unit holds at most: blocks
  // of one unit may share traversals of the tree (its pages), never their results.
  virtual int blocksPerUnit() const { return 1; }
  // n > 0: each block also gets the samples of the pixels one past its right and bottom
  // borders (in its own view, inside the view) whose coordinates are multiples of n, as a halo
  // (UnitBlock::haloCount), for work that reaches across the border (records the block's last
  // pixels interpolate towards). 0: none.
  virtual int blockHalo() const { return 0; }
  // Fills out[s] for every sample of the unit. Must be deterministic in its inputs (whatever
  // the scratch held before) and safe to call from many threads, each with its own scratch.
  virtual absl::Status render(const TileSamples& samples, std::span<PathSample> out,
                              IntegratorScratch* scratch, RenderCounters* counters) const = 0;
};

// An integrator that shades one pixel's samples at a time.
class PixelIntegrator : public Integrator {
 public:
  absl::Status render(const TileSamples& samples, std::span<PathSample> out,
                      IntegratorScratch* scratch, RenderCounters* counters) const final;
  // Fills out[s] from rays[s], drawing random numbers from rngs[s] only. An error fails the
  // unit (the renderer names the pixel).
  virtual absl::Status shadePixel(std::span<const Ray> rays, std::span<Rng> rngs,
                                  std::span<PathSample> out, IntegratorScratch* scratch,
                                  RenderCounters* counters) const = 0;
};

// The reference: the path tracer, sample by sample.
class PathIntegrator final : public PixelIntegrator {
 public:
  PathIntegrator(const Scene& scene, PathTracerSettings settings)
      : scene_(scene), settings_(settings) {}
  std::string name() const override { return "path"; }
  absl::Status shadePixel(std::span<const Ray> rays, std::span<Rng> rngs,
                          std::span<PathSample> out, IntegratorScratch* scratch,
                          RenderCounters* counters) const override;

 private:
  const Scene& scene_;
  PathTracerSettings settings_;
};

}  // namespace pbgi
