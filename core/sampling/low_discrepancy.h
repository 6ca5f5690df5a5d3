#pragma once
// Stratified points for the dimensions every camera sample has (the position in its pixel, the
// point on the lens): the first two dimensions of the Sobol sequence, Owen-scrambled by
// hashing (Burley 2020, "Practical Hash-based Owen Scrambling", after Laine and Karras 2011).
//
// The first 2^k points of the 2-D Sobol sequence are a (0, k, 2)-net: every box of area 2^-k
// with power-of-two sides (4 x 4, 2 x 8, 1 x 16, ... for k = 4) holds exactly one point. Owen
// scrambling keeps that and makes each point uniform on the square, so an estimate is
// unbiased and a pixel's samples cover it evenly: at 4 and 16 samples a pixel the error of
// edges and textures falls far below that of independent points. Each pixel scrambles with its
// own seed, so neighbouring pixels do not repeat one pattern. Counts that are not powers of
// two keep most of the benefit (the first points of a net are well spread too).
#include <cstdint>

#include "core/math/vec.h"
#include "core/sampling/rng.h"

namespace pbgi {

namespace low_discrepancy_internal {

inline constexpr uint32_t reverseBits(uint32_t x) {
  x = ((x & 0x55555555u) << 1u) | ((x >> 1u) & 0x55555555u);
  x = ((x & 0x33333333u) << 2u) | ((x >> 2u) & 0x33333333u);
  x = ((x & 0x0f0f0f0fu) << 4u) | ((x >> 4u) & 0x0f0f0f0fu);
  x = ((x & 0x00ff00ffu) << 8u) | ((x >> 8u) & 0x00ff00ffu);
  return (x << 16u) | (x >> 16u);
}

// Laine and Karras's permutation (Burley's constants): each bit is flipped by a hash of the
// bits below it, which on bit-reversed values is Owen's nested uniform scramble.
inline constexpr uint32_t laineKarras(uint32_t x, uint32_t seed) {
  x += seed;
  x ^= x * 0x6c50b47cu;
  x ^= x * 0xb82f1e52u;
  x ^= x * 0xc7afe638u;
  x ^= x * 0x8d22f6e6u;
  return x;
}

// Owen scrambling of a 32-bit fixed-point coordinate in [0, 1).
inline constexpr uint32_t owenScramble(uint32_t x, uint32_t seed) {
  return reverseBits(laineKarras(reverseBits(x), seed));
}

// Sobol's first dimension is the van der Corput sequence; the second has direction numbers
// v_0 = 1/2, v_i = v_{i-1} xor v_{i-1} / 2 (the primitive polynomial x + 1).
inline constexpr uint32_t sobol0(uint32_t index) { return reverseBits(index); }

inline constexpr uint32_t sobol1(uint32_t index) {
  uint32_t x = 0, v = 0x80000000u;
  for (; index != 0; index >>= 1u) {
    if ((index & 1u) != 0u) x ^= v;
    v ^= v >> 1u;
  }
  return x;
}

inline constexpr float toUnit(uint32_t x) { return static_cast<float>(x >> 8u) * 0x1p-24f; }

}  // namespace low_discrepancy_internal

// Point `index` of the Owen-scrambled 2-D Sobol sequence of `seed`, in [0, 1)^2. The points
// 0 .. 2^k - 1 of one seed are a (0, k, 2)-net; different seeds are independent scrambles.
inline Vec2f owenSobol2D(uint32_t index, uint64_t seed) {
  namespace ld = low_discrepancy_internal;
  const auto seedX = static_cast<uint32_t>(mix64(seed ^ 0x9e3779b97f4a7c15ull));
  const auto seedY = static_cast<uint32_t>(mix64(seed ^ 0xc2b2ae3d27d4eb4full));
  return {ld::toUnit(ld::owenScramble(ld::sobol0(index), seedX)),
          ld::toUnit(ld::owenScramble(ld::sobol1(index), seedY))};
}

// The same index shuffled (an Owen scramble of the index's bits): a second 2-D pattern built
// from owenSobol2D(shuffledIndex(i, s), t) pairs its points with the first's at random, so
// that four dimensions are each stratified in pairs without correlating the pairs. The
// indices 0 .. 2^k - 1 map onto an aligned block of 2^k indices, itself a (0, k, 2)-net.
inline uint32_t shuffledIndex(uint32_t index, uint64_t seed) {
  namespace ld = low_discrepancy_internal;
  return ld::owenScramble(index, static_cast<uint32_t>(mix64(seed ^ 0x165667b19e3779f9ull)));
}

}  // namespace pbgi
