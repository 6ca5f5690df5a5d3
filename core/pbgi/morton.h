#pragma once
// Morton (Z-order) keys for the out-of-core tree build (Kontkanen, Tabellion, Overbeck 2011):
// sorting points by key lays out every octree cell, at every level, as one contiguous run, so
// the tree can be built in a single sweep over the sorted stream.
//
// 21 bits per axis, bit-interleaved as ...z1 y1 x1 z0 y0 x0 (x in the lowest bit of each
// triple), 63 bits in all; the top bit of a key is always 0. Level 0 is the root cell (the
// whole cube), level kMortonLevels the finest cell; the cell at level L is the key's top 3L
// bits.

#include <bit>
#include <cmath>
#include <cstdint>

#include "core/math/vec.h"
#include "core/util/check.h"

namespace pbgi {

inline constexpr int kMortonBitsPerAxis = 21;
inline constexpr int kMortonLevels = kMortonBitsPerAxis;
inline constexpr uint32_t kMortonMaxCoord = (1u << kMortonBitsPerAxis) - 1;
inline constexpr uint64_t kMortonMaxKey = (uint64_t{1} << (3 * kMortonBitsPerAxis)) - 1;

namespace detail {

// Spreads the low 21 bits of v so that bit i lands on bit 3i ("magic bits"; no BMI2 needed,
// so keys are the same on every x86-64 and ARM machine).
inline uint64_t mortonSpread3(uint32_t v) {
  uint64_t x = v & kMortonMaxCoord;
  x = (x | x << 32) & 0x001f00000000ffffull;
  x = (x | x << 16) & 0x001f0000ff0000ffull;
  x = (x | x << 8) & 0x100f00f00f00f00full;
  x = (x | x << 4) & 0x10c30c30c30c30c3ull;
  x = (x | x << 2) & 0x1249249249249249ull;
  return x;
}

// The inverse of mortonSpread3: gathers bits 0, 3, 6, ... into the low 21 bits.
inline uint32_t mortonCompact3(uint64_t x) {
  x &= 0x1249249249249249ull;
  x = (x ^ (x >> 2)) & 0x10c30c30c30c30c3ull;
  x = (x ^ (x >> 4)) & 0x100f00f00f00f00full;
  x = (x ^ (x >> 8)) & 0x001f0000ff0000ffull;
  x = (x ^ (x >> 16)) & 0x001f00000000ffffull;
  x = (x ^ (x >> 32)) & kMortonMaxCoord;
  return static_cast<uint32_t>(x);
}

}  // namespace detail

// Coordinates above 21 bits are a caller bug (they would alias another cell), hence a check.
inline uint64_t mortonEncode3(uint32_t x, uint32_t y, uint32_t z) {
  PBGI_CHECK_LE(x | y | z, kMortonMaxCoord);
  return detail::mortonSpread3(x) | detail::mortonSpread3(y) << 1 | detail::mortonSpread3(z) << 2;
}

struct MortonCoords {
  uint32_t x = 0, y = 0, z = 0;
  bool operator==(const MortonCoords&) const = default;
};

inline MortonCoords mortonDecode3(uint64_t key) {
  return {detail::mortonCompact3(key), detail::mortonCompact3(key >> 1),
          detail::mortonCompact3(key >> 2)};
}

// The cube that keys quantise: anchored at the bounds' min corner, its side the bounds'
// largest extent, so that every octree cell is a cube whatever the scene's proportions.
struct MortonCube {
  Vec3f origin{0.0f};
  float size = 0.0f;

  MortonCube() = default;
  explicit MortonCube(const Bounds3f& bounds) {
    if (bounds.empty()) return;
    origin = bounds.min;
    size = maxComponent(bounds.diagonal());
    // Infinite or NaN bounds quantise everything to the origin cell rather than divide by
    // them; a finite size of 0 (one point) does the same.
    if (!std::isfinite(size) || !isFinite(origin)) size = 0.0f;
  }

  // Cells per axis over the side, in double so that keys do not depend on float rounding
  // of the scale.
  double scale() const {
    return size > 0.0f ? static_cast<double>(kMortonMaxCoord + 1) / size : 0.0;
  }
};

namespace detail {
inline uint32_t mortonQuantize(float p, float origin, double scale) {
  const double q = std::floor((static_cast<double>(p) - origin) * scale);
  // Points outside the cube clamp to its faces; the max face itself belongs to the last cell.
  if (!(q > 0.0)) return 0;  // also catches -inf
  if (q >= static_cast<double>(kMortonMaxCoord)) return kMortonMaxCoord;
  return static_cast<uint32_t>(q);
}
}  // namespace detail

// The key of p in the cube. Policy for a NaN coordinate: key 0 (the first cell). The baker
// rejects NaN positions before keys are made, so this only keeps the function total.
inline uint64_t mortonKey(const Vec3f& p, const MortonCube& cube) {
  if (std::isnan(p.x) || std::isnan(p.y) || std::isnan(p.z)) return 0;
  const double scale = cube.scale();
  return mortonEncode3(detail::mortonQuantize(p.x, cube.origin.x, scale),
                       detail::mortonQuantize(p.y, cube.origin.y, scale),
                       detail::mortonQuantize(p.z, cube.origin.z, scale));
}

inline uint64_t mortonKey(const Vec3f& p, const Bounds3f& bounds) {
  return mortonKey(p, MortonCube(bounds));
}

// The cell containing key at level 0..kMortonLevels: an index in [0, 8^level).
inline uint64_t mortonPrefix(uint64_t key, int level) {
  PBGI_CHECK(level >= 0 && level <= kMortonLevels);
  return key >> (3 * (kMortonLevels - level));
}

// The first and last keys inside a cell; every key of the cell's points sorts between them.
inline uint64_t mortonCellFirstKey(uint64_t prefix, int level) {
  PBGI_CHECK(level >= 0 && level <= kMortonLevels);
  return prefix << (3 * (kMortonLevels - level));
}
inline uint64_t mortonCellLastKey(uint64_t prefix, int level) {
  PBGI_CHECK(level >= 0 && level <= kMortonLevels);
  const int shift = 3 * (kMortonLevels - level);
  return (prefix << shift) | ((uint64_t{1} << shift) - 1);
}

// The deepest level whose cell holds both keys: kMortonLevels when they are equal, 0 when
// only the root does. Keys above kMortonMaxKey are a caller bug.
inline int commonLevel(uint64_t a, uint64_t b) {
  PBGI_CHECK_LE(a | b, kMortonMaxKey);
  const uint64_t diff = a ^ b;
  if (diff == 0) return kMortonLevels;
  const int highestBit = 63 - std::countl_zero(diff);
  return kMortonLevels - 1 - highestBit / 3;
}

// The world-space box of a cell. Quantisation in mortonKey is the authority on which cell a
// point is in; this box is for bounds and debugging, and agrees with it up to float rounding.
inline Bounds3f mortonCellBounds(const MortonCube& cube, uint64_t prefix, int level) {
  PBGI_CHECK(level >= 0 && level <= kMortonLevels);
  const MortonCoords c = mortonDecode3(mortonCellFirstKey(prefix, level));
  const double cell = static_cast<double>(cube.size) / static_cast<double>(1u << level);
  const double unit = static_cast<double>(cube.size) / (kMortonMaxCoord + 1.0);
  Bounds3f b;
  b.min = Vec3f(static_cast<float>(cube.origin.x + c.x * unit),
                static_cast<float>(cube.origin.y + c.y * unit),
                static_cast<float>(cube.origin.z + c.z * unit));
  b.max = Vec3f(static_cast<float>(cube.origin.x + c.x * unit + cell),
                static_cast<float>(cube.origin.y + c.y * unit + cell),
                static_cast<float>(cube.origin.z + c.z * unit + cell));
  return b;
}

}  // namespace pbgi
