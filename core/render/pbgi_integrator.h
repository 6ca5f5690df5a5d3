#pragma once
// The PBGI integrators: indirect light gathered from the baked PBGI tree instead of path
// traced (primary visibility, direct light, mirrors and glass as pbgi_receiver.h says).
//
// Per-pixel (Christensen 2008): every pixel gathers for its own samples. A sample whose first
// hit lies on the plane of an earlier gather of the same pixel, near it, facing the same way
// takes that gather's result; others gather anew into a cube microbuffer (diffuse) or a
// glossy gather (product, adaptive or warped, as glossyGather says), up to maxGathersPerPixel
// records. Diffuse receivers reflect albedo / pi times the gathered irradiance.
//
// Bidirectional (Jarabo et al. 2014, core/pbgi/bidirectional_cut.h): the diffuse receivers
// of every sample of a block of the fixed grid (its pixels x spp x the views of a camera
// array) gather together through one cut of the light tree against a tree of the receivers,
// so that light that is coarse for many pixels is computed once. Glossy receivers keep their
// own gathers; the product's are shared across the record spacing's pixels too
// (pbgi_receiver.h).
#include <memory>

#include "core/pbgi/adaptive_gather.h"
#include "core/pbgi/bidirectional_cut.h"
#include "core/pbgi/gather.h"
#include "core/pbgi/product_gather.h"
#include "core/pbgi/tree_page.h"
#include "core/pbgi/warped_gather.h"
#include "core/render/integrator.h"
#include "core/scene/scene.h"

namespace pbgi {

enum class PbgiGatherKind { kBidirectional, kPerPixel };
// Glossy receivers' gather: a microbuffer warped by the BSDF (Ritschel et al. 2009), the
// adaptive quadtree refined by the BSDF and the light (Wang et al. 2016, adaptive_gather.h), or
// the light gathered once per footprint and reflected by the wavelet product with each
// sample's BSDF slice (Wang et al. 2015, product_gather.h); or traced: rays drawn from each
// sample's BSDF, each taking the light the tree's surfels send back from what it meets (a final
// gather, whose visibility is the scene's own: no light through walls, which a microbuffer's
// partly covering splats let through where a bright room lies behind a thin wall).
enum class GlossyGatherKind { kWarped, kAdaptive, kProduct, kTraced };

struct PbgiSettings {
  PbgiGatherKind gather = PbgiGatherKind::kBidirectional;
  GatherOptions perPixel;      // the per-pixel gather's microbuffer
  GlossyGatherKind glossyGather = GlossyGatherKind::kProduct;
  WarpedGatherOptions glossy;     // glossy receivers' warped microbuffer
  AdaptiveGatherOptions adaptive;  // ... or their adaptive one
  ProductGatherOptions product;    // ... or the product's cube and BSDF slices
  int glossyRays = 8;              // ... or this many BSDF-sampled rays per camera sample
  int maxGathersPerPixel = 4;  // per-pixel gathers a pixel's samples make
  CutOptions cut;              // the bidirectional cut
  int blockSize = 64;          // the bidirectional cut's blocks, in view pixels
  // The bidirectional cut's records lie on pixels whose coordinates are multiples of this;
  // the pixels between interpolate them (1: every pixel gathers).
  int recordSpacing = 2;
  // Environment light on diffuse receivers: once per record (or per-pixel gather) and shared
  // by the samples that read it (sky_irradiance.h), or from each camera sample's light samples.
  bool skyAtRecords = true;
  // Blocks rendered together, their cuts sweeping the tree's pages in step (a 4 x 4 square of
  // 64^2 blocks: a 256^2 farm tile).
  int blocksPerUnit = 16;
  // The path tracer's settings: its maxDepth serves the receivers that are path traced;
  // direct light always uses one scattering vertex.
  PathTracerSettings pathTracer;
};

// The warped microbuffer that goes with a gather preset: a third more pixels a side than the
// cube's faces (the lobe takes them all), the same near field.
WarpedGatherOptions glossyGatherOptions(const GatherOptions& gather);
// (The product gather's: productGatherOptions, product_gather.h.)
// The adaptive microbuffer that goes with a gather preset: its near field.
AdaptiveGatherOptions adaptiveGatherOptions(const GatherOptions& gather);

// `tree` (usually a PageCache) must outlive the integrator and be safe to share between
// threads; the settings must be valid. Errors: the tree source's (a page it cannot give names
// the file and page), and DataLoss for a tree whose radiance makes a gather non-finite.
std::unique_ptr<Integrator> makePbgiIntegrator(const Scene& scene, TreePageSource& tree,
                                               const PbgiSettings& settings);

}  // namespace pbgi
