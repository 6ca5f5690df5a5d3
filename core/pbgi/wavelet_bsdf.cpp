#include "core/pbgi/wavelet_bsdf.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>

#include <fmt/format.h>

#include "core/pbgi/microbuffer.h"
#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

constexpr float kHalfPi = std::numbers::pi_v<float> / 2.0f;

constexpr int kMaxLobeSamples = 1024;

bool isPowerOfTwo(int n) { return n > 0 && (n & (n - 1)) == 0; }

}  // namespace

float WaveletBsdf::binElevation(int bin) const {
  return (static_cast<float>(bin) + 0.5f) * kHalfPi / static_cast<float>(bins());
}

absl::Status WaveletBsdfOptions::validate() const {
  if (!isPowerOfTwo(resolution) || resolution > kMaxMicrobufferResolution) {
    return absl::InvalidArgumentError(
        fmt::format("wavelet BSDF resolution {}: expected a power of two up to {}", resolution,
                    kMaxMicrobufferResolution));
  }
  if (viewBins < 2) {
    return absl::InvalidArgumentError(
        fmt::format("wavelet BSDF view bins {}: expected at least 2", viewBins));
  }
  if (!(relativeError >= 0.0f && relativeError < 1.0f)) {
    return absl::InvalidArgumentError(
        fmt::format("wavelet BSDF relative error {}: expected a number in [0, 1)", relativeError));
  }
  if (lobeSamples < 0 || lobeSamples > kMaxLobeSamples) {
    return absl::InvalidArgumentError(fmt::format(
        "wavelet BSDF lobe samples {}: expected 0 to {} a side", lobeSamples, kMaxLobeSamples));
  }
  return absl::OkStatus();
}

absl::StatusOr<WaveletBsdf> WaveletBsdf::project(const Material& material, const Rgb& albedo,
                                                 const WaveletBsdfOptions& options) {
  if (absl::Status s = options.validate(); !s.ok()) return s;
  WaveletBsdf out;
  out.options_ = options;
  out.material_ = std::make_shared<const Material>(material);
  out.albedo_ = albedo;
  out.slices_ = std::make_unique<Slice[]>(static_cast<size_t>(options.viewBins));
  return out;
}

const WaveletBsdf::Slice& WaveletBsdf::projected(int bin) const {
  PBGI_CHECK(bin >= 0 && bin < bins());
  Slice& slice = slices_[static_cast<size_t>(bin)];
  if (!slice.done.load(std::memory_order_acquire)) {
    std::call_once(slice.once, [&] {
      projectSlice(bin, &slice);
      slice.done.store(true, std::memory_order_release);
    });
  }
  return slice;
}

void WaveletBsdf::projectSlice(int bin, Slice* out) const {
  const int n = options_.resolution;
  const size_t texelCount = size_t{6} * n * n;
  const Bsdf bsdf(*material_, albedo_);
  const float theta = binElevation(bin);
  const Vec3f wo(std::sin(theta), 0.0f, std::cos(theta));
  std::vector<Rgb> texels(texelCount, Rgb(0.0f));
  if (options_.lobeSamples == 0) {
    const std::shared_ptr<const MicrobufferTables> tables = microbufferTables(n);
    for (size_t t = 0; t < texelCount; ++t) {
      const Vec3f& wi = tables->directions[t];
      const float cosine = std::abs(wi.z);
      if (cosine > 0.0f) texels[t] = bsdf.f(wo, wi) * (cosine * tables->solidAngles[t]);
    }
  } else {
    // Stratified over the unit square, the lobe's own sampling: the same directions for every
    // projection of the same options, so a slice is a function of the material alone.
    const int side = options_.lobeSamples;
    const float weight = 1.0f / static_cast<float>(side * side);
    for (int j = 0; j < side; ++j) {
      for (int i = 0; i < side; ++i) {
        const Vec2f u((static_cast<float>(i) + 0.5f) / static_cast<float>(side),
                      (static_cast<float>(j) + 0.5f) / static_cast<float>(side));
        const std::optional<BsdfSample> s = bsdf.sample(wo, 0.5f, u);
        if (!s || s->delta || !(s->pdf > 0.0f) || !(s->wi.z > 0.0f)) continue;
        const Rgb value = s->f * (std::abs(s->wi.z) / s->pdf * weight);
        if (!isFinite(value)) continue;
        texels[static_cast<size_t>(cubePixelIndex(s->wi, n))] += value;
      }
    }
  }
  double sum = 0.0, squares = 0.0;
  for (const Rgb& t : texels) {
    const double y = std::max(0.0f, luminance(t));
    sum += y;
    squares += y * y;
  }
  out->lobeTexels = squares > 0.0 ? static_cast<float>(sum * sum / squares) : 0.0f;
  const WaveletRadiance dense = WaveletRadiance::fromTexels(texels, n, 0.0f);
  out->slice = WaveletRadiance::fromDense(dense.dense(), n, 0.0f, options_.relativeError);
  // The kept coefficients, flat, for the product with dense incoming coefficients.
  const std::vector<float> kept = out->slice.dense();
  const size_t perFace = static_cast<size_t>(n) * n;
  for (size_t face = 0; face < 6; ++face) {
    for (size_t k = 0; k < perFace; ++k) {
      const size_t red = face * 3 * perFace + k;
      const Rgb w(kept[red], kept[red + perFace], kept[red + 2 * perFace]);
      if (w.x != 0.0f || w.y != 0.0f || w.z != 0.0f) {
        out->terms.push_back({static_cast<uint32_t>(red), w});
      }
    }
  }
}

int WaveletBsdf::projectedBins() const {
  int count = 0;
  for (int b = 0; b < bins(); ++b) count += slices_[static_cast<size_t>(b)].done.load() ? 1 : 0;
  return count;
}

void WaveletBsdf::incomingCoefficients(std::span<const Rgb> texels, int n,
                                       std::vector<float>* out) {
  const size_t perFace = static_cast<size_t>(n) * n;
  PBGI_CHECK_EQ(texels.size(), 6 * perFace);
  out->resize(6 * 3 * perFace);
  for (size_t face = 0; face < 6; ++face) {
    for (size_t k = 0; k < perFace; ++k) {
      const Rgb& v = texels[face * perFace + k];
      const bool finite = isFinite(v);
      for (size_t c = 0; c < 3; ++c) (*out)[(face * 3 + c) * perFace + k] = finite ? v[c] : 0.0f;
    }
    for (size_t c = 0; c < 3; ++c) {
      haarForward(std::span(out->data() + (face * 3 + c) * perFace, perFace), n);
    }
  }
}

Rgb WaveletBsdf::dotSlice(std::span<const float> incoming, int bin) const {
  const size_t perFace = static_cast<size_t>(options_.resolution) * options_.resolution;
  Rgb sum(0.0f);
  for (const Term& t : projected(bin).terms) {
    const float* in = incoming.data() + t.index;
    sum += Rgb(t.weight.x * in[0], t.weight.y * in[perFace], t.weight.z * in[2 * perFace]);
  }
  return sum;
}

Rgb WaveletBsdf::reflect(std::span<const float> incoming, float cosThetaO) const {
  const size_t n = static_cast<size_t>(options_.resolution);
  PBGI_CHECK_EQ(incoming.size(), 6 * 3 * n * n);
  return interpolated(cosThetaO, [&](int bin) { return dotSlice(incoming, bin); });
}

bool WaveletBsdf::reflectsNothing(float cosThetaO) const {
  if (!(cosThetaO > 0.0f)) return true;
  const auto [lo, w] = binsAround(cosThetaO);
  return projected(lo).terms.empty() && (w <= 0.0f || projected(lo + 1).terms.empty());
}

float WaveletBsdf::lobeTexels(float cosThetaO) const {
  const auto [lo, w] = binsAround(std::max(cosThetaO, 0.0f));
  const float a = projected(lo).lobeTexels;
  return w <= 0.0f ? a : std::min(a, projected(lo + 1).lobeTexels);
}

std::pair<int, float> WaveletBsdf::binsAround(float cosThetaO) const {
  const float theta = std::acos(std::min(cosThetaO, 1.0f));
  // Bin b's centre is at (b + 0.5) of the bin width.
  const float at = std::clamp(theta / kHalfPi * static_cast<float>(bins()) - 0.5f, 0.0f,
                              static_cast<float>(bins() - 1));
  const int lo = std::min(static_cast<int>(at), bins() - 2);
  return {lo, at - static_cast<float>(lo)};
}

Rgb WaveletBsdf::reflect(const WaveletRadiance& incoming, float cosThetaO) const {
  return interpolated(cosThetaO, [&](int bin) { return incoming.dot(slice(bin)); });
}

size_t WaveletBsdf::keptCoefficients() const {
  size_t kept = 0;
  for (int b = 0; b < bins(); ++b) kept += slice(b).keptCoefficients();
  return kept;
}

float WaveletBsdf::maxRelativeError() const {
  float worst = 0.0f;
  for (int b = 0; b < bins(); ++b) worst = std::max(worst, slice(b).relativeError());
  return worst;
}

absl::StatusOr<std::shared_ptr<const WaveletBsdf>> WaveletBsdfCache::get(
    const Material& m, const WaveletBsdfOptions& options) {
  // What f() reads of the material: its parameters, untextured, and the options.
  const Rgb albedo = untexturedAlbedo(m);
  const std::string key = fmt::format(
      "{} {} {} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} {:a} "
      "{:a} {} {} {:a} {}",
      static_cast<int>(m.type), static_cast<int>(m.distribution), m.complexIor, m.roughness,
      albedo.x, albedo.y, albedo.z, m.specular.x, m.specular.y, m.specular.z, m.eta.x, m.eta.y,
      m.eta.z, m.k.x, m.k.y, m.k.z, m.tint.x, m.tint.y, m.tint.z, m.ior, options.resolution,
      options.viewBins, options.relativeError, options.lobeSamples);
  {
    std::lock_guard lock(mutex_);
    if (const auto it = projected_.find(key); it != projected_.end()) return it->second;
  }
  PBGI_ASSIGN_OR_RETURN(WaveletBsdf projected, WaveletBsdf::project(m, albedo, options));
  auto shared = std::make_shared<const WaveletBsdf>(std::move(projected));
  std::lock_guard lock(mutex_);
  return projected_.emplace(key, std::move(shared)).first->second;
}

size_t WaveletBsdfCache::size() const {
  std::lock_guard lock(mutex_);
  return projected_.size();
}

}  // namespace pbgi
