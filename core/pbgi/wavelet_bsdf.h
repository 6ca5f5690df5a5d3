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
#include <atomic>
#include <map>
#include <memory>
#include <mutex>
#include <span>
#include <string>
#include <utility>
#include <vector>

#include "core/pbgi/wavelet.h"
#include "core/scene/material.h"

namespace pbgi {

struct WaveletBsdfOptions {
  int resolution = 16;          // the cube's texels a side, as the incoming light's
  int viewBins = 16;            // outgoing elevations, bin centres uniform in angle in [0, 90)
  float relativeError = 0.01f;  // of each slice's L2 norm, dropped at most
  // Each texel's value is f |cos| integrated over the texel, by lobeSamples^2 directions drawn
  // from the BSDF (stratified, each adding f |cos| / pdf / count to the texel it falls in);
  // 0 takes f |cos| dOmega at the texel's centre. A lobe narrower than a texel (GGX alpha 0.05
  // against a 16^2 cube's 7-degree texels) needs the integral: at the centres alone its energy
  // is off by whatever the centres happen to hit, and a finer grid only moves the problem to
  // narrower lobes, where sampling the lobe does not.
  int lobeSamples = 0;
  bool operator==(const WaveletBsdfOptions&) const = default;
  // InvalidArgument for a resolution that is not a power of two up to
  // kMaxMicrobufferResolution, fewer than 2 bins, an error outside [0, 1) or lobe samples
  // outside 0 to 1024 a side.
  absl::Status validate() const;
};

class WaveletBsdf {
 public:
  // Projects the BSDF of `material` with `albedo` (a material whose lobes f() evaluates: not a
  // delta), one slice per outgoing elevation bin. A slice is projected the first time it is
  // used (thread-safe), so a render pays for the elevations it sees. Errors: the options'
  // validate().
  static absl::StatusOr<WaveletBsdf> project(const Material& material, const Rgb& albedo,
                                             const WaveletBsdfOptions& options);

  // The radiance reflected towards the outgoing direction of elevation cosThetaO (its azimuth
  // the frame's x axis) from `incoming` (the same resolution and frame): the products with the
  // two slices around the elevation, interpolated linearly in it (clamped at the first and last
  // bins' centres). Black for a direction below the surface.
  Rgb reflect(const WaveletRadiance& incoming, float cosThetaO) const;
  // The same from the incoming radiance's every coefficient (incomingCoefficients): the sum
  // over the slice's kept coefficients only, the sparse product a receiver takes per sample.
  Rgb reflect(std::span<const float> incoming, float cosThetaO) const;
  // Whether reflect() is black towards cosThetaO whatever the light: a direction below the
  // surface (a shading normal turned from the camera), or slices around it that kept no
  // coefficient (a BSDF that reflects nothing there). A receiver then skips its gather.
  bool reflectsNothing(float cosThetaO) const;
  // How many texels the lobe towards cosThetaO spans, in effect: (sum g)^2 / sum g^2 over its
  // texels' luminance g (the participation ratio: n for a lobe spread evenly over n texels, 1
  // for one texel), the smaller of the two slices around it. A product resolves a lobe that
  // spans many texels; one narrower than a few blurs what it reflects over a texel (an edge
  // beside the mirror direction bleeds into it), and a receiver is better served by a gather
  // that refines towards the lobe.
  float lobeTexels(float cosThetaO) const;
  // The Haar coefficients of incoming radiance at the texel centres of six n x n faces (the
  // cube's layout), every one kept: face-major, then channel, then haarForward's pyramid
  // layout, as WaveletRadiance::dense(). Non-finite texels count as black.
  static void incomingCoefficients(std::span<const Rgb> texels, int n, std::vector<float>* out);

  int bins() const { return options_.viewBins; }
  const WaveletRadiance& slice(int bin) const { return projected(bin).slice; }
  // The elevation (radians from the normal) of a bin's centre: its slice's outgoing direction.
  float binElevation(int bin) const;
  int resolution() const { return options_.resolution; }
  const WaveletBsdfOptions& options() const { return options_; }
  // Over every slice (projecting those not yet used): the coefficients kept, and the largest
  // relative L2 error dropped (measured, at most options().relativeError).
  size_t keptCoefficients() const;
  float maxRelativeError() const;
  // Slices projected so far.
  int projectedBins() const;

 private:
  // A kept coefficient of a slice: where it is among the dense coefficients (its red channel's;
  // green and blue follow at + n^2 and + 2 n^2), and its value per channel.
  struct Term {
    uint32_t index;
    Rgb weight;
  };
  struct Slice {
    std::once_flag once;
    std::atomic<bool> done{false};
    WaveletRadiance slice;
    std::vector<Term> terms;  // its kept coefficients
    float lobeTexels = 0.0f;
  };
  const Slice& projected(int bin) const;
  void projectSlice(int bin, Slice* slice) const;
  // The two bins around an outgoing elevation and the weight of the second (clamped at the
  // first and last bins' centres).
  std::pair<int, float> binsAround(float cosThetaO) const;
  // The product with one slice.
  Rgb dotSlice(std::span<const float> incoming, int bin) const;
  // What both reflect()s take: the products with the two slices around cosThetaO
  // (productWith(bin)), interpolated; black below the surface.
  template <typename ProductWith>
  Rgb interpolated(float cosThetaO, ProductWith&& productWith) const {
    if (!(cosThetaO > 0.0f)) return Rgb(0.0f);
    const auto [lo, w] = binsAround(cosThetaO);
    const Rgb a = productWith(lo);
    if (w <= 0.0f) return a;
    return a * (1.0f - w) + productWith(lo + 1) * w;
  }

  WaveletBsdfOptions options_;
  std::shared_ptr<const Material> material_;  // a copy: the BSDF a slice is projected from
  Rgb albedo_{0.0f};
  std::unique_ptr<Slice[]> slices_;
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
