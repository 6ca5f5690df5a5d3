#pragma once
// Glossy receivers by the wavelet product (Wang, Meng and Boubekeur 2015, section 3.3): the
// light arriving at a receiver is rasterized once into a cube in the receiver's own frame
// (gather.h's traversal: clusters far enough away, disks, the exact near field), Haar
// transformed with every coefficient kept, and each camera sample that shares the gather takes
// the sparse dot product of those coefficients with its material's BSDF slice for its own
// outgoing elevation (wavelet_bsdf.h). The gather is a function of where the receiver lies and
// how it faces, not of its material: the samples of a pixel on any glossy material share it.
//
// The frame. Its z is the receiver's normal and its x the tangent towards the view direction
// of the sample that gathered (the slices' frame, whose wo has azimuth 0). A sample that shares
// the gather uses its own elevation and the gatherer's azimuth: the samples that share look
// the same way to within the reuse test's view cosine.
//
// Against the warped and adaptive microbuffers (warped_gather.h, adaptive_gather.h), which
// rasterize again for every BSDF and view, the light is gathered once per footprint at a
// fixed resolution; a lobe narrower than a texel is integrated over the texels (the slices
// sample the lobe) rather than resolved, so a sharp reflection of a bright small source is as
// blurred as a texel is wide.
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
// texels a side than the preset's microbuffer (16 for the default 12), its clusters and near
// field, and BSDF slices every 1.4 degrees of elevation, each texel's integral from 128^2
// stratified samples of the lobe, kept to 1 % of their norm.
ProductGatherOptions productGatherOptions(const GatherOptions& gather);

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
