#pragma once
// Vector types are Imath's; this header adds the few helpers rendering code needs everywhere.

#include <algorithm>
#include <cmath>
#include <numbers>

#include <Imath/ImathVec.h>
#include <fmt/format.h>

namespace pbgi {

using Vec2f = Imath::V2f;
using Vec3f = Imath::V3f;
using Vec2i = Imath::V2i;
// Linear scene-referred RGB. An alias rather than a type: colours and vectors share all
// component-wise arithmetic and the renderer converts between them constantly.
using Rgb = Imath::V3f;

inline constexpr float kPi = std::numbers::pi_v<float>;
inline constexpr float kInvPi = 1.0f / kPi;
inline constexpr float kInv4Pi = 1.0f / (4.0f * kPi);

inline float dot(const Vec3f& a, const Vec3f& b) { return a.dot(b); }
inline Vec3f cross(const Vec3f& a, const Vec3f& b) { return a.cross(b); }
inline float length(const Vec3f& v) { return v.length(); }
inline Vec3f normalize(const Vec3f& v) { return v.normalized(); }
inline float absDot(const Vec3f& a, const Vec3f& b) { return std::abs(a.dot(b)); }
inline float maxComponent(const Vec3f& v) { return std::max({v.x, v.y, v.z}); }
inline float minComponent(const Vec3f& v) { return std::min({v.x, v.y, v.z}); }
inline float maxAbsComponent(const Vec3f& v) {
  return std::max({std::abs(v.x), std::abs(v.y), std::abs(v.z)});
}
inline Vec3f vmin(const Vec3f& a, const Vec3f& b) {
  return {std::min(a.x, b.x), std::min(a.y, b.y), std::min(a.z, b.z)};
}
inline Vec3f vmax(const Vec3f& a, const Vec3f& b) {
  return {std::max(a.x, b.x), std::max(a.y, b.y), std::max(a.z, b.z)};
}
inline bool isFinite(const Vec3f& v) {
  return std::isfinite(v.x) && std::isfinite(v.y) && std::isfinite(v.z);
}
inline bool isBlack(const Rgb& c) { return c.x == 0.0f && c.y == 0.0f && c.z == 0.0f; }
inline float luminance(const Rgb& c) { return 0.2126f * c.x + 0.7152f * c.y + 0.0722f * c.z; }
inline float average(const Rgb& c) { return (c.x + c.y + c.z) * (1.0f / 3.0f); }
inline Rgb rgbExp(const Rgb& c) { return {std::exp(c.x), std::exp(c.y), std::exp(c.z)}; }
inline float lerp(float t, float a, float b) { return a + t * (b - a); }
inline Vec3f lerp(float t, const Vec3f& a, const Vec3f& b) { return a + t * (b - a); }
inline float radians(float deg) { return deg * (kPi / 180.0f); }
inline float degrees(float rad) { return rad * (180.0f / kPi); }
inline float safeSqrt(float x) { return std::sqrt(std::max(0.0f, x)); }
inline float safeAcos(float x) { return std::acos(std::clamp(x, -1.0f, 1.0f)); }
inline float sqr(float x) { return x * x; }

// Orthonormal basis around a unit normal (Duff et al. 2017, branchless and continuous
// except at n.z = -1 where it flips sign).
struct Frame {
  Vec3f s, t, n;

  Frame() : s(1, 0, 0), t(0, 1, 0), n(0, 0, 1) {}
  explicit Frame(const Vec3f& normal) : n(normal) {
    const float sign = std::copysign(1.0f, n.z);
    const float a = -1.0f / (sign + n.z);
    const float b = n.x * n.y * a;
    s = Vec3f(1.0f + sign * n.x * n.x * a, sign * b, -sign * n.x);
    t = Vec3f(b, sign + n.y * n.y * a, -n.y);
  }
  Vec3f toLocal(const Vec3f& v) const { return {dot(v, s), dot(v, t), dot(v, n)}; }
  Vec3f toWorld(const Vec3f& v) const { return s * v.x + t * v.y + n * v.z; }
};

// Bounds of a set of points; empty when min > max.
struct Bounds3f {
  Vec3f min{std::numeric_limits<float>::infinity()};
  Vec3f max{-std::numeric_limits<float>::infinity()};

  bool empty() const { return min.x > max.x || min.y > max.y || min.z > max.z; }
  bool operator==(const Bounds3f& o) const { return min == o.min && max == o.max; }
  void extend(const Vec3f& p) {
    min = vmin(min, p);
    max = vmax(max, p);
  }
  void extend(const Bounds3f& b) {
    min = vmin(min, b.min);
    max = vmax(max, b.max);
  }
  Vec3f diagonal() const { return empty() ? Vec3f(0.0f) : max - min; }
  Vec3f center() const { return (min + max) * 0.5f; }
  // Radius of the bounding sphere around center().
  float radius() const { return 0.5f * length(diagonal()); }
};

}  // namespace pbgi

template <>
struct fmt::formatter<Imath::V3f> : fmt::formatter<float> {
  template <typename Ctx>
  auto format(const Imath::V3f& v, Ctx& ctx) const {
    return fmt::format_to(ctx.out(), "({}, {}, {})", v.x, v.y, v.z);
  }
};
