#include "core/pbgi/tree_page.h"

#include "core/pbgi/tree_page_codec.h"

#include <algorithm>
#include <bit>
#include <cmath>

#include <Imath/half.h>
#include <fmt/format.h>

#include "core/util/bytes.h"
#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi {

using namespace page_codec;

float surfelRadianceScale(float area, const Rgb& powerDc, const Rgb& backPower) {
  const float power = std::max(maxComponent(powerDc), maxComponent(backPower));
  const float mean = power / area;
  if (!(area > 0.0f) || !(power > 0.0f) || !std::isfinite(mean) || !(mean > 0.0f)) return 1.0f;
  // A power of two, so that dividing by it and multiplying back are exact.
  return std::ldexp(1.0f, std::clamp(std::ilogb(mean), -100, 100));
}

void writeFloatAttributes(ByteWriter& w, const NodeAttributes& a) {
  writeVec3(w, a.bounds.min);
  writeVec3(w, a.bounds.max);
  writeVec3(w, a.centroid);
  writeVec3(w, a.cone.axis);
  w.f32(a.cone.cosAngle);
  w.f32(a.area);
  for (float c : a.areaSh.c) w.f32(c);
  float power[Sh9Rgb::kFloats];
  a.powerSh.toFloats(power);
  for (float c : power) w.f32(c);
  writeVec3(w, a.backPower);
}

void readFloatAttributes(ByteReader& r, NodeAttributes* a) {
  a->bounds.min = readVec3(r);
  a->bounds.max = readVec3(r);
  a->centroid = readVec3(r);
  a->cone.axis = readVec3(r);
  a->cone.cosAngle = r.f32();
  a->area = r.f32();
  for (float& c : a->areaSh.c) c = r.f32();
  float power[Sh9Rgb::kFloats];
  for (float& c : power) c = r.f32();
  a->powerSh = Sh9Rgb::fromFloats(power);
  a->backPower = readVec3(r);
}

void writeFloatSurfel(ByteWriter& w, const Surfel& s) {
  writeVec3(w, s.position);
  writeVec3(w, s.normal);
  w.f32(s.radius);
  writeVec3(w, s.radiance);
  writeVec3(w, s.backRadiance);
  writeVec3(w, s.albedo);
  w.u8(static_cast<uint8_t>(s.materialClass));
}

absl::Status readFloatSurfel(ByteReader& r, Surfel* s) {
  s->position = readVec3(r);
  s->normal = readVec3(r);
  s->radius = r.f32();
  s->radiance = readVec3(r);
  s->backRadiance = readVec3(r);
  s->albedo = readVec3(r);
  const uint8_t material = r.u8();
  if (material > static_cast<uint8_t>(MaterialClass::kEmissive)) {
    return absl::DataLossError(fmt::format("material class {}, expected 0..3", material));
  }
  s->materialClass = static_cast<MaterialClass>(material);
  return absl::OkStatus();
}

ShRotation shapeRotation(const Vec3f& coneAxis) {
  uint16_t u, v;
  octEncode(coneAxis, &u, &v);
  return ShRotation::toLocal(Frame(octDecode(u, v)));
}

// ---- Shapes ------------------------------------------------------------------------------------

float areaShDc(float area) { return static_cast<float>(area * std::numbers::pi * kY00); }

void powerShape(const Sh9Rgb& sh, float out[kPowerShapeDims]) {
  for (int ch = 0; ch < 3; ++ch) {
    const float dc = sh.c[0][ch];
    for (int k = 1; k < kShCoefficients; ++k) {
      const float ratio = dc > 0.0f ? sh.c[k][ch] / dc : 0.0f;
      out[(k - 1) * 3 + ch] = std::clamp(ratio, -kMaxShapeRatio, kMaxShapeRatio);
    }
  }
}

Sh9Rgb powerFromShape(const Rgb& dc, std::span<const float> shape) {
  PBGI_CHECK_EQ(shape.size(), static_cast<size_t>(kPowerShapeDims));
  Sh9Rgb sh;
  sh.c[0] = dc;
  for (int k = 1; k < kShCoefficients; ++k) {
    for (int ch = 0; ch < 3; ++ch) sh.c[k][ch] = dc[ch] * shape[(k - 1) * 3 + ch];
  }
  return sh;
}

void areaShape(const Sh9& sh, float out[kAreaShapeDims]) {
  const float dc = sh.c[0];
  for (int k = 1; k < kShCoefficients; ++k) {
    const float ratio = dc > 0.0f ? sh.c[k] / dc : 0.0f;
    out[k - 1] = std::clamp(ratio, -kMaxShapeRatio, kMaxShapeRatio);
  }
}

Sh9 areaFromShape(float dc, std::span<const float> shape) {
  PBGI_CHECK_EQ(shape.size(), static_cast<size_t>(kAreaShapeDims));
  Sh9 sh;
  sh.c[0] = dc;
  for (int k = 1; k < kShCoefficients; ++k) sh.c[k] = dc * shape[k - 1];
  return sh;
}

// ---- Codebooks ---------------------------------------------------------------------------------

std::vector<uint8_t> encodeCodebook(const Codebook& codebook) {
  std::vector<uint8_t> out;
  ByteWriter w(&out);
  w.u32(static_cast<uint32_t>(codebook.dimension));
  w.u32(static_cast<uint32_t>(codebook.size()));
  for (float v : codebook.entries) w.f32(v);
  return out;
}

absl::StatusOr<Codebook> decodeCodebook(std::span<const uint8_t> bytes, int expectedDimension) {
  if (bytes.size() < 8) {
    return absl::DataLossError(fmt::format("codebook: {} bytes, expected at least 8", bytes.size()));
  }
  ByteReader r(bytes.data());
  const uint32_t dim = r.u32(), count = r.u32();
  if (dim != static_cast<uint32_t>(expectedDimension)) {
    return absl::DataLossError(
        fmt::format("codebook: dimension {}, expected {}", dim, expectedDimension));
  }
  if (count < 1 || count > 65536) {
    return absl::DataLossError(fmt::format("codebook: {} entries, expected 1..65536", count));
  }
  const uint64_t expectedBytes = 8 + uint64_t{count} * dim * 4;
  if (bytes.size() != expectedBytes) {
    return absl::DataLossError(fmt::format("codebook: {} bytes for {} entries of {}, expected {}",
                                           bytes.size(), count, dim, expectedBytes));
  }
  Codebook book;
  book.dimension = static_cast<int>(dim);
  book.entries.resize(static_cast<size_t>(count) * dim);
  for (float& v : book.entries) {
    v = r.f32();
    if (!std::isfinite(v)) return absl::DataLossError("codebook: an entry is not finite");
  }
  for (uint32_t i = 0; i < dim; ++i) {
    if (book.entries[i] != 0.0f) return absl::DataLossError("codebook: entry 0 is not black");
  }
  return book;
}

// ---- Pages -------------------------------------------------------------------------------------

size_t TreePage::memoryBytes() const {
  size_t bytes = sizeof(TreePage) + nodes.capacity() * sizeof(TreeNode) +
                 children.capacity() * sizeof(NodeRef) + surfels.capacity() * sizeof(Surfel) +
                 ghostOf.capacity() * sizeof(uint32_t) +
                 wavelets.capacity() * sizeof(WaveletRadiance);
  for (const WaveletRadiance& w : wavelets) {
    for (const WaveletFace& f : w.faces()) bytes += f.nodes.capacity() * sizeof(WaveletFace::Node);
  }
  return bytes;
}

size_t waveletEntryBytes(const WaveletRadiance& w) {
  return 4 + 1 + 1 + 4 + 6 * (16 + 2) + w.keptNodes() * (3 + 18);
}

WaveletPageStats& WaveletPageStats::operator+=(const WaveletPageStats& o) {
  entries += o.entries;
  differences += o.differences;
  keptNodes += o.keptNodes;
  bytes += o.bytes;
  maxRelativeError = std::max(maxRelativeError, o.maxRelativeError);
  return *this;
}
size_t treePageBytes(TreeEncoding encoding, size_t nodes, size_t refs, size_t surfels,
                     size_t exact) {
  return kTreePageHeaderBytes + nodes * nodeRecordBytes(encoding) + refs * kChildRefBytes +
         surfels * surfelRecordBytes(encoding) + exact * kExactShBytes;
}

}  // namespace pbgi
