#include "core/pbgi/gather.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/pbgi/sh.h"
#include "core/pbgi/tree_build.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

// A node's bounding sphere may cover this many times maxSolidAngle before the node must be
// refined, whatever its projected area: a node seen edge-on has a small projected area but
// spreads across the buffer, and one round footprint would misplace its occlusion.
constexpr float kMaxExtentFactor = 4.0f;
// Pages held at once by one traversal. Depth-first order leaves a page's subtree before
// returning to its parent page, so a few suffice; evicting one is safe (it is fetched again).
constexpr size_t kMaxHeldPages = 16;
// Deeper than any tree the builder makes: a reference cycle in a damaged file stops here.
constexpr uint32_t kMaxGatherDepth = 2 * kMaxTreeLevels;
// A cluster's splat reaches this many bounding radii in depth: its round footprint spreads
// past the cluster's true outline (most at grazing views), onto pixels where the same
// surface lies up to a bounding diameter nearer or farther, and those must count as one
// surface (coverage adds up) rather than as layers that hide each other. Measured: 1 loses
// 2-3 % of the light of a surface seen from close by, 4 merges an occluder with what it hides.
constexpr float kLayerExtentFactor = 2.0f;
// Surfels centred within this fraction of their radius of the receiver's tangent plane
// (or behind it) are on the receiver's own surface.
constexpr float kCoplanarFraction = 0.01f;

float absDotExtent(const Vec3f& n, const Vec3f& half) {
  return std::abs(n.x) * half.x + std::abs(n.y) * half.y + std::abs(n.z) * half.z;
}

// True when every surfel under a node with normal cone `cone`, inside the sphere (centre at
// `distance` from the receiver along -toReceiver, radius `radius`), faces away from the
// receiver: the angle between the cone's axis and toReceiver (unit) exceeds 90 degrees plus
// the cone's half-angle plus the angle the sphere subtends.
bool facesAway(const NormalCone& cone, const Vec3f& toReceiver, float distance, float radius) {
  const float sinB = radius / distance;
  const float cosB = safeSqrt(1.0f - sinB * sinB);
  const float cosG = cone.cosAngle;
  const float sinG = safeSqrt(1.0f - cosG * cosG);
  if (cosG * cosB - sinG * sinB <= 0.0f) return false;  // the two angles reach 90 degrees
  return dot(cone.axis, toReceiver) < -(sinG * cosB + cosG * sinB);
}

// The projected area of a node towards w (unit, from the node to the receiver): its SH
// estimate held within what the normal cone allows, area * cos(angle to w) between the
// cone's extremes. Band-2 SH overshoot a clamped cosine by 6 % face-on and ring above 0 past
// 90 degrees; coverage is energy here, so a flat cluster (narrow cone) must get its exact
// area * cos, and only a curved one the SH's shape.
float boundedProjectedArea(const NodeAttributes& a, float shArea, const Vec3f& w) {
  const float cosT = dot(a.cone.axis, w);
  const float sinT = safeSqrt(1.0f - cosT * cosT);
  const float cosG = a.cone.cosAngle;
  const float sinG = safeSqrt(1.0f - cosG * cosG);
  // Largest n.w over the cone: cos(max(0, angle - half-angle)); smallest: cos(angle +
  // half-angle) while that stays below 90 degrees, else 0.
  const float upper = cosT >= cosG ? 1.0f : cosT * cosG + sinT * sinG;
  const float lower = cosG > 0.0f ? cosT * cosG - sinT * sinG : 0.0f;
  return std::clamp(shArea, a.area * std::max(0.0f, lower), a.area * std::max(0.0f, upper));
}

absl::Status receiverError(const Vec3f& position, const Vec3f& normal) {
  return absl::InvalidArgumentError(fmt::format(
      "gather: receiver needs a finite position and a finite non-zero normal, got position {} "
      "normal {}",
      position, normal));
}

absl::StatusOr<Vec3f> receiverNormal(const Vec3f& position, const Vec3f& normal) {
  const float len = length(normal);
  if (!isFinite(position) || !isFinite(normal) || !(len > 0.0f) || !std::isfinite(len)) {
    return receiverError(position, normal);
  }
  return normal / len;
}

// The microbuffer's resolution, once the options are known to be valid: invalid options
// reaching a Gatherer are a caller bug (users' options go through validate()).
int checkedResolution(const GatherOptions& options) {
  if (absl::Status s = options.validate(); !s.ok()) {
    detail::checkFailed(__FILE__, __LINE__, std::string(s.message()));
  }
  return options.resolution;
}

}  // namespace

absl::Status GatherOptions::validate() const {
  if (!(maxSolidAngle > 0.0f && maxSolidAngle <= 4.0f * kPi)) {
    return absl::InvalidArgumentError(fmt::format(
        "gather options: maxSolidAngle must be in (0, 4 pi] sr, got {}", maxSolidAngle));
  }
  if (resolution < kMinMicrobufferResolution || resolution > kMaxMicrobufferResolution) {
    return absl::InvalidArgumentError(
        fmt::format("gather options: resolution must be in [{}, {}], got {}",
                    kMinMicrobufferResolution, kMaxMicrobufferResolution, resolution));
  }
  if (!(nearFieldFactor >= 0.0f && nearFieldFactor <= 1e3f)) {
    return absl::InvalidArgumentError(fmt::format(
        "gather options: nearFieldFactor must be in [0, 1000], got {}", nearFieldFactor));
  }
  if (!(selfSkipRadius >= 0.0f && selfSkipRadius <= 100.0f)) {
    return absl::InvalidArgumentError(
        fmt::format("gather options: selfSkipRadius must be in [0, 100], got {}", selfSkipRadius));
  }
  return absl::OkStatus();
}

std::string GatherOptions::toString() const {
  return fmt::format(
      "gather(maxSolidAngle={:g} resolution={} nearFieldFactor={:g} selfSkipRadius={:g})",
      maxSolidAngle, resolution, nearFieldFactor, selfSkipRadius);
}

absl::StatusOr<GatherOptions> gatherPreset(std::string_view name) {
  GatherOptions o;
  if (name == "draft") {
    o.maxSolidAngle = 0.08f;
    o.resolution = 8;
    o.nearFieldFactor = 2.0f;
  } else if (name == "default") {
    // The defaults of GatherOptions.
  } else if (name == "high") {
    o.maxSolidAngle = 0.01f;
    o.resolution = 20;
    o.nearFieldFactor = 6.0f;
  } else {
    return absl::InvalidArgumentError(
        fmt::format("gather preset \"{}\" unknown; known presets: draft, default, high", name));
  }
  return o;
}

GatherStats& GatherStats::operator+=(const GatherStats& o) {
  gathers += o.gathers;
  nodesVisited += o.nodesVisited;
  nodesCulledPlane += o.nodesCulledPlane;
  nodesCulledCone += o.nodesCulledCone;
  clustersSplatted += o.clustersSplatted;
  clustersInvisible += o.clustersInvisible;
  disksSplatted += o.disksSplatted;
  nearFieldRayCasts += o.nearFieldRayCasts;
  surfelsSkipped += o.surfelsSkipped;
  surfelsBackFacing += o.surfelsBackFacing;
  pagesTouched += o.pagesTouched;
  facesSkipped += o.facesSkipped;
  pixelsSkipped += o.pixelsSkipped;
  return *this;
}

std::string GatherStats::toString() const {
  return fmt::format(
      "gathers={} nodes_visited={} culled_plane={} culled_cone={} clusters={} "
      "clusters_invisible={} disks={} near_field={} surfels_skipped={} surfels_back_facing={} "
      "pages_touched={} faces_skipped={} pixels_skipped={}",
      gathers, nodesVisited, nodesCulledPlane, nodesCulledCone, clustersSplatted, clustersInvisible,
      disksSplatted, nearFieldRayCasts, surfelsSkipped, surfelsBackFacing, pagesTouched,
      facesSkipped, pixelsSkipped);
}

Gatherer::Gatherer(const GatherOptions& options)
    : options_(options), buffer_(checkedResolution(options)) {
  stack_.reserve(8 * kMaxGatherDepth);
  held_.reserve(kMaxHeldPages);
}

absl::StatusOr<const TreePage*> Gatherer::pageFor(TreePageSource& tree, uint32_t id,
                                                  GatherStats* stats) {
  ++useClock_;
  for (HeldPage& h : held_) {
    if (h.id == id) {
      h.lastUse = useClock_;
      return h.page.get();
    }
  }
  ++stats->pagesTouched;
  absl::StatusOr<std::shared_ptr<const TreePage>> page = tree.page(id);
  if (!page.ok()) return page.status();
  PBGI_CHECK(*page != nullptr);  // a source returns a page or an error
  HeldPage* slot;
  if (held_.size() < kMaxHeldPages) {
    slot = &held_.emplace_back();
  } else {
    slot = &*std::min_element(held_.begin(), held_.end(), [](const HeldPage& a, const HeldPage& b) {
      return a.lastUse < b.lastUse;
    });
  }
  slot->id = id;
  slot->page = *std::move(page);
  slot->lastUse = useClock_;
  return slot->page.get();
}

void Gatherer::gatherSurfels(const TreePage& page, const TreeNode& leaf, const Vec3f& p,
                             const Vec3f& n, GatherStats* stats) {
  const float slack = 1e-6f * maxAbsComponent(p);  // float rounding of coplanar positions
  for (const Surfel& s : page.surfelsOf(leaf)) {
    const Vec3f v = s.position - p;
    const float dist2 = v.length2();
    if (dot(v, n) <= kCoplanarFraction * s.radius + slack ||
        dist2 <= sqr(options_.selfSkipRadius * s.radius)) {
      ++stats->surfelsSkipped;
      continue;
    }
    if (dot(s.normal, v) >= 0.0f) {
      ++stats->surfelsBackFacing;
      continue;
    }
    if (dist2 < sqr(options_.nearFieldFactor * s.radius)) {
      buffer_.rayCastDisk(s.position, s.normal, s.radius, s.radiance);
      ++stats->nearFieldRayCasts;
    } else {
      buffer_.splatDisk(s.position, s.normal, s.radius, s.radiance, kLayerExtentFactor * s.radius);
      ++stats->disksSplatted;
    }
  }
}

absl::Status Gatherer::traverse(TreePageSource& tree, const Vec3f& p, const Vec3f& n,
                                GatherStats* stats) {
  const float maxSolidAngle = options_.maxSolidAngle;
  const float planeSlack = 1e-6f * maxAbsComponent(p);
  stack_.clear();
  stack_.push_back({tree.root(), 0});
  while (!stack_.empty()) {
    const StackEntry entry = stack_.back();
    stack_.pop_back();
    absl::StatusOr<const TreePage*> pageOr = pageFor(tree, entry.ref.page, stats);
    if (!pageOr.ok()) return pageOr.status();
    const TreePage& page = **pageOr;
    if (entry.ref.index >= page.nodes.size()) {
      return absl::DataLossError(
          fmt::format("gather: page {} has {} nodes, a reference names node {}", entry.ref.page,
                      page.nodes.size(), entry.ref.index));
    }
    const TreeNode& node = page.nodes[entry.ref.index];
    const NodeAttributes& a = node.attributes;
    ++stats->nodesVisited;

    // Behind the tangent plane: the largest height of the bounds above it is at most 0.
    const Vec3f center = a.bounds.center();
    const Vec3f half = a.bounds.diagonal() * 0.5f;
    const Vec3f fromReceiver = center - p;
    if (a.bounds.empty() || dot(fromReceiver, n) + absDotExtent(n, half) <= planeSlack) {
      ++stats->nodesCulledPlane;
      continue;
    }
    const float boundRadius2 = half.length2();
    const float centerDistance2 = fromReceiver.length2();
    if (centerDistance2 > boundRadius2) {
      const float centerDistance = std::sqrt(centerDistance2);
      if (facesAway(a.cone, fromReceiver / -centerDistance, centerDistance,
                    std::sqrt(boundRadius2))) {
        ++stats->nodesCulledCone;
        continue;
      }
      const Vec3f toCentroid = a.centroid - p;
      const float distance2 = toCentroid.length2();
      // The cheap extent test first: it saves the SH evaluation for large nodes.
      if (distance2 > 0.0f &&
          kPi * boundRadius2 <= kMaxExtentFactor * maxSolidAngle * centerDistance2) {
        const float distance = std::sqrt(distance2);
        const Vec3f dir = toCentroid / distance;
        float basis[kShCoefficients];
        evalShBasis(-dir, basis);  // towards the receiver, as the node's functions expect
        float shArea = 0.0f;
        for (int i = 0; i < kShCoefficients; ++i) shArea += a.areaSh.c[i] * basis[i];
        const float area = boundedProjectedArea(a, shArea, -dir);
        if (area <= maxSolidAngle * distance2) {
          if (!(area > 0.0f)) {
            ++stats->clustersInvisible;
            continue;
          }
          // The radiance is the SH ratio, in which their common ringing cancels.
          Rgb radiance(0.0f);
          if (shArea > 0.0f) {
            for (int i = 0; i < kShCoefficients; ++i) radiance += a.powerSh.c[i] * basis[i];
            radiance = vmax(radiance, Rgb(0.0f)) / shArea;
          }
          buffer_.splatFootprint(dir, distance, area / distance2, radiance,
                                 kLayerExtentFactor * std::sqrt(boundRadius2));
          ++stats->clustersSplatted;
          continue;
        }
      }
    }

    if (node.leaf()) {
      if (uint64_t{node.first} + node.surfelCount > page.surfels.size()) {
        return absl::DataLossError(fmt::format(
            "gather: page {} node {} names surfels {}..{} of {}", entry.ref.page, entry.ref.index,
            node.first, uint64_t{node.first} + node.surfelCount, page.surfels.size()));
      }
      gatherSurfels(page, node, p, n, stats);
      continue;
    }
    if (uint64_t{node.first} + node.childCount > page.children.size()) {
      return absl::DataLossError(fmt::format(
          "gather: page {} node {} names children {}..{} of {}", entry.ref.page, entry.ref.index,
          node.first, uint64_t{node.first} + node.childCount, page.children.size()));
    }
    if (entry.depth + 1 > kMaxGatherDepth) {
      return absl::DataLossError(
          fmt::format("gather: tree deeper than {} levels at page {} node {} (a reference cycle?)",
                      kMaxGatherDepth, entry.ref.page, entry.ref.index));
    }
    // Reversed, so that children come off the stack in Morton order: the page is walked
    // front to back.
    const std::span<const NodeRef> children = page.childrenOf(node);
    for (size_t i = children.size(); i-- > 0;) stack_.push_back({children[i], entry.depth + 1});
  }
  return absl::OkStatus();
}

absl::Status Gatherer::rasterize(TreePageSource& tree, const Vec3f& position, const Vec3f& normal,
                                 GatherStats* stats) {
  absl::StatusOr<Vec3f> n = receiverNormal(position, normal);
  if (!n.ok()) return n.status();
  GatherStats local;
  local.gathers = 1;
  buffer_.clear(position, *n);
  absl::Status status = traverse(tree, position, *n, &local);
  held_.clear();  // pages live no longer than the gather that used them
  local.facesSkipped = static_cast<uint64_t>(buffer_.skippedFaces());
  local.pixelsSkipped = static_cast<uint64_t>(buffer_.skippedPixels());
  if (stats != nullptr) *stats += local;
  return status;
}

absl::StatusOr<Rgb> Gatherer::irradiance(TreePageSource& tree, const Vec3f& position,
                                         const Vec3f& normal, GatherStats* stats) {
  if (absl::Status s = rasterize(tree, position, normal, stats); !s.ok()) return s;
  const Rgb e = buffer_.irradiance(*receiverNormal(position, normal));
  if (!isFinite(e)) {
    return absl::DataLossError(
        fmt::format("gather: irradiance {} at {} is not finite: the tree holds non-finite radiance",
                    e, position));
  }
  return e;
}

absl::StatusOr<Rgb> gatherIrradiance(TreePageSource& tree, const Vec3f& position,
                                     const Vec3f& normal, const GatherOptions& options,
                                     GatherStats* stats) {
  if (absl::Status s = options.validate(); !s.ok()) return s;
  thread_local std::unique_ptr<Gatherer> gatherer;
  if (gatherer == nullptr || !(gatherer->options() == options)) {
    gatherer = std::make_unique<Gatherer>(options);
  }
  return gatherer->irradiance(tree, position, normal, stats);
}

}  // namespace pbgi
