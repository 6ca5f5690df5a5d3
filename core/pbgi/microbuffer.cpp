#include "core/pbgi/microbuffer.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <mutex>
#include <numbers>

#include "core/math/solid_angle.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

struct FaceAxes {
  int a, b, c;  // looking along a, u along b, v along c
  float sign;   // +1 towards +a, -1 towards -a
};

FaceAxes faceAxes(int f) {
  const int a = f >> 1;
  return {a, (a + 1) % 3, (a + 2) % 3, (f & 1) ? -1.0f : 1.0f};
}

// Solid angle of the rectangle [0, x] x [0, y] of the plane at distance 1, seen from the
// origin, signed by the signs of x and y (Mathar, "Solid angle of a rectangular plate"):
// rectangles then add and subtract like areas.
double cornerSolidAngle(double x, double y) {
  return std::atan2(x * y, std::sqrt(1.0 + x * x + y * y));
}

// The unit direction through face coordinates (u, v).
void unitThroughFace(const FaceAxes& axes, double u, double v, Vec3d& out) {
  double p[3];
  p[axes.a] = axes.sign;
  p[axes.b] = u;
  p[axes.c] = v;
  const double len = std::sqrt(p[0] * p[0] + p[1] * p[1] + p[2] * p[2]);
  for (int i = 0; i < 3; ++i) out[i] = p[i] / len;
}

std::shared_ptr<const MicrobufferTables> computeTables(int n) {
  auto tables = std::make_shared<MicrobufferTables>();
  tables->resolution = n;
  const size_t count = static_cast<size_t>(kCubeFaces) * n * n;
  tables->directions.resize(count);
  tables->solidAngles.resize(count);
  tables->widths.resize(count);
  tables->inverseWidths.resize(count);
  tables->vectorSolidAngles.resize(count);
  const double step = 2.0 / n;
  for (int f = 0; f < kCubeFaces; ++f) {
    const FaceAxes axes = faceAxes(f);
    auto unit = [&](double u, double v, Vec3d& out) { unitThroughFace(axes, u, v, out); };
    for (int j = 0; j < n; ++j) {
      const double v0 = -1.0 + j * step, v1 = v0 + step;
      for (int i = 0; i < n; ++i) {
        const double u0 = -1.0 + i * step, u1 = u0 + step;
        const size_t k = (static_cast<size_t>(f) * n + j) * n + i;
        const double omega = cubeRectSolidAngle(u0, u1, v0, v1);
        tables->solidAngles[k] = static_cast<float>(omega);
        tables->widths[k] = static_cast<float>(std::sqrt(omega));
        tables->inverseWidths[k] = static_cast<float>(1.0 / std::sqrt(omega));
        Vec3d center;
        unit(0.5 * (u0 + u1), 0.5 * (v0 + v1), center);
        tables->directions[k] = Vec3f(static_cast<float>(center[0]), static_cast<float>(center[1]),
                                      static_cast<float>(center[2]));
        // The integral of the direction over the pixel, pointing into it.
        std::array<Vec3d, 4> corners;
        unit(u0, v0, corners[0]);
        unit(u1, v0, corners[1]);
        unit(u1, v1, corners[2]);
        unit(u0, v1, corners[3]);
        const Vec3d vsa = vectorSolidAngle(corners, center);
        tables->vectorSolidAngles[k] = Vec3f(static_cast<float>(vsa[0]),
                                             static_cast<float>(vsa[1]),
                                             static_cast<float>(vsa[2]));
        tables->maxWidth = std::max(tables->maxWidth, tables->widths[k]);
      }
    }
  }
  return tables;
}

}  // namespace

std::shared_ptr<const MicrobufferTables> microbufferTables(int resolution) {
  PBGI_CHECK_GE(resolution, kMinMicrobufferResolution);
  PBGI_CHECK_LE(resolution, kMaxMicrobufferResolution);
  static std::mutex mutex;
  static std::array<std::shared_ptr<const MicrobufferTables>, kMaxMicrobufferResolution + 1> cache;
  std::lock_guard lock(mutex);
  auto& entry = cache[resolution];
  if (!entry) entry = computeTables(resolution);
  return entry;
}

Microbuffer::Microbuffer(int resolution)
    : n_(resolution),
      tables_(microbufferTables(resolution)),
      directions_(tables_->directions.data()),
      solidAngles_(tables_->solidAngles.data()),
      inverseWidths_(tables_->inverseWidths.data()),
      vectorSolidAngles_(tables_->vectorSolidAngles.data()),
      pixels_(tables_->directions.size()) {
  scratch_.reserve(tables_->directions.size());
  clear(Vec3f(0.0f));
}

void Microbuffer::clear(const Vec3f& origin) {
  origin_ = origin;
  std::fill(pixels_.begin(), pixels_.end(), Pixel{});
  std::fill(std::begin(faceActive_), std::end(faceActive_), true);
  skippedFaces_ = 0;
  skippedPixels_ = 0;
}

void Microbuffer::clear(const Vec3f& origin, const Vec3f& normal) {
  origin_ = origin;
  std::fill(pixels_.begin(), pixels_.end(), Pixel{});
  skippedFaces_ = 0;
  skippedPixels_ = 0;
  const int facePixels = n_ * n_;
  for (int f = 0; f < kCubeFaces; ++f) {
    const FaceAxes axes = faceAxes(f);
    // The face's directions are positive combinations of its corners, so the largest dot
    // product with the normal is at a corner: sign * n_a + |n_b| + |n_c|.
    const float maxDot =
        axes.sign * normal[axes.a] + std::abs(normal[axes.b]) + std::abs(normal[axes.c]);
    Pixel* pixels = pixels_.data() + f * facePixels;
    const Vec3f* dirs = directions_ + f * facePixels;
    if (!(maxDot > 0.0f)) {
      faceActive_[f] = false;
      for (int k = 0; k < facePixels; ++k) pixels[k].front.depth = 0.0f;
      ++skippedFaces_;
      skippedPixels_ += facePixels;
      continue;
    }
    faceActive_[f] = true;
    for (int k = 0; k < facePixels; ++k) {
      const bool above = dot(dirs[k], normal) > 0.0f;
      pixels[k].front.depth = above ? kEmpty : 0.0f;
      skippedPixels_ += above ? 0 : 1;
    }
  }
}

CubePoint cubePoint(const Vec3f& dir) {
  const float ax = std::abs(dir.x), ay = std::abs(dir.y), az = std::abs(dir.z);
  const int a = (ax >= ay && ax >= az) ? 0 : (ay >= az ? 1 : 2);
  const int f = 2 * a + (dir[a] < 0.0f ? 1 : 0);
  const FaceAxes axes = faceAxes(f);
  const float inv = 1.0f / std::abs(dir[a]);
  return {f, dir[axes.b] * inv, dir[axes.c] * inv};
}

Vec3f cubeDirection(int face, double u, double v) {
  Vec3d d;
  unitThroughFace(faceAxes(face), u, v, d);
  return Vec3f(static_cast<float>(d[0]), static_cast<float>(d[1]), static_cast<float>(d[2]));
}

double cubeRectSolidAngle(double u0, double u1, double v0, double v1) {
  return cornerSolidAngle(u1, v1) - cornerSolidAngle(u0, v1) - cornerSolidAngle(u1, v0) +
         cornerSolidAngle(u0, v0);
}

int cubePixelIndex(const Vec3f& dir, int n) {
  const CubePoint c = cubePoint(dir);
  const float half = 0.5f * static_cast<float>(n);
  const int i = std::clamp(static_cast<int>(std::floor((c.u + 1.0f) * half)), 0, n - 1);
  const int j = std::clamp(static_cast<int>(std::floor((c.v + 1.0f) * half)), 0, n - 1);
  return (c.face * n + j) * n + i;
}

int Microbuffer::pixelIndex(const Vec3f& dir) const { return cubePixelIndex(dir, n_); }

bool Microbuffer::coneRect(int f, const Vec3f& dir, float sinAngle, float cosAngle,
                           PixelRect* rect) const {
  const FaceAxes axes = faceAxes(f);
  const float d = axes.sign * dir[axes.a];
  const PixelRect full{0, n_ - 1, 0, n_ - 1};
  // A cone of half-angle 90 degrees or more reaches every face.
  if (cosAngle <= 0.0f) {
    *rect = full;
    return true;
  }
  // The face is the intersection of four half-spaces through the origin, sign * w_a >= |w_b|
  // and >= |w_c|; a cone that misses one of them (its axis more than its half-angle on the
  // wrong side of the plane) misses the face.
  const float margin = -sinAngle * std::numbers::sqrt2_v<float>;
  if (d - std::abs(dir[axes.b]) < margin || d - std::abs(dir[axes.c]) < margin) return false;
  // Straddling the plane, the cone's trace on the face is unbounded: try the whole face.
  // This only happens for cones wider than about 35 degrees, which cover much of it anyway.
  if (d <= sinAngle) {
    *rect = full;
    return true;
  }
  // In front of the plane, u = w_b / (sign w_a) is extreme where a plane through the origin
  // containing the face's v axis touches the cone: (d_b - u d)^2 = sin^2 (1 + u^2).
  const float s2 = sinAngle * sinAngle;
  const float k = d * d - s2;
  const float half = 0.5f * static_cast<float>(n_);
  auto range = [&](float db, int* lo, int* hi) {
    const float root = sinAngle * safeSqrt(d * d + db * db - s2);
    // A little slack so that rounding never drops a pixel centre on the boundary; the dot
    // or intersection test that follows is the authority.
    const float slack = 1e-4f;
    const float u0 = std::clamp((db * d - root) / k - slack, -2.0f, 2.0f);
    const float u1 = std::clamp((db * d + root) / k + slack, -2.0f, 2.0f);
    *lo = static_cast<int>(std::floor((u0 + 1.0f) * half));
    *hi = static_cast<int>(std::floor((u1 + 1.0f) * half));
    if (*hi < 0 || *lo > n_ - 1) return false;
    *lo = std::max(*lo, 0);
    *hi = std::min(*hi, n_ - 1);
    return true;
  };
  return range(dir[axes.b], &rect->i0, &rect->i1) && range(dir[axes.c], &rect->j0, &rect->j1);
}

bool Microbuffer::compose(int k, float distance, float extent, float alpha, const Rgb& radiance) {
  return pixels_[k].compose(distance, extent, alpha, radiance * alpha);
}

void Microbuffer::composeBuffer(const Microbuffer& other) {
  PBGI_CHECK_EQ(other.n_, n_);
  for (size_t k = 0; k < pixels_.size(); ++k) {
    const Pixel& from = other.pixels_[k];
    if (!(from.front.coverage > 0.0f) || !(from.front.depth > 0.0f)) continue;
    Pixel& to = pixels_[k];
    for (const DepthLayer* layer : {&from.front, &from.back}) {
      if (!(layer->coverage > 0.0f) || layer->depth == kEmpty) continue;
      to.compose(layer->depth, layer->extent, layer->coverage, layer->radiance);
    }
  }
}

int Microbuffer::splatFootprint(const Vec3f& dir, float distance, float solidAngle,
                                const Rgb& radiance, float extent) {
  if (!(distance > 0.0f) || !(solidAngle > 0.0f)) return 0;
  solidAngle = std::min(solidAngle, 4.0f * kPi);
  // Distances on the sphere as chords |w - dir|: a cap of solid angle w has
  // 1 - cos(angle) = w / (2 pi), and its rim lies at chord sqrt(2 (1 - cos)).
  const float rimChord = std::sqrt(solidAngle * kInvPi);
  // A pixel centre up to half a pixel outside the rim is still partly covered.
  const float reach = rimChord + 0.5f * tables_->maxWidth;
  const float cosReach = std::max(-1.0f, 1.0f - 0.5f * reach * reach);
  const float sinReach = safeSqrt(1.0f - cosReach * cosReach);
  // First pass: the fractions by a linear ramp one pixel wide across the rim, over every
  // face (below the horizon too: what falls there is lost, not given to the rest).
  scratch_.clear();
  float full = 0.0f, partial = 0.0f, room = 0.0f;
  auto fractions = [&](int f, const PixelRect& r) {
    for (int j = r.j0; j <= r.j1; ++j) {
      const int row = (f * n_ + j) * n_;
      for (int k = row + r.i0; k <= row + r.i1; ++k) {
        const float chord = safeSqrt(2.0f - 2.0f * dot(directions_[k], dir));
        const float alpha = 0.5f + (rimChord - chord) * inverseWidths_[k];
        if (!(alpha > 0.0f)) continue;
        if (alpha >= 1.0f) {
          full += solidAngles_[k];
          scratch_.push_back({k, 1.0f});
        } else {
          partial += alpha * solidAngles_[k];
          room += (1.0f - alpha) * solidAngles_[k];
          scratch_.push_back({k, alpha});
        }
      }
    }
  };
  for (int f = 0; f < kCubeFaces; ++f) {
    PixelRect rect;
    if (coneRect(f, dir, sinReach, cosReach, &rect)) fractions(f, rect);
  }
  if (scratch_.empty()) {
    // Smaller than a pixel and between centres: a fraction of the pixel it lies in.
    const int k = pixelIndex(dir);
    return compose(k, distance, extent, std::min(1.0f, solidAngle / solidAngles_[k]), radiance) ? 1
                                                                                                : 0;
  }
  // Make the splat cover exactly its solid angle. Usually the rim makes up what the interior
  // lacks by scaling its fractions; when that would push them past 1 (a cap so wide that its
  // rim wraps around the sphere) they grow towards 1 instead; when the interior alone covers
  // too much (a footprint of a pixel or two), everything shrinks alike.
  const float lack = solidAngle - full;
  float interior = 1.0f, scale = 0.0f, fill = 0.0f;
  if (lack < 0.0f) {
    interior = scale = solidAngle / (full + partial);
  } else if (lack <= partial) {
    scale = lack / partial;
  } else {
    scale = 1.0f;
    fill = room > 0.0f ? std::min(1.0f, (lack - partial) / room) : 0.0f;
  }
  int reached = 0;
  for (const Fraction& fr : scratch_) {
    const float alpha = fr.alpha >= 1.0f ? interior : fr.alpha * scale + (1.0f - fr.alpha) * fill;
    if (alpha > 0.0f && compose(fr.pixel, distance, extent, alpha, radiance)) ++reached;
  }
  return reached;
}

int Microbuffer::splatCluster(const Vec3f& centroid, float projectedArea, const Rgb& radiance,
                              float extent) {
  const Vec3f v = centroid - origin_;
  const float distance = length(v);
  if (!(distance > 0.0f)) return 0;
  return splatFootprint(v / distance, distance, projectedArea / (distance * distance), radiance,
                        extent);
}

int Microbuffer::diskRect(int f, const PixelRect& r, const Vec3f& toCenter, const Vec3f& normal,
                          float radius, const Rgb& radiance) {
  // The centre ray w hits the disk's plane at t = dot(c - o, n) / dot(w, n); the disk faces
  // the origin, so only rays with dot(w, n) < 0 reach its front.
  const float planeDistance = dot(toCenter, normal);  // < 0: the origin is in front
  const float r2 = radius * radius;
  int won = 0;
  for (int j = r.j0; j <= r.j1; ++j) {
    const int row = (f * n_ + j) * n_;
    for (int k = row + r.i0; k <= row + r.i1; ++k) {
      const Vec3f& w = directions_[k];
      const float denom = dot(w, normal);
      if (!(denom < 0.0f)) continue;
      const float t = planeDistance / denom;
      if ((w * t - toCenter).length2() > r2) continue;
      if (compose(k, t, radius, 1.0f, radiance)) ++won;
    }
  }
  return won;
}

int Microbuffer::splatDisk(const Vec3f& center, const Vec3f& normal, float radius,
                           const Rgb& radiance, float extent) {
  const Vec3f v = center - origin_;
  const float distance = length(v);
  if (!(distance > 0.0f) || !(radius > 0.0f)) return 0;
  const float facing = -dot(v, normal) / distance;
  if (!(facing > 0.0f)) return 0;  // seen from behind or edge-on
  // The solid angle of a disk seen face-on, 2 pi (1 - d / sqrt(d^2 + r^2)) (written without
  // the cancellation), times the cosine it is seen at.
  const float s = std::sqrt(distance * distance + radius * radius);
  const float solidAngle = 2.0f * kPi * radius * radius * facing / (s * (s + distance));
  return splatFootprint(v / distance, distance, solidAngle, radiance, extent);
}

int Microbuffer::rayCastDisk(const Vec3f& center, const Vec3f& normal, float radius,
                             const Rgb& radiance) {
  const Vec3f v = center - origin_;
  if (!(dot(v, normal) < 0.0f) || !(radius > 0.0f)) return 0;  // seen from behind or edge-on
  const float distance = length(v);
  // Every ray that hits the disk lies in the cone around its centre that holds its bounding
  // sphere, when the origin is outside that sphere.
  const float sinAngle = std::min(1.0f, radius / distance);
  const float cosAngle = safeSqrt(1.0f - sinAngle * sinAngle);
  const Vec3f dir = v / distance;
  const PixelRect full{0, n_ - 1, 0, n_ - 1};
  int reached = 0;
  for (int f = 0; f < kCubeFaces; ++f) {
    PixelRect r = full;
    if (!faceActive_[f] || (sinAngle < 1.0f && !coneRect(f, dir, sinAngle, cosAngle, &r))) {
      continue;
    }
    reached += diskRect(f, r, v, normal, radius, radiance);
  }
  return reached;
}

Rgb Microbuffer::irradiance(const Vec3f& normal) const {
  // Empty and inactive pixels are black, so every pixel of an active face can be summed.
  Rgb sum(0.0f);
  const int facePixels = n_ * n_;
  for (int f = 0; f < kCubeFaces; ++f) {
    if (!faceActive_[f]) continue;
    for (int k = f * facePixels; k < (f + 1) * facePixels; ++k) {
      const float c = dot(vectorSolidAngles_[k], normal);
      if (c > 0.0f) sum += radiance(k) * c;
    }
  }
  return sum;
}

int Microbuffer::coveredPixels() const {
  int count = 0;
  for (int k = 0; k < pixelCount(); ++k) count += covered(k) ? 1 : 0;
  return count;
}

float Microbuffer::coveredSolidAngle() const {
  double sum = 0.0;
  for (int k = 0; k < pixelCount(); ++k) sum += coverage(k) * solidAngles_[k];
  return static_cast<float>(sum);
}

}  // namespace pbgi
