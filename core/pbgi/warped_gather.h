#pragma once
// Importance-warped microbuffers for glossy receivers (Ritschel et al. 2009, "Micro-rendering
// for scalable, parallel final gathering", sections 2.2 and 2.3): the gather of gather.h, but
// into an N x N buffer whose pixels are a regular grid in the BSDF's sample space instead of
// a cube around the receiver, so that a glossy lobe gets as many pixels as a diffuse
// hemisphere does, and the convolution is a Monte Carlo sum.
//
// The warp. Pixel (i, j) is the stratum [i/N, (i+1)/N) x [j/N, (j+1)/N) of the square that
// Bsdf::sample maps to directions (the BSDF's own importance sampling, no table). Its region
// on the sphere is the spherical quad of the four warped lattice corners, cut into two
// geodesic triangles; the regions tile the hemisphere, so their solid angles add up to 2 pi.
// Where the warp does not reach the horizon by itself its corners are moved there, along the
// great circle from the lobe's centre: corners the BSDF cannot sample next to ones it can (a
// microfacet lobe reflected below the horizon), and sides of the square that are neither a
// seam (the azimuth of a polar warp) nor collapsed to a point (its pole) but stop short of
// the rim (an inverse CDF clamped at 0 and 1). The pixel's sample is its stratum's point
// offset by the receiver's jitter, u = ((i + jitter.x)/N, (j + jitter.y)/N): a shifted
// lattice, stratified, unbiased over the jitter. Regions do not depend on the jitter.
//
// The traversal (the paper's "traversal by solid angle per warped pixel"): a node is splatted
// into the pixel its centroid's direction falls in once its projected solid angle is at most
// that pixel's (and its bounding sphere not much larger), and refined otherwise. A splat
// covers the fraction of the pixel's solid angle it has, composed in two depth layers as
// Microbuffer does (closer wins). Leaves give surfels; a surfel larger than its pixel, nearer
// than nearFieldFactor radii, or in no pixel is ray-cast after the traversal against every
// pixel's sample direction (the paper's "post-traversal ray casting"). Culling, self-skip and
// page handling are gather.h's.
//
// The convolution: L = sum over pixels of L(pixel) f(wo, wi) cos(wi) / (pdf(wi) N^2), the
// stratified Monte Carlo estimator of the reflected radiance, L(pixel) being what the pixel
// holds (coverage-weighted). A pixel whose sample the BSDF could not draw is black.
//
// The lobe choice uc of Bsdf::sample is stratified over the pixels (a golden-ratio sequence
// offset by the jitter); corners use uc = 0. A rough dielectric thus gets its reflection
// unbiased, if noisy (the pixels whose uc picks transmission are black): PBGI gathers the
// reflection hemisphere only. Delta BSDFs have no warp and reflect nothing here.
#include <array>
#include <cstdint>
#include <limits>
#include <memory>
#include <string>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/math/vec.h"
#include "core/pbgi/gather.h"
#include "core/pbgi/layered_pixel.h"
#include "core/pbgi/tree_page.h"
#include "core/pbgi/tree_walk.h"
#include "core/scene/material.h"

namespace pbgi {

struct WarpedGatherOptions {
  int resolution = 16;  // the warped buffer is resolution x resolution pixels
  // Surfels nearer than this many radii are ray-cast, as in GatherOptions.
  float nearFieldFactor = 4.0f;
  // Surfels whose disk, grown by this factor, holds the receiver are not gathered.
  float selfSkipRadius = 1.0f;

  bool operator==(const WarpedGatherOptions&) const = default;
  // InvalidArgument naming the field when a value is out of range.
  absl::Status validate() const;
  std::string toString() const;
};

// A reusable warped gather: owns the warp, the buffer, the traversal stack and the pages in
// use, so that gathers after the first allocate nothing (unless a receiver needs more room
// than any before: more surfels to ray-cast, longer bucket lists). One per thread; not
// thread-safe.
class WarpedGatherer {
 public:
  // Options must be valid (validate() first when they come from a user).
  explicit WarpedGatherer(const WarpedGatherOptions& options);

  const WarpedGatherOptions& options() const { return options_; }

  // Outgoing radiance towards wo from the light the tree holds, reflected by `bsdf` at
  // `position`. `frame` is the shading frame (z = shading normal, on wo's side); woLocal =
  // frame.toLocal(wo), need not be unit. `jitter` in [0, 1)^2 offsets the samples in their
  // strata (wrapped into [0, 1) when outside). A wo at or below the frame's horizon reflects
  // nothing here: black. Errors: InvalidArgument for a non-finite position, frame, wo or
  // jitter, or a zero wo; the source's error for a page it cannot give; DataLoss for a damaged
  // page or radiance that makes the result non-finite. `stats` may be null.
  absl::StatusOr<Rgb> reflect(TreePageSource& tree, const Vec3f& position, const Frame& frame,
                              const Bsdf& bsdf, const Vec3f& woLocal, const Vec2f& jitter,
                              GatherStats* stats);

  // The warp alone, what reflect() builds first: pixels, regions and weights, for tests and
  // debugging pictures. Errors as reflect()'s InvalidArgument.
  absl::Status warp(const Frame& frame, const Bsdf& bsdf, const Vec3f& woLocal,
                    const Vec2f& jitter);

  // The last warp's pixels, k = j N + i.
  int resolution() const { return n_; }
  int pixelCount() const { return n_ * n_; }
  // World direction of the pixel's sample: unit, or zero where the BSDF could not sample it.
  const Vec3f& pixelDirection(int k) const { return dirWorld_[k]; }
  // Solid angle of the pixel's region.
  float pixelSolidAngle(int k) const { return solidAngle_[k]; }
  // f cos / (pdf N^2) of the pixel's sample; black where the BSDF could not sample it.
  const Rgb& pixelWeight(int k) const { return weight_[k]; }
  // The sum of the pixels' solid angles: what the warp covers.
  double coveredSolidAngle() const;
  // The pixel whose region holds world direction `dir` (any length but 0), -1 for none.
  int pixelOf(const Vec3f& dir) const;
  // What the last reflect() left in pixel k: coverage-weighted radiance, front and back.
  Rgb pixelRadiance(int k) const;

 private:
  using Pixel = LayeredPixel;
  // A surfel to ray-cast after the traversal.
  struct Disk {
    Vec3f center, normal;
    float radius;
    Rgb radiance;
  };

  int pixelOfLocal(const Vec3f& w) const;
  // The steps of warp().
  void sampleCorners(const Bsdf& bsdf, const Vec3f& wo);
  // Corners next to sampled ones to the horizon, beyond them from the lobe's centre
  // (neighbours wrap around the square across a seam: u.x = 0 is u.x = 1, u.y likewise).
  void moveUnsampledCorners(const Vec3f& lobe, const bool seams[2]);
  void samplePixels(const Bsdf& bsdf, const Vec3f& wo, const Vec2f& jitter);
  // Corner indices of pixel k's quad, counter-clockwise in the square.
  std::array<int, 4> quadCorners(int k) const;
  void buildRegions();
  void buildBuckets();
  // Composes `coverage` of the pixel (for visibility) bringing `radiance` (already scaled by
  // its energy) at `distance` into pixel k, as Microbuffer does.
  void compose(int k, float distance, float extent, float coverage, const Rgb& radiance);
  absl::Status traverse(TreePageSource& tree, const Vec3f& p, GatherStats* stats);
  void gatherSurfels(const TreePage& page, const TreeNode& leaf, const Vec3f& p,
                     GatherStats* stats);
  void rayCast(const Vec3f& p);

  WarpedGatherOptions options_;
  int n_;
  Frame frame_;
  // The warp: lattice corners ((N+1)^2), then per pixel its sample and its region, a quad of
  // two triangles (areas and whether they hold directions) with five inward edge normals
  // (four sides, then the diagonal).
  std::vector<Vec3f> corner_;
  std::vector<uint8_t> cornerState_;
  std::vector<Vec3f> dirWorld_;
  std::vector<Rgb> weight_;
  std::vector<uint8_t> sampled_;  // 0 where the BSDF could not sample the pixel: black
  std::vector<float> solidAngle_;
  std::vector<float> triArea_;
  std::vector<uint8_t> triKept_;
  std::vector<Vec3f> quadEdge_;
  // Buckets over the stereographic chart of the hemisphere, split at quantiles of the
  // corners: the pixels whose region may meet each bucket (CSR).
  std::vector<Vec2f> cornerChart_;
  std::vector<uint8_t> quadRect_;  // the buckets a pixel meets: x0, x1, y0, y1
  std::vector<float> splitX_, splitY_, scratch_;
  std::vector<uint32_t> bucketStart_, bucketPixels_;
  // Buffer and traversal.
  std::vector<Pixel> pixels_;
  std::vector<Disk> rayCasts_;
  TreeWalk walk_;
};

}  // namespace pbgi
