#pragma once
// Pair refinement (Wang, Meng, Boubekeur 2015, "Wavelet point-based global illumination",
// Algorithm 1): the microbuffers of many receivers rasterized together, a sender (a node of the
// PBGI tree) that looks alike from a whole group of receivers splatted once into the group's
// buffer instead of once into each receiver's.
//
// Two trees. The light tree is the PBGI tree as gather.h walks it. The receiver tree is a
// binary tree built here over the receivers' positions (split at the median of the longest
// axis), single receivers at its leaves; each node has the bounding sphere of its receivers.
//
// The refinement. Pairs start as (light root, receiver root). A pair (S, R), R a group:
//   - when R's bounding sphere seen from S is larger than receiverSolidAngle (the paper's
//     alpha_RS >= epsilon: pi r_R^2 / d^2, d the distance from R's centre to S's bounding
//     sphere) or S reaches into it, S goes down to R's children (R is refined);
//   - otherwise S is taken as gather.h's walk would take it from R's centre (the paper's
//     alpha_SR < epsilon is the gather's own cluster test, maxSolidAngle): splatted whole into
//     R's buffer, a picture of the whole sphere around R's centre; when it is too large there,
//     its children are paired with R (S is refined), a leaf of the light tree going down to
//     R's children instead, for its surfels are gathered receiver by receiver.
// At a single receiver, the senders that came down to it are walked as Gatherer::rasterize
// walks the root (the same culling, clusters, surfels, near field and self skip), into a
// buffer that starts as the buffers of the receiver's groups composed root first: each of
// their pixels' layers joins the receiver's pixel as a piece of that depth and coverage
// (layered_pixel.h); pixels below the receiver's horizon stay empty.
//
// So with receiverSolidAngle 0 no group keeps anything and every receiver's buffer is
// Gatherer::rasterize's, bit for bit. Above 0, a sender splatted into a group is seen from the
// group's centre: its direction is off by at most the angle R subtends from S (for the
// default, 0.004 sr: 2 degrees, a third of a 16^2 buffer's pixel).
//
// Groups rasterize the whole sphere, so the receivers of one point may face opposite ways (the
// bake gathers both sides of a glossy leaf). Buffers are world-aligned (rasterize, not
// rasterizeLocal). Groups' subtrees run in parallel (TBB); a receiver's buffer does not depend
// on the thread count, only on the receivers given (they shape the receiver tree).
#include <cstdint>
#include <functional>
#include <span>
#include <string>

#include <absl/status/status.h>

#include "core/math/vec.h"
#include "core/pbgi/gather.h"
#include "core/pbgi/microbuffer.h"
#include "core/pbgi/tree_page.h"

namespace pbgi {

struct PairGatherOptions {
  GatherOptions gather;  // the walk at each receiver, and the cluster test at each group
  // epsilon for the receiver side: a group is taken whole by a sender when its bounding sphere
  // seen from the sender is at most this (sr). 0: every receiver gathers alone.
  float receiverSolidAngle = 0.004f;

  bool operator==(const PairGatherOptions&) const = default;
  // InvalidArgument naming the field when a value is out of range.
  absl::Status validate() const;
};

// A receiver: a point gathering above `normal`, and also below it when twoSided (two buffers,
// the second for -normal).
struct PairReceiver {
  Vec3f position{0.0f};
  Vec3f normal{0.0f, 0.0f, 1.0f};
  bool twoSided = false;
};

struct PairGatherStats {
  uint64_t receivers = 0;
  uint64_t groups = 0;           // receiver-tree nodes above the single receivers
  uint64_t groupBuffers = 0;     // of them, those that took a sender whole
  uint64_t pairs = 0;            // (sender, group) pairs looked at
  uint64_t groupSplats = 0;      // senders splatted into a group's buffer
  uint64_t splatsServed = 0;     // those times the receivers under the group (the cost unshared)
  uint64_t refinedSender = 0;    // pairs whose sender was refined at the group
  uint64_t refinedReceiver = 0;  // pairs passed down to the group's children
  uint64_t composed = 0;         // group buffers composed into receivers' buffers

  PairGatherStats& operator+=(const PairGatherStats& o);
  std::string toString() const;
};

// Called once per receiver when its buffers are complete, from any thread: the receiver's
// index and its buffer (above the normal), then the one below it (twoSided only, else null).
// The buffers are reused after the call returns.
using PairGatherUse =
    std::function<void(size_t receiver, const Microbuffer& above, const Microbuffer* below)>;

// Rasterizes every receiver's buffer(s) by pair refinement (above). Errors: InvalidArgument for
// invalid options or a receiver with a non-finite position or a zero normal (before any
// work); otherwise Gatherer::rasterize's, the first met. `gatherStats` (the walks at the
// receivers and the groups' splats) and `stats` may be null.
absl::Status pairGather(TreePageSource& tree, std::span<const PairReceiver> receivers,
                        const PairGatherOptions& options, const PairGatherUse& use,
                        GatherStats* gatherStats, PairGatherStats* stats);

}  // namespace pbgi
