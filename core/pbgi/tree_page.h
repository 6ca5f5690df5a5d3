#pragma once
// What a page of a PBGI tree holds, in bytes and decoded: the payload that the `.pbgi`
// container (formats/pbgi/page_file) stores, compresses and checksums without looking in.
//
// A page holds whole subtrees laid out depth-first in Morton order (a parent before its
// children), so that a top-down traversal walks a page from front to back and crosses into
// another page only where a subtree was too big to share one. A node names each child by
// NodeRef (page id, index of the node in that page).
//
// Two encodings share the layout. Float stores every attribute as computed. Quantized
// (Buchholz and Boubekeur 2012) stores the spherical functions as a DC term plus a codebook
// index into the shapes (coefficients 1..8 over coefficient 0, per channel), normals
// octahedral in 2 x u16, bounds in u16 relative to the parent's (dequantized) bounds where
// the parent comes earlier in the same page, else to the page's bounds, surfel positions in u16 relative to their
// leaf's bounds and radiance in half floats over a power of two of their leaf's
// (surfelRadianceScale). Quantized bounds and cones are conservative:
// dequantized bounds contain the float ones and a dequantized cone contains its normals.
//
// Ghosts (version 3). A node whose children were placed in other pages keeps a copy of each
// such child's record in its own page: a ghost, a node record with neither children nor
// surfels whose `first` is the index of the child reference it copies. A traversal that must
// weigh a node's children against one another (the cut picking where a shadow ray goes) reads
// them there instead of asking for the children's pages, so it visits pages in the order a
// sweep does. Ghosts follow the page's other nodes; their bounds are relative to the page's.
// No reference points at a ghost.
//
// Payload layout, version 3 (little-endian, fixed width, no padding; version 1 had no back
// radiance or back power, version 2 no ghosts):
//   u32 node count, u32 child-reference count, u32 surfel count, u32 exact count, u8 encoding (0 float,
//   1 quantized, 2 quantized with 8-bit indices; plus 0x80 when quantized surfel radii are
//   over their leaf's largest side: absolute half-float radii lose precision below 6e-5
//   units), 6 x f32 page bounds (min xyz, max xyz),
//   then the node records, the child references (u32 page, u32 index each), the surfel
//   records, and the float SH of exact nodes (area 9 x f32, power 27 x f32 each, in node
//   order). Record sizes below.
// Wavelet section (optional, its own version): when the payload runs on past the
//   exact SH, the rest is u32 magic 0x56574250 ("PBWV"), u16 section version (1), u32 entry
//   count, then per node that has a wavelet vector, in node order:
//   u32 node index (ghosts too, whose vectors keep only the faces' averages), u8 log2 of
//   the cube's resolution n, u8 coding, f32 factor, and per face (6): scaling 3 x f32,
//   detail scale f32, u16 kept-node count, then per kept quadtree node (pyramid order):
//   u8 level, u8 x, u8 y, details 9 x f16 (horizontal, vertical, diagonal x RGB, each over
//   the face's detail scale). A page without wavelets has no section and reads as before.
//   Hierarchical coding (Wang et al. section 3.1): coding 0 stores the node's vector whole;
//   coding 1 stores its difference from `factor` times its in-page parent's (decoded) vector,
//   the parent's entry coming first. A page root has no parent in its page, so it is stored
//   whole: the bootstrap level, a page deep. The encoder keeps, of whole vector and
//   difference, the one with fewer kept nodes, each thresholded (WaveletRadiance::fromDense)
//   to within the page's relative error of the node's vector as given, measured on the
//   decoded (half-float) values.
// Node record: u8 child count (0 for a leaf), u8 surfel count (leaves), u32 first child
//   reference or first surfel, u32 point count, then
//   float:     bounds 6 x f32, centroid 3 x f32, cone axis 3 x f32, cone cos f32, area f32,
//              area SH 9 x f32, power SH 27 x f32 (coefficient-major, RGB), back power
//              3 x f32                                                                = 222
//   quantized: bounds 6 x u16, centroid 3 x u16 (in the node's bounds), cone axis 2 x u16
//              (octahedral), cone cos u16, area f32, power DC 3 x f32, back power 3 x f32,
//              power shape index u16, area shape index u16                            =  66
//              (u8 indices in kQuantized8                                             =  64)
//              A power index of all ones (0xffff, 0xff) marks an exact node: the biggest
//              clusters, few but carrying most of the light, keep their SH in float.
// Surfel record:
//   float:     position 3 x f32, normal 3 x f32, radius f32, radiance 3 x f32, back
//              radiance 3 x f32, albedo 3 x f32, material class u8                    =  65
//   quantized: position 3 x u16 (in the leaf's bounds), normal 2 x u16 (octahedral),
//              radius f16 (absolute, or over the leaf's largest side: see the encoding
//              byte), radiance 3 x f16, back radiance 3 x f16, albedo 3 x u8,
//              material class u8                                                      =  28
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/pbgi/quantize.h"
#include "core/pbgi/tree.h"
#include "core/pbgi/wavelet.h"
#include "core/util/bytes.h"

namespace pbgi {

inline constexpr uint32_t kTreePageHeaderBytes = 4 + 4 + 4 + 4 + 1 + 24;
// The float spherical functions of an exact node: area SH 9 x f32, power SH 27 x f32.
inline constexpr uint32_t kExactShBytes = 36 * 4;
inline constexpr uint32_t kChildRefBytes = 8;
inline constexpr uint32_t kWaveletMagic = 0x56574250;  // "PBWV"
inline constexpr uint16_t kWaveletSectionVersion = 1;
inline constexpr uint32_t kWaveletSectionHeaderBytes = 4 + 2 + 4;
inline constexpr uint32_t kNoWavelet = UINT32_MAX;
// Bytes of one node's entry in the wavelet section.
size_t waveletEntryBytes(const WaveletRadiance& w);
// The most an entry of at most `maxNodes` kept quadtree nodes takes.
inline constexpr size_t maxWaveletEntryBytes(size_t maxNodes) {
  return 4 + 1 + 1 + 4 + 6 * (16 + 2) + maxNodes * (3 + 18);
}

// What the wavelet sections of pages hold, summed over pages.
struct WaveletPageStats {
  uint64_t entries = 0;       // vectors stored (ghosts' included)
  uint64_t differences = 0;   // of them, coded against their parent's
  uint64_t keptNodes = 0;     // quadtree nodes stored
  uint64_t bytes = 0;         // the sections' bytes
  double maxRelativeError = 0.0;  // of a decoded vector against the one given, L2
  WaveletPageStats& operator+=(const WaveletPageStats& o);
};

// kQuantized stores 16-bit codebook indices, kQuantized8 8-bit ones (codebooks of at most
// 256 entries, 2 bytes less per node).
enum class TreeEncoding : uint8_t { kFloat = 0, kQuantized = 1, kQuantized8 = 2 };

inline constexpr uint32_t nodeRecordBytes(TreeEncoding e) {
  return e == TreeEncoding::kFloat ? 222 : e == TreeEncoding::kQuantized ? 66 : 64;
}
inline constexpr bool quantized(TreeEncoding e) { return e != TreeEncoding::kFloat; }
// The largest codebook an encoding's indices address.
// The largest index is reserved: it marks an exact node.
inline constexpr int maxCodebookEntries(TreeEncoding e) {
  return e == TreeEncoding::kQuantized8 ? 255 : 65535;
}
inline constexpr uint32_t surfelRecordBytes(TreeEncoding e) {
  return e == TreeEncoding::kFloat ? 65 : 28;
}

struct NodeRef {
  uint32_t page = 0;
  uint32_t index = 0;
  bool operator==(const NodeRef&) const = default;
};

// A node as a traversal sees it: attributes in float (dequantized), where its children are.
struct TreeNode {
  NodeAttributes attributes;
  uint32_t childCount = 0;  // 0 for a leaf
  uint32_t first = 0;       // first child in TreePage::children, or first surfel
  uint32_t surfelCount = 0;
  uint32_t wavelet = kNoWavelet;  // index into TreePage::wavelets: glossy light, if any
  bool leaf() const { return childCount == 0; }
  // A copy of a child in another page (see Ghosts above): `first` is its child reference.
  bool ghost() const { return childCount == 0 && surfelCount == 0; }
};

inline constexpr uint32_t kNoGhost = UINT32_MAX;

// One decoded page. Immutable once built, shared by the traversals that use it.
struct TreePage {
  uint32_t id = 0;
  TreeEncoding encoding = TreeEncoding::kFloat;
  Bounds3f bounds;
  std::vector<TreeNode> nodes;
  std::vector<NodeRef> children;
  std::vector<Surfel> surfels;  // triangle and barycentric are not stored: left 0
  // Per child reference: the node index of its ghost, kNoGhost for a child in this page.
  std::vector<uint32_t> ghostOf;
  // The wavelet intensity (W/sr as a function of direction) of the nodes that have one: the
  // light their glossy and refractive surfels send out, beside the SH's diffuse light.
  std::vector<WaveletRadiance> wavelets;
  // What the page's wavelet section stored: its bytes and quadtree nodes (differences from
  // parents count as stored, not as decoded).
  uint32_t waveletSectionBytes = 0;
  uint32_t waveletStoredNodes = 0;

  const WaveletRadiance* waveletOf(const TreeNode& n) const {
    return n.wavelet == kNoWavelet ? nullptr : &wavelets[n.wavelet];
  }

  // `first` indexes children for interior nodes and surfels for leaves; each accessor is
  // empty for the other kind (the index would be out of its range).
  std::span<const NodeRef> childrenOf(const TreeNode& n) const {
    if (n.leaf()) return {};
    return std::span(children).subspan(n.first, n.childCount);
  }
  std::span<const Surfel> surfelsOf(const TreeNode& n) const {
    if (!n.leaf() || n.ghost()) return {};
    return std::span(surfels).subspan(n.first, n.surfelCount);
  }
  // The attributes of child `c` of interior node `n`: the child itself when it is in this
  // page, its ghost when it is in another; null for a child in another page without a ghost
  // (trees of payload version 3 have one for every such child).
  const NodeAttributes* childAttributes(const TreeNode& n, uint32_t c) const {
    const NodeRef ref = children[n.first + c];
    if (ref.page == id) return ref.index < nodes.size() ? &nodes[ref.index].attributes : nullptr;
    const uint32_t g = n.first + c < ghostOf.size() ? ghostOf[n.first + c] : kNoGhost;
    return g == kNoGhost ? nullptr : &nodes[g].attributes;
  }
  // The wavelet vector of child `c` of interior node `n`, as childAttributes finds it (a
  // ghost's keeps only its faces' averages); null when it has none.
  const WaveletRadiance* childWavelet(const TreeNode& n, uint32_t c) const {
    const NodeRef ref = children[n.first + c];
    if (ref.page == id) return ref.index < nodes.size() ? waveletOf(nodes[ref.index]) : nullptr;
    const uint32_t g = n.first + c < ghostOf.size() ? ghostOf[n.first + c] : kNoGhost;
    return g == kNoGhost ? nullptr : waveletOf(nodes[g]);
  }
  // Memory the decoded page holds, what a page cache budgets.
  size_t memoryBytes() const;
};

// The codebooks of a quantized tree: shapes of the power SH (24 floats: coefficients 1..8 of
// each channel over that channel's coefficient 0) and of the area SH (8 floats).
inline constexpr int kPowerShapeDims = 3 * (kShCoefficients - 1);
inline constexpr int kAreaShapeDims = kShCoefficients - 1;
// Shape ratios of non-negative functions stay within a few units; the clamp keeps a node
// whose DC term nearly cancels from producing a huge vector that would own a centre.
inline constexpr float kMaxShapeRatio = 4.0f;

struct TreeCodebooks {
  Codebook power;  // dimension kPowerShapeDims
  Codebook area;   // dimension kAreaShapeDims
};

// Shapes are taken in a frame around the node's cone axis as the page stores it (octahedral,
// rounded), where most clusters look alike (a clamped cosine around +z for a flat patch),
// so that a small codebook serves every orientation. Encoder and decoder both build it
// from the stored axis.
ShRotation shapeRotation(const Vec3f& coneAxis);

// The shape vectors quantization clusters (of functions already in the shape frame), and
// back.
void powerShape(const Sh9Rgb& sh, float out[kPowerShapeDims]);
Sh9Rgb powerFromShape(const Rgb& dc, std::span<const float> shape);
void areaShape(const Sh9& sh, float out[kAreaShapeDims]);
Sh9 areaFromShape(float dc, std::span<const float> shape);
// The DC coefficient of projected area is area * pi * Y00 for any normal.
float areaShDc(float area);

// Codebook bytes for the file's sections: u32 dimension, u32 entry count, then the entries
// as f32. Decoding checks the dimension and that entry 0 is black.
std::vector<uint8_t> encodeCodebook(const Codebook& codebook);
absl::StatusOr<Codebook> decodeCodebook(std::span<const uint8_t> bytes, int expectedDimension);

// A copy of a child placed in another page, for its parent's page (see Ghosts above).
struct GhostNode {
  uint32_t child = 0;  // which of the parent's children
  NodeAttributes attributes;
  uint32_t powerIndex = 0;
  uint32_t areaIndex = 0;
  bool exact = false;
  // The child's wavelet vector's face averages alone (no details): enough to weigh it
  // against its siblings (empty: none).
  std::shared_ptr<const WaveletRadiance> wavelet;
};

// A node on its way into a page: its float attributes, its surfels for a leaf, and its
// children as references, some of which point into the same page (set by the pager).
struct PageNode {
  NodeAttributes attributes;
  std::vector<NodeRef> children;
  std::vector<Surfel> surfels;
  // For quantized pages, the nearest codebook entries (the pager looks them up once).
  uint32_t powerIndex = 0;
  uint32_t areaIndex = 0;
  bool exact = false;  // quantized pages: keep this node's SH in float
  // Copies of children in other pages. The encoder writes those whose reference leads out
  // of the page and drops the others.
  std::vector<GhostNode> ghosts;
  // The node's glossy light as wavelet intensity (empty: none; see TreePage::wavelets).
  std::shared_ptr<const WaveletRadiance> wavelet;
  // `wavelet` thresholded whole to the page's error (WaveletRadiance::fromDense), when the
  // writer has it: the entry the page stores unless a difference from the parent's is
  // smaller, so the most the entry takes (what the pager counts), and what the encoder then
  // need not compute again. Null: the encoder computes it, the pager counts `wavelet`.
  std::shared_ptr<const WaveletRadiance> waveletWhole;
};

// The float fields of a node record after its point count (bounds, centroid, cone, area,
// area SH, power SH) and a float surfel record: shared by float pages and the build's spill.
void writeFloatAttributes(ByteWriter& w, const NodeAttributes& a);
void readFloatAttributes(ByteReader& r, NodeAttributes* a);  // leaves pointCount alone
void writeFloatSurfel(ByteWriter& w, const Surfel& s);
// Fails on a material class byte that names no MaterialClass.
absl::Status readFloatSurfel(ByteReader& r, Surfel* s);

// What a quantized leaf's surfels' radiance is stored over (a half float each): a power of two
// near the leaf's mean radiance, from its record's area, power DC and back power (stored
// exactly, so that writer and reader agree); 1 when those give none. Pages written before it
// store radiance absolute.
float surfelRadianceScale(float area, const Rgb& powerDc, const Rgb& backPower);

// Encoded size of a page holding `nodes` nodes (`exact` of them exact), `refs` references and
// `surfels` surfels.
size_t treePageBytes(TreeEncoding encoding, size_t nodes, size_t refs, size_t surfels,
                     size_t exact);

// Encodes nodes (in page order: mostly parents before children; a parent may also follow
// children packed into the page before it) into a payload. `id` is the page's own id: references with that page id are in-page.
// `waveletError`: the relative error each node's wavelet vector is coded within (above);
// `waveletStats`, when given, is added to.
std::vector<uint8_t> encodeTreePage(uint32_t id, TreeEncoding encoding,
                                    std::span<const PageNode> nodes,
                                    const TreeCodebooks* codebooks, float waveletError = 0.1f,
                                    WaveletPageStats* waveletStats = nullptr);

// Decodes and validates a payload: counts against the size, every reference and surfel range
// in bounds, indices inside the codebooks, at most one in-page parent per node. Errors name
// the page and what was wrong (DataLoss). `codebooks` is needed for quantized pages.
absl::StatusOr<std::shared_ptr<const TreePage>> decodeTreePage(uint32_t id,
                                                               std::span<const uint8_t> bytes,
                                                               const TreeCodebooks* codebooks);

// Where a traversal gets pages: a file read directly, a bounded cache, the network.
class TreePageSource {
 public:
  virtual ~TreePageSource() = default;
  virtual NodeRef root() const = 0;
  // The page, decoded and validated; errors name the file and page.
  virtual absl::StatusOr<std::shared_ptr<const TreePage>> page(uint32_t id) = 0;
};

}  // namespace pbgi
