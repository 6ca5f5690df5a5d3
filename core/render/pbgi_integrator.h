#pragma once
// The PBGI integrator (Christensen 2008): primary visibility and direct light from the path
// tracer's own code (tracePath with one scattering vertex, so that the two integrators draw
// the same random numbers and differ only in indirect light), and indirect light gathered at
// the first hit from the baked PBGI tree instead of path traced.
//
// Per pixel, the samples share gathers: a sample whose first hit lies on the plane of an
// earlier gather of the same pixel, near it, facing the same way (and, for glossy receivers,
// of the same material seen from the same direction) takes that gather's result; others
// gather anew, up to maxGathersPerPixel records. Diffuse receivers reflect albedo / pi times
// the gathered irradiance. Rough conductors gather into an importance-warped microbuffer
// (Ritschel et al. 2009, core/pbgi/warped_gather.h) whose pixels follow their BRDF lobe,
// jittered per sample against banding.
// Receivers the gather cannot serve (mirrors, glass) are path traced, counted; those that
// reflect nothing (emitters, black albedo) gather nothing, counted.
#include <memory>

#include "core/pbgi/gather.h"
#include "core/pbgi/tree_page.h"
#include "core/pbgi/warped_gather.h"
#include "core/render/integrator.h"

namespace pbgi {

struct PbgiIntegratorSettings {
  GatherOptions gather;
  WarpedGatherOptions glossy;  // glossy receivers' warped microbuffer
  int maxGathersPerPixel = 4;
  // The path tracer's settings: its maxDepth serves the receivers that are path traced;
  // direct light always uses one scattering vertex.
  PathTracerSettings pathTracer;
};

// The warped microbuffer that goes with a gather preset: a third more pixels a side than the
// cube's faces (the lobe takes them all), the same near field.
WarpedGatherOptions glossyGatherOptions(const GatherOptions& gather);

class PbgiIntegrator final : public Integrator {
 public:
  // `tree` (usually a PageCache) must outlive the integrator and be safe to share between
  // threads; the settings must be valid (GatherOptions::validate).
  PbgiIntegrator(const Scene& scene, TreePageSource& tree, const PbgiIntegratorSettings& settings);

  std::string name() const override { return "pbgi"; }
  std::unique_ptr<IntegratorScratch> newScratch() const override;
  // Errors: the tree source's (a page it cannot give names the file and page), and
  // DataLoss for a tree whose radiance makes a gather non-finite.
  absl::Status shadePixel(std::span<const Ray> rays, std::span<Rng> rngs,
                          std::span<PathSample> out, IntegratorScratch* scratch,
                          RenderCounters* counters) const override;

 private:
  const Scene& scene_;
  TreePageSource& tree_;
  PbgiIntegratorSettings settings_;
};

}  // namespace pbgi
