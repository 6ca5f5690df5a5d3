// A tree page's bytes from its nodes: the header, the node records (the page's nodes, then the
// ghosts of children in other pages), the child references, the surfels, the exact SH of exact
// nodes, then the optional wavelet section.
#include <fmt/format.h>

#include "core/pbgi/tree_page_codec.h"
#include "core/util/check.h"

namespace pbgi {

using namespace page_codec;

namespace {

// A ghost the page writes: a child whose reference leads out of the page, after the other
// nodes, with the index of the reference it copies.
struct Ghost {
  const GhostNode* node;
  uint32_t ref;
};

// What the page holds, before a byte is written: its ghosts, counts and bounds.
struct PagePlan {
  std::vector<Ghost> ghosts;
  PageCounts counts;
  Bounds3f bounds;
};

PagePlan planPage(uint32_t id, TreeEncoding encoding, std::span<const PageNode> nodes) {
  PagePlan plan;
  for (const PageNode& n : nodes) {
    for (const GhostNode& g : n.ghosts) {
      PBGI_CHECK_LT(g.child, n.children.size());
      if (n.children[g.child].page == id) continue;
      plan.ghosts.push_back({&g, plan.counts.refs + g.child});
      plan.counts.exact += quantized(encoding) && g.exact ? 1 : 0;
      plan.bounds.extend(g.attributes.bounds.min);
      plan.bounds.extend(g.attributes.bounds.max);
    }
    plan.counts.refs += static_cast<uint32_t>(n.children.size());
    plan.counts.surfels += static_cast<uint32_t>(n.surfels.size());
    plan.counts.exact += quantized(encoding) && n.exact ? 1 : 0;
    plan.bounds.extend(n.attributes.bounds.min);
    plan.bounds.extend(n.attributes.bounds.max);
  }
  plan.counts.nodes = static_cast<uint32_t>(nodes.size() + plan.ghosts.size());
  return plan;
}

// What a node record holds besides its attributes.
struct RecordShape {
  size_t childCount = 0, surfelCount = 0;
  uint32_t first = 0;  // its first child reference or surfel; a ghost's reference
  bool exact = false;
  uint32_t powerIndex = 0, areaIndex = 0;
};

// One node record, its bounds relative to `reference`; returns the bounds its decoder will see.
Bounds3f writeNodeRecord(ByteWriter& w, TreeEncoding encoding, const TreeCodebooks* codebooks,
                         const NodeAttributes& a, const RecordShape& shape,
                         const Bounds3f& reference) {
  w.u8(static_cast<uint8_t>(shape.childCount));
  w.u8(static_cast<uint8_t>(shape.surfelCount));
  w.u32(shape.first);
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
  const float half =
      a.cone.cosAngle <= -1.0f ? kPi : safeAcos(a.cone.cosAngle) + safeAcos(dot(axis, a.cone.axis));
  w.u16(half >= kPi ? 0 : quantizeCosDown(std::cos(half)));
  w.f32(a.area);
  writeVec3(w, a.powerSh.c[0]);
  writeVec3(w, a.backPower);
  if (!shape.exact) {
    PBGI_CHECK_LT(shape.powerIndex, static_cast<uint32_t>(codebooks->power.size()));
    PBGI_CHECK_LT(shape.areaIndex, static_cast<uint32_t>(codebooks->area.size()));
  }
  const uint32_t power = shape.exact ? exactMarker(encoding) : shape.powerIndex;
  const uint32_t area = shape.exact ? 0 : shape.areaIndex;
  if (encoding == TreeEncoding::kQuantized8) {
    w.u8(static_cast<uint8_t>(power));
    w.u8(static_cast<uint8_t>(area));
  } else {
    w.u16(static_cast<uint16_t>(power));
    w.u16(static_cast<uint16_t>(area));
  }
  return decoded;
}

// The node records, then the ghosts'. Each node's bounds are relative to those its decoder will
// know: its in-page parent's dequantized bounds, else the page's. Returns each node's decoded
// bounds (a leaf's surfels are quantized in them).
std::vector<Bounds3f> writeNodeRecords(ByteWriter& w, uint32_t id, TreeEncoding encoding,
                                       const TreeCodebooks* codebooks,
                                       std::span<const PageNode> nodes, const PagePlan& plan) {
  std::vector<Bounds3f> reference(nodes.size(), plan.bounds);
  std::vector<Bounds3f> decodedBounds(nodes.size());
  uint32_t firstRef = 0, firstSurfel = 0;
  for (size_t i = 0; i < nodes.size(); ++i) {
    const PageNode& n = nodes[i];
    PBGI_CHECK_LE(n.children.size(), 8u);
    PBGI_CHECK_LE(n.surfels.size(), 255u);
    PBGI_CHECK(n.children.empty() != n.surfels.empty());
    const Bounds3f decoded = writeNodeRecord(w, encoding, codebooks, n.attributes,
                                             {.childCount = n.children.size(),
                                              .surfelCount = n.surfels.size(),
                                              .first = n.children.empty() ? firstSurfel : firstRef,
                                              .exact = n.exact,
                                              .powerIndex = n.powerIndex,
                                              .areaIndex = n.areaIndex},
                                             reference[i]);
    decodedBounds[i] = decoded;
    firstRef += static_cast<uint32_t>(n.children.size());
    firstSurfel += static_cast<uint32_t>(n.surfels.size());
    for (const NodeRef& c : n.children) {
      PBGI_CHECK(c.page != id || c.index != i);
      if (c.page == id && c.index > i) reference[c.index] = decoded;
    }
  }
  for (const Ghost& g : plan.ghosts) {
    writeNodeRecord(w, encoding, codebooks, g.node->attributes,
                    {.first = g.ref,
                     .exact = g.node->exact,
                     .powerIndex = g.node->powerIndex,
                     .areaIndex = g.node->areaIndex},
                    plan.bounds);
  }
  return decodedBounds;
}

// The leaves' surfels, quantized in their leaf's decoded bounds.
void writeSurfels(ByteWriter& w, TreeEncoding encoding, std::span<const PageNode> nodes,
                  std::span<const Bounds3f> decodedBounds) {
  for (size_t i = 0; i < nodes.size(); ++i) {
    const Bounds3f& lb = decodedBounds[i];
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
}

// The exact nodes' SH (quantized pages), nodes then ghosts.
void writeExactSh(ByteWriter& w, std::span<const PageNode> nodes, const PagePlan& plan) {
  auto writeExact = [&](const NodeAttributes& a) {
    for (float c : a.areaSh.c) w.f32(c);
    float power[Sh9Rgb::kFloats];
    a.powerSh.toFloats(power);
    for (float c : power) w.f32(c);
  };
  for (const PageNode& n : nodes) {
    if (n.exact) writeExact(n.attributes);
  }
  for (const Ghost& g : plan.ghosts) {
    if (g.node->exact) writeExact(g.node->attributes);
  }
}

// The wavelet section, when any node or ghost has a wavelet; returns its bytes.
size_t writeWavelets(ByteWriter& w, uint32_t id, std::span<const PageNode> nodes,
                     const PagePlan& plan, float waveletError, WaveletPageStats* waveletStats) {
  std::vector<int64_t> parentOf(nodes.size(), -1);
  for (size_t i = 0; i < nodes.size(); ++i) {
    for (const NodeRef& c : nodes[i].children) {
      if (c.page == id) parentOf[c.index] = static_cast<int64_t>(i);
    }
  }
  std::vector<std::shared_ptr<const WaveletRadiance>> ghostWavelets;
  for (const Ghost& g : plan.ghosts) ghostWavelets.push_back(g.node->wavelet);
  WaveletPageStats sectionStats;
  const std::vector<WaveletEntry> entries =
      codeWavelets(nodes, parentOf, ghostWavelets, waveletError, &sectionStats);
  size_t entryBytes = 0;
  for (const WaveletEntry& e : entries) entryBytes += waveletEntryBytes(e.stored);
  writeWaveletSection(w, entries);
  if (waveletStats != nullptr) *waveletStats += sectionStats;
  return entries.empty() ? 0 : kWaveletSectionHeaderBytes + entryBytes;
}

}  // namespace

std::vector<uint8_t> encodeTreePage(uint32_t id, TreeEncoding encoding,
                                    std::span<const PageNode> nodes, const TreeCodebooks* codebooks,
                                    float waveletError, WaveletPageStats* waveletStats) {
  PBGI_CHECK(!quantized(encoding) || codebooks != nullptr);
  const PagePlan plan = planPage(id, encoding, nodes);
  const PageCounts& counts = plan.counts;
  const size_t recordBytes =
      treePageBytes(encoding, counts.nodes, counts.refs, counts.surfels, counts.exact);
  std::vector<uint8_t> out;
  out.reserve(recordBytes);
  ByteWriter w(&out);
  w.u32(counts.nodes);
  w.u32(counts.refs);
  w.u32(counts.surfels);
  w.u32(counts.exact);
  w.u8(static_cast<uint8_t>(encoding) | (quantized(encoding) ? kEncodingFlags : 0));
  writeVec3(w, plan.bounds.min);
  writeVec3(w, plan.bounds.max);
  const std::vector<Bounds3f> decodedBounds =
      writeNodeRecords(w, id, encoding, codebooks, nodes, plan);
  for (const PageNode& n : nodes) {
    for (const NodeRef& c : n.children) {
      w.u32(c.page);
      w.u32(c.index);
    }
  }
  writeSurfels(w, encoding, nodes, decodedBounds);
  if (quantized(encoding)) writeExactSh(w, nodes, plan);
  PBGI_CHECK_EQ(out.size(), recordBytes);
  const size_t waveletBytes = writeWavelets(w, id, nodes, plan, waveletError, waveletStats);
  PBGI_CHECK_EQ(out.size(), recordBytes + waveletBytes);
  return out;
}

}  // namespace pbgi
