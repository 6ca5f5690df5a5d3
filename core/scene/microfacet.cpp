#include "core/scene/microfacet.h"

#include <complex>
#include <limits>

namespace pbgi {
namespace {

constexpr float kInf = std::numeric_limits<float>::infinity();
constexpr float kInvSqrtPi = 0.56418958354775628f;

// Exact Smith Lambda of the Beckmann distribution, a = 1 / (alpha tan theta). Written with
// erfc so that the two small terms do not cancel to garbage for large a; in double for the
// same reason. The exact form (not the usual rational fit) keeps the visible-normal density
// normalised, which the sampling code and the chi-square test rely on.
float beckmannLambda(double a) {
  if (a <= 0.0) return kInf;
  const double v = 0.5 * (std::exp(-a * a) / (a * 1.7724538509055159) - std::erfc(a));
  return static_cast<float>(std::max(0.0, v));
}

// Heitz & d'Eon 2014: a slope (x, y) of the alpha = 1 Beckmann surface seen from a direction
// at cosThetaI in the xz-plane. x inverts the 1-D visible-slope CDF numerically
// (Newton steps safeguarded by bisection, in the erf domain), y is a plain Gaussian slope.
Vec2f sampleBeckmannSlope11(float cosThetaI, const Vec2f& u) {
  const float ux = std::max(u.x, 1e-6f);
  const float uy = std::max(u.y, 1e-6f);
  const float sinThetaI = safeSqrt(1.0f - cosThetaI * cosThetaI);
  if (sinThetaI < 1e-6f) {
    // Normal incidence: the visible slopes are the slopes; sample them in polar form.
    const float r = std::sqrt(-std::log(1.0f - u.x));
    const float phi = 2.0f * kPi * u.y;
    return {r * std::cos(phi), r * std::sin(phi)};
  }
  // Grazing views make tan overflow the normalisation; this close to the horizon the
  // visible-normal distribution no longer changes.
  const float cosClamped = std::max(cosThetaI, 1e-6f);
  const float tanThetaI = safeSqrt(1.0f - cosClamped * cosClamped) / cosClamped;
  const float cotThetaI = 1.0f / tanThetaI;
  float a = -1.0f;
  float c = std::erf(cotThetaI);
  // A fitted initial guess (Jakob, Mitsuba) makes Newton converge in a couple of steps.
  const float thetaI = std::acos(cosClamped);
  const float fit = 1.0f + thetaI * (-0.876f + thetaI * (0.4265f - 0.0594f * thetaI));
  float b = c - (1.0f + c) * std::pow(1.0f - ux, fit);
  const float normalization =
      1.0f / (1.0f + c + kInvSqrtPi * tanThetaI * std::exp(-cotThetaI * cotThetaI));
  for (int it = 0; it < 10; ++it) {
    // Written so that a NaN b also falls back to bisection.
    if (!(b >= a && b <= c)) b = 0.5f * (a + c);
    const float invErf = erfInv(b);
    const float value =
        normalization * (1.0f + b + kInvSqrtPi * tanThetaI * std::exp(-invErf * invErf)) - ux;
    const float derivative = normalization * (1.0f - invErf * tanThetaI);
    if (std::abs(value) < 1e-5f) break;
    if (value > 0.0f) {
      c = b;
    } else {
      a = b;
    }
    b -= value / derivative;
  }
  if (!(b >= a && b <= c)) b = 0.5f * (a + c);
  return {erfInv(b), erfInv(2.0f * uy - 1.0f)};
}

}  // namespace

Microfacet::Microfacet(MicrofacetDistribution type, float alpha)
    : type_(type),
      alpha_(std::isfinite(alpha) ? std::clamp(alpha, kMinAlpha, kMaxAlpha) : kMaxAlpha) {}

float Microfacet::d(const Vec3f& wm) const {
  if (wm.z <= 0.0f) return 0.0f;
  const float cos2 = wm.z * wm.z;
  // From x and y rather than 1 - cos^2, which cancels to noise exactly where sharp lobes
  // live (a 1e-3 relative error in D at alpha = 0.01).
  const float sin2 = wm.x * wm.x + wm.y * wm.y;
  const float a2 = alpha_ * alpha_;
  if (type_ == MicrofacetDistribution::kGgx) {
    // alpha^2 / (pi (sin^2 + alpha^2 cos^2)^2): the tan-free form has no 0 * inf at the
    // horizon and no overflow for tiny alpha.
    const float t = sin2 + a2 * cos2;
    return a2 / (kPi * t * t);
  }
  const float e = std::exp(-(sin2 / cos2) / a2);
  if (e == 0.0f) return 0.0f;
  return e / (kPi * a2 * cos2 * cos2);
}

float Microfacet::lambda(const Vec3f& w) const {
  const float cos2 = w.z * w.z;
  const float sin2 = std::max(0.0f, w.x * w.x + w.y * w.y);
  if (sin2 == 0.0f) return 0.0f;
  if (cos2 == 0.0f) return kInf;
  const float tan2 = sin2 / cos2;
  if (type_ == MicrofacetDistribution::kGgx) {
    // (sqrt(1 + x) - 1) / 2 rewritten to avoid cancellation when alpha tan is small.
    const float x = alpha_ * alpha_ * tan2;
    if (!std::isfinite(x)) return kInf;
    return x / (2.0f * (std::sqrt(1.0f + x) + 1.0f));
  }
  return beckmannLambda(1.0 / (static_cast<double>(alpha_) * std::sqrt(static_cast<double>(tan2))));
}

float Microfacet::visibleDensity(const Vec3f& w, const Vec3f& wm) const {
  const float cosW = std::abs(w.z);
  if (cosW == 0.0f) return 0.0f;
  const Vec3f up = w.z < 0.0f ? -w : w;
  const float cosWm = dot(up, wm);
  if (cosWm <= 0.0f) return 0.0f;
  return g1(w) / cosW * d(wm) * cosWm;
}

Vec3f Microfacet::sampleVisible(const Vec3f& w, const Vec2f& u) const {
  const Vec3f up = w.z < 0.0f ? -w : w;
  return type_ == MicrofacetDistribution::kGgx ? sampleVisibleGgx(up, u)
                                               : sampleVisibleBeckmann(up, u);
}

Vec3f Microfacet::sampleVisibleGgx(const Vec3f& w, const Vec2f& u) const {
  // Heitz 2018: stretch to the alpha = 1 configuration, where the visible normals are a
  // uniformly sampled projected hemisphere, then unstretch.
  const Vec3f wh = normalize(Vec3f(alpha_ * w.x, alpha_ * w.y, w.z));
  const float lensq = wh.x * wh.x + wh.y * wh.y;
  const Vec3f t1 = lensq > 0.0f ? Vec3f(-wh.y, wh.x, 0.0f) / std::sqrt(lensq) : Vec3f(1, 0, 0);
  const Vec3f t2 = cross(wh, t1);
  const float r = std::sqrt(u.x);
  const float phi = 2.0f * kPi * u.y;
  const float p1 = r * std::cos(phi);
  const float s = 0.5f * (1.0f + wh.z);
  const float p2 = (1.0f - s) * safeSqrt(1.0f - p1 * p1) + s * r * std::sin(phi);
  const Vec3f nh = p1 * t1 + p2 * t2 + safeSqrt(1.0f - p1 * p1 - p2 * p2) * wh;
  return normalize(Vec3f(alpha_ * nh.x, alpha_ * nh.y, std::max(0.0f, nh.z)));
}

Vec3f Microfacet::sampleVisibleBeckmann(const Vec3f& w, const Vec2f& u) const {
  const Vec3f wh = normalize(Vec3f(alpha_ * w.x, alpha_ * w.y, w.z));
  Vec2f slope = sampleBeckmannSlope11(wh.z, u);
  const float sin2 = wh.x * wh.x + wh.y * wh.y;
  float cosPhi = 1.0f;
  float sinPhi = 0.0f;
  if (sin2 > 0.0f) {
    const float invSin = 1.0f / std::sqrt(sin2);
    cosPhi = wh.x * invSin;
    sinPhi = wh.y * invSin;
  }
  slope = Vec2f(cosPhi * slope.x - sinPhi * slope.y, sinPhi * slope.x + cosPhi * slope.y);
  return normalize(Vec3f(-alpha_ * slope.x, -alpha_ * slope.y, 1.0f));
}

float frDielectric(float cosThetaI, float eta) {
  cosThetaI = std::clamp(cosThetaI, -1.0f, 1.0f);
  if (cosThetaI < 0.0f) {
    eta = 1.0f / eta;
    cosThetaI = -cosThetaI;
  }
  const float sin2I = 1.0f - cosThetaI * cosThetaI;
  const float sin2T = sin2I / (eta * eta);
  if (sin2T >= 1.0f) return 1.0f;  // total internal reflection
  const float cosT = safeSqrt(1.0f - sin2T);
  const float rParl = (eta * cosThetaI - cosT) / (eta * cosThetaI + cosT);
  const float rPerp = (cosThetaI - eta * cosT) / (cosThetaI + eta * cosT);
  return 0.5f * (rParl * rParl + rPerp * rPerp);
}

float frComplex(float cosThetaI, float eta, float k) {
  using Complex = std::complex<float>;
  cosThetaI = std::clamp(cosThetaI, 0.0f, 1.0f);
  const float sin2I = 1.0f - cosThetaI * cosThetaI;
  const Complex n(eta, k);
  if (std::norm(n) == 0.0f) return 1.0f;  // an unphysical zero index: call it a mirror
  const Complex sin2T = sin2I / (n * n);
  const Complex cosT = std::sqrt(Complex(1.0f) - sin2T);
  const Complex parlDen = n * cosThetaI + cosT;
  const Complex perpDen = cosThetaI + n * cosT;
  if (std::norm(parlDen) == 0.0f || std::norm(perpDen) == 0.0f) return 1.0f;
  const Complex rParl = (n * cosThetaI - cosT) / parlDen;
  const Complex rPerp = (cosThetaI - n * cosT) / perpDen;
  const float r = 0.5f * (std::norm(rParl) + std::norm(rPerp));
  return std::isfinite(r) ? std::clamp(r, 0.0f, 1.0f) : 1.0f;
}

float erfInv(float x) {
  x = std::clamp(x, -0.99999f, 0.99999f);
  float w = -std::log((1.0f - x) * (1.0f + x));
  float p;
  if (w < 5.0f) {
    w = w - 2.5f;
    p = 2.81022636e-08f;
    p = 3.43273939e-07f + p * w;
    p = -3.5233877e-06f + p * w;
    p = -4.39150654e-06f + p * w;
    p = 0.00021858087f + p * w;
    p = -0.00125372503f + p * w;
    p = -0.00417768164f + p * w;
    p = 0.246640727f + p * w;
    p = 1.50140941f + p * w;
  } else {
    w = std::sqrt(w) - 3.0f;
    p = -0.000200214257f;
    p = 0.000100950558f + p * w;
    p = 0.00134934322f + p * w;
    p = -0.00367342844f + p * w;
    p = 0.00573950773f + p * w;
    p = -0.0076224613f + p * w;
    p = 0.00943887047f + p * w;
    p = 1.00167406f + p * w;
    p = 2.83297682f + p * w;
  }
  return p * x;
}

bool refract(const Vec3f& wi, Vec3f n, float eta, float* etap, Vec3f* wt) {
  float cosI = dot(n, wi);
  if (cosI < 0.0f) {
    eta = 1.0f / eta;
    cosI = -cosI;
    n = -n;
  }
  const float sin2I = std::max(0.0f, 1.0f - cosI * cosI);
  const float sin2T = sin2I / (eta * eta);
  if (sin2T >= 1.0f) return false;
  const float cosT = safeSqrt(1.0f - sin2T);
  *wt = -wi / eta + (cosI / eta - cosT) * n;
  *etap = eta;
  return true;
}

}  // namespace pbgi
