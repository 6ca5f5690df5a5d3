#pragma once
// The bidirectional cut (Jarabo, Buisan, Gutierrez 2014, "Bidirectional clustering for
// scalable VPL-based global illumination"): the light that a set of receivers (a block's
// camera samples, a chunk of surfels in a bake's bounce) gathers from the PBGI tree, computed
// once for clusters of receivers instead of once per receiver.
//
// Two trees. The light tree is the baked tree as it is (surfel leaves, SH clusters), read
// through a TreePageSource. The receiver tree is an octree built here over the receivers'
// positions (leaves of at most receiverLeafSize), each node with its bounds and the cone of
// its receivers' normals; single receivers sit below its leaves.
//
// The cut. From the pair (light root, receiver root), a pair (L, E) is
//   - culled when L lies entirely below the tangent planes of every receiver in E;
//   - evaluated when it meets the paper's termination criteria: L's projected solid angle
//     from E, A_L(w) / d^2 with A_L its SH projected area, at most lightSolidAngle (eps_L);
//     L's bounding sphere pi r_L^2 / d^2 at most lightBound (eps~_L); E's bounding sphere seen
//     from L at most receiverBound (eps~_E); E's normal cone narrower than normalAngle
//     (alpha); and the direction to L above the horizon of every normal in E;
//   - otherwise refined on one side only, the light side when h_L > h_E (the paper's eqs. 7
//     and 8: h_L = max(Omega_L / eps_L, Omega~_L / eps~_L), h_E = infinity when E's cone is
//     wider than alpha, else Omega~_E / eps~_E), a single surfel or receiver being refined no
//     further. A surfel and a single receiver are evaluated exactly (below) whatever the
//     criteria.
//
// Evaluation. A cluster pair adds L's radiance towards E (its SH intensity over its SH
// projected area) times its solid angle A_L / d^2 and a visibility sample, arriving from the
// direction of L's centroid, to E's incoming radiance. That radiance is kept as its band-1
// spherical harmonics, three RGB vectors V: the irradiance a receiver with normal n gets from
// it is n . V, which is exact (not the 6 %-ringing band-2 convolution of a clamped cosine)
// because a pair is only evaluated when its light lies above the horizon of every receiver in
// E. At the end each node's V is pushed down to its receivers. A surfel and a single receiver
// are a virtual spherical light (Hasan et al. 2009): E = L A |cos_s| cos_r / (d^2 + r^2), the
// disk's own radius softening the 1/d^2 spike (exact for a coaxial disk).
//
// Visibility is a shadow ray in the scene (Embree), not the cluster's approximation: from a
// random receiver of E (off its surface) towards one of L's surfels, picked by descending
// from L and choosing each child in proportion to the light it sends that receiver, up to
// just short of the surfel. The sample is random rather than fixed so that neighbouring
// clusters do not band (the paper's figure 5). Random numbers come from (key, light node,
// receiver node), so the result does not depend on threads or on the order pages arrive in.
//
// Near field. Within a few surfel radii of a receiver, surfels as disks miss light: which disks
// happen to lie next to it, how they overlap and gap, what of them a ray to their centre sees.
// Receivers within half a radius of other geometry gathered 0.92 of what rays measure with unit
// radiance on every surfel, 0.98 by the near field's rays (Sponza, 250k surfels, transfer_bench
// --light unit --brute). With nearRays > 0 the surfels whose centres lie within the near radius
// (kNearFieldRadii mean surfel radii of the tree's root) are left out, and rays from the receiver
// as long as that radius take their place: where a ray meets a surface, the radiance there is the
// weighted mean of that surface's surfels around the hit (the side the ray sees), read from the
// tree in the cut's own page sweep. The rays' directions are a scrambled Sobol set keyed by the
// receiver's position and normal, so a receiver gathers the same light in any cut, tile or
// thread. Clusters that reach into a receiver's near radius are refined until their surfels are
// taken one by one.
//
// Pages. Pairs wait in one bucket per light page, and the pages are visited from the highest
// id down: the tree writer places children before their parents, so every reference points to
// the same page or a lower one, and each page is asked for once per cut. A shadow ray's
// descent weighs children in other pages by their ghosts (copies kept in the parent's page,
// tree_page.h) and, when it goes on into another page, waits in that page's bucket too, so
// nothing leaves the sweep. (A tree that breaks the order is still rendered right, at the
// cost of asking for a page again.) cutTogether runs the cuts of several blocks in step, so
// that each page is loaded once for all of them: a page cache of a few pages serves a whole
// render unit.
#include <cstdint>
#include <memory>
#include <optional>
#include <span>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/math/vec.h"
#include "core/pbgi/tree.h"
#include "core/pbgi/tree_page.h"

namespace pbgi {

class Scene;

// The near field's radius, in the tree's mean surfel radii (CutOptions::nearRays).
inline constexpr float kNearFieldRadii = 4.0f;
inline constexpr int kMaxNearRays = 4096;
inline constexpr int kMaxClusterRays = 64;

// How far from a hit readSurfaceRadiance reads the tree's surfels: the near field's reading
// radius (kNearReadRadii mean surfel radii of the tree's root). Errors: the source's, or
// DataLoss for a damaged root.
absl::StatusOr<float> surfaceReadRadius(TreePageSource& tree);
// The radiance a surface sends back along a ray that meets it at x (normal n, either way; the
// ray's direction w), read from the tree's surfels within `radius` (surfaceReadRadius) of x as
// the near field reads a hit (see "Near field" above: on x's surface, seen from x along it,
// weighted by distance, the side w sees). nullopt where no surfel was read. Errors: the
// source's, or DataLoss for a damaged tree.
absl::StatusOr<std::optional<Rgb>> readSurfaceRadiance(TreePageSource& tree, const Scene& scene,
                                                       float radius, const Vec3f& x, const Vec3f& n,
                                                       const Vec3f& w);

struct CutOptions {
  float lightSolidAngle = 0.01f;   // eps_L (sr)
  float lightBound = 0.1f;         // eps~_L (sr)
  float receiverBound = 0.001f;    // eps~_E (sr)
  float normalAngle = 0.3f;        // alpha (radians)
  int receiverLeafSize = 8;
  // Surfels whose disk, grown by this factor, holds the receiver are not gathered (its own).
  float selfSkipRadius = 1.0f;
  // The near field by rays: each receiver sends this many rays (cosine-weighted, stratified)
  // no farther than kNearFieldRadii mean surfel radii, and takes what they meet at the
  // radiance the tree's surfels hold there, in place of the surfels whose centres lie that
  // near (0: those surfels, as disks). See "Near field" above.
  int nearRays = 0;
  // Shadow rays (each with its own descent to a surfel) that decide a cluster's light at a
  // receiver node, leaving from receivers spread over the node (one from each of as many equal
  // runs of its receivers in the tree's order), each carrying its share. One ray decides the
  // light of every receiver under the node at once: its visibility and the descent's
  // correction, a random factor per pair that shows as a patch the node's size, with steps where
  // nodes meet. More rays shrink those patches' contrast by their square root. Single
  // receivers take one.
  int clusterRays = 1;
  // Whether a cluster pair's shadow ray is traced from every receiver of the node (to the one
  // surfel its descent picked), each receiver taking the cluster's light exactly when its own
  // ray arrives: visibility per receiver, with no step where receiver nodes meet, at the cost
  // of a ray per receiver served. Otherwise one ray, from a random receiver, decides for the
  // whole node, which takes the light as a linear field.
  bool recordVisibility = false;
  // How a shadow ray's descent weighs a cluster's children (descend() in the .cpp): false, by
  // what each one's SH sends the receiver; true, by its power and normal cone alone (no SH:
  // faster, and noisier where children face different ways). The bake's first bounce uses it.
  bool coneDescent = false;

  bool operator==(const CutOptions&) const = default;
  // InvalidArgument naming the field when a value is out of range. Zero thresholds are
  // allowed: the cut then refines down to every surfel against every receiver.
  absl::Status validate() const;
  std::string toString() const;
};

// Quality presets: "draft", "default", "high". Unknown names are InvalidArgument.
absl::StatusOr<CutOptions> cutPreset(std::string_view name);

// A receiver: a point that gathers on the side of its normal.
struct CutReceiver {
  Vec3f p{0.0f};
  Vec3f n{0.0f, 0.0f, 1.0f};   // unit shading normal, on the gathering side
  Vec3f ng{0.0f, 0.0f, 1.0f};  // geometric normal on that side: shadow rays leave along it
};

// The cut's counters, each declared once: X(member of CutStats, the renderer's PbgiCounter, its
// name among the render's counters, what it counts). CutStats holds them, adds them up and
// prints them; the PBGI integrator reports them (core/render/pbgi_receiver.h).
#define PBGI_CUT_COUNTERS(X)                                                                       \
  X(cuts, kCuts, "cuts", "bidirectional cuts (one per block)")                                     \
  X(receivers, kCutReceivers, "cut_receivers", "shading points in the cuts")                       \
  X(receiverNodes, kCutReceiverNodes, "cut_receiver_nodes", "nodes of the shading-point trees")    \
  X(pairs, kCutPairs, "cut_pairs", "light x receiver pairs looked at")                             \
  X(clusterPairs, kCutClusterPairs, "cut_cluster_pairs",                                           \
    "light clusters (interior nodes) evaluated against receivers")                                 \
  X(receiversServed, kCutReceiversServed, "cut_receivers_served",                                  \
    "evaluations times the shading points under them (the cost unshared)")                         \
  X(leafPairs, kCutLeafPairs, "cut_leaf_pairs", "light leaves evaluated surfel by surfel")         \
  X(surfelTerms, kCutSurfelTerms, "cut_surfel_terms", "surfels in those leaves")                   \
  X(refinedLight, kCutRefinedLight, "cut_refined_light", "pairs refined on the light side")        \
  X(refinedReceiver, kCutRefinedReceiver, "cut_refined_receiver",                                  \
    "pairs refined on the receiver side")                                                          \
  X(culled, kCutCulled, "cut_culled",                                                              \
    "pairs below every receiver's horizon, or of the receiver's own surfel")                       \
  X(shadowRays, kCutShadowRays, "cut_shadow_rays", "visibility rays between clusters and surfels") \
  X(occluded, kCutOccluded, "cut_occluded", "of the visibility rays, blocked")                     \
  X(pageRequests, kCutPageRequests, "cut_page_requests", "tree pages the cuts asked for")          \
  X(nearRays, kCutNearRays, "cut_near_rays", "near-field rays traced")                             \
  X(nearHits, kCutNearHits, "cut_near_hits", "of those, that met a surface within the near field") \
  X(nearUnread, kCutNearUnread, "cut_near_unread",                                                 \
    "of those, where no surfel was read (they take the others' mean)")

struct CutStats {
#define PBGI_CUT_COUNTER_MEMBER(member, counter, name, what) uint64_t member = 0;
  PBGI_CUT_COUNTERS(PBGI_CUT_COUNTER_MEMBER)
#undef PBGI_CUT_COUNTER_MEMBER
  uint64_t peakPendingPairs = 0;  // the most pairs any cut held waiting on pages: a maximum

  CutStats& operator+=(const CutStats& o);
  // "cuts=... receivers=... peak_pending_pairs=...": the counters' names without "cut_".
  std::string toString() const;
};

// One cut of several run together (cutTogether): its receivers, its key, where its irradiance
// goes (the receivers' size).
struct CutJob {
  std::span<const CutReceiver> receivers;
  uint64_t key = 0;
  std::span<Rgb> out;
  // When set, the random numbers of each light node's evaluations (its shadow rays' descents
  // and origins) come from this key and the node alone, not from `key` and the receiver node:
  // cuts that share it (a frame's blocks) pick the same surfels of a cluster for neighbouring
  // receivers, so that what one cluster's sampling gets wrong varies smoothly across receiver
  // nodes and blocks instead of stepping where they meet.
  std::optional<uint64_t> lightKey;
};

// How many pages cutTogether's cuts sweep at a time: one, so that a cache of two pages loads
// each page once per unit.
inline constexpr uint32_t kCutWindowPages = 1;

class BidirectionalCut;

// Several cuts through one tree at once (the blocks of a render unit), each exactly as
// BidirectionalCut::irradiance would run it alone, but swept in step: the cuts evaluate their
// pairs on the highest kCutWindowPages pages any of them waits on, then the next pages down,
// so a page is asked for by every cut that needs it within a few pages of one another and a
// small page cache serves all but the first. Cuts run in parallel (TBB, isolated: the calling
// thread takes no other work while it waits). cuts[i] runs jobs[i]; stats add up in job order.
// Errors: the first job's (in order) that failed.
absl::Status cutTogether(TreePageSource& tree, const Scene& scene,
                         std::span<BidirectionalCut* const> cuts, std::span<const CutJob> jobs,
                         CutStats* stats);

// Reusable buffers for cuts, so that cuts after the first allocate little. One per thread.
class BidirectionalCut {
 public:
  // Options must be valid (validate() first when they come from a user).
  explicit BidirectionalCut(const CutOptions& options);
  ~BidirectionalCut();
  BidirectionalCut(BidirectionalCut&&) noexcept;

  const CutOptions& options() const { return options_; }

  // out[i] = irradiance at receivers[i] from the light the tree holds (out has the receivers'
  // size). `key` seeds every random number. Errors: InvalidArgument for a non-finite receiver
  // or a zero normal; the source's error for a page it cannot give; DataLoss for a damaged
  // tree (references outside a page, a tree deeper than any the builder makes) or radiance
  // that makes the result non-finite.
  absl::Status irradiance(TreePageSource& tree, const Scene& scene,
                          std::span<const CutReceiver> receivers, uint64_t key,
                          std::span<Rgb> out, CutStats* stats,
                          std::optional<uint64_t> lightKey = std::nullopt);

 private:
  friend absl::Status cutTogether(TreePageSource&, const Scene&, std::span<BidirectionalCut* const>,
                                  std::span<const CutJob>, CutStats*);
  struct State;
  CutOptions options_;
  std::unique_ptr<State> state_;
};

// The same light by brute force: every surfel of the tree against every receiver, each pair as
// the cut evaluates a surfel and a single receiver (the same visibility samples). For tests:
// a cut with all thresholds 0 must agree with it.
absl::Status bruteForceIrradiance(TreePageSource& tree, const Scene& scene,
                                  std::span<const CutReceiver> receivers, const CutOptions& options,
                                  std::span<Rgb> out);

}  // namespace pbgi
