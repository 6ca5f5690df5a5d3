#pragma once
// The passes of a multi-bounce bake (Christensen's multi-pass), over surfels that stream from a
// spill file in the tree's order (sorted along the Morton curve), in bounded memory: a batch
// of kBounceBatchSurfels at a time.
//
// Bounce k gathers, for every surfel, the irradiance on its two sides from the tree of the
// light bounce k - 1 added (the direct light's tree for the first), with a BounceGatherer over
// groups of kBounceChunkSurfels consecutive surfels whose random numbers are keyed by (seed,
// frame, bounce, the group's first surfel): the result does not depend on threads, budget or
// batch size. It keeps each surfel's irradiance so far in a spill (the last bounce's plus its
// own), and hands on the light it adds (albedo / pi of its irradiance, on diffuse surfels) for
// the next bounce's tree. After the last, finalLight gives each surfel its direct light plus
// what all bounces reflect, with the estimated tail (tailFactor in surfel_bounce.h, tailLight).
//
// The caller owns the files: it opens the tree a bounce reads (through a page cache) and
// builds the trees from what the sinks receive.
#include <atomic>
#include <cstdint>
#include <functional>
#include <span>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/bake/surfel_bounce.h"
#include "core/pbgi/bidirectional_cut.h"
#include "core/pbgi/external_sort.h"
#include "core/pbgi/tree_page.h"
#include "core/scene/scene.h"
#include "core/util/spill_file.h"

namespace pbgi {

// A bounce's receivers: this many consecutive sorted surfels make one cut.
inline constexpr size_t kBounceChunkSurfels = 4096;
// Surfels read from the spills at a time by default (whole groups).
inline constexpr size_t kBounceBatchSurfels = 64 * 1024;
static_assert(kBounceBatchSurfels % kBounceChunkSurfels == 0);

// Takes each surfel in the spill's order (a tree writer's add).
using SurfelSink = std::function<absl::Status(const SortedSurfel&)>;

struct BounceRequest {
  TreePageSource* from = nullptr;  // the light the last bounce added (or the direct light)
  SpillFile* sorted = nullptr;     // every surfel, with its direct light, in the tree's order
  SpillFile* previous = nullptr;   // each surfel's irradiance so far; null before the first
  SpillFile* next = nullptr;       // receives the irradiance so far with this bounce's
  SurfelSink added;                // receives the light this bounce adds; empty: not needed
  const Scene* scene = nullptr;
  CutOptions cut;                  // bounceCutOptions(first, bounce)
  int receiverSpacing = kBounceReceiverSpacing;  // bounceReceiverSpacing(first, bounce)
  uint64_t seed = 0;
  int frame = 0;
  int bounce = 1;
  uint64_t surfels = 0;            // in the spill
  size_t groupsTogether = 1;       // groups whose cuts sweep the tree together
  size_t batchSurfels = kBounceBatchSurfels;  // read at a time: a multiple of the group's size
  std::function<void(uint64_t done, uint64_t total)> progress;
  // Stops the bounce between batches when set (a cancelled farm task): Cancelled.
  const std::atomic<bool>* cancel = nullptr;
  uint64_t* shutSides = nullptr;  // adds the records' sides not gathered: shut (BounceGatherer)
};

// One bounce for every surfel. Returns the power it reflects (what its light adds). Errors:
// the spills', the cuts' (a damaged tree, a page the source cannot give).
absl::StatusOr<Rgb> runBounce(const BounceRequest& request, CutStats* stats);

// The light of bounces K+1, K+2, ... on one side of a surfel, from what bounces K, K-1 and K-2
// added there (dE_K `added`, `addedBefore`, `addedEarlier`: irradiance) and the scene's tail
// factor f = r / (1 - r) (tailFactor: r the bounces' ratio in the limit). The scene's light
// goes as r^k in the end, but a surface's need not yet: a room lit through a door gets its
// light a bounce or more after the room next door, so that its light still rises when the
// scene's falls, and the geometric tail dE_K f leaves out much of what follows. So with
// `local` each surface's light is taken as A r^k + C q^k, the scene's mode and one of its own:
// x_k = dE_k - r dE_{k-1} = C q^(k-1) (q - r) gives q = x_K / x_{K-1} (held to [0, r]; where
// the two differ in sign, no second mode: the geometric tail), and the bounces past K add
// dE_K f + x_K q / ((1 - q)(1 - r)) (at least nothing). Light that rises (x > 0) gets more than
// the geometric tail, and as much as the series k r^(k-1) of two like rooms where q = r; light
// that falls faster than the scene's (a surface lit directly) less.
Rgb tailLight(const Rgb& added, const Rgb& addedBefore, const Rgb& addedEarlier, const Rgb& tail,
              bool local);
// The bounces' irradiance the tail reads: E_K, E_{K-1}, E_{K-2}, E_{K-3}.
inline constexpr size_t kTailBounces = 4;

// Every surfel of `sorted` with its direct light plus albedo / pi of E_K and its tail
// (tailLight) on each side. `cumulative` holds the irradiance so far after each of the last
// bounces, up to kTailBounces of them, the last one last (..., E_{K-1}, E_K); the tail follows
// each surface's own light (`local`) from three bounces on. Into `out`.
absl::Status finalLight(SpillFile& sorted, std::span<SpillFile* const> cumulative, const Rgb& tail,
                        uint64_t surfels, const SurfelSink& out);

}  // namespace pbgi
