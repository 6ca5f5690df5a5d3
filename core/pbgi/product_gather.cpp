#include "core/pbgi/product_gather.h"

#include <algorithm>

#include <fmt/format.h>

namespace pbgi {

absl::Status ProductGatherOptions::validate() const {
  if (absl::Status s = gather.validate(); !s.ok()) return s;
  const int n = gather.resolution;
  if ((n & (n - 1)) != 0) {
    return absl::InvalidArgumentError(fmt::format(
        "product gather options: the resolution must be a power of two (the Haar transform), "
        "got {}",
        n));
  }
  if (bsdf.resolution != n) {
    return absl::InvalidArgumentError(
        fmt::format("product gather options: the BSDF's resolution {} is not the gather's {}",
                    bsdf.resolution, n));
  }
  return bsdf.validate();
}

ProductGatherOptions productGatherOptions(const GatherOptions& gather) {
  ProductGatherOptions o;
  o.gather = gather;
  int n = 1;
  while (n < gather.resolution * 4 / 3 && n < kMaxMicrobufferResolution) n *= 2;
  o.gather.resolution = n;
  o.gather.maxSolidAngle = std::min(gather.maxSolidAngle, 4.0f * kPi / (6.0f * n * n));
  o.bsdf = {.resolution = n, .viewBins = 64, .relativeError = 0.01f, .lobeSamples = 128};
  return o;
}

Frame viewFrame(const Vec3f& normal, const Vec3f& wo) {
  Frame f(normal);
  const Vec3f tangent = wo - normal * dot(wo, normal);
  const float len = length(tangent);
  if (len > 1e-6f) {
    f.s = tangent / len;
    f.t = cross(normal, f.s);
  }
  return f;
}

ProductGatherer::ProductGatherer(const ProductGatherOptions& options)
    : options_(options), gatherer_(options.gather) {}

absl::Status ProductGatherer::gather(TreePageSource& tree, const Vec3f& position,
                                     const Frame& frame, std::vector<float>* incoming,
                                     GatherStats* stats) {
  if (absl::Status s = gatherer_.rasterizeLocal(tree, position, frame, stats); !s.ok()) return s;
  const Microbuffer& buffer = gatherer_.microbuffer();
  texels_.resize(static_cast<size_t>(buffer.pixelCount()));
  for (int k = 0; k < buffer.pixelCount(); ++k) {
    texels_[static_cast<size_t>(k)] = buffer.covered(k) ? buffer.radiance(k) : Rgb(0.0f);
  }
  WaveletBsdf::incomingCoefficients(texels_, buffer.resolution(), incoming);
  return absl::OkStatus();
}

}  // namespace pbgi
