#pragma once
// What both PBGI integrators (per-pixel and bidirectional) do with a camera sample before
// gathering: its primary visibility and direct light from the path tracer's own code
// (tracePath with one scattering vertex, so that PBGI and the path tracer draw the same random
// numbers and differ only in indirect light), and what its first hit needs:
//   - nothing, when the ray escapes, or the hit reflects nothing (an emitter, black albedo);
//   - the path tracer, for mirrors and glass (delta or refractive BSDFs), whose indirect light
//     PBGI cannot gather: its paths through them read, on the first diffuse surface they
//     reach, the light the tree's surfels there send back (PathTracerSettings::specularChainEnd);
//   - the adaptive microbuffer gather for glossy receivers (Wang et al. 2016), or the warped
//     one (Ritschel et al. 2009) or the wavelet product when the settings ask for it, shared
//     between a pixel's samples that see the same material the same way;
//   - a diffuse gather: the per-pixel microbuffer or the bidirectional cut, also for a rough
//     glossy receiver whose lobe the tree's SH hold (LambertianLobes below).
// Surfaces are two-sided, as for the path tracer: a receiver gathers on the side its camera
// ray arrives from.
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include <absl/status/status.h>

#include "core/pbgi/adaptive_gather.h"
#include "core/pbgi/bidirectional_cut.h"
#include "core/pbgi/gather.h"
#include "core/pbgi/gather_reuse.h"
#include "core/pbgi/product_gather.h"
#include "core/pbgi/warped_gather.h"
#include "core/render/integrator.h"
#include "core/render/path_tracer.h"
#include "core/render/pbgi_integrator.h"
#include "core/scene/scene.h"

namespace pbgi {

// The PBGI integrator's counters, by index into pbgiCounterSpecs() (integrators.h).
enum PbgiCounter : size_t {
  kBlackReceivers,       // first hit reflects nothing: no gather
  kPathTracedReceivers,  // mirrors and glass: path traced
  kGathers,              // diffuse receivers (microbuffers or the cut's) and glossy gathers
  kGatherReuses,         // samples that took an earlier gather of their pixel
  kGlossyGathers,
  kGlossyProducts,
  kGlossyProductsSkipped,
  kGlossyNarrowLobes,
  kGlossyAsDiffuse,
  kGlossyTracedRays,
  kGlossyTracedUnread,
  kNodesVisited,
  kNodesCulledPlane,
  kClustersSplatted,
  kClustersInvisible,
  kDisksSplatted,
  kNearFieldRayCasts,
  kSurfelsSkipped,
  kSurfelsBackFacing,
  kPagesTouched,
  kFacesSkipped,
  kPixelsSkipped,
#define PBGI_CUT_COUNTER_ENUM(member, counter, name, what) counter,
  PBGI_CUT_COUNTERS(PBGI_CUT_COUNTER_ENUM)  // the bidirectional cut's (bidirectional_cut.h)
#undef PBGI_CUT_COUNTER_ENUM
  kSkyRays,
  kPbgiCounterCount
};

void addGatherStats(const GatherStats& s, RenderCounters* counters);
void addCutStats(const CutStats& s, RenderCounters* counters);

enum class ReceiverKind { kNone, kBlack, kPathTraced, kGlossy, kDiffuse };

// Glossy materials whose first hits reflect as diffuse ones: a rough
// conductor whose lobes the tree's SH hold (needsWavelets false, so that the bake made its
// surfels diffuse ones of its hemispherical albedo) takes the diffuse gather, and reflects the
// irradiance E it gathers by its directional albedo towards the camera: rho(wo) / pi E, exact
// under uniform light. A glossy gather would refine a microbuffer, or project a product, for a
// lobe the cut's SH already carry. Its light samples stay the path tracer's (its sky too: the
// records' sky light is for diffuse materials, whose samples leave it out).
class LambertianLobes {
 public:
  // The directional albedo's table: this many cosines of the view, from 0 to 1.
  static constexpr int kBins = 32;
  // Measures each conductor of `scene`: whether the SH hold its lobe (0.35 ms), and for those
  // they hold the table, 32^2 stratified BSDF samples a bin (about 4 ms).
  explicit LambertianLobes(const Scene& scene);
  // Whether material `m` reflects as a diffuse one.
  bool has(uint32_t m) const { return m < tables_.size() && !tables_[m].empty(); }
  // Its directional albedo towards a view at `cosTheta` from the normal (interpolated).
  Rgb albedo(uint32_t m, float cosTheta) const;

 private:
  std::vector<std::vector<Rgb>> tables_;  // by material; empty: reflects by its own lobe
};

struct Receiver {
  ReceiverKind kind = ReceiverKind::kNone;
  SurfaceHit hit;
  Vec3f n{0.0f, 0.0f, 1.0f};   // shading normal on the camera's side
  Vec3f ng{0.0f, 0.0f, 1.0f};  // geometric normal on the camera's side
  Vec3f wo{0.0f, 0.0f, 1.0f};  // towards the camera
  // A diffuse receiver's: what multiplies the gathered irradiance / pi, and the environment's
  // irradiance / pi at the records (black where the sample's own light samples took the sky).
  Rgb reflectance{0.0f};
  Rgb skyReflectance{0.0f};
};

// Fills `out` with the sample's direct light and AOVs (its indirect light too, for receivers
// the path tracer serves) and says what the rest needs. Counts black and path-traced
// receivers, and glossy ones that take the diffuse path (`lobes`).
Receiver traceReceiver(const Scene& scene, const LambertianLobes& lobes, const Ray& ray, Rng& rng,
                       const PathTracerSettings& pathTracer, PathSample* out,
                       RenderCounters* counters);

// How near a sample's first hit must lie to an earlier gather of its pixel to share it, as
// fractions of that gather's distance from the camera: along the gather's normal (the same
// plane), and in all (the same neighbourhood; a pixel spans about 1/500 of its distance).
inline constexpr float kReusePlaneFraction = 0.005f;
inline constexpr float kReuseDistanceFraction = 0.05f;

// A pixel's gathers, shared between its samples: glossy receivers' microbuffer gathers (key:
// their material, and their view direction) or product gathers (key: any glossy material, and
// the view direction), and, for the per-pixel integrator, diffuse irradiance
// (key kNoMaterial: any diffuse material shares it).
//
// Glossy gathers are shared across pixels too, when `spacing` > 1 (the bidirectional
// integrator's record spacing), as the diffuse records are. The pixels whose coordinates are
// multiples of the spacing (anchors) keep their glossy gathers for the other pixels of their
// spacing x spacing square: a sample there takes the first of its own anchor's, else of the
// next anchor's along the row, that passes the test a pixel's samples share by (the same
// plane, near, facing and seen the same way, the same key). What it takes:
//   - a product gather: the light arriving, which depends on where the receiver lies and how
//     it faces, not on its material; the sample reflects it with its own view and BSDF;
//   - a microbuffer gather (adaptive or warped): the radiance its material reflects towards a
//     view within 2.6 degrees of the sample's, as a pixel's own samples share it. A lobe is
//     degrees wide and a pixel's view hundredths of one at film resolutions, so a glossy
//     reflection changes little across the square.
// One that finds none gathers its own, shared within its pixel. (The diffuse records' tighter
// reach, kInterpolationReachFraction, kept 1,157 of the 1,502 product gathers of a 96^2 glossy
// Cornell box: a pixel's samples lie up to a filter's width apart, which a grazing wall
// stretches; this test kept 420.) An anchor must come before the pixels that take it (a
// block's Morton order visits each square anchor first); a pixel whose anchor has not come, or
// whose row of anchors has since been left, gathers its own. The result depends only on the
// pixels' order. Memory: the gathers of one row of anchors at most.
class PixelGathers {
 public:
  // `bsdfs` (the product gather's BSDF slices, shared by every thread of a render) may be null
  // unless the settings ask for the product.
  PixelGathers(const PbgiSettings& settings, size_t maxGathersPerPixel,
               std::shared_ptr<WaveletBsdfCache> bsdfs = nullptr, int spacing = 1);
  // Forget every gather kept across pixels: call before each block of pixels.
  void newBlock() {
    anchorRowY_ = kNoRow;
    anchorKept_.clear();
    anchorKeptX_.clear();
    anchorProducts_ = 0;
  }
  // Forget the pixel's gathers (all but the anchors' products): call before each pixel.
  void newPixel(const Vec2i& pixel);
  GatherReuse& shared() { return shared_; }
  // The glossy reflected radiance towards the camera; jitter drawn from `rng` when it gathers
  // anew.
  absl::StatusOr<Rgb> reflect(TreePageSource& tree, const Scene& scene, const Receiver& r,
                              const Rgb& albedo, Rng& rng, GatherStats* stats,
                              RenderCounters* counters);

 private:
  // The product's: a gather's light, its frame, and the sample's reflection by it.
  struct ProductGather {
    Frame frame;
    std::vector<float> incoming;
  };
  // Counts a glossy gather and keeps it for the pixel's later samples (its value, or where
  // the product's light is); returns what it kept.
  SharedGather keep(const Receiver& r, uint32_t key, const Rgb& value, uint32_t slot,
                    RenderCounters* counters);
  // The product's BSDF slices of a material (projected the first time a thread asks).
  absl::StatusOr<const WaveletBsdf*> productSlices(const Scene& scene, uint32_t material);
  absl::StatusOr<Rgb> reflectByProduct(TreePageSource& tree, const WaveletBsdf& slices,
                                       const Receiver& r, GatherStats* stats,
                                       RenderCounters* counters);
  // The traced gather's (GlossyGatherKind::kTraced): the sample's own BSDF rays.
  absl::StatusOr<Rgb> reflectByRays(TreePageSource& tree, const Scene& scene, const Receiver& r,
                                    const Rgb& albedo, Rng& rng, RenderCounters* counters);

  std::optional<WarpedGatherer> warped_;      // as the settings say: warped, adaptive, or
  std::optional<AdaptiveGatherer> adaptive_;  // product and adaptive (for narrow lobes)
  std::optional<ProductGatherer> product_;
  int tracedRays_ = 0;        // the traced gather's rays a sample (0: another gather)
  float readRadius_ = -1.0f;  // how far its hits read the tree (surfaceReadRadius; < 0: not yet)
  std::shared_ptr<WaveletBsdfCache> bsdfs_;
  std::vector<ProductGather> products_;  // the pixel's, by slot (capacity kept across pixels)
  size_t productsUsed_ = 0;
  // Across pixels: the current row of anchors' glossy gathers, each with its anchor's x (the
  // product's light in products_[0, anchorProducts_)), and where the pixel's anchor is.
  static constexpr int kNoRow = INT32_MIN;
  int spacing_ = 1;
  int anchorRowY_ = kNoRow;
  int anchorX_ = 0;
  bool atAnchor_ = true;
  size_t anchorProducts_ = 0;
  std::vector<SharedGather> anchorKept_;
  std::vector<int> anchorKeptX_;
  // The anchor's glossy gather of key `key` a sample of another pixel may take: null for none.
  const SharedGather* anchorGather(const Receiver& r, uint32_t key) const;
  // Keeps a gather of an anchor pixel for the pixels after it.
  void keepForPixelsAfter(const SharedGather& g);
  std::vector<std::shared_ptr<const WaveletBsdf>> slices_;  // by the scene's material index
  GatherReuse shared_;
};

// A gathered value that is not finite means a damaged or hostile tree.
absl::Status checkGathered(const Rgb& value);

}  // namespace pbgi
