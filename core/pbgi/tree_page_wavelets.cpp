// A tree page's optional wavelet section: glossy nodes' radiance as Haar wavelets, coded
// hierarchically against their in-page parents.
#include <bit>

#include <fmt/format.h>

#include "core/pbgi/tree_page_codec.h"
#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi::page_codec {

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

}  // namespace

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
std::vector<WaveletEntry> codeWavelets(
    std::span<const PageNode> nodes, std::span<const int64_t> parentOf,
    std::span<const std::shared_ptr<const WaveletRadiance>> ghosts, float relativeError,
    WaveletPageStats* stats) {
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
    WaveletEntry entry{
        static_cast<uint32_t>(i), 0, 0.0f,
        asStored(nodes[i].waveletWhole ? *nodes[i].waveletWhole
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
    entries.push_back(
        WaveletEntry{static_cast<uint32_t>(nodes.size() + g), 0, 0.0f, asStored(*ghosts[g])});
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
      if (c.page == page->id && c.index < parentOf.size())
        parentOf[c.index] = static_cast<int64_t>(i);
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
    return fail(
        fmt::format("{} bytes after the page's records, not a wavelet section (magic "
                    "{:#010x}, expected {:#010x})",
                    bytes.size(), magic, kWaveletMagic));
  }
  const uint16_t version = r.u16();
  if (version != kWaveletSectionVersion) {
    return fail(
        fmt::format("version {}, this build reads version {}", version, kWaveletSectionVersion));
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
      return fail(
          fmt::format("entry {} names node {} (the page has {}; entries in node order, "
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
        return fail(
            fmt::format("entry {} face {}: {} nodes, more than the bytes left", e, f, count));
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
      return fail(
          fmt::format("entry {} (node {}): coding {} factor {}, expected coding 0 (whole) "
                      "or 1 (difference) and a finite factor",
                      e, node, coding, factor));
    }
    if (coding == 1) {
      const int64_t p = parentOf[node];
      const WaveletRadiance* parent = p >= 0 ? page->waveletOf(page->nodes[p]) : nullptr;
      if (parent == nullptr || p >= static_cast<int64_t>(node) ||
          parent->resolution() != w->resolution()) {
        return fail(
            fmt::format("entry {} (node {}) is a difference from its parent's vector, "
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

}  // namespace pbgi::page_codec
