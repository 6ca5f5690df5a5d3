#pragma once
// Microfacet distributions and Fresnel terms behind the conductor and dielectric BSDFs.
// Private to core/scene: material.h is the public face. Everything works in the local
// shading frame (z = macro-surface normal) and is isotropic.
//
// Masking-shadowing is Smith's height-correlated form G2 = 1 / (1 + Lambda(wo) + Lambda(wi))
// (Heitz 2014, "Understanding the Masking-Shadowing Function"), used for reflection and, as
// pbrt-v4 does, for transmission too, where it is the usual approximation.

#include "core/math/vec.h"
#include "core/scene/shot.h"

namespace pbgi {

// Below this roughness a lobe is treated as a perfect (delta) mirror or refractor: the
// distribution is too sharp for floats and for any light-sampling strategy to hit.
inline constexpr float kDeltaRoughness = 1e-3f;
// Rough lobes keep alpha inside this range so that D, Lambda and the visible-normal warp
// never overflow; past kMaxAlpha the lobe is already indistinguishable from "very rough".
inline constexpr float kMinAlpha = 1e-4f;
inline constexpr float kMaxAlpha = 1e3f;

class Microfacet {
 public:
  Microfacet(MicrofacetDistribution type, float alpha);

  float alpha() const { return alpha_; }
  // Normal distribution D(wm); zero for wm.z <= 0.
  float d(const Vec3f& wm) const;
  // Smith's Lambda(w); symmetric in w.z, infinite at grazing.
  float lambda(const Vec3f& w) const;
  float g1(const Vec3f& w) const { return 1.0f / (1.0f + lambda(w)); }
  float g(const Vec3f& wo, const Vec3f& wi) const {
    return 1.0f / (1.0f + lambda(wo) + lambda(wi));
  }
  // Density (solid angle, over wm) of the normals visible from w, D_w(wm) =
  // G1(w) max(0, w.wm) D(wm) / |w.z|. A w below the surface looks at it from below, so it
  // is mirrored to the upper side first; wm is always in the upper hemisphere.
  float visibleDensity(const Vec3f& w, const Vec3f& wm) const;
  // Draws wm (upper hemisphere) with density visibleDensity(w, .). GGX uses Heitz 2018,
  // Beckmann the slope-space inversion of Heitz & d'Eon 2014 (as in pbrt-v3 / Mitsuba).
  Vec3f sampleVisible(const Vec3f& w, const Vec2f& u) const;

 private:
  Vec3f sampleVisibleGgx(const Vec3f& w, const Vec2f& u) const;
  Vec3f sampleVisibleBeckmann(const Vec3f& w, const Vec2f& u) const;

  MicrofacetDistribution type_;
  float alpha_;
};

// Unpolarised Fresnel reflectance of a dielectric interface. cosThetaI < 0 means the ray
// arrives from the side of the normal's opposite, where the relative index is 1 / eta.
float frDielectric(float cosThetaI, float eta);
// Unpolarised Fresnel reflectance of a conductor with complex index eta + i k, from the
// outside (cosThetaI is clamped to [0, 1]).
float frComplex(float cosThetaI, float eta, float k);
inline float frSchlick(float cosThetaI, float f0) {
  const float m = std::clamp(1.0f - cosThetaI, 0.0f, 1.0f);
  const float m2 = m * m;
  return f0 + (1.0f - f0) * (m2 * m2 * m);
}

// Inverse error function (Giles 2010, single precision), argument clamped to |x| < 1.
float erfInv(float x);

// Mirror of wo about n (both pointing away from the surface).
inline Vec3f reflect(const Vec3f& wo, const Vec3f& n) { return -wo + 2.0f * dot(wo, n) * n; }
// Refracts wi through the interface with normal n and relative index eta (inside over
// outside, outside being n's side). Flips to 1 / eta when wi is on n's back; *etap
// receives the ratio actually used. False on total internal reflection.
bool refract(const Vec3f& wi, Vec3f n, float eta, float* etap, Vec3f* wt);

}  // namespace pbgi
