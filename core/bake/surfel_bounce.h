#pragma once
// One bounce of indirect light for the surfels of a bake (Christensen's multi-pass): every
// surfel that reflects light (diffuse, non-black albedo) takes the irradiance a tree (the
// light the previous bounce added) sends each of its two sides (surfaces are two-sided), and
// reflects albedo / pi of each (multi_bounce.h runs the passes). The surfels of a chunk
// (neighbours along the Morton curve) gather together, through one bidirectional cut whose
// receivers are records among them: the same machinery as a frame's shading points, so that
// bounce light and the image agree on how light is gathered.
//
// Records, not every surfel. The surfels of a group that share a cell of a grid (about
// sqrt(receiverSpacing) surfel spacings wide), face within kPatchNormalCos of each other and see
// each other on both sides along their surface (Scene::seeAlongSurface) make a patch; the member
// nearest its centre is the record, gathered on both sides. Each surfel reads the records of the
// patches in its cell and the cells around it that face its way, weighted by distance, each on
// the sides its record and the surfel's own see each other: what a frame's pixels between
// records do (pbgi_integrator.cpp). A floor that runs on under a wall is two floors: the light
// of one room never reaches the other through a record.
// Bounce light is smooth at the scale of a few surfels, and a bounce costs what its cuts'
// receivers do.
//
// The light past the last bounce. K bounces leave out bounces K+1, K+2, ...: with power P_k in
// bounce k, their sum is close to a geometric tail, P_K r / (1 - r), spread as the last bounce
// spreads (higher bounces converge to the same distribution). So the last bounce's light is
// scaled by 1 + r / (1 - r) instead of being baked further. The ratio of successive bounces
// swings about its limit while the light settles (a pool of light on a ceiling sends the floor
// its first bounce, which sends the ceiling its second), so from three bounces on r is taken
// over the last two steps, sqrt(P_K / P_{K-2}), where the swings cancel; else P_K / P_{K-1}.
#include <array>
#include <cstdint>
#include <span>
#include <string_view>
#include <unordered_map>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/pbgi/bidirectional_cut.h"
#include "core/pbgi/surfel.h"
#include "core/pbgi/tree_page.h"
#include "core/scene/scene.h"

namespace pbgi {

// How bounce `bounce` (1 is the first) gathers, given how the first gathers: light reflected
// twice or more is smoother and dimmer than the direct light the first bounce gathers, so
// later bounces gather with the first's solid-angle thresholds (eps_L, eps~_L, eps~_E) times
// kLaterBounceCoarsening, clamped to their valid range. The first bounce's shadow rays descend
// by cones (CutOptions::coneDescent): the first bounce is most of a bake's time, and its
// records are dense and its clusters small, where cones lose least (transfer_bench compares
// cones and SH against brute force); the later bounces' coarser clusters stay by SH.
inline constexpr float kLaterBounceCoarsening = 4.0f;
CutOptions bounceCutOptions(const CutOptions& first, int bounce);

// The first bounce's cut for a quality preset: the preset without the near field's rays
// (CutOptions::nearRays) and with one shadow ray a cluster pair (CutOptions::recordVisibility:
// a bounce's records already stand for patches of surfels). Bounce light reaches the frame
// through one more gather, whose records take the near field by rays; in the bounces the rays
// would cost more of the bake than the light they add.
absl::StatusOr<CutOptions> bounceCutPreset(std::string_view quality);

// Whether a surfel reflects gathered light at all.
bool reflectsLight(const Surfel& s);

// The irradiance on a surfel's two sides.
struct SurfelIrradiance {
  Rgb front{0.0f};
  Rgb back{0.0f};
};

// Surfels a bounce record stands for, about (1: every surfel gathers its own light).
inline constexpr int kBounceReceiverSpacing = 16;
inline constexpr int kMaxBounceSpacing = 1024;
// Bounce `bounce`'s spacing, given the first's: light reflected twice or more is smoother, so
// the second bounce's records stand for kLaterBounceSpacing times as many surfels and each
// later bounce's for twice as many as the one before (up to kMaxBounceSpacing; a spacing of 1
// stays 1, every surfel its own): later bounces cost a fraction of the first, for a fraction of
// a percent of the image's mean.
inline constexpr int kLaterBounceSpacing = 8;
int bounceReceiverSpacing(int first, int bounce);
// The least cosine between the normals of surfels of one patch, and of a surfel and a record
// it reads (about 18 degrees).
inline constexpr float kPatchNormalCos = 0.95f;
// How far a record reaches from the surfels that read it, in cell widths.
inline constexpr float kRecordReachCells = 1.5f;

// Gathers for the surfels of a bake, reusing its buffers.
class BounceGatherer {
 public:
  explicit BounceGatherer(const CutOptions& options, int receiverSpacing = kBounceReceiverSpacing);

  // irradiance[i] = what surfels[i]'s two sides gather from `tree` (black for surfels that
  // reflect nothing). The surfels fall in groups of `groupSize` consecutive ones (the last
  // may be shorter), keys[g] seeding group g's two cuts (one per side): derive them from the
  // groups' places in the bake, so that the result does not depend on the threads or on how
  // many groups one call gathers. The cuts of `groupsTogether` groups at a time sweep the tree
  // together (cutTogether, in parallel), so that a small page cache loads each page once per
  // such batch; each cut in flight holds its waiting pairs (up to about a million for 4,096
  // receivers), so the batch is what bounds the bounce's memory.
  //
  // Shut sides. `previous`, when given (bounces after the first), is each surfel's irradiance
  // so far. A record whose side gathered exactly nothing in every bounce before gathers nothing
  // now either, and its cut is not run (counted in shutSides), unless `probeBlackSides` is set
  // and it sees a surface (seesNoSurface): light that reached no surface it sees in one bounce
  // may in the next (the floor under a table sees no lit surface in the first bounce, and the
  // lit walls in the second). The bake probes in its second bounce, so that a side stays shut
  // from the third on only when it saw nothing, or gathered nothing even then (the inside of a
  // closed object, a wall's far face).
  absl::Status gather(TreePageSource& tree, const Scene& scene, std::span<const Surfel> surfels,
                      size_t groupSize, std::span<const uint64_t> keys, size_t groupsTogether,
                      std::span<SurfelIrradiance> irradiance, CutStats* stats,
                      std::span<const SurfelIrradiance> previous = {}, uint64_t* shutSides = nullptr,
                      bool probeBlackSides = false);

 private:
  struct Side {
    explicit Side(const CutOptions& options) : cut(options) {}
    BidirectionalCut cut;
    std::vector<CutReceiver> receivers;  // the group's records that are not shut, on this side
    std::vector<uint32_t> recordOf;      // receiver -> its record (patch)
    std::vector<Rgb> gathered;           // by receiver
    std::vector<Rgb> byRecord;           // by record (black for shut ones)
  };
  // A group's patches: patch k's record is surfel recordOf[k], in grid cell cellOf[k];
  // surfel i of the group (first + i) is in patch patchOf[i] (kNoPatch: it reflects nothing).
  struct Patches {
    static constexpr uint32_t kNoPatch = UINT32_MAX;
    float cell = 0.0f;  // the grid's cell width
    std::vector<uint32_t> recordOf, patchOf;
    std::vector<std::array<int32_t, 3>> cellOf;
    std::unordered_map<uint64_t, std::vector<uint32_t>> inCell;  // cell key -> its patches
  };
  void makePatches(const Scene& scene, std::span<const Surfel> surfels, size_t first, size_t end,
                   Patches& out) const;
  void spread(const Scene& scene, std::span<const Surfel> surfels, size_t first,
              const Patches& patches, const Side& front, const Side& back,
              std::span<SurfelIrradiance> irradiance) const;

  CutOptions options_;
  int receiverSpacing_;
  std::vector<Side> sides_;  // group g's front side at 2 g, its back at 2 g + 1
  std::vector<Patches> patches_;  // group g's
};

// Rays a record's side that gathered nothing so far sends to learn whether it sees any surface.
inline constexpr int kShutProbeRays = 16;
// Whether a side at p facing n (unit) sees no surface: none of kShutProbeRays cosine-weighted
// rays, stratified and jittered from `key`, meets anything. A side that sees surfaces only
// through a small fraction of its hemisphere may pass for one that sees none.
bool seesNoSurface(const Scene& scene, const Vec3f& p, const Vec3f& n, uint64_t key);

// The power (per channel, area times radiance, both sides) that a surfel reflects from `e`.
Rgb reflectedPower(const Surfel& s, const SurfelIrradiance& e);

// A surfel lit by `e` on top of its direct light: radiance += albedo / pi * (front, back).
void addReflected(Surfel& s, const SurfelIrradiance& e);

// The factor r / (1 - r), per channel, that estimates bounces K+1, K+2, ... from the powers of
// the bounces so far, `power[k]` bounce k's (power[0] the direct light's reflected power):
// r = sqrt(P_K / P_{K-2}) from K = 3 on, else P_K / P_{K-1}, held to [0, maxRatio] (0 where a
// power it divides or is divided by is 0, and without two powers). r stands for the limit of
// the bounces' ratio, which no scene's light exceeds its largest reflectance in: pass
// largestBounceRatio(scene), so that bounces whose powers rise (light that reaches the diffuse
// surfels late, by way of glossy ones, whose own power the sums leave out) do not extrapolate
// to a tail many times the light there is.
inline constexpr float kMaxBounceRatio = 0.95f;
Rgb tailFactor(std::span<const std::array<double, 3>> power, float maxRatio = kMaxBounceRatio);
// The largest fraction of the light arriving at any of the scene's surfaces that it sends on
// (per channel, the most of any material's hemispherical albedo; 1 for a textured albedo and
// for glass), at most kMaxBounceRatio.
float largestBounceRatio(const Scene& scene);

}  // namespace pbgi
