// A tree page from its bytes, every count, range, reference and value checked before use: a
// damaged or hostile page is a DataLoss naming the page and what is wrong, never a crash.
#include <fmt/format.h>

#include "core/pbgi/tree_page_codec.h"
#include "core/util/status.h"

namespace pbgi {

using namespace page_codec;

namespace {

absl::Status pageError(uint32_t id, const std::string& what) {
  return absl::DataLossError(fmt::format("page {}: {}", id, what));
}

// The page's header: its counts and encoding, and where its records end (the wavelet section,
// when there is one, follows).
struct PageHeader {
  PageCounts counts;
  TreeEncoding encoding = TreeEncoding::kFloat;
  bool relativeRadii = false;
  bool relativeRadiance = false;
  uint64_t recordsEnd = 0;
};

absl::StatusOr<PageHeader> readPageHeader(uint32_t id, std::span<const uint8_t> bytes,
                                          const TreeCodebooks* codebooks, Bounds3f* bounds) {
  if (bytes.size() < kTreePageHeaderBytes) {
    return pageError(id, fmt::format("{} bytes, shorter than the {}-byte page header", bytes.size(),
                                     kTreePageHeaderBytes));
  }
  ByteReader header(bytes.data());
  PageHeader h;
  PageCounts& counts = h.counts;
  counts.nodes = header.u32();
  counts.refs = header.u32();
  counts.surfels = header.u32();
  counts.exact = header.u32();
  const uint8_t flaggedEncoding = header.u8();
  h.relativeRadii = (flaggedEncoding & kRelativeRadiiFlag) != 0;
  h.relativeRadiance = (flaggedEncoding & kRelativeRadianceFlag) != 0;
  const uint8_t encodingByte = flaggedEncoding & ~kEncodingFlags;
  if (encodingByte > static_cast<uint8_t>(TreeEncoding::kQuantized8) ||
      ((flaggedEncoding & kEncodingFlags) != 0 &&
       encodingByte == static_cast<uint8_t>(TreeEncoding::kFloat))) {
    return pageError(id, fmt::format("encoding {}, expected 0 (float), 1 or 2 (quantized; plus "
                                     "128 with surfel radii relative to their leaf, plus 64 with "
                                     "radiance so)",
                                     flaggedEncoding));
  }
  h.encoding = static_cast<TreeEncoding>(encodingByte);
  // Counts are checked against the size in 64 bits before anything is allocated.
  h.recordsEnd = kTreePageHeaderBytes + uint64_t{counts.nodes} * nodeRecordBytes(h.encoding) +
                 uint64_t{counts.refs} * kChildRefBytes +
                 uint64_t{counts.surfels} * surfelRecordBytes(h.encoding) +
                 uint64_t{counts.exact} * kExactShBytes;
  if (h.recordsEnd > bytes.size() || counts.nodes == 0 || counts.exact > counts.nodes) {
    return pageError(id, fmt::format("{} nodes ({} exact), {} references and {} surfels need {} "
                                     "bytes, found {}",
                                     counts.nodes, counts.exact, counts.refs, counts.surfels,
                                     h.recordsEnd, bytes.size()));
  }
  if (quantized(h.encoding) && codebooks == nullptr) {
    return pageError(id, "quantized page, but the tree has no codebooks");
  }
  bounds->min = readVec3(header);
  bounds->max = readVec3(header);
  if (!isFinite(bounds->min) || !isFinite(bounds->max) || bounds->empty()) {
    return pageError(id, "page bounds are not a finite box");
  }
  return h;
}

// Topology first: ranges inside the page, and one in-page parent per node at most. A parent
// usually precedes its children; one packed after children that were placed before it refers
// back to them. (Cycles, which hostile files can also build across pages, are caught by
// traversals, which stop at the tree's maximum depth.)
absl::Status readTopology(TreePage& page, const uint8_t* records, uint32_t nodeBytes,
                          const PageCounts& counts) {
  const uint32_t id = page.id;
  std::vector<uint8_t> hasParent(counts.nodes, 0);
  for (uint32_t i = 0; i < counts.nodes; ++i) {
    TreeNode& n = page.nodes[i];
    ByteReader r(records + size_t{i} * nodeBytes);
    n.childCount = r.u8();
    n.surfelCount = r.u8();
    n.first = r.u32();
    n.attributes.pointCount = r.u32();
    if (n.childCount > 8) {
      return pageError(id, fmt::format("node {}: {} children, at most 8", i, n.childCount));
    }
    if (n.childCount > 0 && n.surfelCount > 0) {
      return pageError(id, fmt::format("node {}: {} children and {} surfels, expected one of "
                                       "them",
                                       i, n.childCount, n.surfelCount));
    }
    if (n.ghost()) {
      // A copy of the child that reference `first` leads to, in another page.
      if (n.first >= counts.refs || page.children[n.first].page == id) {
        return pageError(id, fmt::format("node {}: a ghost of reference {}, which is not a "
                                         "reference out of the page ({} references)",
                                         i, n.first, counts.refs));
      }
      continue;
    }
    const uint64_t end = uint64_t{n.first} + (n.leaf() ? n.surfelCount : n.childCount);
    if (end > (n.leaf() ? counts.surfels : counts.refs)) {
      return pageError(id, fmt::format("node {}: {} [{}, {}) past the page's {}", i,
                                       n.leaf() ? "surfels" : "children", n.first, end,
                                       n.leaf() ? counts.surfels : counts.refs));
    }
    for (const NodeRef& c : page.childrenOf(n)) {
      if (c.page != id) continue;
      if (c.index == i || c.index >= counts.nodes || hasParent[c.index]) {
        return pageError(id, fmt::format("node {}: in-page child {} is not another node of its "
                                         "own",
                                         i, c.index));
      }
      hasParent[c.index] = 1;
    }
  }
  return absl::OkStatus();
}

// Each reference out of the page to its ghost, at most one; no in-page child is a ghost.
absl::Status indexGhosts(TreePage& page, uint32_t refCount) {
  page.ghostOf.assign(refCount, kNoGhost);
  for (uint32_t i = 0; i < page.nodes.size(); ++i) {
    const TreeNode& n = page.nodes[i];
    if (n.ghost()) {
      if (page.ghostOf[n.first] != kNoGhost) {
        return pageError(page.id, fmt::format("nodes {} and {}: two ghosts of reference {}",
                                              page.ghostOf[n.first], i, n.first));
      }
      page.ghostOf[n.first] = i;
      continue;
    }
    for (const NodeRef& c : page.childrenOf(n)) {
      if (c.page == page.id && page.nodes[c.index].ghost()) {
        return pageError(page.id, fmt::format("node {}: child {} is a ghost", i, c.index));
      }
    }
  }
  return absl::OkStatus();
}

// A quantized node's SH: exact (the next of the page's exact records, counted in `exactSeen`),
// or its codebook entries rotated to its cone's axis.
absl::Status readNodeSh(uint32_t id, uint32_t i, TreeEncoding encoding, ByteReader& r,
                        const uint8_t* exact, uint32_t exactCount, uint32_t* exactSeen,
                        const TreeCodebooks& codebooks, const Rgb& dc, NodeAttributes& a) {
  uint32_t powerIndex, areaIndex;
  if (encoding == TreeEncoding::kQuantized8) {
    powerIndex = r.u8();
    areaIndex = r.u8();
  } else {
    powerIndex = r.u16();
    areaIndex = r.u16();
  }
  if (powerIndex == exactMarker(encoding)) {
    if (*exactSeen == exactCount) {
      return pageError(id, fmt::format("node {}: more exact nodes than the {} the header counts", i,
                                       exactCount));
    }
    ByteReader e(exact + size_t{(*exactSeen)++} * kExactShBytes);
    for (float& c : a.areaSh.c) c = e.f32();
    float power[Sh9Rgb::kFloats];
    for (float& c : power) c = e.f32();
    a.powerSh = Sh9Rgb::fromFloats(power);
    return absl::OkStatus();
  }
  if (powerIndex >= static_cast<uint32_t>(codebooks.power.size()) ||
      areaIndex >= static_cast<uint32_t>(codebooks.area.size())) {
    return pageError(
        id, fmt::format("node {}: codebook indices {} and {}, the codebooks have {} "
                        "and {}",
                        i, powerIndex, areaIndex, codebooks.power.size(), codebooks.area.size()));
  }
  const ShRotation rotation = ShRotation::toLocal(Frame(a.cone.axis));
  a.powerSh = rotation.applyInverse(
      powerFromShape(dc, codebooks.power.entry(static_cast<int>(powerIndex))));
  a.areaSh = rotation.applyInverse(
      areaFromShape(areaShDc(a.area), codebooks.area.entry(static_cast<int>(areaIndex))));
  return absl::OkStatus();
}

// Attributes, parents before children: a quantized node's bounds are relative to its in-page
// parent's, or to the page's. Returns what each leaf's surfels' radiance is stored over.
absl::StatusOr<std::vector<float>> readAttributes(TreePage& page, const uint8_t* records,
                                                  const uint8_t* exact, const PageHeader& h,
                                                  const TreeCodebooks* codebooks) {
  const PageCounts& counts = h.counts;
  const uint32_t nodeBytes = nodeRecordBytes(h.encoding);
  std::vector<Bounds3f> reference(counts.nodes, page.bounds);
  std::vector<float> radianceScale(counts.nodes, 1.0f);
  uint32_t exactSeen = 0;
  for (uint32_t i = 0; i < counts.nodes; ++i) {
    TreeNode& n = page.nodes[i];
    NodeAttributes& a = n.attributes;
    ByteReader r(records + size_t{i} * nodeBytes + 10);
    if (!quantized(h.encoding)) {
      readFloatAttributes(r, &a);
      continue;
    }
    a.bounds = decodeBounds(r, reference[i]);
    for (const NodeRef& c : page.childrenOf(n)) {
      if (c.page == page.id && c.index > i) reference[c.index] = a.bounds;
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
    if (h.relativeRadiance) radianceScale[i] = surfelRadianceScale(a.area, dc, a.backPower);
    PBGI_RETURN_IF_ERROR(
        readNodeSh(page.id, i, h.encoding, r, exact, counts.exact, &exactSeen, *codebooks, dc, a));
  }
  if (exactSeen != counts.exact) {
    return pageError(page.id,
                     fmt::format("{} exact nodes, the header counts {}", exactSeen, counts.exact));
  }
  return radianceScale;
}

// Surfels: their leaf's bounds are needed for quantized positions, so the leaves are walked
// first.
absl::Status readSurfels(TreePage& page, ByteReader r, const PageHeader& h,
                         std::span<const float> radianceScale) {
  const uint32_t count = h.counts.surfels;
  std::vector<const Bounds3f*> surfelBounds(count, nullptr);
  std::vector<float> surfelScale(count, 1.0f);
  for (const TreeNode& n : page.nodes) {
    if (!n.leaf()) continue;
    for (uint32_t k = 0; k < n.surfelCount; ++k) {
      if (surfelBounds[n.first + k] != nullptr) {
        return pageError(page.id, fmt::format("surfel {} belongs to two leaves", n.first + k));
      }
      surfelBounds[n.first + k] = &n.attributes.bounds;
      surfelScale[n.first + k] = radianceScale[static_cast<size_t>(&n - page.nodes.data())];
    }
  }
  for (uint32_t si = 0; si < count; ++si) {
    Surfel& s = page.surfels[si];
    if (!quantized(h.encoding)) {
      if (auto status = readFloatSurfel(r, &s); !status.ok()) {
        return pageError(page.id, fmt::format("surfel {}: {}", si, status.message()));
      }
      continue;
    }
    if (surfelBounds[si] == nullptr) {
      return pageError(page.id, fmt::format("surfel {} is in no leaf", si));
    }
    const Bounds3f& lb = *surfelBounds[si];
    const uint16_t px = r.u16(), py = r.u16(), pz = r.u16();
    s.position = Vec3f(dequantizeIn(px, lb.min.x, lb.max.x), dequantizeIn(py, lb.min.y, lb.max.y),
                       dequantizeIn(pz, lb.min.z, lb.max.z));
    const uint16_t u = r.u16(), v = r.u16();
    s.normal = octDecode(u, v);
    s.radius = halfBits(r.u16()) * (h.relativeRadii ? radiusScale(lb) : 1.0f);
    for (int ch = 0; ch < 3; ++ch) s.radiance[ch] = halfBits(r.u16()) * surfelScale[si];
    for (int ch = 0; ch < 3; ++ch) s.backRadiance[ch] = halfBits(r.u16()) * surfelScale[si];
    for (int ch = 0; ch < 3; ++ch) s.albedo[ch] = r.u8() / 255.0f;
    const uint8_t material = r.u8();
    if (material > static_cast<uint8_t>(MaterialClass::kEmissive)) {
      return pageError(page.id,
                       fmt::format("surfel {}: material class {}, expected 0..3", si, material));
    }
    s.materialClass = static_cast<MaterialClass>(material);
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::shared_ptr<const TreePage>> decodeTreePage(uint32_t id,
                                                               std::span<const uint8_t> bytes,
                                                               const TreeCodebooks* codebooks) {
  auto page = std::make_shared<TreePage>();
  page->id = id;
  PBGI_ASSIGN_OR_RETURN(const PageHeader h, readPageHeader(id, bytes, codebooks, &page->bounds));
  const PageCounts& counts = h.counts;
  page->encoding = h.encoding;
  page->nodes.resize(counts.nodes);
  page->children.resize(counts.refs);
  page->surfels.resize(counts.surfels);
  const uint8_t* records = bytes.data() + kTreePageHeaderBytes;
  ByteReader refs(records + size_t{counts.nodes} * nodeRecordBytes(h.encoding));
  for (NodeRef& c : page->children) {
    c.page = refs.u32();
    c.index = refs.u32();
  }
  PBGI_RETURN_IF_ERROR(readTopology(*page, records, nodeRecordBytes(h.encoding), counts));
  PBGI_RETURN_IF_ERROR(indexGhosts(*page, counts.refs));
  const uint8_t* exact = bytes.data() + h.recordsEnd - size_t{counts.exact} * kExactShBytes;
  PBGI_ASSIGN_OR_RETURN(const std::vector<float> radianceScale,
                        readAttributes(*page, records, exact, h, codebooks));
  PBGI_RETURN_IF_ERROR(readSurfels(*page, ByteReader(refs.position()), h, radianceScale));
  if (h.recordsEnd < bytes.size()) {
    PBGI_RETURN_IF_ERROR(readWaveletSection(bytes.subspan(h.recordsEnd), page.get()));
  }
  return std::shared_ptr<const TreePage>(std::move(page));
}

}  // namespace pbgi
