#include "core/pbgi/wavelet.h"

#include <algorithm>
#include <bit>
#include <cmath>

#include "core/pbgi/sh.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

// Each face: its main axis and the two axes u and v run along (u along s, v along t).
struct FaceAxes {
  int main;
  float sign;
  int s, t;
};
constexpr std::array<FaceAxes, 6> kFaces = {{
    {0, 1.0f, 1, 2},
    {0, -1.0f, 1, 2},
    {1, 1.0f, 2, 0},
    {1, -1.0f, 2, 0},
    {2, 1.0f, 0, 1},
    {2, -1.0f, 0, 1},
}};

// The solid angle of the part of a face, at distance 1 from the centre, between the origin
// of its plane and (a, b) (signed): the standard closed form.
double cornerSolidAngle(double a, double b) {
  return std::atan2(a * b, std::sqrt(a * a + b * b + 1.0));
}

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

CubeCoord cubeCoord(const Vec3f& dir) {
  const float ax = std::abs(dir.x), ay = std::abs(dir.y), az = std::abs(dir.z);
  const int axis = (ax >= ay && ax >= az) ? 0 : (ay >= az ? 1 : 2);
  const int face = 2 * axis + (dir[axis] < 0.0f ? 1 : 0);
  const FaceAxes& f = kFaces[face];
  const float m = std::abs(dir[axis]);
  constexpr float kBelowOne = 0.99999994f;  // the largest float below 1
  CubeCoord c;
  c.face = face;
  c.u = std::clamp(0.5f * (dir[f.s] / m + 1.0f), 0.0f, kBelowOne);
  c.v = std::clamp(0.5f * (dir[f.t] / m + 1.0f), 0.0f, kBelowOne);
  return c;
}

Vec3f cubeDirection(int face, float u, float v) {
  PBGI_CHECK(face >= 0 && face < 6);
  const FaceAxes& f = kFaces[face];
  Vec3f d(0.0f);
  d[f.main] = f.sign;
  d[f.s] = 2.0f * u - 1.0f;
  d[f.t] = 2.0f * v - 1.0f;
  return normalize(d);
}

float cubeTexelSolidAngle(int n, int x, int y) {
  const double a0 = 2.0 * x / n - 1.0, a1 = 2.0 * (x + 1) / n - 1.0;
  const double b0 = 2.0 * y / n - 1.0, b1 = 2.0 * (y + 1) / n - 1.0;
  return static_cast<float>(cornerSolidAngle(a1, b1) - cornerSolidAngle(a0, b1) -
                            cornerSolidAngle(a1, b0) + cornerSolidAngle(a0, b0));
}

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
  PBGI_CHECK(n > 0);
  struct Texel {
    Vec3f dir;
    float solidAngle;
    float value;
  };
  std::vector<Texel> texels;
  texels.reserve(6 * static_cast<size_t>(n) * n);
  std::array<double, kShCoefficients> projection{};
  float basis[kShCoefficients];
  for (int face = 0; face < 6; ++face) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        Texel t;
        t.dir = cubeDirection(face, (x + 0.5f) / n, (y + 0.5f) / n);
        t.solidAngle = cubeTexelSolidAngle(n, x, y);
        t.value = f(t.dir);
        if (!std::isfinite(t.value)) t.value = 0.0f;
        evalShBasis(t.dir, basis);
        for (int i = 0; i < kShCoefficients; ++i) {
          projection[i] += double{t.value} * basis[i] * t.solidAngle;
        }
        texels.push_back(t);
      }
    }
  }
  double error = 0.0, norm = 0.0;
  for (const Texel& t : texels) {
    evalShBasis(t.dir, basis);
    double approx = 0.0;
    for (int i = 0; i < kShCoefficients; ++i) approx += projection[i] * basis[i];
    error += (t.value - approx) * (t.value - approx) * t.solidAngle;
    norm += double{t.value} * t.value * t.solidAngle;
  }
  return norm > 0.0 ? static_cast<float>(std::sqrt(error / norm)) : 0.0f;
}

WaveletRadiance WaveletRadiance::project(const std::function<Rgb(const Vec3f&)>& radiance, int n,
                                         float threshold) {
  PBGI_CHECK(isPowerOfTwo(n) && n <= 256);
  PBGI_CHECK(threshold >= 0.0f);
  WaveletRadiance w;
  w.n_ = n;
  const size_t texels = static_cast<size_t>(n) * n;
  std::array<std::vector<float>, 3> channel;
  for (auto& c : channel) c.resize(texels);
  double dropped = 0.0;
  const float threshold2 = threshold * threshold;
  for (int face = 0; face < 6; ++face) {
    for (int y = 0; y < n; ++y) {
      for (int x = 0; x < n; ++x) {
        Rgb value = radiance(cubeDirection(face, (x + 0.5f) / n, (y + 0.5f) / n));
        if (!isFinite(value)) {
          value = Rgb(0.0f);
          ++w.nonFinite_;
        }
        for (int c = 0; c < 3; ++c) channel[c][static_cast<size_t>(y) * n + x] = value[c];
      }
    }
    for (auto& c : channel) haarForward(c, n);
    WaveletFace& out = w.faces_[face];
    out.scaling = Rgb(channel[0][0], channel[1][0], channel[2][0]);
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
            node.detail[k] = Rgb(channel[0][at[k]], channel[1][at[k]], channel[2][at[k]]);
            norm2 += node.detail[k].length2();
          }
          if (norm2 > threshold2 && norm2 > 0.0f) {
            out.nodes.push_back(node);
          } else {
            dropped += norm2;
          }
        }
      }
    }
  }
  w.rmsError_ = static_cast<float>(std::sqrt(dropped / (6.0 * 3.0 * static_cast<double>(texels))));
  return w;
}

Rgb WaveletRadiance::evaluate(const Vec3f& dir) const {
  if (n_ == 0) return Rgb(0.0f);
  const CubeCoord c = cubeCoord(dir);
  const WaveletFace& face = faces_[c.face];
  const int px = std::min(n_ - 1, static_cast<int>(c.u * n_));
  const int py = std::min(n_ - 1, static_cast<int>(c.v * n_));
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
