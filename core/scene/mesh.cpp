#include "core/scene/mesh.h"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <unordered_map>
#include <unordered_set>

#include <fmt/format.h>

#include "core/util/check.h"

namespace pbgi {
namespace {

// A triangle whose area is below this fraction of its longest edge squared is a sliver that
// float arithmetic cannot tell from a line: its face normal would be noise or NaN.
constexpr double kDegenerateRelativeArea = 1e-12;

// Normals within this of unit length are left bit-for-bit as the file gave them.
constexpr float kUnitLengthTolerance = 1e-6f;

bool isFinite2(const Vec2f& v) { return std::isfinite(v.x) && std::isfinite(v.y); }

enum class TriangleFault { kNone, kBadIndex, kNonFinite, kDegenerate };

TriangleFault classify(const MeshData& mesh, size_t t) {
  const uint32_t i0 = mesh.indices[3 * t], i1 = mesh.indices[3 * t + 1],
                 i2 = mesh.indices[3 * t + 2];
  const size_t n = mesh.positions.size();
  if (i0 >= n || i1 >= n || i2 >= n) return TriangleFault::kBadIndex;
  const Vec3f& a = mesh.positions[i0];
  const Vec3f& b = mesh.positions[i1];
  const Vec3f& c = mesh.positions[i2];
  if (!isFinite(a) || !isFinite(b) || !isFinite(c)) return TriangleFault::kNonFinite;
  // The renderer computes the face normal in float: finite vertices far apart can still
  // overflow it, and a cross product that rounds to zero has no direction.
  const Vec3f floatCross = cross(b - a, c - a);
  if (!isFinite(floatCross)) return TriangleFault::kNonFinite;
  if (floatCross.x == 0.0f && floatCross.y == 0.0f && floatCross.z == 0.0f) {
    return TriangleFault::kDegenerate;
  }
  // Double precision for the relative test so that tiny or huge coordinates neither underflow
  // nor overflow when squared.
  const Imath::V3d da(a), db(b), dc(c);
  const Imath::V3d e0 = db - da, e1 = dc - da, e2 = dc - db;
  const double twiceArea = e0.cross(e1).length();
  const double maxEdgeSq = std::max({e0.length2(), e1.length2(), e2.length2()});
  if (0.5 * twiceArea <= kDegenerateRelativeArea * maxEdgeSq) return TriangleFault::kDegenerate;
  return TriangleFault::kNone;
}

// Keeps the triangles `keep(t)` holds for, in order, `materials` in step; returns how many
// went. `keep` sees each triangle's original index once, in order.
template <typename Keep>
size_t keepTriangles(MeshData& mesh, Keep&& keep) {
  const size_t triangles = mesh.triangleCount();
  size_t kept = 0;
  for (size_t t = 0; t < triangles; ++t) {
    if (!keep(t)) continue;
    if (kept != t) {
      std::copy_n(mesh.indices.begin() + 3 * t, 3, mesh.indices.begin() + 3 * kept);
      mesh.materials[kept] = mesh.materials[t];
    }
    ++kept;
  }
  mesh.indices.resize(3 * kept);
  mesh.materials.resize(kept);
  return triangles - kept;
}

// FNV-1a over the 32-bit words of a key of float bit patterns.
struct WordsHash {
  template <size_t N>
  size_t operator()(const std::array<uint32_t, N>& k) const {
    uint64_t h = 1469598103934665603ull;
    for (const uint32_t w : k) h = (h ^ w) * 1099511628211ull;
    return static_cast<size_t>(h);
  }
};

std::string counted(size_t n, const char* singular, const char* plural) {
  return fmt::format("{} {}", n, n == 1 ? singular : plural);
}

}  // namespace

std::string MeshCleanReport::toString() const {
  std::vector<std::string> dropped;
  if (nonFiniteTriangles > 0) {
    dropped.push_back(counted(nonFiniteTriangles, "triangle with NaN/Inf vertices",
                              "triangles with NaN/Inf vertices"));
  }
  if (degenerateTriangles > 0) {
    dropped.push_back(counted(degenerateTriangles, "degenerate (zero-area) triangle",
                              "degenerate (zero-area) triangles"));
  }
  if (badIndices > 0) {
    dropped.push_back(counted(badIndices, "triangle with out-of-range vertex indices",
                              "triangles with out-of-range vertex indices"));
  }
  std::vector<std::string> parts;
  if (!dropped.empty()) parts.push_back("dropped " + fmt::format("{}", fmt::join(dropped, ", ")));
  if (badNormals > 0) {
    parts.push_back(counted(badNormals, "vertex normal", "vertex normals") +
                    " missing, zero or non-finite (face normal used)");
  }
  if (badUvs > 0) {
    parts.push_back(counted(badUvs, "non-finite uv", "non-finite uvs") + " set to 0");
  }
  return fmt::format("{}", fmt::join(parts, "; "));
}

MeshCleanReport cleanMesh(MeshData& mesh) {
  PBGI_CHECK_EQ(mesh.indices.size() % 3, size_t{0});
  PBGI_CHECK_EQ(mesh.materials.size(), mesh.triangleCount());
  PBGI_CHECK(mesh.normals.empty() || mesh.normals.size() == mesh.positions.size());
  PBGI_CHECK(mesh.uvs.empty() || mesh.uvs.size() == mesh.positions.size());

  MeshCleanReport report;
  keepTriangles(mesh, [&](size_t t) {
    switch (classify(mesh, t)) {
      case TriangleFault::kBadIndex:
        ++report.badIndices;
        return false;
      case TriangleFault::kNonFinite:
        ++report.nonFiniteTriangles;
        return false;
      case TriangleFault::kDegenerate:
        ++report.degenerateTriangles;
        return false;
      case TriangleFault::kNone:
        break;
    }
    return true;
  });

  // Only vertices that a surviving triangle uses count towards the report: a NaN normal on a
  // vertex whose triangles were dropped already is not news. All of them are repaired.
  std::vector<bool> used(mesh.positions.size(), false);
  for (uint32_t i : mesh.indices) used[i] = true;

  for (size_t v = 0; v < mesh.normals.size(); ++v) {
    Vec3f& n = mesh.normals[v];
    const float len2 = isFinite(n) ? n.length2() : 0.0f;
    if (len2 > 0.0f && std::isfinite(len2)) {
      if (std::abs(len2 - 1.0f) > kUnitLengthTolerance) n = normalize(n);
      continue;
    }
    // Imath's normalize() copes with lengths that underflow when squared; it returns zero
    // only for the zero vector.
    if (isFinite(n) && (n.x != 0.0f || n.y != 0.0f || n.z != 0.0f)) {
      n = normalize(n);
      if (isFinite(n) && n.length2() > 0.0f) continue;
    }
    n = Vec3f(0.0f);
    if (used[v]) ++report.badNormals;
  }
  for (size_t v = 0; v < mesh.uvs.size(); ++v) {
    Vec2f& uv = mesh.uvs[v];
    if (isFinite2(uv)) continue;
    uv = Vec2f(0.0f);
    if (used[v]) ++report.badUvs;
  }
  return report;
}

size_t joinIdenticalVertices(MeshData& mesh) {
  using Key = std::array<uint32_t, 8>;
  const size_t count = mesh.positions.size();
  auto bits = [](float f) { return std::bit_cast<uint32_t>(f); };
  std::unordered_map<Key, uint32_t, WordsHash> first;
  first.reserve(count);
  std::vector<uint32_t> remap(count);
  size_t kept = 0;
  for (size_t v = 0; v < count; ++v) {
    Key k{};
    const Vec3f& p = mesh.positions[v];
    k[0] = bits(p.x), k[1] = bits(p.y), k[2] = bits(p.z);
    if (!mesh.normals.empty()) {
      const Vec3f& n = mesh.normals[v];
      k[3] = bits(n.x), k[4] = bits(n.y), k[5] = bits(n.z);
    }
    if (!mesh.uvs.empty()) k[6] = bits(mesh.uvs[v].x), k[7] = bits(mesh.uvs[v].y);
    const auto [it, added] = first.try_emplace(k, static_cast<uint32_t>(kept));
    remap[v] = it->second;
    if (!added) continue;
    if (kept != v) {
      mesh.positions[kept] = mesh.positions[v];
      if (!mesh.normals.empty()) mesh.normals[kept] = mesh.normals[v];
      if (!mesh.uvs.empty()) mesh.uvs[kept] = mesh.uvs[v];
    }
    ++kept;
  }
  for (uint32_t& i : mesh.indices) {
    if (i < count) i = remap[i];  // an out-of-range index stays so for cleanMesh to report
  }
  mesh.positions.resize(kept);
  if (!mesh.normals.empty()) mesh.normals.resize(kept);
  if (!mesh.uvs.empty()) mesh.uvs.resize(kept);
  return count - kept;
}

struct TriangleSet::Impl {
  using Key = std::array<uint32_t, 9>;
  std::unordered_set<Key, WordsHash> seen;
};

TriangleSet::TriangleSet() : impl_(std::make_unique<Impl>()) {}
TriangleSet::~TriangleSet() = default;

size_t TriangleSet::dropCoincident(MeshData& mesh) {
  return keepTriangles(mesh, [&](size_t t) {
    std::array<std::array<uint32_t, 3>, 3> corners;
    for (int c = 0; c < 3; ++c) {
      const Vec3f& p = mesh.positions.at(mesh.indices[3 * t + c]);
      corners[c] = {std::bit_cast<uint32_t>(p.x), std::bit_cast<uint32_t>(p.y),
                    std::bit_cast<uint32_t>(p.z)};
    }
    std::sort(corners.begin(), corners.end());
    Impl::Key key;
    for (int c = 0; c < 3; ++c) std::copy_n(corners[c].begin(), 3, key.begin() + 3 * c);
    return impl_->seen.insert(key).second;
  });
}

}  // namespace pbgi
