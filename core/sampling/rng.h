#pragma once
// Deterministic random numbers. Every stream is keyed by the coordinates of the work it
// serves, (seed, frame, pixel, sample) or (seed, frame, surfel), never by thread or time:
// this is what makes a tile bit-identical whatever the tiling, threads, worker or retry.

#include <bit>
#include <cstdint>

#include "core/math/vec.h"

namespace pbgi {

// A strong 64-bit mix (splitmix64's finaliser).
inline constexpr uint64_t mix64(uint64_t x) {
  x ^= x >> 30;
  x *= 0xbf58476d1ce4e5b9ull;
  x ^= x >> 27;
  x *= 0x94d049bb133111ebull;
  x ^= x >> 31;
  return x;
}

// Hashes any number of integer keys into one 64-bit value.
template <typename... Keys>
inline constexpr uint64_t hashKeys(Keys... keys) {
  uint64_t h = 0x9e3779b97f4a7c15ull;
  ((h = mix64(h ^ (static_cast<uint64_t>(keys) + 0x632be59bd9b4e019ull))), ...);
  return h;
}

// A point's bits hashed (and a direction's with it): random numbers keyed by where they are
// used, the same for the same point whichever tile, block or thread asks.
inline uint64_t hashPoint(const Vec3f& p) {
  return hashKeys(std::bit_cast<uint32_t>(p.x), std::bit_cast<uint32_t>(p.y),
                  std::bit_cast<uint32_t>(p.z));
}
inline uint64_t hashPoint(const Vec3f& p, const Vec3f& n) {
  return hashKeys(std::bit_cast<uint32_t>(p.x), std::bit_cast<uint32_t>(p.y),
                  std::bit_cast<uint32_t>(p.z), std::bit_cast<uint32_t>(n.x),
                  std::bit_cast<uint32_t>(n.y), std::bit_cast<uint32_t>(n.z));
}

// PCG32 (O'Neill 2014): small state, good statistics, and a stream selector.
class Rng {
 public:
  Rng() = default;
  explicit Rng(uint64_t key) { seed(key); }
  template <typename... Keys>
  static Rng forKeys(Keys... keys) {
    return Rng(hashKeys(keys...));
  }

  void seed(uint64_t key) {
    inc_ = (mix64(key ^ 0xda3e39cb94b95bdbull) << 1u) | 1u;
    state_ = 0;
    nextU32();
    state_ += mix64(key);
    nextU32();
  }

  uint32_t nextU32() {
    const uint64_t old = state_;
    state_ = old * 6364136223846793005ull + inc_;
    const uint32_t xorshifted = static_cast<uint32_t>(((old >> 18u) ^ old) >> 27u);
    const uint32_t rot = static_cast<uint32_t>(old >> 59u);
    return (xorshifted >> rot) | (xorshifted << ((~rot + 1u) & 31));
  }

  // Uniform in [0, 1): 24 random bits, so the result is exactly representable and < 1.
  float uniform() { return static_cast<float>(nextU32() >> 8) * 0x1p-24f; }

 private:
  uint64_t state_ = 0x853c49e6748fea9bull;
  uint64_t inc_ = 0xda3e39cb94b95bdbull;
};

}  // namespace pbgi
