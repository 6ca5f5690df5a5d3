#pragma once
// The PBGI gather (Christensen 2008, "Point-based approximate color bleeding"): the light
// arriving at one receiver, from a top-down traversal of the PBGI tree rasterized into a
// cube microbuffer around it.
//
// Per node, from the receiver at p with normal n:
//   - culled when its bounds lie entirely behind the tangent plane at p (surfels are
//     two-sided: seen from behind, a surfel occludes and sends its back side's radiance);
//   - splatted as a cluster when small from p: its projected area towards p (from its SH,
//     held within what its normal cone allows) over its distance squared is at most
//     maxSolidAngle, and its bounding sphere not much larger; with the mean radiance its
//     spherical harmonics send towards p;
//   - refined otherwise; a leaf too large to be a cluster gives its surfels one by one, as
//     footprints of their solid angle, or ray-cast exactly when nearer than nearFieldFactor
//     radii.
// Surfels centred on or behind the tangent plane, and those whose disk holds the receiver
// (the receiver's own surfel and its overlapping neighbours), are left out: on a flat or
// gently curved surface they would otherwise shadow the receiver with itself.
//
// Pages come from a TreePageSource and are held (shared_ptr) only while the traversal is in
// them; a page the source cannot give fails the gather with the source's error.
#include <cstdint>
#include <memory>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/math/vec.h"
#include "core/pbgi/microbuffer.h"
#include "core/pbgi/tree_page.h"
#include "core/pbgi/tree_walk.h"

namespace pbgi {

namespace gather_internal {
struct NodeBounds;
}  // namespace gather_internal
class PairWalk;

// Changes whenever a gather's result for the same tree and options changes (a bake whose
// bounces gathered with another revision is stale): 2 gave clusters their bounding box's depth.
inline constexpr int kGatherRevision = 2;

struct GatherOptions {
  // A node whose projected solid angle from the receiver is at most this (sr) is splatted as
  // a cluster; Christensen uses 0.02 to 0.03.
  float maxSolidAngle = 0.03f;
  int resolution = 12;  // microbuffer pixels per face side
  // Surfels nearer than this many radii are ray-cast (exact disks) instead of splatted as
  // round footprints: near, a disk's outline spans many pixels.
  float nearFieldFactor = 4.0f;
  // Surfels whose disk, grown by this factor, holds the receiver are not gathered.
  float selfSkipRadius = 1.0f;

  bool operator==(const GatherOptions&) const = default;
  // InvalidArgument naming the field when a value is out of range.
  absl::Status validate() const;
  std::string toString() const;
};

// Quality presets: "draft", "default", "high". Unknown names are InvalidArgument.
absl::StatusOr<GatherOptions> gatherPreset(std::string_view name);

// Counts of one or more gathers: gathers add to them, never reset them.
struct GatherStats {
  uint64_t gathers = 0;
  uint64_t nodesVisited = 0;
  uint64_t nodesCulledPlane = 0;  // entirely behind the receiver's tangent plane
  uint64_t clustersSplatted = 0;
  uint64_t clustersInvisible = 0;  // small, but no projected area towards the receiver
  uint64_t disksSplatted = 0;
  uint64_t nearFieldRayCasts = 0;
  uint64_t surfelsSkipped = 0;  // behind or on the tangent plane, or holding the receiver
  uint64_t surfelsBackFacing = 0;  // seen from behind: their back side gathered
  uint64_t pagesTouched = 0;   // page() calls
  uint64_t facesSkipped = 0;   // microbuffer faces entirely below the horizon
  uint64_t pixelsSkipped = 0;  // microbuffer pixels below the horizon, never rasterized

  GatherStats& operator+=(const GatherStats& o);
  std::string toString() const;
};

// A reusable gather: owns the microbuffer, the traversal stack and the pages in use, so that
// gathers after the first allocate nothing (what the source does to fetch a page aside).
// One per thread; not thread-safe.
class Gatherer {
 public:
  // Options must be valid (validate() first when they come from a user).
  explicit Gatherer(const GatherOptions& options);

  const GatherOptions& options() const { return options_; }

  // Rasterizes the tree around the receiver into microbuffer(); `normal` need not be unit.
  // Errors: InvalidArgument for a non-finite position or a zero or non-finite normal; the
  // source's error for a page it cannot give; DataLoss for a page whose references point
  // outside it or a tree deeper than any the builder makes.
  absl::Status rasterize(TreePageSource& tree, const Vec3f& position, const Vec3f& normal,
                         GatherStats* stats);
  // The same picture in a receiver's own frame (unit, orthonormal, right-handed): the buffer's
  // axes are the frame's s, t and n, so its faces are the frame's and its +z face looks along
  // the normal. What a product with a BSDF projected in that frame needs (product_gather.h).
  // The traversal, its culling and its counters are rasterize()'s.
  absl::Status rasterizeLocal(TreePageSource& tree, const Vec3f& position, const Frame& frame,
                              GatherStats* stats);
  // rasterize, then the clamped-cosine convolution. DataLoss when the tree's radiance makes
  // the result non-finite.
  absl::StatusOr<Rgb> irradiance(TreePageSource& tree, const Vec3f& position, const Vec3f& normal,
                                 GatherStats* stats);

  // The last rasterized picture, for other convolutions (a BRDF) and debugging.
  const Microbuffer& microbuffer() const { return buffer_; }

 private:
  friend class PairWalk;  // pair_gather.cpp: groups splat as the walk would, receivers walk
  friend absl::Status gatherTogether(TreePageSource&, std::span<Gatherer>,
                                     std::span<const Vec3f>, std::span<const Vec3f>,
                                     std::span<Rgb>, GatherStats*);
  absl::Status traverse(TreePageSource& tree, const Vec3f& p, const Vec3f& n, GatherStats* stats);
  // A node seen from p: splatted whole (true) or to be refined (false).
  bool splatNode(const NodeAttributes& a, const gather_internal::NodeBounds& bounds,
                 const WaveletRadiance* wavelet, const Vec3f& p, GatherStats* stats);
  void gatherSurfels(const TreePage& page, const TreeNode& leaf, const Vec3f& p, const Vec3f& n,
                     GatherStats* stats);

  // rasterize (frame null) and rasterizeLocal.
  absl::Status rasterizeIn(TreePageSource& tree, const Vec3f& position, const Vec3f& normal,
                           const Frame* frame, GatherStats* stats);
  // A world vector in the buffer's axes: itself, or the frame's coordinates (rasterizeLocal).
  Vec3f toBuffer(const Vec3f& v) const { return local_ ? local_->toLocal(v) : v; }

  GatherOptions options_;
  Microbuffer buffer_;
  const Frame* local_ = nullptr;  // set during rasterizeLocal only
  TreeWalk walk_;
  SweptWalk swept_;
};

// The irradiance of many receivers (a tile's), each as Gatherer::irradiance gathers it but
// walking the tree page by page (SweptWalk, so its splats come in another order and its value
// differs from irradiance()'s by the microbuffer's layering, within its own accuracy), the
// walks in step: each page is asked for by every receiver that needs it at about the same
// time, so that a page cache of a few pages loads it about once for all of them. A receiver's
// value depends on its own position and normal alone, never on the receivers beside it.
// gatherers[i] (at least as many as receivers) gathers receiver i; out[i] is its irradiance.
// Errors as irradiance()'s, the first receiver's in order.
absl::Status gatherTogether(TreePageSource& tree, std::span<Gatherer> gatherers,
                            std::span<const Vec3f> positions, std::span<const Vec3f> normals,
                            std::span<Rgb> out, GatherStats* stats);

// One gather with a Gatherer kept per thread (rebuilt when the options change). Invalid
// options are InvalidArgument; otherwise as Gatherer::irradiance. `stats` may be null.
absl::StatusOr<Rgb> gatherIrradiance(TreePageSource& tree, const Vec3f& position,
                                     const Vec3f& normal, const GatherOptions& options,
                                     GatherStats* stats);

}  // namespace pbgi
