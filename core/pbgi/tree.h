#pragma once
// The nodes of a PBGI tree (Christensen 2008) as the builder computes them and the gather
// reads them: what a cluster of surfels looks like from far away.
//
// Per node: tight bounds, the area-weighted centroid, a cone bounding the surfels' normals,
// the total disk area, the projected area as a spherical function (9 SH coefficients), and
// the radiant intensity it sends out (9 x RGB SH coefficients, "outgoing power" in
// Christensen's words). Surfels are two-sided, as surfaces are for the path tracer: each side
// sends its own radiance, and a tree's surfels face their brighter side (the writer turns them,
// so a wall wound the wrong way is lit and seen as it is). The SH describe the front sides;
// the back sides, dimmer and most often black, are kept as their summed power (area times
// back radiance): seen from direction w, a node's back sides cover evaluate(areaSh, -w) and
// send its mean back radiance. Both spherical functions are sums over the surfels, so a parent's
// are the sums of its children's: a node is built from its children alone, never from the
// points below them, which is what lets the out-of-core build hold only m + 1 points.
//
// Seen from direction w (pointing away from the node), the node covers projected area
// evaluate(areaSh, w) and sends intensity evaluate(powerSh, w); their ratio is the mean
// radiance a receiver in direction w sees. Both are clamped at 0 by whoever evaluates
// them: band-limited SH ring slightly negative behind a one-sided disk.
//
// A node goes by several types on its way from the builder to a traversal; each exists for one
// stage:
//   NodeAttributes (here)         what a node is, in float: every stage carries it.
//   BuiltNode (tree_build.h)      the builder's output, in post-order: attributes, child
//                                 count, a leaf's surfels.
//   InMemoryNode (tree_build.h)   the same held whole in memory (tests, small trees).
//   PageNode (tree_page.h)        a node placed in a page by the pager: children as NodeRefs,
//                                 codebook indices, ghosts of children in other pages.
//   GhostNode (tree_page.h)       a copy of a child's record kept in its parent's page.
//   TreeNode (tree_page.h)        a node as a traversal reads it from a decoded TreePage:
//                                 dequantized attributes, where its children or surfels are.
//   NodeRef (tree_page.h)         where a node is: (page, index in the page).
// The page's byte layout is in tree_page.h; the file around the pages in
// formats/pbgi/page_file.h.
#include <cstdint>
#include <span>
#include <string>

#include "core/math/vec.h"
#include "core/pbgi/sh.h"
#include "core/pbgi/surfel.h"

namespace pbgi {

// The directions a node's surfels face: every normal n has dot(n, axis) >= cosAngle.
// cosAngle = -1 means any direction (the axis is then meaningless but still unit).
struct NormalCone {
  Vec3f axis{0.0f, 0.0f, 1.0f};
  float cosAngle = 1.0f;

  bool operator==(const NormalCone&) const = default;
};

struct NodeAttributes {
  Bounds3f bounds;      // of the surfels' centres, grown by their radius
  Vec3f centroid{0.0f};  // area-weighted mean of the surfels' centres
  NormalCone cone;
  float area = 0.0f;       // sum of the disks' areas
  uint64_t pointCount = 0;  // surfels below the node
  Sh9 areaSh;              // projected area towards w
  Sh9Rgb powerSh;          // radiant intensity towards w (W/sr) of the front sides
  Rgb backPower{0.0f};     // sum of area times back radiance

  bool operator==(const NodeAttributes&) const = default;
  std::string toString() const;
};

// The attributes of a leaf holding `surfels`, and of an interior node over `children`.
// Deterministic: sums run in the order given, in float, so the same inputs in the same order
// give the same bits. Children of interior nodes are in Morton order.
NodeAttributes leafAttributes(std::span<const Surfel> surfels);
NodeAttributes mergeAttributes(std::span<const NodeAttributes> children);

// Mean radiance the node sends towards direction w (unit, pointing away from the node): its
// intensity over its projected area, both clamped at 0, black where the projected area is 0.
Rgb meanRadiance(const NodeAttributes& node, const Vec3f& w);

}  // namespace pbgi
