#pragma once
// A cube microbuffer (Christensen 2008; Ritschel et al. 2009): a tiny fisheye picture of the
// scene around one receiver, 6 faces of N x N pixels, that the gather rasterizes the PBGI
// tree into and then convolves with a BRDF (the clamped cosine for diffuse receivers).
//
// Face f looks along axis a = f / 2, towards +a for even f and -a for odd f. Its pixel (i, j)
// is the square [u0, u1] x [v0, v1] of the plane at distance 1, u along axis (a + 1) % 3 and
// v along (a + 2) % 3, u0 = -1 + 2 i / N; pixel index (f N + j) N + i. Each pixel is sampled
// at its centre direction and weighted by its exact solid angle.
//
// Coverage. Every splat covers pixels with a fraction alpha in (0, 1]: 1 where a ray-cast
// disk's exact hit or a footprint's interior holds the pixel centre, less on a footprint's rim and
// for splats smaller than a pixel, scaled so that a splat adds exactly its own solid angle. That
// keeps both a lone far cluster (a fraction of one pixel) and a surface tiled by clusters
// (round footprints that overlap and leave gaps) right in energy, where point-sampled
// all-or-nothing coverage is off by the gaps or by whole pixels.
//
// Depth. Each splat has a depth range (distance +- extent, about its size). A pixel
// keeps two layers, each a depth range with a coverage and a coverage-weighted radiance; a
// splat whose range overlaps a layer's is another piece of that surface and adds to it (so
// energy is kept where pieces overlap and lost where they leave gaps, on average even).
// A splat in front of the front layer becomes the front, the old front going over the back;
// one behind it joins the back layer, or goes over or under it. The pixel shows the front
// and as much of the back as fits in what the front leaves open: a solid splat (coverage 1)
// in front hides everything behind, which is the depth test, closer wins; a partly covered
// pixel shows what lies behind through its open part. Three or more layers in one pixel are
// approximated.
//
// A diffuse receiver only sees the hemisphere above its normal: clear(origin, normal) marks
// the pixels below it inactive and skips whole faces below it; splats never write there.
#include <algorithm>
#include <limits>
#include <memory>
#include <vector>

#include "core/math/vec.h"
#include "core/pbgi/layered_pixel.h"

namespace pbgi {

inline constexpr int kMinMicrobufferResolution = 1;
inline constexpr int kMaxMicrobufferResolution = 64;
inline constexpr int kCubeFaces = 6;

// What every buffer of one resolution shares: the pixels' unit centre directions, their
// exact solid angles (the atan2 form of the solid angle of a rectangle seen from a point on
// its normal through a corner, by inclusion-exclusion; they sum to 4 pi), their angular
// widths (square roots of those), and the integral of the direction over each pixel, which
// makes the clamped-cosine convolution exact for pixels entirely above the horizon.
struct MicrobufferTables {
  int resolution = 0;
  std::vector<Vec3f> directions;
  std::vector<float> solidAngles;
  std::vector<float> widths;
  std::vector<float> inverseWidths;
  std::vector<Vec3f> vectorSolidAngles;
  float maxWidth = 0.0f;
};

// The tables of resolution N (kMinMicrobufferResolution..kMaxMicrobufferResolution), computed
// once per N per process and shared; thread-safe.
std::shared_ptr<const MicrobufferTables> microbufferTables(int resolution);

// The pixel of an N x N cube whose square holds direction `dir` (any length but 0), in the
// layout above: (f N + j) N + i.
int cubePixelIndex(const Vec3f& dir, int resolution);

// Where direction `dir` (any length but 0) meets the cube: face f (layout above) and its face
// coordinates (u, v) in [-1, 1].
struct CubePoint {
  int face;
  float u, v;
};
CubePoint cubePoint(const Vec3f& dir);
// The unit direction through face coordinates (u, v) of face f.
Vec3f cubeDirection(int face, double u, double v);
// The exact solid angle of the square [u0, u1] x [v0, v1] of a face.
double cubeRectSolidAngle(double u0, double u1, double v0, double v1);

class Microbuffer {
 public:
  explicit Microbuffer(int resolution);

  int resolution() const { return n_; }
  int pixelCount() const { return kCubeFaces * n_ * n_; }

  // Starts a picture around `origin`: every pixel empty. The first form rasterizes the whole
  // sphere, the second only directions above `normal` (unit).
  void clear(const Vec3f& origin);
  void clear(const Vec3f& origin, const Vec3f& normal);

  // A cluster seen from far: `radiance` over a round footprint of `solidAngle` sr around unit
  // direction `dir` at `distance`, reaching `extent` in depth either way. Pixels whose
  // centre is inside are covered, those on the rim partly; a footprint smaller than a pixel
  // covers a fraction of the pixels around its direction. Returns the pixels it reached.
  int splatFootprint(const Vec3f& dir, float distance, float solidAngle, const Rgb& radiance,
                     float extent);
  // The same for a point at `centroid` covering `projectedArea` (seen from the origin).
  int splatCluster(const Vec3f& centroid, float projectedArea, const Rgb& radiance, float extent);

  // A one-sided disk (surfel) in the mid field, as a footprint of its solid angle around the
  // direction of its centre, reaching `extent` in depth: a disk a few pixels wide or less
  // is round enough, and the footprint keeps its energy exact where point-sampled exact
  // coverage would count a disk either as nothing or as whole pixels. Seen from behind a
  // disk is transparent (its back is the inside of a surface, which the tree's one-sided
  // projected areas make transparent too).
  int splatDisk(const Vec3f& center, const Vec3f& normal, float radius, const Rgb& radiance,
                float extent);
  // Near field, exact: every pixel whose centre ray hits the disk's front side is covered
  // (alpha 1) at the hit distance. The origin may be inside the disk's bounding sphere.
  int rayCastDisk(const Vec3f& center, const Vec3f& normal, float radius, const Rgb& radiance);

  // Adds `other`'s picture (same resolution; a receiver group's, pair_gather.h) under what this
  // buffer holds: each of its pixels' layers, front then back, composed into this buffer's
  // pixel as a piece of that depth, extent, coverage and radiance. Inactive pixels stay so.
  void composeBuffer(const Microbuffer& other);

  // Irradiance at the origin for a receiver facing `normal` (unit): the sum over pixels of
  // radiance times the clamped cosine integrated over the pixel (exact for pixels above the
  // horizon, from the tables' vector solid angles).
  Rgb irradiance(const Vec3f& normal) const;
  // The sum over pixels of radiance * weight(centre direction) * solid angle, for any
  // per-direction weight (a BRDF times the cosine). Inactive pixels are black.
  template <typename Weight>
  Rgb convolve(Weight&& weight) const {
    Rgb sum(0.0f);
    for (int f = 0; f < kCubeFaces; ++f) {
      if (!faceActive_[f]) continue;
      const int end = (f + 1) * n_ * n_;
      for (int k = f * n_ * n_; k < end; ++k) {
        if (!covered(k)) continue;
        sum += radiance(k) * (weight(directions_[k]) * solidAngles_[k]);
      }
    }
    return sum;
  }

  // Pixel access, for convolutions, tests and debugging pictures.
  const Vec3f& direction(int pixel) const { return directions_[pixel]; }
  float solidAngle(int pixel) const { return solidAngles_[pixel]; }
  // The front layer's nearest distance (infinite when empty, 0 below the horizon).
  float depth(int pixel) const { return pixels_[pixel].front.depth; }
  // The fraction of the pixel covered, front and back layers together (above 1 where
  // pieces of one surface overlap).
  float coverage(int pixel) const {
    return pixels_[pixel].coverage();
  }
  // Coverage-weighted: a pixel half covered by radiance L holds L / 2.
  Rgb radiance(int pixel) const {
    return pixels_[pixel].radiance();
  }
  bool active(int pixel) const { return pixels_[pixel].front.depth > 0.0f; }
  bool covered(int pixel) const { return coverage(pixel) > 0.0f; }
  // The pixel whose square holds direction `dir` (any length but 0).
  int pixelIndex(const Vec3f& dir) const;
  int coveredPixels() const;
  // The sum of solid angle times coverage.
  float coveredSolidAngle() const;

  // What the last clear left out: whole faces below the normal, and pixels never
  // rasterized (inactive ones, those of skipped faces included).
  int skippedFaces() const { return skippedFaces_; }
  int skippedPixels() const { return skippedPixels_; }

 private:
  static constexpr float kEmpty = DepthLayer::kEmpty;
  using Pixel = LayeredPixel;

  struct PixelRect {
    int i0, i1, j0, j1;  // inclusive
  };
  struct Fraction {
    int pixel;
    float alpha;
  };
  // The pixels of face f whose centre can lie within the cone around unit `dir` of half-angle
  // with these sine and cosine; false when the cone misses the face.
  bool coneRect(int f, const Vec3f& dir, float sinAngle, float cosAngle, PixelRect* rect) const;
  // Composes alpha of `radiance` at `distance` into pixel k (see the header comment); false
  // when it changed nothing (inactive pixel, or behind a full one).
  bool compose(int k, float distance, float extent, float alpha, const Rgb& radiance);
  // Exact disk test over the pixels of `rect` on face f.
  int diskRect(int f, const PixelRect& rect, const Vec3f& toCenter, const Vec3f& normal,
               float radius, const Rgb& radiance);

  int n_ = 0;
  std::shared_ptr<const MicrobufferTables> tables_;
  const Vec3f* directions_ = nullptr;
  const float* solidAngles_ = nullptr;
  const float* inverseWidths_ = nullptr;
  const Vec3f* vectorSolidAngles_ = nullptr;
  Vec3f origin_{0.0f};
  std::vector<Pixel> pixels_;
  std::vector<Fraction> scratch_;  // a footprint's pixels between its two passes
  bool faceActive_[kCubeFaces] = {};
  int skippedFaces_ = 0;
  int skippedPixels_ = 0;
};

}  // namespace pbgi
