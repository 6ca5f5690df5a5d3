#pragma once
// A glossy BSDF in the wavelet domain (Wang, Meng and Boubekeur 2015, section 3.3). For each
// of a set of outgoing directions, the function wi -> f(wo, wi) |cos(wi)| dOmega(texel),
// sampled at the texel centres of the cube map of microbuffer.h in the local shading frame
// (z the normal, x the tangent towards wo: the BSDFs here are isotropic, so wo's azimuth is 0
// in that frame and only its elevation varies), Haar transformed (wavelet.h) and thresholded
// to a stated relative L2 error. The radiance reflected towards wo is then the sparse dot
// product of the incoming radiance's coefficients, gathered in the same frame and resolution,
// with the slice's (WaveletRadiance::dot): by Parseval, the sum over the texels of
// L f |cos| dOmega.
//
// The error of the product is bounded by Cauchy-Schwarz: |<L, g> - <L, g_kept>| is at most
// |L| |g - g_kept|, and |g - g_kept| is at most relativeError |g| (WaveletRadiance::fromDense
// keeps coefficients to that bound and measures what it dropped).
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "core/pbgi/wavelet.h"
#include "core/scene/material.h"

namespace pbgi {

struct WaveletBsdfOptions {
  int resolution = 16;          // the cube's texels a side, as the incoming light's
  int viewBins = 16;            // outgoing elevations, bin centres uniform in angle in [0, 90)
  float relativeError = 0.01f;  // of each slice's L2 norm, dropped at most
  bool operator==(const WaveletBsdfOptions&) const = default;
};

class WaveletBsdf {
 public:
  // Projects `bsdf` (a material whose lobes f() evaluates: not a delta), one slice per
  // outgoing elevation bin. InvalidArgument for a resolution that is not a power of two up to
  // kMaxMicrobufferResolution, fewer than 2 bins or an error outside [0, 1).
  static absl::StatusOr<WaveletBsdf> project(const Bsdf& bsdf, const WaveletBsdfOptions& options);

  // The radiance reflected towards the outgoing direction of elevation cosThetaO (its azimuth
  // the frame's x axis) from `incoming` (the same resolution and frame): the products with the
  // two slices around the elevation, interpolated linearly in it (clamped at the first and last
  // bins' centres). Black for a direction below the surface.
  Rgb reflect(const WaveletRadiance& incoming, float cosThetaO) const;

  int bins() const { return static_cast<int>(slices_.size()); }
  const WaveletRadiance& slice(int bin) const { return slices_[static_cast<size_t>(bin)]; }
  // The elevation (radians from the normal) of a bin's centre: its slice's outgoing direction.
  float binElevation(int bin) const;
  int resolution() const { return options_.resolution; }
  const WaveletBsdfOptions& options() const { return options_; }
  // Over every slice: the coefficients kept, and the largest relative L2 error dropped
  // (measured, at most options().relativeError).
  size_t keptCoefficients() const;
  float maxRelativeError() const;

 private:
  WaveletBsdfOptions options_;
  std::vector<WaveletRadiance> slices_;
};

// One projection per material's parameters and options, shared by every surfel and receiver
// of a bake; thread-safe. A textured material is projected with its untextured albedo.
class WaveletBsdfCache {
 public:
  absl::StatusOr<std::shared_ptr<const WaveletBsdf>> get(const Material& material,
                                                         const WaveletBsdfOptions& options);
  size_t size() const;

 private:
  mutable std::mutex mutex_;
  std::map<std::string, std::shared_ptr<const WaveletBsdf>> projected_;
};

}  // namespace pbgi
