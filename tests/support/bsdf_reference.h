#pragma once
// Materials and brute-force references the glossy gathers' tests share.
#include <array>
#include <cmath>
#include <span>

#include "core/math/vec.h"
#include "core/pbgi/surfel.h"
#include "core/sampling/rng.h"
#include "core/scene/material.h"

namespace pbgi::testing {

inline Material diffuseMaterial(const Rgb& albedo) {
  Material m;
  m.type = MaterialType::kDiffuse;
  m.albedo = albedo;
  return m;
}

inline Material dielectricMaterial(float roughness) {
  Material m;
  m.type = MaterialType::kDielectric;
  m.roughness = roughness;
  m.ior = 1.5f;
  return m;
}

inline Material conductorMaterial(
    float roughness, const Rgb& specular,
    MicrofacetDistribution distribution = MicrofacetDistribution::kGgx) {
  Material m;
  m.type = MaterialType::kConductor;
  m.roughness = roughness;
  m.specular = specular;
  m.distribution = distribution;
  return m;
}

// The directional albedo, by stratified Monte Carlo with the BSDF's own sampling.
inline Rgb directionalAlbedo(const Bsdf& bsdf, const Vec3f& wo, int n = 512) {
  Rng rng(3);
  double sum[3] = {0.0, 0.0, 0.0};
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const Vec2f u((i + rng.uniform()) / n, (j + rng.uniform()) / n);
      const auto s = bsdf.sample(wo, rng.uniform(), u);
      if (!s || s->wi.z <= 0.0f) continue;
      const Rgb w = s->f * (s->wi.z / s->pdf);
      for (int c = 0; c < 3; ++c) sum[c] += w[c];
    }
  }
  const double count = double(n) * n;
  return Rgb(float(sum[0] / count), float(sum[1] / count), float(sum[2] / count));
}

inline float relativeError(float value, float expected) {
  return std::abs(value / expected - 1.0f);
}

inline Vec3f unitWo(float x, float y, float z) { return normalize(Vec3f(x, y, z)); }

// Reflected radiance (red channel) from disks facing the receiver at the origin, by brute
// force: n x n stratified BSDF samples ray-cast against every disk, each disk hit adding its
// radiance (as a gather's buffer does: the disks of a surface sum to its area, overlapping
// where others leave holes).
inline double referenceDisksReflection(const Bsdf& bsdf, const Frame& frame, const Vec3f& wo,
                                       std::span<const Surfel> disks, int n = 1024) {
  Rng rng(5);
  double sum = 0.0;
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const auto s =
          bsdf.sample(wo, rng.uniform(), Vec2f((i + rng.uniform()) / n, (j + rng.uniform()) / n));
      if (!s || s->wi.z <= 0.0f) continue;
      const Vec3f w = frame.toWorld(s->wi);
      for (const Surfel& d : disks) {
        const float denom = dot(w, d.normal);
        if (!(denom < 0.0f)) continue;
        const float t = dot(d.position, d.normal) / denom;
        if (!(t > 0.0f) || (w * t - d.position).length2() > d.radius * d.radius) continue;
        sum += s->f.x * s->wi.z / s->pdf * d.radiance.x;
      }
    }
  }
  return sum / (double(n) * n);
}

inline double referenceDiskReflection(const Bsdf& bsdf, const Frame& frame, const Vec3f& wo,
                                      const Vec3f& center, const Vec3f& normal, float radius,
                                      float radiance) {
  Surfel disk;
  disk.position = center;
  disk.normal = normal;
  disk.radius = radius;
  disk.radiance = Rgb(radiance);
  return referenceDisksReflection(bsdf, frame, wo, std::span(&disk, 1));
}

// The glossy gathers' small bright source: for a receiver at the origin facing +z, seen from
// each of four views, a disk 3 units away a little off the view's mirror direction, facing the
// receiver.
struct DiskNearMirror {
  Vec3f wo, center, normal;
};
inline std::array<DiskNearMirror, 4> disksNearMirror() {
  const std::array<Vec3f, 4> views = {unitWo(0.4f, 0.1f, 1), unitWo(-0.2f, 0.7f, 1),
                                      unitWo(0.05f, 0, 1), unitWo(1, 0.3f, 0.8f)};
  std::array<DiskNearMirror, 4> out;
  for (size_t i = 0; i < views.size(); ++i) {
    const Vec3f& wo = views[i];
    const Vec3f mirror(-wo.x, -wo.y, wo.z);
    const Vec3f center = 3.0f * normalize(mirror + Vec3f(0.02f, -0.01f, 0));
    out[i] = {wo, center, -normalize(center)};
  }
  return out;
}

}  // namespace pbgi::testing
