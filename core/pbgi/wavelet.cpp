#include "core/pbgi/wavelet.h"

#include <algorithm>
#include <bit>
#include <cmath>

#include <fmt/format.h>

#include "core/pbgi/sh.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

bool isPowerOfTwo(int n) { return n > 0 && (n & (n - 1)) == 0; }

int log2Of(int n) { return std::countr_zero(static_cast<unsigned>(n)); }

// The node's place among every level's nodes: levels above come first.
uint32_t nodeKey(int level, int x, int y) {
  const uint32_t above = ((uint32_t{1} << (2 * level)) - 1) / 3;
  return above + (static_cast<uint32_t>(y) << level) + static_cast<uint32_t>(x);
}

constexpr float kInvSqrt2 = 0.70710678118654752f;

// One analysis step along a line of `count` values (count even), stride `stride`.
void analyse(float* line, int count, int stride, std::vector<float>& scratch) {
  const int half = count / 2;
  scratch.resize(count);
  for (int i = 0; i < half; ++i) {
    const float a = line[(2 * i) * stride], b = line[(2 * i + 1) * stride];
    scratch[i] = (a + b) * kInvSqrt2;
    scratch[half + i] = (a - b) * kInvSqrt2;
  }
  for (int i = 0; i < count; ++i) line[i * stride] = scratch[i];
}

void synthesise(float* line, int count, int stride, std::vector<float>& scratch) {
  const int half = count / 2;
  scratch.resize(count);
  for (int i = 0; i < half; ++i) {
    const float s = line[i * stride], d = line[(half + i) * stride];
    scratch[2 * i] = (s + d) * kInvSqrt2;
    scratch[2 * i + 1] = (s - d) * kInvSqrt2;
  }
  for (int i = 0; i < count; ++i) line[i * stride] = scratch[i];
}

}  // namespace

void haarForward(std::span<float> image, int n) {
  PBGI_CHECK(isPowerOfTwo(n));
  PBGI_CHECK_EQ(image.size(), static_cast<size_t>(n) * n);
  std::vector<float> scratch;
  for (int size = n; size >= 2; size /= 2) {
    for (int y = 0; y < size; ++y) analyse(&image[static_cast<size_t>(y) * n], size, 1, scratch);
    for (int x = 0; x < size; ++x) analyse(&image[x], size, n, scratch);
  }
}

void haarInverse(std::span<float> image, int n) {
  PBGI_CHECK(isPowerOfTwo(n));
  PBGI_CHECK_EQ(image.size(), static_cast<size_t>(n) * n);
  std::vector<float> scratch;
  for (int size = 2; size <= n; size *= 2) {
    for (int x = 0; x < size; ++x) synthesise(&image[x], size, n, scratch);
    for (int y = 0; y < size; ++y) synthesise(&image[static_cast<size_t>(y) * n], size, 1, scratch);
  }
}

float shProjectionError(const std::function<float(const Vec3f&)>& f, int n) {
  const std::shared_ptr<const MicrobufferTables> cube = microbufferTables(n);
  const size_t count = cube->directions.size();
  std::vector<float> values(count);
  std::array<double, kShCoefficients> projection{};
  float basis[kShCoefficients];
  for (size_t k = 0; k < count; ++k) {
    values[k] = f(cube->directions[k]);
    if (!std::isfinite(values[k])) values[k] = 0.0f;
    evalShBasis(cube->directions[k], basis);
    for (int i = 0; i < kShCoefficients; ++i) {
      projection[i] += double{values[k]} * basis[i] * cube->solidAngles[k];
    }
  }
  double error = 0.0, norm = 0.0;
  for (size_t k = 0; k < count; ++k) {
    evalShBasis(cube->directions[k], basis);
    double approx = 0.0;
    for (int i = 0; i < kShCoefficients; ++i) approx += projection[i] * basis[i];
    error += (values[k] - approx) * (values[k] - approx) * cube->solidAngles[k];
    norm += double{values[k]} * values[k] * cube->solidAngles[k];
  }
  return norm > 0.0 ? static_cast<float>(std::sqrt(error / norm)) : 0.0f;
}

WaveletRadiance WaveletRadiance::project(const std::function<Rgb(const Vec3f&)>& radiance, int n,
                                         float threshold) {
  PBGI_CHECK(isPowerOfTwo(n) && n <= kMaxMicrobufferResolution);
  const std::shared_ptr<const MicrobufferTables> cube = microbufferTables(n);
  std::vector<Rgb> values(cube->directions.size());
  for (size_t t = 0; t < values.size(); ++t) values[t] = radiance(cube->directions[t]);
  return fromTexels(values, n, threshold);
}

WaveletRadiance WaveletRadiance::fromTexels(std::span<const Rgb> values, int n, float threshold) {
  PBGI_CHECK(isPowerOfTwo(n) && n <= kMaxMicrobufferResolution);
  PBGI_CHECK(threshold >= 0.0f);
  const size_t texels = static_cast<size_t>(n) * n;
  PBGI_CHECK_EQ(values.size(), 6 * texels);
  std::vector<float> coefficients(6 * 3 * texels);
  uint64_t nonFinite = 0;
  for (int face = 0; face < 6; ++face) {
    float* channel = &coefficients[face * 3 * texels];
    for (size_t k = 0; k < texels; ++k) {
      Rgb value = values[face * texels + k];
      if (!isFinite(value)) {
        value = Rgb(0.0f);
        ++nonFinite;
      }
      for (int c = 0; c < 3; ++c) channel[c * texels + k] = value[c];
    }
    for (int c = 0; c < 3; ++c) haarForward(std::span(channel + c * texels, texels), n);
  }
  WaveletRadiance w = fromDense(coefficients, n, threshold);
  w.nonFinite_ = nonFinite;
  return w;
}

WaveletRadiance WaveletRadiance::fromDense(std::span<const float> dense, int n, float threshold,
                                           float relativeError, size_t maxNodes) {
  PBGI_CHECK(isPowerOfTwo(n) && n <= kMaxMicrobufferResolution);
  const size_t texels = static_cast<size_t>(n) * n;
  PBGI_CHECK_EQ(dense.size(), 6 * 3 * texels);
  double total = 0.0;
  for (const float v : dense) total += double{v} * v;
  const float bound2 = threshold * threshold;
  WaveletRadiance w;
  w.n_ = n;
  double dropped = 0.0;
  struct Candidate {
    float norm2;
    int face;
    size_t node;
  };
  std::vector<Candidate> kept;
  for (int face = 0; face < 6; ++face) {
    const float* channel = &dense[face * 3 * texels];
    WaveletFace& out = w.faces_[face];
    out.scaling = Rgb(channel[0], channel[texels], channel[2 * texels]);
    for (int level = 0; (1 << level) < n; ++level) {
      const int side = 1 << level;
      for (int y = 0; y < side; ++y) {
        for (int x = 0; x < side; ++x) {
          const std::array<size_t, 3> at = {static_cast<size_t>(y) * n + side + x,
                                            static_cast<size_t>(side + y) * n + x,
                                            static_cast<size_t>(side + y) * n + side + x};
          WaveletFace::Node node;
          node.level = static_cast<uint16_t>(level);
          node.x = static_cast<uint16_t>(x);
          node.y = static_cast<uint16_t>(y);
          float norm2 = 0.0f;
          for (int k = 0; k < 3; ++k) {
            node.detail[k] = Rgb(channel[at[k]], channel[texels + at[k]], channel[2 * texels + at[k]]);
            norm2 += node.detail[k].length2();
          }
          if (norm2 > bound2 && norm2 > 0.0f) {
            kept.push_back({norm2, face, out.nodes.size()});
            out.nodes.push_back(node);
          } else {
            dropped += norm2;
          }
        }
      }
    }
  }
  // The error budget: the smallest nodes go while what is dropped stays within it; then at
  // most maxNodes of the largest stay.
  const double budget = double{relativeError} * relativeError * total;
  if ((budget > dropped && !kept.empty()) || (maxNodes > 0 && kept.size() > maxNodes)) {
    // Largest first; ties go to the earlier node, so the result is deterministic.
    std::stable_sort(kept.begin(), kept.end(),
                     [](const Candidate& a, const Candidate& b) { return a.norm2 > b.norm2; });
    size_t keepCount = kept.size();
    while (keepCount > 0 && dropped + kept[keepCount - 1].norm2 <= budget) {
      dropped += kept[--keepCount].norm2;
    }
    std::array<std::vector<bool>, 6> keep;
    for (int f = 0; f < 6; ++f) keep[f].assign(w.faces_[f].nodes.size(), false);
    for (size_t i = 0; i < keepCount; ++i) {
      if (maxNodes == 0 || i < maxNodes) {
        keep[kept[i].face][kept[i].node] = true;
      } else {
        dropped += kept[i].norm2;
      }
    }
    for (int f = 0; f < 6; ++f) {
      std::vector<WaveletFace::Node>& nodes = w.faces_[f].nodes;
      size_t to = 0;
      for (size_t i = 0; i < nodes.size(); ++i) {
        if (keep[f][i]) nodes[to++] = nodes[i];
      }
      nodes.resize(to);
    }
  }
  w.rmsError_ = static_cast<float>(std::sqrt(dropped / (6.0 * 3.0 * static_cast<double>(texels))));
  w.relativeError_ = total > 0.0 ? static_cast<float>(std::sqrt(dropped / total)) : 0.0f;
  return w;
}

std::vector<float> WaveletRadiance::dense() const {
  const size_t texels = static_cast<size_t>(n_) * n_;
  std::vector<float> out(6 * 3 * texels, 0.0f);
  for (int face = 0; face < 6; ++face) {
    float* channel = &out[face * 3 * texels];
    const WaveletFace& f = faces_[face];
    for (int c = 0; c < 3; ++c) channel[c * texels] = f.scaling[c];
    for (const WaveletFace::Node& node : f.nodes) {
      const size_t side = size_t{1} << node.level;
      const std::array<size_t, 3> at = {node.y * n_ + side + node.x,
                                        (side + node.y) * n_ + node.x,
                                        (side + node.y) * n_ + side + node.x};
      for (int k = 0; k < 3; ++k) {
        for (int c = 0; c < 3; ++c) channel[c * texels + at[k]] = node.detail[k][c];
      }
    }
  }
  return out;
}

WaveletRadiance WaveletRadiance::sum(std::span<const WaveletRadiance* const> parts,
                                     float threshold, float relativeError, size_t maxNodes) {
  int n = 0;
  for (const WaveletRadiance* p : parts) {
    if (p == nullptr || p->empty()) continue;
    PBGI_CHECK(n == 0 || p->n_ == n);
    n = p->n_;
  }
  if (n == 0) return WaveletRadiance();
  const size_t texels = static_cast<size_t>(n) * n;
  std::vector<float> total(6 * 3 * texels, 0.0f);
  for (const WaveletRadiance* p : parts) {
    if (p == nullptr || p->empty()) continue;
    const std::vector<float> d = p->dense();
    for (size_t i = 0; i < total.size(); ++i) total[i] += d[i];
  }
  return fromDense(total, n, threshold, relativeError, maxNodes);
}

absl::StatusOr<WaveletRadiance> WaveletRadiance::fromFaces(int n,
                                                           std::array<WaveletFace, 6> faces) {
  if (!isPowerOfTwo(n) || n > kMaxMicrobufferResolution) {
    return absl::InvalidArgumentError(
        fmt::format("wavelet resolution {}: expected a power of two up to {}", n,
                    kMaxMicrobufferResolution));
  }
  const int levels = log2Of(n);
  for (int f = 0; f < 6; ++f) {
    if (!isFinite(faces[f].scaling)) {
      return absl::InvalidArgumentError(fmt::format("wavelet face {}: scaling not finite", f));
    }
    int64_t last = -1;
    for (const WaveletFace::Node& node : faces[f].nodes) {
      if (node.level >= levels || node.x >= (1u << node.level) || node.y >= (1u << node.level)) {
        return absl::InvalidArgumentError(fmt::format(
            "wavelet face {}: node (level {}, {}, {}) outside the {} levels of a {}-texel face",
            f, node.level, node.x, node.y, levels, n));
      }
      const int64_t key = nodeKey(node.level, node.x, node.y);
      if (key <= last) {
        return absl::InvalidArgumentError(fmt::format(
            "wavelet face {}: node (level {}, {}, {}) out of pyramid order or repeated", f,
            node.level, node.x, node.y));
      }
      last = key;
      for (const Rgb& d : node.detail) {
        if (!isFinite(d)) {
          return absl::InvalidArgumentError(fmt::format(
              "wavelet face {}: node (level {}, {}, {}) has a detail that is not finite", f,
              node.level, node.x, node.y));
        }
      }
    }
  }
  WaveletRadiance w;
  w.n_ = n;
  w.faces_ = std::move(faces);
  return w;
}

Rgb WaveletRadiance::dot(const WaveletRadiance& other) const {
  if (n_ == 0 || other.n_ == 0) return Rgb(0.0f);
  PBGI_CHECK_EQ(n_, other.n_);
  Rgb sum(0.0f);
  for (int f = 0; f < 6; ++f) {
    const WaveletFace& a = faces_[f];
    const WaveletFace& b = other.faces_[f];
    sum += a.scaling * b.scaling;
    // Both node lists are in pyramid order: a merge finds the nodes both keep.
    auto i = a.nodes.begin();
    auto j = b.nodes.begin();
    while (i != a.nodes.end() && j != b.nodes.end()) {
      const uint32_t ki = nodeKey(i->level, i->x, i->y), kj = nodeKey(j->level, j->x, j->y);
      if (ki < kj) {
        ++i;
      } else if (kj < ki) {
        ++j;
      } else {
        for (int k = 0; k < 3; ++k) sum += i->detail[k] * j->detail[k];
        ++i;
        ++j;
      }
    }
  }
  return sum;
}

Rgb WaveletRadiance::evaluate(const Vec3f& dir) const {
  if (n_ == 0) return Rgb(0.0f);
  const int texel = cubePixelIndex(dir, n_);
  const int texels = n_ * n_;
  const WaveletFace& face = faces_[texel / texels];
  const int px = texel % n_, py = (texel % texels) / n_;
  Rgb value = face.scaling / static_cast<float>(n_);
  const int levels = log2Of(n_);
  auto next = face.nodes.begin();
  for (int level = 0; level < levels; ++level) {
    const int size = n_ >> level;  // pixels a side of this level's nodes
    const int x = px / size, y = py / size;
    const uint32_t key = nodeKey(level, x, y);
    next = std::lower_bound(next, face.nodes.end(), key, [](const WaveletFace::Node& node, uint32_t k) {
      return nodeKey(node.level, node.x, node.y) < k;
    });
    if (next == face.nodes.end()) break;
    if (nodeKey(next->level, next->x, next->y) != key) continue;
    const float sx = (px % size) < size / 2 ? 1.0f : -1.0f;
    const float sy = (py % size) < size / 2 ? 1.0f : -1.0f;
    value += (next->detail[0] * sx + next->detail[1] * sy + next->detail[2] * (sx * sy)) /
             static_cast<float>(size);
  }
  return value;
}

std::vector<Rgb> WaveletRadiance::reconstructFace(int face) const {
  PBGI_CHECK(face >= 0 && face < 6 && n_ > 0);
  const size_t texels = static_cast<size_t>(n_) * n_;
  std::array<std::vector<float>, 3> channel;
  for (auto& c : channel) c.assign(texels, 0.0f);
  const WaveletFace& f = faces_[face];
  for (int c = 0; c < 3; ++c) channel[c][0] = f.scaling[c];
  for (const WaveletFace::Node& node : f.nodes) {
    const size_t side = size_t{1} << node.level;
    const std::array<size_t, 3> at = {node.y * n_ + side + node.x, (side + node.y) * n_ + node.x,
                                      (side + node.y) * n_ + side + node.x};
    for (int k = 0; k < 3; ++k) {
      for (int c = 0; c < 3; ++c) channel[c][at[k]] = node.detail[k][c];
    }
  }
  for (auto& c : channel) haarInverse(c, n_);
  std::vector<Rgb> out(texels);
  for (size_t i = 0; i < texels; ++i) out[i] = Rgb(channel[0][i], channel[1][i], channel[2][i]);
  return out;
}

size_t WaveletRadiance::keptNodes() const {
  size_t count = 0;
  for (const WaveletFace& f : faces_) count += f.nodes.size();
  return count;
}

}  // namespace pbgi
