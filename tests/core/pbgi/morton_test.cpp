#include "core/pbgi/morton.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <limits>
#include <random>
#include <vector>

namespace pbgi {
namespace {

// Bit-by-bit interleave: the definition the magic-bits version must match.
uint64_t naiveEncode(uint32_t x, uint32_t y, uint32_t z) {
  uint64_t key = 0;
  for (int i = 0; i < kMortonBitsPerAxis; ++i) {
    key |= static_cast<uint64_t>((x >> i) & 1) << (3 * i);
    key |= static_cast<uint64_t>((y >> i) & 1) << (3 * i + 1);
    key |= static_cast<uint64_t>((z >> i) & 1) << (3 * i + 2);
  }
  return key;
}

TEST(Morton, EncodeMatchesBitByBitInterleaveAndDecodes) {
  std::mt19937_64 rng(7);
  for (int i = 0; i < 100000; ++i) {
    const uint64_t bits = rng();
    const uint32_t x = bits & kMortonMaxCoord;
    const uint32_t y = (bits >> 21) & kMortonMaxCoord;
    const uint32_t z = (bits >> 42) & kMortonMaxCoord;
    const uint64_t key = mortonEncode3(x, y, z);
    ASSERT_EQ(key, naiveEncode(x, y, z)) << x << " " << y << " " << z;
    ASSERT_EQ(mortonDecode3(key), (MortonCoords{x, y, z}));
  }
}

TEST(Morton, EncodeKnownValues) {
  EXPECT_EQ(mortonEncode3(0, 0, 0), 0u);
  EXPECT_EQ(mortonEncode3(1, 0, 0), 1u);
  EXPECT_EQ(mortonEncode3(0, 1, 0), 2u);
  EXPECT_EQ(mortonEncode3(0, 0, 1), 4u);
  EXPECT_EQ(mortonEncode3(3, 0, 0), 0b1001u);
  EXPECT_EQ(mortonEncode3(kMortonMaxCoord, 0, 0), 0x1249249249249249ull);
  EXPECT_EQ(mortonEncode3(0, kMortonMaxCoord, 0), 0x1249249249249249ull << 1);
  EXPECT_EQ(mortonEncode3(0, 0, kMortonMaxCoord), 0x1249249249249249ull << 2);
  EXPECT_EQ(mortonEncode3(kMortonMaxCoord, kMortonMaxCoord, kMortonMaxCoord), kMortonMaxKey);
  EXPECT_EQ(kMortonMaxKey, 0x7fffffffffffffffull);
}

TEST(Morton, DecodeIgnoresNothingBelowBit63) {
  // Every one of the 63 key bits must land in some coordinate.
  for (int bit = 0; bit < 63; ++bit) {
    const MortonCoords c = mortonDecode3(uint64_t{1} << bit);
    const uint32_t expected = 1u << (bit / 3);
    EXPECT_EQ(c.x, bit % 3 == 0 ? expected : 0u) << bit;
    EXPECT_EQ(c.y, bit % 3 == 1 ? expected : 0u) << bit;
    EXPECT_EQ(c.z, bit % 3 == 2 ? expected : 0u) << bit;
  }
}

TEST(Morton, KeysOfBoundsCorners) {
  Bounds3f cube;
  cube.extend(Vec3f(-1.0f, 2.0f, 10.0f));
  cube.extend(Vec3f(3.0f, 6.0f, 14.0f));
  EXPECT_EQ(mortonKey(cube.min, cube), 0u);
  EXPECT_EQ(mortonKey(cube.max, cube), kMortonMaxKey);
  EXPECT_EQ(mortonKey(Vec3f(3.0f, 2.0f, 10.0f), cube), mortonEncode3(kMortonMaxCoord, 0, 0));
  EXPECT_EQ(mortonKey(Vec3f(-1.0f, 6.0f, 10.0f), cube), mortonEncode3(0, kMortonMaxCoord, 0));
  EXPECT_EQ(mortonKey(Vec3f(-1.0f, 2.0f, 14.0f), cube), mortonEncode3(0, 0, kMortonMaxCoord));
  // The centre is the first cell of the upper half on every axis: the root's last child.
  EXPECT_EQ(mortonKey(cube.center(), cube), mortonEncode3(1u << 20, 1u << 20, 1u << 20));
  EXPECT_EQ(mortonPrefix(mortonKey(cube.center(), cube), 1), 7u);

  // Flat bounds: the cube's side is the largest extent, so the short axes use only part of
  // the key range and cells stay cubes.
  Bounds3f flat;
  flat.extend(Vec3f(0.0f, 0.0f, 0.0f));
  flat.extend(Vec3f(2.0f, 1.0f, 0.5f));
  EXPECT_EQ(mortonDecode3(mortonKey(flat.max, flat)),
            (MortonCoords{kMortonMaxCoord, 1u << 20, 1u << 19}));
}

TEST(Morton, OutsidePointsClampAndNanIsKeyZero) {
  Bounds3f b;
  b.extend(Vec3f(0.0f));
  b.extend(Vec3f(1.0f));
  EXPECT_EQ(mortonKey(Vec3f(-5.0f, -5.0f, -5.0f), b), 0u);
  EXPECT_EQ(mortonKey(Vec3f(5.0f, 5.0f, 5.0f), b), kMortonMaxKey);
  const float inf = std::numeric_limits<float>::infinity();
  EXPECT_EQ(mortonKey(Vec3f(inf, -inf, 0.5f), b), mortonEncode3(kMortonMaxCoord, 0, 1u << 20));
  const float nan = std::numeric_limits<float>::quiet_NaN();
  EXPECT_EQ(mortonKey(Vec3f(0.9f, nan, 0.9f), b), 0u);
  // Degenerate bounds (one point, or empty): every key is 0 rather than a division by zero.
  Bounds3f point;
  point.extend(Vec3f(1.0f, 2.0f, 3.0f));
  EXPECT_EQ(mortonKey(Vec3f(1.0f, 2.0f, 3.0f), point), 0u);
  EXPECT_EQ(mortonKey(Vec3f(7.0f, 2.0f, 3.0f), point), 0u);
  EXPECT_EQ(mortonKey(Vec3f(7.0f, 2.0f, 3.0f), Bounds3f()), 0u);
}

TEST(Morton, PrefixCellRangesAndCommonLevel) {
  const uint64_t key = mortonEncode3(0b101, 0b011, 0b110);
  EXPECT_EQ(mortonPrefix(key, 0), 0u);
  EXPECT_EQ(mortonPrefix(key, kMortonLevels), key);
  EXPECT_EQ(mortonCellFirstKey(0, 0), 0u);
  EXPECT_EQ(mortonCellLastKey(0, 0), kMortonMaxKey);
  EXPECT_EQ(mortonCellFirstKey(7, 1), uint64_t{7} << 60);
  EXPECT_EQ(mortonCellLastKey(7, 1), kMortonMaxKey);
  EXPECT_EQ(mortonCellLastKey(key, kMortonLevels), key);

  EXPECT_EQ(commonLevel(key, key), kMortonLevels);
  EXPECT_EQ(commonLevel(0, kMortonMaxKey), 0);
  EXPECT_EQ(commonLevel(0, 1), kMortonLevels - 1);  // siblings at the finest level
  EXPECT_EQ(commonLevel(0, 7), kMortonLevels - 1);
  EXPECT_EQ(commonLevel(0, 8), kMortonLevels - 2);
  EXPECT_EQ(commonLevel(uint64_t{1} << 60, uint64_t{1} << 61), 0);  // different root children
  EXPECT_EQ(commonLevel(uint64_t{1} << 59, 0), 1);
}

// The property the one-sweep tree build relies on: for every level, the points of one cell
// are contiguous in key order and their keys lie in the cell's key range; and commonLevel
// is exactly the deepest level whose cell (by quantised coordinates) holds both points.
TEST(Morton, CellsAreContiguousInKeyOrder) {
  Bounds3f b;
  b.extend(Vec3f(-3.0f, 0.0f, 1.0f));
  b.extend(Vec3f(5.0f, 2.0f, 4.0f));
  const MortonCube cube(b);
  std::mt19937 rng(11);
  std::uniform_real_distribution<float> u(0.0f, 1.0f);
  std::vector<uint64_t> keys;
  for (int i = 0; i < 20000; ++i) {
    // Clusters, so that deep levels have cells with several points.
    const Vec3f c(lerp(u(rng), b.min.x, b.max.x), lerp(u(rng), b.min.y, b.max.y),
                  lerp(u(rng), b.min.z, b.max.z));
    for (int j = 0; j < 4; ++j) {
      const float s = 1e-4f * static_cast<float>(1 << (3 * j));
      keys.push_back(mortonKey(c + Vec3f(u(rng), u(rng), u(rng)) * s, cube));
    }
  }
  std::sort(keys.begin(), keys.end());
  for (int level : {1, 2, 5, 9, 14, 18, 21}) {
    const int shift = kMortonLevels - level;
    std::vector<uint64_t> seen;  // cells in the order they start
    for (size_t i = 0; i < keys.size(); ++i) {
      const uint64_t cell = mortonPrefix(keys[i], level);
      ASSERT_GE(keys[i], mortonCellFirstKey(cell, level));
      ASSERT_LE(keys[i], mortonCellLastKey(cell, level));
      // The cell from quantised coordinates is the same cell.
      const MortonCoords c = mortonDecode3(keys[i]);
      ASSERT_EQ(mortonEncode3(c.x >> shift, c.y >> shift, c.z >> shift), cell);
      if (seen.empty() || seen.back() != cell) seen.push_back(cell);
    }
    // Contiguity: no cell starts twice, i.e. the starts are strictly increasing.
    for (size_t i = 1; i < seen.size(); ++i) ASSERT_LT(seen[i - 1], seen[i]) << level;
  }
  for (size_t i = 1; i < keys.size(); ++i) {
    const int level = commonLevel(keys[i - 1], keys[i]);
    const MortonCoords a = mortonDecode3(keys[i - 1]), c = mortonDecode3(keys[i]);
    const int shift = kMortonLevels - level;
    ASSERT_EQ(a.x >> shift, c.x >> shift);
    ASSERT_EQ(a.y >> shift, c.y >> shift);
    ASSERT_EQ(a.z >> shift, c.z >> shift);
    if (level < kMortonLevels) {
      ASSERT_TRUE((a.x >> (shift - 1)) != (c.x >> (shift - 1)) ||
                  (a.y >> (shift - 1)) != (c.y >> (shift - 1)) ||
                  (a.z >> (shift - 1)) != (c.z >> (shift - 1)));
    }
  }
}

// A point inside a child cell gets a key inside that child's range, which lies inside the
// parent's range.
TEST(Morton, ChildCellKeysNestInParentRange) {
  Bounds3f b;
  b.extend(Vec3f(0.0f));
  b.extend(Vec3f(8.0f, 4.0f, 2.0f));
  const MortonCube cube(b);
  std::mt19937 rng(3);
  std::uniform_real_distribution<float> u(0.05f, 0.95f);  // away from cell faces
  for (int level = 1; level <= 12; ++level) {
    for (int trial = 0; trial < 50; ++trial) {
      const uint64_t cell =
          std::uniform_int_distribution<uint64_t>(0, (uint64_t{1} << (3 * level)) - 1)(rng);
      const Bounds3f box = mortonCellBounds(cube, cell, level);
      const Vec3f p(lerp(u(rng), box.min.x, box.max.x), lerp(u(rng), box.min.y, box.max.y),
                    lerp(u(rng), box.min.z, box.max.z));
      const uint64_t key = mortonKey(p, cube);
      ASSERT_EQ(mortonPrefix(key, level), cell) << level;
      const uint64_t parent = cell >> 3;
      ASSERT_GE(key, mortonCellFirstKey(parent, level - 1));
      ASSERT_LE(key, mortonCellLastKey(parent, level - 1));
      ASSERT_GE(mortonCellFirstKey(cell, level), mortonCellFirstKey(parent, level - 1));
      ASSERT_LE(mortonCellLastKey(cell, level), mortonCellLastKey(parent, level - 1));
    }
  }
}

}  // namespace
}  // namespace pbgi
