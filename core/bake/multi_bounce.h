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
// what all bounces reflect, with the estimated tail (surfel_bounce.h).
//
// The caller owns the files: it opens the tree a bounce reads (through a page cache) and
// builds the trees from what the sinks receive.
#include <atomic>
#include <cstdint>
#include <functional>

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

// Every surfel of `sorted` with its direct light plus albedo / pi of E_K + (E_K - E_{K-1}) tail
// on each side (E_K: `last`, the irradiance after the last bounce; E_{K-1}: `previous`, or
// black), into `out`.
absl::Status finalLight(SpillFile& sorted, SpillFile& last, SpillFile* previous, const Rgb& tail,
                        uint64_t surfels, const SurfelSink& out);

}  // namespace pbgi
