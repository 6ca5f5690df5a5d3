#include "core/pbgi/tree_page.h"

#include <algorithm>
#include <bit>
#include <cmath>

#include <Imath/half.h>
#include <fmt/format.h>

#include "core/util/bytes.h"
#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

constexpr float kU16Max = 65535.0f;

// ---- Octahedral normals (Meyer et al. 2010) ----------------------------------------------

float signNotZero(float v) { return v < 0.0f ? -1.0f : 1.0f; }

uint16_t toUnorm16(float v) {  // v in [-1, 1]
  return static_cast<uint16_t>(std::lround((std::clamp(v, -1.0f, 1.0f) * 0.5f + 0.5f) * kU16Max));
}
float fromUnorm16(uint16_t q) { return q / kU16Max * 2.0f - 1.0f; }

void octEncode(const Vec3f& n, uint16_t* u, uint16_t* v) {
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

Vec3f octDecode(uint16_t u, uint16_t v) {
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
float dequantizeIn(uint16_t q, float lo, float hi) {
  if (!(hi > lo) || q == 0) return lo;
  if (q == 65535) return hi;
  return lo + (hi - lo) * (q / kU16Max);
}

uint16_t quantizeNearest(float v, float lo, float hi) {
  if (!(hi > lo)) return 0;
  return static_cast<uint16_t>(std::lround(std::clamp((v - lo) / (hi - lo), 0.0f, 1.0f) * kU16Max));
}

// The largest code whose value is at most v (a min bound), and the smallest whose value is
// at least v (a max bound): dequantized boxes contain the float ones despite rounding.
uint16_t quantizeDown(float v, float lo, float hi) {
  if (!(hi > lo)) return 0;
  int q = static_cast<int>(std::floor(std::clamp((v - lo) / (hi - lo), 0.0f, 1.0f) * kU16Max));
  while (q > 0 && dequantizeIn(static_cast<uint16_t>(q), lo, hi) > v) --q;
  return static_cast<uint16_t>(q);
}
uint16_t quantizeUp(float v, float lo, float hi) {
  if (!(hi > lo)) return 0;
  int q = static_cast<int>(std::ceil(std::clamp((v - lo) / (hi - lo), 0.0f, 1.0f) * kU16Max));
  while (q < 65535 && dequantizeIn(static_cast<uint16_t>(q), lo, hi) < v) ++q;
  return static_cast<uint16_t>(q);
}

// Cone cosines quantize downwards: a wider cone is still a bound.
uint16_t quantizeCosDown(float c) {
  int q = static_cast<int>(std::floor((std::clamp(c, -1.0f, 1.0f) * 0.5f + 0.5f) * kU16Max));
  while (q > 0 && fromUnorm16(static_cast<uint16_t>(q)) > c) --q;
  return static_cast<uint16_t>(q);
}

float halfBits(uint16_t bits) {
  half h;
  h.setBits(bits);
  return h;
}

// Set in a page's encoding byte (quantized pages written since): surfel radii are stored
// over their leaf's largest side, so that a half float keeps them in any unit (absolute, a
// radius below 6e-5 lost its precision and one above 65504 was clamped). Pages without it
// read as before.
constexpr uint8_t kRelativeRadiiFlag = 0x80;
// Set beside it (quantized pages written since): surfel radiance is stored over its leaf's
// surfelRadianceScale, so that a half float keeps it in any unit of light (absolute, radiance
// above 65504 was clamped: a room lit by a light of 1e10 lost 6 % of its bounced light, and a
// scene in photometric units is near that already). Pages without it read as before.
constexpr uint8_t kRelativeRadianceFlag = 0x40;
constexpr uint8_t kEncodingFlags = kRelativeRadiiFlag | kRelativeRadianceFlag;

// What a quantized surfel's radius is stored relative to: its leaf's decoded bounds' largest
// side (1 for a leaf of one point, whose bounds have no size).
float radiusScale(const Bounds3f& leaf) {
  const float side = maxAbsComponent(leaf.max - leaf.min);
  return side > 0.0f && std::isfinite(side) ? side : 1.0f;
}

}  // namespace

float surfelRadianceScale(float area, const Rgb& powerDc, const Rgb& backPower) {
  const float power = std::max(maxComponent(powerDc), maxComponent(backPower));
  const float mean = power / area;
  if (!(area > 0.0f) || !(power > 0.0f) || !std::isfinite(mean) || !(mean > 0.0f)) return 1.0f;
  // A power of two, so that dividing by it and multiplying back are exact.
  return std::ldexp(1.0f, std::clamp(std::ilogb(mean), -100, 100));
}

namespace {

half toHalf(float v) {
  // Finite, within half's range: radiance beyond 65504 is clamped by the caller, who counts it.
  return half(std::clamp(v, -static_cast<float>(HALF_MAX), static_cast<float>(HALF_MAX)));
}

// The bytes of a page: header, then three arrays of fixed-size records.
struct PageCounts {
  uint32_t nodes = 0, refs = 0, surfels = 0, exact = 0;
};

uint32_t exactMarker(TreeEncoding e) { return e == TreeEncoding::kQuantized8 ? 0xffu : 0xffffu; }

void encodeBounds(ByteWriter& w, const Bounds3f& b, const Bounds3f& ref, Bounds3f* decoded) {
  const uint16_t q[6] = {quantizeDown(b.min.x, ref.min.x, ref.max.x),
                         quantizeDown(b.min.y, ref.min.y, ref.max.y),
                         quantizeDown(b.min.z, ref.min.z, ref.max.z),
                         quantizeUp(b.max.x, ref.min.x, ref.max.x),
                         quantizeUp(b.max.y, ref.min.y, ref.max.y),
                         quantizeUp(b.max.z, ref.min.z, ref.max.z)};
  for (uint16_t v : q) w.u16(v);
  decoded->min = Vec3f(dequantizeIn(q[0], ref.min.x, ref.max.x),
                       dequantizeIn(q[1], ref.min.y, ref.max.y),
                       dequantizeIn(q[2], ref.min.z, ref.max.z));
  decoded->max = Vec3f(dequantizeIn(q[3], ref.min.x, ref.max.x),
                       dequantizeIn(q[4], ref.min.y, ref.max.y),
                       dequantizeIn(q[5], ref.min.z, ref.max.z));
}

Bounds3f decodeBounds(ByteReader& r, const Bounds3f& ref) {
  uint16_t q[6];
  for (uint16_t& v : q) v = r.u16();
  Bounds3f b;
  b.min = Vec3f(dequantizeIn(q[0], ref.min.x, ref.max.x), dequantizeIn(q[1], ref.min.y, ref.max.y),
                dequantizeIn(q[2], ref.min.z, ref.max.z));
  b.max = Vec3f(dequantizeIn(q[3], ref.min.x, ref.max.x), dequantizeIn(q[4], ref.min.y, ref.max.y),
                dequantizeIn(q[5], ref.min.z, ref.max.z));
  return b;
}

void writeVec3(ByteWriter& w, const Vec3f& v) {
  w.f32(v.x);
  w.f32(v.y);
  w.f32(v.z);
}
Vec3f readVec3(ByteReader& r) {
  const float x = r.f32(), y = r.f32();
  return {x, y, r.f32()};
}

}  // namespace

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

namespace {

// A face's details are stored as half floats over the face's largest magnitude.
float detailScale(const WaveletFace& f) {
  float scale = 0.0f;
  for (const WaveletFace::Node& node : f.nodes) {
    for (const Rgb& d : node.detail) scale = std::max(scale, maxComponent(vmax(d, -d)));
  }
  return scale;
}

// The vector as a reader decodes it: details through half floats.
WaveletRadiance asStored(const WaveletRadiance& w) {
  std::array<WaveletFace, 6> faces = w.faces();
  for (WaveletFace& f : faces) {
    const float scale = detailScale(f);
    const float inv = scale > 0.0f ? 1.0f / scale : 0.0f;
    for (WaveletFace::Node& node : f.nodes) {
      for (Rgb& d : node.detail) {
        for (int c = 0; c < 3; ++c) d[c] = halfBits(toHalf(d[c] * inv).bits()) * scale;
      }
    }
  }
  absl::StatusOr<WaveletRadiance> stored = WaveletRadiance::fromFaces(w.resolution(), faces);
  PBGI_CHECK(stored.ok());
  return *std::move(stored);
}

double norm2Of(std::span<const float> v) {
  double sum = 0.0;
  for (const float x : v) sum += double{x} * x;
  return sum;
}

struct WaveletEntry {
  uint32_t node;
  uint8_t coding;  // 0 whole, 1 difference from factor x the in-page parent's
  float factor;
  WaveletRadiance stored;
};

void writeWaveletSection(ByteWriter& w, std::span<const WaveletEntry> entries) {
  if (entries.empty()) return;
  w.u32(kWaveletMagic);
  w.u16(kWaveletSectionVersion);
  w.u32(static_cast<uint32_t>(entries.size()));
  for (const WaveletEntry& entry : entries) {
    const WaveletRadiance& wr = entry.stored;
    w.u32(entry.node);
    w.u8(static_cast<uint8_t>(std::countr_zero(static_cast<unsigned>(wr.resolution()))));
    w.u8(entry.coding);
    w.f32(entry.factor);
    for (const WaveletFace& f : wr.faces()) {
      writeVec3(w, f.scaling);
      const float scale = detailScale(f);
      w.f32(scale);
      PBGI_CHECK_LE(f.nodes.size(), size_t{UINT16_MAX});
      w.u16(static_cast<uint16_t>(f.nodes.size()));
      const float inv = scale > 0.0f ? 1.0f / scale : 0.0f;
      for (const WaveletFace::Node& node : f.nodes) {
        w.u8(static_cast<uint8_t>(node.level));
        w.u8(static_cast<uint8_t>(node.x));
        w.u8(static_cast<uint8_t>(node.y));
        for (const Rgb& d : node.detail) {
          for (int c = 0; c < 3; ++c) w.u16(toHalf(d[c] * inv).bits());
        }
      }
    }
  }
}

// The page's wavelet entries, hierarchically coded (see the header): nodes in page order,
// then the ghosts (whole, face averages). `parentOf[i]` is node i's in-page parent or -1.
std::vector<WaveletEntry> codeWavelets(std::span<const PageNode> nodes,
                                       std::span<const int64_t> parentOf,
                                       std::span<const std::shared_ptr<const WaveletRadiance>> ghosts,
                                       float relativeError, WaveletPageStats* stats) {
  std::vector<WaveletEntry> entries;
  std::vector<std::vector<float>> decoded(nodes.size());
  WaveletPageStats local;
  auto measure = [&](const std::vector<float>& given, const std::vector<float>& got) {
    double d2 = 0.0;
    for (size_t k = 0; k < given.size(); ++k) d2 += double(given[k] - got[k]) * (given[k] - got[k]);
    const double n2 = norm2Of(given);
    if (n2 > 0.0) local.maxRelativeError = std::max(local.maxRelativeError, std::sqrt(d2 / n2));
  };
  for (size_t i = 0; i < nodes.size(); ++i) {
    const std::shared_ptr<const WaveletRadiance>& given = nodes[i].wavelet;
    if (!given || given->empty()) continue;
    const int n = given->resolution();
    const std::vector<float> full = given->dense();
    const double fullNorm = std::sqrt(norm2Of(full));
    WaveletEntry entry{static_cast<uint32_t>(i), 0, 0.0f,
                       asStored(nodes[i].waveletWhole
                                    ? *nodes[i].waveletWhole
                                    : WaveletRadiance::fromDense(full, n, 0.0f, relativeError))};
    std::vector<float> got = entry.stored.dense();
    const int64_t p = parentOf[i];
    if (p >= 0 && static_cast<size_t>(p) < i && !decoded[p].empty() &&
        decoded[p].size() == full.size()) {
      const std::vector<float>& parent = decoded[p];
      const double pp = norm2Of(parent);
      double fp = 0.0;
      for (size_t k = 0; k < full.size(); ++k) fp += double{full[k]} * parent[k];
      const float factor = pp > 0.0 ? static_cast<float>(fp / pp) : 0.0f;
      std::vector<float> residual(full.size());
      for (size_t k = 0; k < full.size(); ++k) residual[k] = full[k] - factor * parent[k];
      const double residualNorm = std::sqrt(norm2Of(residual));
      // The difference's budget is the node's, not the difference's own norm.
      const float budget =
          residualNorm > 0.0
              ? static_cast<float>(std::min(0.999, relativeError * fullNorm / residualNorm))
              : 0.0f;
      WaveletRadiance difference = asStored(WaveletRadiance::fromDense(residual, n, 0.0f, budget));
      if (difference.keptNodes() < entry.stored.keptNodes()) {
        std::vector<float> sum = difference.dense();
        for (size_t k = 0; k < sum.size(); ++k) sum[k] += factor * parent[k];
        entry = WaveletEntry{static_cast<uint32_t>(i), 1, factor, std::move(difference)};
        got = std::move(sum);
        ++local.differences;
      }
    }
    measure(full, got);
    decoded[i] = std::move(got);
    entries.push_back(std::move(entry));
  }
  for (size_t g = 0; g < ghosts.size(); ++g) {
    if (!ghosts[g] || ghosts[g]->empty()) continue;
    entries.push_back(WaveletEntry{static_cast<uint32_t>(nodes.size() + g), 0, 0.0f,
                                   asStored(*ghosts[g])});
  }
  for (const WaveletEntry& e : entries) {
    ++local.entries;
    local.keptNodes += e.stored.keptNodes();
    local.bytes += waveletEntryBytes(e.stored);
  }
  if (!entries.empty()) local.bytes += kWaveletSectionHeaderBytes;
  if (stats != nullptr) *stats += local;
  return entries;
}


// Reads the section that follows a page's base payload into `page` (nodes already decoded).
absl::Status readWaveletSection(std::span<const uint8_t> bytes, TreePage* page) {
  // Each node's in-page parent (decodeTreePage has checked there is at most one).
  std::vector<int64_t> parentOf(page->nodes.size(), -1);
  for (size_t i = 0; i < page->nodes.size(); ++i) {
    for (const NodeRef& c : page->childrenOf(page->nodes[i])) {
      if (c.page == page->id && c.index < parentOf.size()) parentOf[c.index] = static_cast<int64_t>(i);
    }
  }
  auto fail = [&](const std::string& what) {
    return absl::DataLossError(fmt::format("page {}: wavelet section: {}", page->id, what));
  };
  ByteReader r(bytes.data());
  size_t left = bytes.size();
  auto take = [&](size_t n) {
    if (n > left) return false;
    left -= n;
    return true;
  };
  if (!take(kWaveletSectionHeaderBytes)) {
    return fail(fmt::format("{} bytes after the page's records, shorter than the {}-byte header",
                            bytes.size(), kWaveletSectionHeaderBytes));
  }
  const uint32_t magic = r.u32();
  if (magic != kWaveletMagic) {
    return fail(fmt::format("{} bytes after the page's records, not a wavelet section (magic "
                            "{:#010x}, expected {:#010x})",
                            bytes.size(), magic, kWaveletMagic));
  }
  const uint16_t version = r.u16();
  if (version != kWaveletSectionVersion) {
    return fail(fmt::format("version {}, this build reads version {}", version,
                            kWaveletSectionVersion));
  }
  const uint32_t entries = r.u32();
  if (entries == 0 || entries > page->nodes.size()) {
    return fail(fmt::format("{} entries for {} nodes", entries, page->nodes.size()));
  }
  page->wavelets.reserve(entries);
  int64_t lastNode = -1;
  for (uint32_t e = 0; e < entries; ++e) {
    if (!take(10)) return fail(fmt::format("entry {} cut short", e));
    const uint32_t node = r.u32();
    const uint8_t log2n = r.u8();
    const uint8_t coding = r.u8();
    const float factor = r.f32();
    if (node >= page->nodes.size() || static_cast<int64_t>(node) <= lastNode) {
      return fail(fmt::format("entry {} names node {} (the page has {}; entries in node order, "
                              "one a node)",
                              e, node, page->nodes.size()));
    }
    lastNode = node;
    if ((1 << std::min<int>(log2n, 30)) > kMaxMicrobufferResolution) {
      return fail(fmt::format("entry {}: resolution 2^{}, at most {}", e, log2n,
                              kMaxMicrobufferResolution));
    }
    std::array<WaveletFace, 6> faces;
    for (int f = 0; f < 6; ++f) {
      if (!take(18)) return fail(fmt::format("entry {} face {} cut short", e, f));
      faces[f].scaling = readVec3(r);
      const float scale = r.f32();
      const uint16_t count = r.u16();
      if (!std::isfinite(scale) || scale < 0.0f) {
        return fail(fmt::format("entry {} face {}: detail scale {}", e, f, scale));
      }
      if (!take(size_t{count} * 21)) {
        return fail(fmt::format("entry {} face {}: {} nodes, more than the bytes left", e, f,
                                count));
      }
      faces[f].nodes.resize(count);
      for (WaveletFace::Node& q : faces[f].nodes) {
        q.level = r.u8();
        q.x = r.u8();
        q.y = r.u8();
        for (Rgb& d : q.detail) {
          for (int c = 0; c < 3; ++c) d[c] = halfBits(r.u16()) * scale;
        }
      }
      page->waveletStoredNodes += count;
    }
    auto w = WaveletRadiance::fromFaces(1 << log2n, std::move(faces));
    if (!w.ok()) return fail(fmt::format("entry {} (node {}): {}", e, node, w.status().message()));
    if (coding > 1 || !std::isfinite(factor)) {
      return fail(fmt::format("entry {} (node {}): coding {} factor {}, expected coding 0 (whole) "
                              "or 1 (difference) and a finite factor",
                              e, node, coding, factor));
    }
    if (coding == 1) {
      const int64_t p = parentOf[node];
      const WaveletRadiance* parent = p >= 0 ? page->waveletOf(page->nodes[p]) : nullptr;
      if (parent == nullptr || p >= static_cast<int64_t>(node) ||
          parent->resolution() != w->resolution()) {
        return fail(fmt::format("entry {} (node {}) is a difference from its parent's vector, "
                                "but the node has no in-page parent with a vector of its "
                                "resolution before it",
                                e, node));
      }
      std::vector<float> sum = w->dense();
      const std::vector<float> base = parent->dense();
      for (size_t k = 0; k < sum.size(); ++k) sum[k] += factor * base[k];
      bool finite = true;
      for (const float v : sum) finite = finite && std::isfinite(v);
      if (!finite) return fail(fmt::format("entry {} (node {}): not finite decoded", e, node));
      *w = WaveletRadiance::fromDense(sum, w->resolution(), 0.0f);
    }
    page->nodes[node].wavelet = static_cast<uint32_t>(page->wavelets.size());
    page->wavelets.push_back(std::move(*w));
  }
  if (left != 0) return fail(fmt::format("{} bytes left over after {} entries", left, entries));
  page->waveletSectionBytes = static_cast<uint32_t>(bytes.size());
  return absl::OkStatus();
}

}  // namespace

size_t treePageBytes(TreeEncoding encoding, size_t nodes, size_t refs, size_t surfels,
                     size_t exact) {
  return kTreePageHeaderBytes + nodes * nodeRecordBytes(encoding) + refs * kChildRefBytes +
         surfels * surfelRecordBytes(encoding) + exact * kExactShBytes;
}

std::vector<uint8_t> encodeTreePage(uint32_t id, TreeEncoding encoding,
                                    std::span<const PageNode> nodes,
                                    const TreeCodebooks* codebooks, float waveletError,
                                    WaveletPageStats* waveletStats) {
  PBGI_CHECK(!quantized(encoding) || codebooks != nullptr);
  // The ghosts written: those of children whose reference leads out of the page, after the
  // other nodes, each with the index of the reference it copies.
  struct Ghost {
    const GhostNode* node;
    uint32_t ref;
  };
  std::vector<Ghost> ghosts;
  PageCounts counts;
  Bounds3f pageBounds;
  for (const PageNode& n : nodes) {
    for (const GhostNode& g : n.ghosts) {
      PBGI_CHECK_LT(g.child, n.children.size());
      if (n.children[g.child].page == id) continue;
      ghosts.push_back({&g, counts.refs + g.child});
      counts.exact += quantized(encoding) && g.exact ? 1 : 0;
      pageBounds.extend(g.attributes.bounds.min);
      pageBounds.extend(g.attributes.bounds.max);
    }
    counts.refs += static_cast<uint32_t>(n.children.size());
    counts.surfels += static_cast<uint32_t>(n.surfels.size());
    counts.exact += quantized(encoding) && n.exact ? 1 : 0;
    pageBounds.extend(n.attributes.bounds.min);
    pageBounds.extend(n.attributes.bounds.max);
  }
  counts.nodes = static_cast<uint32_t>(nodes.size() + ghosts.size());
  std::vector<uint8_t> out;
  out.reserve(treePageBytes(encoding, counts.nodes, counts.refs, counts.surfels, counts.exact));
  ByteWriter w(&out);
  w.u32(counts.nodes);
  w.u32(counts.refs);
  w.u32(counts.surfels);
  w.u32(counts.exact);
  w.u8(static_cast<uint8_t>(encoding) | (quantized(encoding) ? kEncodingFlags : 0));
  writeVec3(w, pageBounds.min);
  writeVec3(w, pageBounds.max);

  // One node record; returns the bounds its decoder will see.
  auto writeRecord = [&](const NodeAttributes& a, size_t childCount, size_t surfelCount,
                         uint32_t first, bool exact, uint32_t powerIndex, uint32_t areaIndex,
                         const Bounds3f& reference) {
    w.u8(static_cast<uint8_t>(childCount));
    w.u8(static_cast<uint8_t>(surfelCount));
    w.u32(first);
    PBGI_CHECK_LE(a.pointCount, uint64_t{UINT32_MAX});
    w.u32(static_cast<uint32_t>(a.pointCount));
    if (!quantized(encoding)) {
      writeFloatAttributes(w, a);
      return a.bounds;
    }
    Bounds3f decoded;
    encodeBounds(w, a.bounds, reference, &decoded);
    w.u16(quantizeNearest(a.centroid.x, decoded.min.x, decoded.max.x));
    w.u16(quantizeNearest(a.centroid.y, decoded.min.y, decoded.max.y));
    w.u16(quantizeNearest(a.centroid.z, decoded.min.z, decoded.max.z));
    uint16_t u, v;
    octEncode(a.cone.axis, &u, &v);
    w.u16(u);
    w.u16(v);
    // The decoded axis is off by a little; the stored angle grows by as much.
    const Vec3f axis = octDecode(u, v);
    const float half = a.cone.cosAngle <= -1.0f
                           ? kPi
                           : safeAcos(a.cone.cosAngle) + safeAcos(dot(axis, a.cone.axis));
    w.u16(half >= kPi ? 0 : quantizeCosDown(std::cos(half)));
    w.f32(a.area);
    writeVec3(w, a.powerSh.c[0]);
    writeVec3(w, a.backPower);
    if (!exact) {
      PBGI_CHECK_LT(powerIndex, static_cast<uint32_t>(codebooks->power.size()));
      PBGI_CHECK_LT(areaIndex, static_cast<uint32_t>(codebooks->area.size()));
    }
    const uint32_t power = exact ? exactMarker(encoding) : powerIndex;
    const uint32_t area = exact ? 0 : areaIndex;
    if (encoding == TreeEncoding::kQuantized8) {
      w.u8(static_cast<uint8_t>(power));
      w.u8(static_cast<uint8_t>(area));
    } else {
      w.u16(static_cast<uint16_t>(power));
      w.u16(static_cast<uint16_t>(area));
    }
    return decoded;
  };

  // Each node's bounds are relative to those its decoder will know: its in-page parent's
  // dequantized bounds, else the page's.
  std::vector<Bounds3f> reference(nodes.size(), pageBounds);
  std::vector<Bounds3f> leafBounds(nodes.size());
  uint32_t firstRef = 0, firstSurfel = 0;
  for (size_t i = 0; i < nodes.size(); ++i) {
    const PageNode& n = nodes[i];
    PBGI_CHECK_LE(n.children.size(), 8u);
    PBGI_CHECK_LE(n.surfels.size(), 255u);
    PBGI_CHECK(n.children.empty() != n.surfels.empty());
    const Bounds3f decoded =
        writeRecord(n.attributes, n.children.size(), n.surfels.size(),
                    n.children.empty() ? firstSurfel : firstRef, n.exact, n.powerIndex,
                    n.areaIndex, reference[i]);
    leafBounds[i] = decoded;
    firstRef += static_cast<uint32_t>(n.children.size());
    firstSurfel += static_cast<uint32_t>(n.surfels.size());
    for (const NodeRef& c : n.children) {
      PBGI_CHECK(c.page != id || c.index != i);
      if (c.page == id && c.index > i) reference[c.index] = decoded;
    }
  }
  for (const Ghost& g : ghosts) {
    writeRecord(g.node->attributes, 0, 0, g.ref, g.node->exact, g.node->powerIndex,
                g.node->areaIndex, pageBounds);
  }
  for (const PageNode& n : nodes) {
    for (const NodeRef& c : n.children) {
      w.u32(c.page);
      w.u32(c.index);
    }
  }
  for (size_t i = 0; i < nodes.size(); ++i) {
    const Bounds3f& lb = leafBounds[i];
    const NodeAttributes& leaf = nodes[i].attributes;
    const float over = 1.0f / surfelRadianceScale(leaf.area, leaf.powerSh.c[0], leaf.backPower);
    for (const Surfel& s : nodes[i].surfels) {
      if (!quantized(encoding)) {
        writeFloatSurfel(w, s);
        continue;
      }
      w.u16(quantizeNearest(s.position.x, lb.min.x, lb.max.x));
      w.u16(quantizeNearest(s.position.y, lb.min.y, lb.max.y));
      w.u16(quantizeNearest(s.position.z, lb.min.z, lb.max.z));
      uint16_t u, v;
      octEncode(s.normal, &u, &v);
      w.u16(u);
      w.u16(v);
      w.u16(toHalf(s.radius / radiusScale(lb)).bits());
      for (int ch = 0; ch < 3; ++ch) w.u16(toHalf(s.radiance[ch] * over).bits());
      for (int ch = 0; ch < 3; ++ch) w.u16(toHalf(s.backRadiance[ch] * over).bits());
      for (int ch = 0; ch < 3; ++ch) {
        w.u8(static_cast<uint8_t>(std::lround(std::clamp(s.albedo[ch], 0.0f, 1.0f) * 255.0f)));
      }
      w.u8(static_cast<uint8_t>(s.materialClass));
    }
  }
  if (quantized(encoding)) {
    auto writeExact = [&](const NodeAttributes& a) {
      for (float c : a.areaSh.c) w.f32(c);
      float power[Sh9Rgb::kFloats];
      a.powerSh.toFloats(power);
      for (float c : power) w.f32(c);
    };
    for (const PageNode& n : nodes) {
      if (n.exact) writeExact(n.attributes);
    }
    for (const Ghost& g : ghosts) {
      if (g.node->exact) writeExact(g.node->attributes);
    }
  }
  PBGI_CHECK_EQ(out.size(),
                treePageBytes(encoding, counts.nodes, counts.refs, counts.surfels, counts.exact));
  std::vector<int64_t> parentOf(nodes.size(), -1);
  for (size_t i = 0; i < nodes.size(); ++i) {
    for (const NodeRef& c : nodes[i].children) {
      if (c.page == id) parentOf[c.index] = static_cast<int64_t>(i);
    }
  }
  std::vector<std::shared_ptr<const WaveletRadiance>> ghostWavelets;
  for (const Ghost& g : ghosts) ghostWavelets.push_back(g.node->wavelet);
  WaveletPageStats sectionStats;
  const std::vector<WaveletEntry> entries =
      codeWavelets(nodes, parentOf, ghostWavelets, waveletError, &sectionStats);
  size_t entryBytes = 0;
  for (const WaveletEntry& e : entries) entryBytes += waveletEntryBytes(e.stored);
  writeWaveletSection(w, entries);
  if (waveletStats != nullptr) *waveletStats += sectionStats;
  PBGI_CHECK_EQ(out.size(),
                treePageBytes(encoding, counts.nodes, counts.refs, counts.surfels, counts.exact) +
                    (entries.empty() ? 0 : kWaveletSectionHeaderBytes + entryBytes));
  return out;
}

absl::StatusOr<std::shared_ptr<const TreePage>> decodeTreePage(uint32_t id,
                                                               std::span<const uint8_t> bytes,
                                                               const TreeCodebooks* codebooks) {
  auto fail = [id](const std::string& what) {
    return absl::DataLossError(fmt::format("page {}: {}", id, what));
  };
  if (bytes.size() < kTreePageHeaderBytes) {
    return fail(fmt::format("{} bytes, shorter than the {}-byte page header", bytes.size(),
                            kTreePageHeaderBytes));
  }
  ByteReader header(bytes.data());
  PageCounts counts;
  counts.nodes = header.u32();
  counts.refs = header.u32();
  counts.surfels = header.u32();
  counts.exact = header.u32();
  const uint8_t flaggedEncoding = header.u8();
  const bool relativeRadii = (flaggedEncoding & kRelativeRadiiFlag) != 0;
  const bool relativeRadiance = (flaggedEncoding & kRelativeRadianceFlag) != 0;
  const uint8_t encodingByte = flaggedEncoding & ~kEncodingFlags;
  if (encodingByte > static_cast<uint8_t>(TreeEncoding::kQuantized8) ||
      ((flaggedEncoding & kEncodingFlags) != 0 &&
       encodingByte == static_cast<uint8_t>(TreeEncoding::kFloat))) {
    return fail(fmt::format("encoding {}, expected 0 (float), 1 or 2 (quantized; plus 128 with "
                            "surfel radii relative to their leaf, plus 64 with radiance so)",
                            flaggedEncoding));
  }
  const auto encoding = static_cast<TreeEncoding>(encodingByte);
  // Counts are checked against the size in 64 bits before anything is allocated.
  const uint64_t expected = kTreePageHeaderBytes +
                            uint64_t{counts.nodes} * nodeRecordBytes(encoding) +
                            uint64_t{counts.refs} * kChildRefBytes +
                            uint64_t{counts.surfels} * surfelRecordBytes(encoding) +
                            uint64_t{counts.exact} * kExactShBytes;
  // Bytes past the records are the optional wavelet section, read last.
  if (expected > bytes.size() || counts.nodes == 0 || counts.exact > counts.nodes) {
    return fail(fmt::format(
        "{} nodes ({} exact), {} references and {} surfels need {} bytes, found {}",
        counts.nodes, counts.exact, counts.refs, counts.surfels, expected, bytes.size()));
  }
  if (quantized(encoding) && codebooks == nullptr) {
    return fail("quantized page, but the tree has no codebooks");
  }
  auto page = std::make_shared<TreePage>();
  page->id = id;
  page->encoding = encoding;
  page->bounds.min = readVec3(header);
  page->bounds.max = readVec3(header);
  if (!isFinite(page->bounds.min) || !isFinite(page->bounds.max) || page->bounds.empty()) {
    return fail("page bounds are not a finite box");
  }
  page->nodes.resize(counts.nodes);
  page->children.resize(counts.refs);
  page->surfels.resize(counts.surfels);
  const uint32_t nodeBytes = nodeRecordBytes(encoding);
  const uint8_t* records = bytes.data() + kTreePageHeaderBytes;
  ByteReader refs(records + size_t{counts.nodes} * nodeBytes);
  for (NodeRef& c : page->children) {
    c.page = refs.u32();
    c.index = refs.u32();
  }

  // Topology first: ranges inside the page, and one in-page parent per node at most. A
  // parent usually precedes its children; one packed after children that were placed before
  // it refers back to them. (Cycles, which hostile files can also build across pages, are
  // caught by traversals, which stop at the tree's maximum depth.)
  std::vector<uint8_t> hasParent(counts.nodes, 0);
  for (uint32_t i = 0; i < counts.nodes; ++i) {
    TreeNode& n = page->nodes[i];
    ByteReader r(records + size_t{i} * nodeBytes);
    n.childCount = r.u8();
    n.surfelCount = r.u8();
    n.first = r.u32();
    n.attributes.pointCount = r.u32();
    if (n.childCount > 8) return fail(fmt::format("node {}: {} children, at most 8", i, n.childCount));
    if (n.childCount > 0 && n.surfelCount > 0) {
      return fail(fmt::format("node {}: {} children and {} surfels, expected one of them", i,
                              n.childCount, n.surfelCount));
    }
    if (n.ghost()) {
      // A copy of the child that reference `first` leads to, in another page.
      if (n.first >= counts.refs || page->children[n.first].page == id) {
        return fail(fmt::format("node {}: a ghost of reference {}, which is not a reference "
                                "out of the page ({} references)",
                                i, n.first, counts.refs));
      }
      continue;
    }
    const uint64_t end = uint64_t{n.first} + (n.leaf() ? n.surfelCount : n.childCount);
    if (end > (n.leaf() ? counts.surfels : counts.refs)) {
      return fail(fmt::format("node {}: {} [{}, {}) past the page's {}", i,
                              n.leaf() ? "surfels" : "children", n.first, end,
                              n.leaf() ? counts.surfels : counts.refs));
    }
    for (const NodeRef& c : page->childrenOf(n)) {
      if (c.page != id) continue;
      if (c.index == i || c.index >= counts.nodes || hasParent[c.index]) {
        return fail(fmt::format("node {}: in-page child {} is not another node of its own", i,
                                c.index));
      }
      hasParent[c.index] = 1;
    }
  }

  page->ghostOf.assign(counts.refs, kNoGhost);
  for (uint32_t i = 0; i < counts.nodes; ++i) {
    const TreeNode& n = page->nodes[i];
    if (n.ghost()) {
      if (page->ghostOf[n.first] != kNoGhost) {
        return fail(fmt::format("nodes {} and {}: two ghosts of reference {}",
                                page->ghostOf[n.first], i, n.first));
      }
      page->ghostOf[n.first] = i;
      continue;
    }
    for (const NodeRef& c : page->childrenOf(n)) {
      if (c.page == id && page->nodes[c.index].ghost()) {
        return fail(fmt::format("node {}: child {} is a ghost", i, c.index));
      }
    }
  }

  // Attributes, parents before children: a quantized node's bounds are relative to its
  // in-page parent's, or to the page's.
  std::vector<Bounds3f> reference(counts.nodes, page->bounds);
  std::vector<float> radianceScale(counts.nodes, 1.0f);  // what a leaf's surfels' is over
  const uint8_t* exact = bytes.data() + expected - size_t{counts.exact} * kExactShBytes;
  uint32_t exactSeen = 0;
  for (uint32_t i = 0; i < counts.nodes; ++i) {
    TreeNode& n = page->nodes[i];
    NodeAttributes& a = n.attributes;
    ByteReader r(records + size_t{i} * nodeBytes + 10);
    if (!quantized(encoding)) {
      readFloatAttributes(r, &a);
      continue;
    }
    a.bounds = decodeBounds(r, reference[i]);
    for (const NodeRef& c : page->childrenOf(n)) {
      if (c.page == id && c.index > i) reference[c.index] = a.bounds;
    }
    const uint16_t cx = r.u16(), cy = r.u16(), cz = r.u16();
    a.centroid = Vec3f(dequantizeIn(cx, a.bounds.min.x, a.bounds.max.x),
                       dequantizeIn(cy, a.bounds.min.y, a.bounds.max.y),
                       dequantizeIn(cz, a.bounds.min.z, a.bounds.max.z));
    const uint16_t u = r.u16(), v = r.u16();
    a.cone.axis = octDecode(u, v);
    a.cone.cosAngle = fromUnorm16(r.u16());
    a.area = r.f32();
    const Rgb dc = readVec3(r);
    a.backPower = readVec3(r);
    if (relativeRadiance) radianceScale[i] = surfelRadianceScale(a.area, dc, a.backPower);
    uint32_t powerIndex, areaIndex;
    if (encoding == TreeEncoding::kQuantized8) {
      powerIndex = r.u8();
      areaIndex = r.u8();
    } else {
      powerIndex = r.u16();
      areaIndex = r.u16();
    }
    if (powerIndex == exactMarker(encoding)) {
      if (exactSeen == counts.exact) {
        return fail(fmt::format("node {}: more exact nodes than the {} the header counts", i,
                                counts.exact));
      }
      ByteReader e(exact + size_t{exactSeen++} * kExactShBytes);
      for (float& c : a.areaSh.c) c = e.f32();
      float power[Sh9Rgb::kFloats];
      for (float& c : power) c = e.f32();
      a.powerSh = Sh9Rgb::fromFloats(power);
      continue;
    }
    if (powerIndex >= static_cast<uint32_t>(codebooks->power.size()) ||
        areaIndex >= static_cast<uint32_t>(codebooks->area.size())) {
      return fail(fmt::format("node {}: codebook indices {} and {}, the codebooks have {} and {}",
                              i, powerIndex, areaIndex, codebooks->power.size(),
                              codebooks->area.size()));
    }
    const ShRotation rotation = ShRotation::toLocal(Frame(a.cone.axis));
    a.powerSh = rotation.applyInverse(
        powerFromShape(dc, codebooks->power.entry(static_cast<int>(powerIndex))));
    a.areaSh = rotation.applyInverse(
        areaFromShape(areaShDc(a.area), codebooks->area.entry(static_cast<int>(areaIndex))));
  }

  if (exactSeen != counts.exact) {
    return fail(fmt::format("{} exact nodes, the header counts {}", exactSeen, counts.exact));
  }
  // Surfels: their leaf's bounds are needed for quantized positions, so walk the leaves.
  std::vector<const Bounds3f*> surfelBounds(counts.surfels, nullptr);
  std::vector<float> surfelScale(counts.surfels, 1.0f);
  for (const TreeNode& n : page->nodes) {
    if (!n.leaf()) continue;
    for (uint32_t k = 0; k < n.surfelCount; ++k) {
      if (surfelBounds[n.first + k] != nullptr) {
        return fail(fmt::format("surfel {} belongs to two leaves", n.first + k));
      }
      surfelBounds[n.first + k] = &n.attributes.bounds;
      surfelScale[n.first + k] = radianceScale[static_cast<size_t>(&n - page->nodes.data())];
    }
  }
  ByteReader r(refs.position());
  for (uint32_t si = 0; si < counts.surfels; ++si) {
    Surfel& s = page->surfels[si];
    if (!quantized(encoding)) {
      if (auto status = readFloatSurfel(r, &s); !status.ok()) {
        return fail(fmt::format("surfel {}: {}", si, status.message()));
      }
      continue;
    }
    if (surfelBounds[si] == nullptr) return fail(fmt::format("surfel {} is in no leaf", si));
    const Bounds3f& lb = *surfelBounds[si];
    const uint16_t px = r.u16(), py = r.u16(), pz = r.u16();
    s.position = Vec3f(dequantizeIn(px, lb.min.x, lb.max.x), dequantizeIn(py, lb.min.y, lb.max.y),
                       dequantizeIn(pz, lb.min.z, lb.max.z));
    const uint16_t u = r.u16(), v = r.u16();
    s.normal = octDecode(u, v);
    s.radius = halfBits(r.u16()) * (relativeRadii ? radiusScale(lb) : 1.0f);
    for (int ch = 0; ch < 3; ++ch) s.radiance[ch] = halfBits(r.u16()) * surfelScale[si];
    for (int ch = 0; ch < 3; ++ch) s.backRadiance[ch] = halfBits(r.u16()) * surfelScale[si];
    for (int ch = 0; ch < 3; ++ch) s.albedo[ch] = r.u8() / 255.0f;
    const uint8_t material = r.u8();
    if (material > static_cast<uint8_t>(MaterialClass::kEmissive)) {
      return fail(fmt::format("surfel {}: material class {}, expected 0..3", si, material));
    }
    s.materialClass = static_cast<MaterialClass>(material);
  }
  if (expected < bytes.size()) {
    if (auto s = readWaveletSection(bytes.subspan(expected), page.get()); !s.ok()) return s;
  }
  return std::shared_ptr<const TreePage>(std::move(page));
}

}  // namespace pbgi
