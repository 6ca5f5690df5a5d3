#pragma once
// Little-endian fixed-width fields, the only way pbgi puts numbers into bytes: spill files,
// page payloads and containers are written and read field by field, never as struct images,
// so files are the same on every machine and padding never reaches the disk. Floats travel
// as their bit patterns (NaN payloads and -0 survive).
#include <bit>
#include <cstddef>
#include <cstdint>
#include <vector>

namespace pbgi {

inline uint16_t loadU16(const uint8_t* p) { return static_cast<uint16_t>(p[0] | p[1] << 8); }
inline uint32_t loadU32(const uint8_t* p) {
  return uint32_t{p[0]} | uint32_t{p[1]} << 8 | uint32_t{p[2]} << 16 | uint32_t{p[3]} << 24;
}
inline uint64_t loadU64(const uint8_t* p) {
  return uint64_t{loadU32(p)} | uint64_t{loadU32(p + 4)} << 32;
}
inline float loadF32(const uint8_t* p) { return std::bit_cast<float>(loadU32(p)); }

inline void storeU16(uint8_t* p, uint16_t v) {
  p[0] = static_cast<uint8_t>(v);
  p[1] = static_cast<uint8_t>(v >> 8);
}
inline void storeU32(uint8_t* p, uint32_t v) {
  for (int i = 0; i < 4; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
inline void storeU64(uint8_t* p, uint64_t v) {
  for (int i = 0; i < 8; ++i) p[i] = static_cast<uint8_t>(v >> (8 * i));
}
inline void storeF32(uint8_t* p, float v) { storeU32(p, std::bit_cast<uint32_t>(v)); }

// Appends fields to a growing buffer.
class ByteWriter {
 public:
  explicit ByteWriter(std::vector<uint8_t>* out) : out_(out) {}
  void u8(uint8_t v) { out_->push_back(v); }
  void u16(uint16_t v) { storeU16(grow(2), v); }
  void u32(uint32_t v) { storeU32(grow(4), v); }
  void u64(uint64_t v) { storeU64(grow(8), v); }
  void f32(float v) { storeF32(grow(4), v); }

 private:
  uint8_t* grow(size_t n) {
    const size_t at = out_->size();
    out_->resize(at + n);
    return out_->data() + at;
  }
  std::vector<uint8_t>* out_;
};

// Reads fields in order from a buffer whose size the caller has already checked against
// what it will read (a reader of untrusted bytes validates counts first, then reads).
class ByteReader {
 public:
  explicit ByteReader(const uint8_t* p) : p_(p) {}
  uint8_t u8() { return *p_++; }
  uint16_t u16() { return advance(loadU16(p_), 2); }
  uint32_t u32() { return advance(loadU32(p_), 4); }
  uint64_t u64() { return advance(loadU64(p_), 8); }
  float f32() { return advance(loadF32(p_), 4); }
  const uint8_t* position() const { return p_; }

 private:
  template <typename T>
  T advance(T v, size_t n) {
    p_ += n;
    return v;
  }
  const uint8_t* p_;
};

}  // namespace pbgi
