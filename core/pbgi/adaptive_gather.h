#pragma once
// Importance-driven adaptive microbuffers for glossy receivers (Wang, Meng and Boubekeur,
// "Wavelet Point-Based Global Illumination", section 3.2): the gather of warped_gather.h, but
// into a quadtree on the full sphere whose leaves (the buffer's pixels) are refined where the
// receiver's BSDF and the light it gathers put their weight.
//
// The buffer. Each cube face (microbuffer.h's layout) starts as baseResolution^2 cells, each
// a quadtree down to maxLevel further halvings; a cell knows its face square, centre direction
// and exact solid angle, so the leaves tile the sphere (their solid angles sum to 4 pi).
// Cells entirely below the receiver's horizon are never rasterized.
//
// Refinement by the BSDF (the paper's F_p, Ritschel et al.'s importance, by subdivision
// instead of warping): brdfSamples directions drawn from the BSDF (a jittered stratified
// lattice, as the warped gather's pixels are) each carry f cos / pdf / count; a cell holding
// more than 1/brdfCells of their sum is split, down to maxLevel. A narrow lobe thus gets small
// cells and the rest of the hemisphere few large ones.
//
// Refinement by the light (the paper's F_l, and its re-splatting): the traversal records every
// node and disk it splats into a cell. A cell carrying more than lightFraction of the
// receiver's reflected radiance is split, and what it recorded goes to its children: splats
// no larger than the child they land in are composed there; nodes larger are walked again
// (their subtree, against the refined cells), disks larger are ray-cast. Passes repeat until
// no cell qualifies, maxLevel is reached or the buffer holds maxCells leaves. A bright small
// source (a caustic's spot, a light's reflection) thus ends in cells of its own size.
//
// The convolution: L = sum over leaf cells of L(cell) f(wo, w) cos(w) solid angle (cell), w
// its centre, the paper's form; the weights are scaled so that their sum equals the sampled
// f cos / pdf mean (the BSDF's directional albedo), which holds the energy of lobes narrower
// than the finest cell. Splats, depth layers, near-field ray casts, culling and pages are the
// warped gather's. It gathers the reflection hemisphere (transmission is path traced by the
// integrators); delta BSDFs reflect nothing here.
#include <cstdint>
#include <span>
#include <string>
#include <utility>
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

struct AdaptiveGatherOptions {
  int baseResolution = 4;    // cells a face side before any refinement
  int maxLevel = 5;          // halvings of a base cell at most
  int brdfSamples = 256;     // BSDF samples that drive the first refinement
  int brdfCells = 64;        // a cell holding more than 1/brdfCells of the BSDF's weight splits
  float lightFraction = 1.0f / 32.0f;  // a cell reflecting more than this share splits
  int maxCells = 2048;       // leaf cells at most
  // A node is splatted whole into a cell when its solid angle is at most this share of the
  // cell's, refined otherwise: splats placed by their centres then even out over a cell. (A disk
  // no larger than its cell is splatted whole, a larger one ray-cast.)
  float splatFraction = 0.25f;
  // Surfels nearer than this many radii are ray-cast, as in GatherOptions.
  float nearFieldFactor = 4.0f;
  // Surfels whose disk, grown by this factor, holds the receiver are not gathered.
  float selfSkipRadius = 1.0f;

  bool operator==(const AdaptiveGatherOptions&) const = default;
  // InvalidArgument naming the field when a value is out of range.
  absl::Status validate() const;
  std::string toString() const;
};

// One per thread; not thread-safe. Gathers after the first reuse its buffers.
class AdaptiveGatherer {
 public:
  // Options must be valid (validate() first when they come from a user).
  explicit AdaptiveGatherer(const AdaptiveGatherOptions& options);

  const AdaptiveGatherOptions& options() const { return options_; }

  // Outgoing radiance towards wo, as WarpedGatherer::reflect (the same arguments, errors and
  // black cases).
  absl::StatusOr<Rgb> reflect(TreePageSource& tree, const Vec3f& position, const Frame& frame,
                              const Bsdf& bsdf, const Vec3f& woLocal, const Vec2f& jitter,
                              GatherStats* stats);

  // The last reflect()'s leaf cells, for tests and debugging pictures: how many, and each
  // one's centre direction, solid angle, refinement level and convolution weight (black below
  // the horizon) and what it gathered (coverage-weighted radiance).
  int cellCount() const { return static_cast<int>(leaves_.size()); }
  const Vec3f& cellDirection(int k) const { return cells_[leaves_[k]].dir; }
  float cellSolidAngle(int k) const { return cells_[leaves_[k]].solidAngle; }
  int cellLevel(int k) const { return cells_[leaves_[k]].level; }
  const Rgb& cellWeight(int k) const { return cells_[leaves_[k]].weight; }
  Rgb cellRadiance(int k) const { return cells_[leaves_[k]].pixel.radiance(); }
  // The leaf cell holding world direction `dir` (any length but 0): an index for the above.
  int cellOf(const Vec3f& dir) const;
  // Cells split by the light in the last reflect() (after the BSDF's refinement).
  int lightSplits() const { return lightSplits_; }

 private:
  struct Cell {
    Vec3f dir{0.0f};   // unit centre direction
    float solidAngle = 0.0f;  // exact
    float u0 = 0.0f, v0 = 0.0f, size = 0.0f;  // the face square [u0, u0 + size] x [v0, v0 + size]
    int32_t child = -1;  // first of four (u low v low, u high v low, u low v high, high high), -1: leaf
    int32_t firstRecord = -1;  // its splats, a list through Record::next; -1: none
    int32_t leafIndex = -1;    // in leaves_, -1 for split cells
    uint8_t face = 0, level = 0;
    bool active = false;       // reaches above the horizon
    float cosRadius = 1.0f, sinRadius = 0.0f;  // of the angle from dir to the farthest corner
    float smallestLeaf = 0.0f;  // the least solid angle of a leaf in its subtree (its own if a leaf)
    int32_t parent = -1;
    Rgb weight{0.0f};  // f cos solid angle at the centre, scaled (see the header comment)
    LayeredPixel pixel;
  };
  // What the traversal composed into a cell, to do again in its children when it splits.
  struct Record {
    TreeWalk::StackEntry node;  // a tree node (surfel < 0) or a piece of a far disk
    int32_t surfel;
    int32_t next;
    Vec3f dir;
    float distance, extent, omega;  // omega: the splat's solid angle
    float boundOmega;               // a node's bounding sphere's solid angle ...
    float boundSin;                 // ... and the sine of its half-angle (0 for disks)
    Rgb radiance;                   // not yet scaled by coverage
  };
  struct Disk {
    Vec3f center, normal;
    float radius;
    Rgb radiance;
  };
  struct Sample {
    Vec3f dir;
    Rgb weight;  // f cos / pdf / count
  };

  void initCells();
  // Splits leaf cell c into four; the caller re-sorts what it held.
  void split(int c);
  int leafOf(const Vec3f& dir) const;  // index in cells_
  void refineByBsdf(const Bsdf& bsdf, const Vec3f& wo, const Vec2f& jitter);
  void weigh(const Bsdf& bsdf, const Vec3f& wo);
  // Sets a cell's centre, solid angle, angular radius and whether it reaches above the
  // horizon from its face square; clears its links.
  void shape(Cell* c) const;
  // Whether the cone of half-angle asin(sinRadius) around dir reaches a cell of less than
  // `solidAngle` (the quadtree walked from the roots, only into cells the cone reaches).
  bool reachesCellBelow(const Vec3f& dir, float sinRadius, float solidAngle);
  // Composes a splat into leaf cell c (recording it); false when c cannot hold it whole.
  bool place(int c, const Record& r, GatherStats* stats);
  void compose(int c, const Record& r);
  // A far disk's footprint, in pieces no larger than the cells they land in.
  void placeDisk(const Record& disk, GatherStats* stats);
  absl::Status traverse(TreePageSource& tree, std::span<const TreeWalk::StackEntry> starts,
                        const Vec3f& p, GatherStats* stats);
  void gatherSurfels(const TreePage& page, const TreeNode& leaf, const Vec3f& p,
                     GatherStats* stats);
  absl::Status refineByLight(TreePageSource& tree, const Vec3f& p, GatherStats* stats);
  void rayCast(const Vec3f& p);
  void collectLeaves();

  AdaptiveGatherOptions options_;
  Frame frame_;
  Vec3f wo_{0.0f, 0.0f, 1.0f};
  const Bsdf* bsdf_ = nullptr;
  Rgb weightScale_{1.0f};
  Rgb sampledAlbedo_{0.0f};     // the samples' sum of f cos / pdf / count
  bool sampleWeights_ = false;  // cells weigh their samples (a lobe narrower than the cells)
  std::vector<Cell> cells_;
  std::vector<int32_t> leaves_;
  std::vector<Record> records_;
  std::vector<std::pair<Record, int>> pieces_;  // a disk's footprint pieces and their depth
  std::vector<Disk> rayCasts_;  // near or large disks, ray-cast at the end
  std::vector<Sample> samples_;
  std::vector<float> mass_;
  std::vector<int32_t> work_;
  std::vector<int32_t> cellStack_;
  std::vector<TreeWalk::StackEntry> rewalk_;
  int leafCount_ = 0;
  int lightSplits_ = 0;
  TreeWalk walk_;
};

}  // namespace pbgi
