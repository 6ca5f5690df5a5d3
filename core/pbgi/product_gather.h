#pragma once
// Glossy receivers by the wavelet product (Wang, Meng and Boubekeur 2015, section 3.3): the
// light arriving at a receiver is rasterized once into a cube in the receiver's own frame
// (gather.h's traversal: clusters far enough away, disks, the exact near field), Haar
// transformed with every coefficient kept, and each camera sample that shares the gather takes
// the sparse dot product of those coefficients with its material's BSDF slice for its own
// outgoing elevation (wavelet_bsdf.h). The gather is a function of where the receiver lies and
// how it faces, not of its material: the samples of a pixel on any glossy material share it
// (and, through the bidirectional cut, the pixels around it: core/render/pbgi_receiver.h).
//
// The frame. Its z is the receiver's normal and its x the tangent towards the view direction
// of the sample that gathered (the slices' frame, whose wo has azimuth 0). A sample that shares
// the gather uses its own elevation and the gatherer's azimuth: the samples that share look
// the same way to within the reuse test's view cosine.
//
// Against the warped and adaptive microbuffers (warped_gather.h, adaptive_gather.h), which
// rasterize again for every BSDF and view, the light is gathered once per footprint at a
// fixed resolution; a lobe is integrated over the texels (the slices sample the lobe) rather
// than resolved, so a reflection is as blurred as a texel is wide. A lobe that spans few
// texels is therefore left to the adaptive microbuffer (kMinProductLobeTexels below).
#include <span>
#include <vector>

#include <absl/status/status.h>

#include "core/math/vec.h"
#include "core/pbgi/gather.h"
#include "core/pbgi/tree_page.h"
#include "core/pbgi/wavelet_bsdf.h"

namespace pbgi {

struct ProductGatherOptions {
  GatherOptions gather;     // its resolution a power of two: the cube the light is gathered in
  WaveletBsdfOptions bsdf;  // its resolution the gather's

  bool operator==(const ProductGatherOptions&) const = default;
  // InvalidArgument naming the field when a value is out of range.
  absl::Status validate() const;
};

// The product gather that goes with a gather preset: a power of two at least a third more
// texels a side than the preset's microbuffer (16 for the default 12), its near field, clusters
// no larger than a texel (the preset's or a texel's solid angle, whichever is smaller), and
// BSDF slices every 1.4 degrees of elevation, each texel's integral from 128^2 stratified
// samples of the lobe, kept to 1 % of their norm.
//
// Clusters a texel at most: a glossy lobe reads the light a few texels around its mirror
// direction, and a cluster splatted wider spreads its light past its outline, across an edge
// into the dark beside it. On the glossy plates (their lobes point past the wall's lit top edge
// into the dark), the GGX 0.35 plate's indirect light was 1.142 of the path tracer's with the
// default preset's 0.03 sr clusters, 1.050 with 0.008 sr (a 16^2 cube's texel), 1.014 with
// 0.002 sr; the render took 4.8, 5.9 and 8.0 s.
ProductGatherOptions productGatherOptions(const GatherOptions& gather);

// The fewest texels a lobe must span (WaveletBsdf::lobeTexels) for the product to reflect it;
// a narrower one's receivers gather by the adaptive microbuffer, which refines towards the
// lobe. Measured on the glossy plates, indirect light over the path tracer's with 0.002 sr
// clusters, by the lobe's texels at 16^2 (view cosines 0.5 to 0.95): GGX 0.35 (190 to 255
// texels) 1.014, GGX 0.15 (34 to 58) 1.093, GGX 0.05 (8 to 9) 1.21, GGX 0.01 (3) 6.2; the
// adaptive buffer 0.88 to 1.07 on each.
inline constexpr float kMinProductLobeTexels = 100.0f;

// The frame a receiver gathers in: z its normal (unit), x the tangent towards wo (any tangent
// when wo lies along the normal).
Frame viewFrame(const Vec3f& normal, const Vec3f& wo);

// One per thread; not thread-safe.
class ProductGatherer {
 public:
  // Options must be valid (validate() first when they come from a user).
  explicit ProductGatherer(const ProductGatherOptions& options);

  const ProductGatherOptions& options() const { return options_; }

  // The light arriving at `position` from the tree, in `frame` (viewFrame), as Haar
  // coefficients into *incoming (WaveletBsdf::incomingCoefficients' layout). Errors as
  // Gatherer::rasterize's.
  absl::Status gather(TreePageSource& tree, const Vec3f& position, const Frame& frame,
                      std::vector<float>* incoming, GatherStats* stats);

 private:
  ProductGatherOptions options_;
  Gatherer gatherer_;
  std::vector<Rgb> texels_;
};

}  // namespace pbgi
