#pragma once
// An integrator turns the camera rays of one pixel into radiance samples. The tile renderer
// drives one, pixel by pixel: a whole pixel at a time, so that an integrator can share work
// between the samples of a pixel (the PBGI gather), and with a status, so that a failure it
// cannot recover from (a damaged tree page) fails the tile instead of being rendered.

#include <memory>
#include <span>
#include <string>

#include <absl/status/status.h>

#include "core/pbgi/gather.h"
#include "core/render/path_tracer.h"

namespace pbgi {

// What the renderer counts; integrators add their own counts to it.
struct RenderCounters {
  uint64_t cameraSamples = 0;
  uint64_t discardedSamples = 0;  // NaN or Inf radiance, dropped from the pixel's average
  uint64_t pixelsWithoutHit = 0;  // primary rays found no geometry in any sample: no gather
  // PBGI: samples whose first hit reflects nothing (an emitter, a black albedo): no gather.
  uint64_t blackReceivers = 0;
  // PBGI: gathers made, and samples served by an earlier gather of their own pixel.
  uint64_t gathers = 0;
  uint64_t gatherReuses = 0;
  uint64_t glossyGathers = 0;  // of `gathers`, convolved with a glossy BRDF
  // PBGI: samples whose first hit the gather cannot serve (a delta or refractive BSDF),
  // path traced instead.
  uint64_t pathTracedReceivers = 0;
  GatherStats gather;

  void add(const RenderCounters& o);
};

// Scratch an integrator keeps per thread between pixels (buffers, traversal state).
class IntegratorScratch {
 public:
  virtual ~IntegratorScratch() = default;
};

class Integrator {
 public:
  virtual ~Integrator() = default;
  virtual std::string name() const = 0;
  // One per rendering thread; null when the integrator needs none.
  virtual std::unique_ptr<IntegratorScratch> newScratch() const { return nullptr; }
  // Fills out[s] from rays[s], drawing random numbers from rngs[s] only. Must be
  // deterministic in its inputs (whatever the scratch held before) and safe to call from
  // many threads, each with its own scratch. An error fails the tile.
  virtual absl::Status shadePixel(std::span<const Ray> rays, std::span<Rng> rngs,
                                  std::span<PathSample> out, IntegratorScratch* scratch,
                                  RenderCounters* counters) const = 0;
};

class PathIntegrator final : public Integrator {
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
