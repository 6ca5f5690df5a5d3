#include "core/scene/material.h"

#include "core/sampling/sampling.h"
#include "core/scene/microfacet.h"

namespace pbgi {
namespace {

// The two-sided lobes are written for wo.z > 0; mirroring the z axis maps the other side
// onto that case (an isotropic BSDF is unchanged by the mirror).
Vec3f flipZ(const Vec3f& v) { return {v.x, v.y, -v.z}; }
bool sameHemisphere(const Vec3f& a, const Vec3f& b) { return a.z * b.z > 0.0f; }

// NaN roughness counts as smooth rather than poisoning every evaluation.
bool isSmooth(const Material& m) { return !(m.roughness >= kDeltaRoughness); }

Microfacet microfacetOf(const Material& m) { return Microfacet(m.distribution, m.roughness); }

// ior == 1 makes the interface invisible: the rough model's generalised half-vector
// degenerates (wi = -wo), so it is handled as the smooth pass-through it is.
float dielectricEta(const Material& m) {
  return std::isfinite(m.ior) && m.ior > 0.0f ? m.ior : 1.0f;
}
bool isSmoothDielectric(const Material& m) { return isSmooth(m) || dielectricEta(m) == 1.0f; }

// Every value that leaves this file passes here: a NaN or Inf would poison a whole pixel.
std::optional<BsdfSample> checked(const BsdfSample& s) {
  if (!(s.pdf > 0.0f) || !std::isfinite(s.pdf) || !isFinite(s.f) || !isFinite(s.wi) ||
      isBlack(s.f) || minComponent(s.f) < 0.0f) {
    return std::nullopt;
  }
  return s;
}
Rgb finiteOrBlack(const Rgb& f) { return isFinite(f) ? f : Rgb(0.0f); }
float finiteOrZero(float pdf) { return std::isfinite(pdf) ? pdf : 0.0f; }

// ---- Conductor (wo.z > 0 in everything below) ----

Rgb conductorFresnel(const Material& m, float cosTheta) {
  Rgb fr;
  for (int c = 0; c < 3; ++c) {
    fr[c] =
        m.complexIor ? frComplex(cosTheta, m.eta[c], m.k[c]) : frSchlick(cosTheta, m.specular[c]);
  }
  return fr * m.tint;
}

Rgb conductorEval(const Material& m, const Vec3f& wo, const Vec3f& wi) {
  if (wo.z <= 0.0f || wi.z <= 0.0f) return Rgb(0.0f);
  const Vec3f h = wo + wi;
  if (h.length2() == 0.0f) return Rgb(0.0f);
  const Vec3f wm = normalize(h);
  const Microfacet mf = microfacetOf(m);
  const float value = mf.d(wm) * mf.g(wo, wi) / (4.0f * wo.z * wi.z);
  return conductorFresnel(m, absDot(wo, wm)) * value;
}

float conductorPdf(const Material& m, const Vec3f& wo, const Vec3f& wi) {
  if (wo.z <= 0.0f || wi.z <= 0.0f) return 0.0f;
  const Vec3f h = wo + wi;
  if (h.length2() == 0.0f) return 0.0f;
  const Vec3f wm = normalize(h);
  const float cosOm = dot(wo, wm);
  if (cosOm <= 0.0f) return 0.0f;
  // Reflection about wm: dwm/dwi = 1 / (4 |wo.wm|).
  return microfacetOf(m).visibleDensity(wo, wm) / (4.0f * cosOm);
}

std::optional<BsdfSample> conductorSample(const Material& m, const Vec3f& wo, const Vec2f& u) {
  if (wo.z <= 0.0f) return std::nullopt;
  BsdfSample s;
  if (isSmooth(m)) {
    s.wi = Vec3f(-wo.x, -wo.y, wo.z);
    s.f = conductorFresnel(m, wo.z) / wo.z;
    s.pdf = 1.0f;
    s.delta = true;
    return checked(s);
  }
  const Microfacet mf = microfacetOf(m);
  const Vec3f wm = mf.sampleVisible(wo, u);
  const float cosOm = dot(wo, wm);
  if (cosOm <= 0.0f) return std::nullopt;
  s.wi = reflect(wo, wm);
  if (s.wi.z <= 0.0f) return std::nullopt;
  s.pdf = mf.visibleDensity(wo, wm) / (4.0f * cosOm);
  s.f = conductorFresnel(m, cosOm) * (mf.d(wm) * mf.g(wo, s.wi) / (4.0f * wo.z * s.wi.z));
  return checked(s);
}

// ---- Dielectric (wo.z > 0: outside, index 1; wo.z < 0: inside, index ior) ----

// The microfacet normal that takes wo to wi, and the relative index etap of wi's side over
// wo's side (1 for reflection); nullopt when no front-facing microfacet does it.
struct HalfVector {
  Vec3f wm;
  float etap;
};
std::optional<HalfVector> dielectricHalfVector(float eta, const Vec3f& wo, const Vec3f& wi) {
  const float cosO = wo.z;
  const float cosI = wi.z;
  if (cosO == 0.0f || cosI == 0.0f) return std::nullopt;
  const bool reflection = cosO * cosI > 0.0f;
  const float etap = reflection ? 1.0f : (cosO > 0.0f ? eta : 1.0f / eta);
  // Generalised half-vector (Walter 2007): parallel to the microfacet normal for both
  // reflection and refraction.
  Vec3f wm = wi * etap + wo;
  if (wm.length2() == 0.0f) return std::nullopt;
  wm = normalize(wm);
  if (wm.z < 0.0f) wm = -wm;
  if (wm.z == 0.0f) return std::nullopt;
  // Back-facing microfacets neither reflect nor refract in this model.
  if (dot(wm, wi) * cosI < 0.0f || dot(wm, wo) * cosO < 0.0f) return std::nullopt;
  return HalfVector{wm, etap};
}

// Fresnel transmittance of a refraction between wo and wi through wm. T is the same from
// either side, but from the dense side near the critical angle it is ill-conditioned (cos_t
// comes from 1 - eta^2 sin^2), so it is taken from the outer direction, which is where
// float rounding of wm matters least. This keeps f(wo, wi) and f(wi, wo) consistent.
float dielectricTransmittance(float eta, const Vec3f& wo, const Vec3f& wi, const Vec3f& wm) {
  return 1.0f - frDielectric(dot(wo.z > 0.0f ? wo : wi, wm), eta);
}

// The transmitted value before the radiance-mode 1 / etap^2 scale.
float dielectricTransmission(const Microfacet& mf, float t, const Vec3f& wo, const Vec3f& wi,
                             const Vec3f& wm, float etap) {
  const float denom = sqr(dot(wi, wm) + dot(wo, wm) / etap) * wi.z * wo.z;
  if (denom == 0.0f) return 0.0f;
  return t * mf.d(wm) * mf.g(wo, wi) * std::abs(dot(wi, wm) * dot(wo, wm) / denom);
}

Rgb dielectricEval(const Material& m, TransportMode mode, const Vec3f& wo, const Vec3f& wi) {
  const float eta = dielectricEta(m);
  const auto hv = dielectricHalfVector(eta, wo, wi);
  if (!hv) return Rgb(0.0f);
  const Microfacet mf = microfacetOf(m);
  if (sameHemisphere(wo, wi)) {
    const float r = frDielectric(dot(wo, hv->wm), eta);
    return Rgb(mf.d(hv->wm) * mf.g(wo, wi) * r / std::abs(4.0f * wi.z * wo.z));
  }
  const float t = dielectricTransmittance(eta, wo, wi, hv->wm);
  float ft = dielectricTransmission(mf, t, wo, wi, hv->wm, hv->etap);
  if (mode == TransportMode::kRadiance) ft /= sqr(hv->etap);
  return Rgb(ft);
}

float dielectricPdf(const Material& m, const Vec3f& wo, const Vec3f& wi) {
  const float eta = dielectricEta(m);
  const auto hv = dielectricHalfVector(eta, wo, wi);
  if (!hv) return 0.0f;
  const Microfacet mf = microfacetOf(m);
  // sample() picks reflection with probability R (R + T = 1).
  const float r = frDielectric(dot(wo, hv->wm), eta);
  const float visible = mf.visibleDensity(wo, hv->wm);
  if (sameHemisphere(wo, wi)) return visible / (4.0f * absDot(wo, hv->wm)) * r;
  const float denom = sqr(dot(wi, hv->wm) + dot(wo, hv->wm) / hv->etap);
  if (denom == 0.0f) return 0.0f;
  return visible * (absDot(wi, hv->wm) / denom) * (1.0f - r);
}

std::optional<BsdfSample> dielectricSample(const Material& m, TransportMode mode, const Vec3f& wo,
                                           float uc, const Vec2f& u) {
  if (wo.z == 0.0f) return std::nullopt;
  const float eta = dielectricEta(m);
  BsdfSample s;
  if (isSmoothDielectric(m)) {
    const float r = frDielectric(wo.z, eta);
    if (uc < r) {
      s.wi = Vec3f(-wo.x, -wo.y, wo.z);
      s.f = Rgb(r / std::abs(s.wi.z));
      s.pdf = r;
    } else {
      float etap = 1.0f;
      if (!refract(wo, Vec3f(0, 0, 1), eta, &etap, &s.wi) || s.wi.z == 0.0f) return std::nullopt;
      float ft = (1.0f - r) / std::abs(s.wi.z);
      if (mode == TransportMode::kRadiance) ft /= sqr(etap);
      s.f = Rgb(ft);
      s.pdf = 1.0f - r;
      s.transmission = true;
    }
    s.delta = true;
    return checked(s);
  }

  const Microfacet mf = microfacetOf(m);
  const Vec3f wm = mf.sampleVisible(wo, u);
  const float cosOm = dot(wo, wm);
  if (cosOm == 0.0f) return std::nullopt;
  const float r = frDielectric(cosOm, eta);
  const float visible = mf.visibleDensity(wo, wm);
  if (uc < r) {
    s.wi = reflect(wo, wm);
    if (!sameHemisphere(wo, s.wi)) return std::nullopt;
    s.pdf = visible / (4.0f * std::abs(cosOm)) * r;
    s.f = Rgb(mf.d(wm) * mf.g(wo, s.wi) * r / std::abs(4.0f * s.wi.z * wo.z));
    return checked(s);
  }
  float etap = 1.0f;
  if (!refract(wo, wm, eta, &etap, &s.wi)) return std::nullopt;
  if (sameHemisphere(wo, s.wi) || s.wi.z == 0.0f) return std::nullopt;
  const float denom = sqr(dot(s.wi, wm) + cosOm / etap);
  if (denom == 0.0f) return std::nullopt;
  s.pdf = visible * (absDot(s.wi, wm) / denom) * (1.0f - r);
  float ft =
      dielectricTransmission(mf, dielectricTransmittance(eta, wo, s.wi, wm), wo, s.wi, wm, etap);
  if (mode == TransportMode::kRadiance) ft /= sqr(etap);
  s.f = Rgb(ft);
  s.transmission = true;
  return checked(s);
}

}  // namespace

Rgb untexturedAlbedo(const Material& m) {
  switch (m.type) {
    case MaterialType::kDiffuse:
      return m.albedo;
    case MaterialType::kConductor:
      return m.complexIor ? m.tint : m.specular * m.tint;
    case MaterialType::kDielectric:
      return Rgb(1.0f);
    case MaterialType::kEmissive:
      return Rgb(0.0f);
  }
  return Rgb(0.0f);
}

Bsdf::Bsdf(const Material& material, const Rgb& albedo, TransportMode mode)
    : material_(&material), albedo_(albedo), mode_(mode) {}

Rgb Bsdf::f(const Vec3f& wo, const Vec3f& wi) const {
  const Material& m = *material_;
  switch (m.type) {
    case MaterialType::kDiffuse:
      if (!sameHemisphere(wo, wi)) return Rgb(0.0f);
      return finiteOrBlack(albedo_ * kInvPi);
    case MaterialType::kConductor:
      if (isSmooth(m) || !sameHemisphere(wo, wi)) return Rgb(0.0f);
      return finiteOrBlack(wo.z > 0.0f ? conductorEval(m, wo, wi)
                                       : conductorEval(m, flipZ(wo), flipZ(wi)));
    case MaterialType::kDielectric:
      if (isSmoothDielectric(m)) return Rgb(0.0f);
      return finiteOrBlack(dielectricEval(m, mode_, wo, wi));
    case MaterialType::kEmissive:
      return Rgb(0.0f);
  }
  return Rgb(0.0f);
}

float Bsdf::pdf(const Vec3f& wo, const Vec3f& wi) const {
  const Material& m = *material_;
  switch (m.type) {
    case MaterialType::kDiffuse:
      if (!sameHemisphere(wo, wi)) return 0.0f;
      return std::abs(wi.z) * kInvPi;
    case MaterialType::kConductor:
      if (isSmooth(m) || !sameHemisphere(wo, wi)) return 0.0f;
      return finiteOrZero(wo.z > 0.0f ? conductorPdf(m, wo, wi)
                                      : conductorPdf(m, flipZ(wo), flipZ(wi)));
    case MaterialType::kDielectric:
      if (isSmoothDielectric(m)) return 0.0f;
      return finiteOrZero(dielectricPdf(m, wo, wi));
    case MaterialType::kEmissive:
      return 0.0f;
  }
  return 0.0f;
}

std::optional<BsdfSample> Bsdf::sample(const Vec3f& wo, float uc, const Vec2f& u) const {
  const Material& m = *material_;
  switch (m.type) {
    case MaterialType::kDiffuse: {
      if (wo.z == 0.0f) return std::nullopt;
      BsdfSample s;
      s.wi = sampleCosineHemisphere(u);
      if (wo.z < 0.0f) s.wi = flipZ(s.wi);
      s.pdf = std::abs(s.wi.z) * kInvPi;
      s.f = albedo_ * kInvPi;
      return checked(s);
    }
    case MaterialType::kConductor: {
      if (wo.z == 0.0f) return std::nullopt;
      if (wo.z > 0.0f) return conductorSample(m, wo, u);
      auto s = conductorSample(m, flipZ(wo), u);
      if (s) s->wi = flipZ(s->wi);
      return s;
    }
    case MaterialType::kDielectric:
      return dielectricSample(m, mode_, wo, uc, u);
    case MaterialType::kEmissive:
      return std::nullopt;
  }
  return std::nullopt;
}

bool Bsdf::isDelta() const {
  switch (material_->type) {
    case MaterialType::kConductor:
      return isSmooth(*material_);
    case MaterialType::kDielectric:
      return isSmoothDielectric(*material_);
    default:
      return false;
  }
}

bool Bsdf::isBlack() const { return material_->type == MaterialType::kEmissive; }

}  // namespace pbgi
