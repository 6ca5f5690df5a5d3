#pragma once
// What the tree page's encoder (tree_page_encode.cpp), decoder (tree_page_decode.cpp) and
// wavelet section (tree_page_wavelets.cpp) share: the quantizers and the page's layout. Not an
// interface: tree_page.h is.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <span>
#include <vector>

#include <Imath/half.h>
#include <absl/status/status.h>

#include "core/pbgi/tree_page.h"
#include "core/util/bytes.h"

namespace pbgi::page_codec {

inline constexpr float kU16Max = 65535.0f;

// ---- Octahedral normals (Meyer et al. 2010) ----------------------------------------------

inline float signNotZero(float v) { return v < 0.0f ? -1.0f : 1.0f; }

inline uint16_t toUnorm16(float v) {  // v in [-1, 1]
  return static_cast<uint16_t>(std::lround((std::clamp(v, -1.0f, 1.0f) * 0.5f + 0.5f) * kU16Max));
}
inline float fromUnorm16(uint16_t q) { return q / kU16Max * 2.0f - 1.0f; }

inline void octEncode(const Vec3f& n, uint16_t* u, uint16_t* v) {
  const float l1 = std::abs(n.x) + std::abs(n.y) + std::abs(n.z);
  float x = l1 > 0.0f ? n.x / l1 : 0.0f, y = l1 > 0.0f ? n.y / l1 : 0.0f;
  if (n.z < 0.0f) {
    const float ox = x;
    x = (1.0f - std::abs(y)) * signNotZero(ox);
    y = (1.0f - std::abs(ox)) * signNotZero(y);
  }
  *u = toUnorm16(x);
  *v = toUnorm16(y);
}

inline Vec3f octDecode(uint16_t u, uint16_t v) {
  float x = fromUnorm16(u), y = fromUnorm16(v);
  const float z = 1.0f - std::abs(x) - std::abs(y);
  if (z < 0.0f) {
    const float ox = x;
    x = (1.0f - std::abs(y)) * signNotZero(ox);
    y = (1.0f - std::abs(ox)) * signNotZero(y);
  }
  const Vec3f n(x, y, z);
  const float len = length(n);
  return len > 0.0f ? n / len : Vec3f(0.0f, 0.0f, 1.0f);
}

// ---- Values relative to a box ---------------------------------------------------------------

// The ends map to the box's own ends exactly, so that a child touching its parent's face is
// still inside the dequantized parent whatever the rounding in between.
inline float dequantizeIn(uint16_t q, float lo, float hi) {
  if (!(hi > lo) || q == 0) return lo;
  if (q == 65535) return hi;
  return lo + (hi - lo) * (q / kU16Max);
}

inline uint16_t quantizeNearest(float v, float lo, float hi) {
  if (!(hi > lo)) return 0;
  return static_cast<uint16_t>(std::lround(std::clamp((v - lo) / (hi - lo), 0.0f, 1.0f) * kU16Max));
}

// The largest code whose value is at most v (a min bound), and the smallest whose value is
// at least v (a max bound): dequantized boxes contain the float ones despite rounding.
inline uint16_t quantizeDown(float v, float lo, float hi) {
  if (!(hi > lo)) return 0;
  int q = static_cast<int>(std::floor(std::clamp((v - lo) / (hi - lo), 0.0f, 1.0f) * kU16Max));
  while (q > 0 && dequantizeIn(static_cast<uint16_t>(q), lo, hi) > v) --q;
  return static_cast<uint16_t>(q);
}
inline uint16_t quantizeUp(float v, float lo, float hi) {
  if (!(hi > lo)) return 0;
  int q = static_cast<int>(std::ceil(std::clamp((v - lo) / (hi - lo), 0.0f, 1.0f) * kU16Max));
  while (q < 65535 && dequantizeIn(static_cast<uint16_t>(q), lo, hi) < v) ++q;
  return static_cast<uint16_t>(q);
}

// Cone cosines quantize downwards: a wider cone is still a bound.
inline uint16_t quantizeCosDown(float c) {
  int q = static_cast<int>(std::floor((std::clamp(c, -1.0f, 1.0f) * 0.5f + 0.5f) * kU16Max));
  while (q > 0 && fromUnorm16(static_cast<uint16_t>(q)) > c) --q;
  return static_cast<uint16_t>(q);
}

inline float halfBits(uint16_t bits) {
  half h;
  h.setBits(bits);
  return h;
}

// Set in a page's encoding byte (quantized pages written since): surfel radii are stored
// over their leaf's largest side, so that a half float keeps them in any unit (absolute, a
// radius below 6e-5 lost its precision and one above 65504 was clamped). Pages without it
// read as before.
inline constexpr uint8_t kRelativeRadiiFlag = 0x80;
// Set beside it (quantized pages written since): surfel radiance is stored over its leaf's
// surfelRadianceScale, so that a half float keeps it in any unit of light (absolute, radiance
// above 65504 was clamped: a room lit by a light of 1e10 lost 6 % of its bounced light, and a
// scene in photometric units is near that already). Pages without it read as before.
inline constexpr uint8_t kRelativeRadianceFlag = 0x40;
inline constexpr uint8_t kEncodingFlags = kRelativeRadiiFlag | kRelativeRadianceFlag;

// What a quantized surfel's radius is stored relative to: its leaf's decoded bounds' largest
// side (1 for a leaf of one point, whose bounds have no size).
inline float radiusScale(const Bounds3f& leaf) {
  const float side = maxAbsComponent(leaf.max - leaf.min);
  return side > 0.0f && std::isfinite(side) ? side : 1.0f;
}

inline half toHalf(float v) {
  // Finite, within half's range: radiance beyond 65504 is clamped by the caller, who counts it.
  return half(std::clamp(v, -static_cast<float>(HALF_MAX), static_cast<float>(HALF_MAX)));
}

// The bytes of a page: header, then three arrays of fixed-size records.
struct PageCounts {
  uint32_t nodes = 0, refs = 0, surfels = 0, exact = 0;
};

inline uint32_t exactMarker(TreeEncoding e) {
  return e == TreeEncoding::kQuantized8 ? 0xffu : 0xffffu;
}

inline void encodeBounds(ByteWriter& w, const Bounds3f& b, const Bounds3f& ref, Bounds3f* decoded) {
  const uint16_t q[6] = {
      quantizeDown(b.min.x, ref.min.x, ref.max.x), quantizeDown(b.min.y, ref.min.y, ref.max.y),
      quantizeDown(b.min.z, ref.min.z, ref.max.z), quantizeUp(b.max.x, ref.min.x, ref.max.x),
      quantizeUp(b.max.y, ref.min.y, ref.max.y),   quantizeUp(b.max.z, ref.min.z, ref.max.z)};
  for (uint16_t v : q) w.u16(v);
  decoded->min =
      Vec3f(dequantizeIn(q[0], ref.min.x, ref.max.x), dequantizeIn(q[1], ref.min.y, ref.max.y),
            dequantizeIn(q[2], ref.min.z, ref.max.z));
  decoded->max =
      Vec3f(dequantizeIn(q[3], ref.min.x, ref.max.x), dequantizeIn(q[4], ref.min.y, ref.max.y),
            dequantizeIn(q[5], ref.min.z, ref.max.z));
}

inline Bounds3f decodeBounds(ByteReader& r, const Bounds3f& ref) {
  uint16_t q[6];
  for (uint16_t& v : q) v = r.u16();
  Bounds3f b;
  b.min = Vec3f(dequantizeIn(q[0], ref.min.x, ref.max.x), dequantizeIn(q[1], ref.min.y, ref.max.y),
                dequantizeIn(q[2], ref.min.z, ref.max.z));
  b.max = Vec3f(dequantizeIn(q[3], ref.min.x, ref.max.x), dequantizeIn(q[4], ref.min.y, ref.max.y),
                dequantizeIn(q[5], ref.min.z, ref.max.z));
  return b;
}

inline void writeVec3(ByteWriter& w, const Vec3f& v) {
  w.f32(v.x);
  w.f32(v.y);
  w.f32(v.z);
}
inline Vec3f readVec3(ByteReader& r) {
  const float x = r.f32(), y = r.f32();
  return {x, y, r.f32()};
}

// A node's wavelet as the page stores it: whole, or as a difference from a factor times its
// in-page parent's (tree_page_wavelets.cpp).
struct WaveletEntry {
  uint32_t node;
  uint8_t coding;  // 0 whole, 1 difference from factor x the in-page parent's
  float factor;
  WaveletRadiance stored;
};
// The entries of a page's nodes (then its ghosts) that have wavelets, each coded within
// `relativeError`; `parentOf` gives each node's in-page parent (-1 for none).
std::vector<WaveletEntry> codeWavelets(
    std::span<const PageNode> nodes, std::span<const int64_t> parentOf,
    std::span<const std::shared_ptr<const WaveletRadiance>> ghosts, float relativeError,
    WaveletPageStats* stats);
// The optional section after a page's records, and back (DataLoss naming what is wrong).
void writeWaveletSection(ByteWriter& w, std::span<const WaveletEntry> entries);
absl::Status readWaveletSection(std::span<const uint8_t> bytes, TreePage* page);

}  // namespace pbgi::page_codec
