#include "core/pbgi/wavelet_bsdf.h"

#include <algorithm>
#include <cmath>
#include <numbers>

#include <fmt/format.h>

#include "core/pbgi/microbuffer.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

constexpr float kHalfPi = std::numbers::pi_v<float> / 2.0f;

bool isPowerOfTwo(int n) { return n > 0 && (n & (n - 1)) == 0; }

}  // namespace

float WaveletBsdf::binElevation(int bin) const {
  return (static_cast<float>(bin) + 0.5f) * kHalfPi / static_cast<float>(bins());
}

absl::StatusOr<WaveletBsdf> WaveletBsdf::project(const Bsdf& bsdf,
                                                  const WaveletBsdfOptions& options) {
  if (!isPowerOfTwo(options.resolution) || options.resolution > kMaxMicrobufferResolution) {
    return absl::InvalidArgumentError(fmt::format(
        "wavelet BSDF resolution {}: expected a power of two up to {}", options.resolution,
        kMaxMicrobufferResolution));
  }
  if (options.viewBins < 2) {
    return absl::InvalidArgumentError(
        fmt::format("wavelet BSDF view bins {}: expected at least 2", options.viewBins));
  }
  if (!(options.relativeError >= 0.0f && options.relativeError < 1.0f)) {
    return absl::InvalidArgumentError(fmt::format(
        "wavelet BSDF relative error {}: expected a number in [0, 1)", options.relativeError));
  }
  WaveletBsdf out;
  out.options_ = options;
  out.slices_.resize(static_cast<size_t>(options.viewBins));
  const std::shared_ptr<const MicrobufferTables> tables = microbufferTables(options.resolution);
  std::vector<Rgb> texels(tables->directions.size());
  for (int b = 0; b < options.viewBins; ++b) {
    const float theta = out.binElevation(b);
    const Vec3f wo(std::sin(theta), 0.0f, std::cos(theta));
    for (size_t t = 0; t < texels.size(); ++t) {
      const Vec3f& wi = tables->directions[t];
      const float cosine = std::abs(wi.z);
      texels[t] = cosine > 0.0f ? bsdf.f(wo, wi) * (cosine * tables->solidAngles[t]) : Rgb(0.0f);
    }
    const WaveletRadiance dense = WaveletRadiance::fromTexels(texels, options.resolution, 0.0f);
    out.slices_[static_cast<size_t>(b)] = WaveletRadiance::fromDense(
        dense.dense(), options.resolution, 0.0f, options.relativeError);
  }
  return out;
}

Rgb WaveletBsdf::reflect(const WaveletRadiance& incoming, float cosThetaO) const {
  if (!(cosThetaO > 0.0f)) return Rgb(0.0f);
  const float theta = std::acos(std::min(cosThetaO, 1.0f));
  // Bin b's centre is at (b + 0.5) of the bin width.
  const float at = std::clamp(theta / kHalfPi * static_cast<float>(bins()) - 0.5f, 0.0f,
                              static_cast<float>(bins() - 1));
  const int lo = std::min(static_cast<int>(at), bins() - 2);
  const float w = at - static_cast<float>(lo);
  const Rgb a = incoming.dot(slices_[static_cast<size_t>(lo)]);
  if (w <= 0.0f) return a;
  return a * (1.0f - w) + incoming.dot(slices_[static_cast<size_t>(lo + 1)]) * w;
}

size_t WaveletBsdf::keptCoefficients() const {
  size_t kept = 0;
  for (const WaveletRadiance& s : slices_) kept += s.keptCoefficients();
  return kept;
}

float WaveletBsdf::maxRelativeError() const {
  float worst = 0.0f;
  for (const WaveletRadiance& s : slices_) worst = std::max(worst, s.relativeError());
  return worst;
}

absl::StatusOr<std::shared_ptr<const WaveletBsdf>> WaveletBsdfCache::get(
    const Material& m, const WaveletBsdfOptions& options) {
  // What f() reads of the material: its parameters, untextured, and the options.
  const Rgb albedo = untexturedAlbedo(m);
  const std::string key = fmt::format(
      "{} {} {} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} "
      "{:a} {} {} {:a}",
      static_cast<int>(m.type), static_cast<int>(m.distribution), m.complexIor, m.roughness,
      albedo.x, albedo.y, albedo.z, m.specular.x, m.specular.y, m.specular.z, m.eta.x, m.eta.y,
      m.eta.z, m.k.x, m.k.y, m.k.z, m.tint.x, m.tint.y, m.tint.z, m.ior, options.resolution,
      options.viewBins, options.relativeError);
  {
    std::lock_guard lock(mutex_);
    if (const auto it = projected_.find(key); it != projected_.end()) return it->second;
  }
  const Bsdf bsdf(m, albedo);
  PBGI_ASSIGN_OR_RETURN(WaveletBsdf projected, WaveletBsdf::project(bsdf, options));
  auto shared = std::make_shared<const WaveletBsdf>(std::move(projected));
  std::lock_guard lock(mutex_);
  return projected_.emplace(key, std::move(shared)).first->second;
}

size_t WaveletBsdfCache::size() const {
  std::lock_guard lock(mutex_);
  return projected_.size();
}

}  // namespace pbgi
