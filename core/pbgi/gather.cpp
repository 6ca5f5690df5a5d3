#include "core/pbgi/gather.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/pbgi/gather_internal.h"
#include "core/pbgi/sh.h"
#include "core/pbgi/tree_build.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

using namespace gather_internal;

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
  return gather_internal::validateNearField("gather options", nearFieldFactor, selfSkipRadius);
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
      "gathers={} nodes_visited={} culled_plane={} clusters={} "
      "clusters_invisible={} disks={} near_field={} surfels_skipped={} surfels_back_facing={} "
      "pages_touched={} faces_skipped={} pixels_skipped={}",
      gathers, nodesVisited, nodesCulledPlane, clustersSplatted, clustersInvisible,
      disksSplatted, nearFieldRayCasts, surfelsSkipped, surfelsBackFacing, pagesTouched,
      facesSkipped, pixelsSkipped);
}

Gatherer::Gatherer(const GatherOptions& options)
    : options_(options), buffer_(checkedResolution(options)) {
}

void Gatherer::gatherSurfels(const TreePage& page, const TreeNode& leaf, const Vec3f& p,
                             const Vec3f& n, GatherStats* stats) {
  forEachSeenSurfel(page, leaf, p, n, options_.selfSkipRadius, options_.nearFieldFactor, stats,
                    [&](const SeenSurfel& seen) {
                      const Surfel& s = *seen.surfel;
                      // In the buffer's axes about the receiver (the identity unless local).
                      const Vec3f center = local_ ? p + toBuffer(s.position - p) : s.position;
                      const Vec3f normal = toBuffer(seen.side.normal);
                      if (seen.near) {
                        buffer_.rayCastDisk(center, normal, s.radius, seen.side.radiance);
                        ++stats->nearFieldRayCasts;
                      } else {
                        buffer_.splatDisk(center, normal, s.radius, seen.side.radiance,
                                          kLayerExtentFactor * s.radius);
                        ++stats->disksSplatted;
                      }
                    });
}

bool Gatherer::splatNode(const NodeAttributes& a, const NodeBounds& bounds,
                         const WaveletRadiance* wavelet, const Vec3f& p,
                         GatherStats* stats) {
  const float maxSolidAngle = options_.maxSolidAngle;
  const Vec3f toCentroid = a.centroid - p;
  const float distance2 = toCentroid.length2();
  // The cheap extent test first: it saves the SH evaluation for large nodes.
  if (!(distance2 > 0.0f) ||
      kPi * bounds.boundRadius2 > kMaxExtentFactor * maxSolidAngle * bounds.centerDistance2) {
    return false;
  }
  const float distance = std::sqrt(distance2);
  const Vec3f dir = toCentroid / distance;
  ClusterView view;
  viewCluster(a, dir, &view);
  const float area = view.coverage();  // both sides: a node seen from behind covers too
  if (area > maxSolidAngle * distance2) return false;
  if (!(area > 0.0f)) {
    ++stats->clustersInvisible;
    return true;
  }
  buffer_.splatFootprint(toBuffer(dir), distance, area / distance2,
                         clusterRadiance(a, view, wavelet), clusterDepthExtent(a, dir));
  ++stats->clustersSplatted;
  return true;
}

absl::Status Gatherer::traverse(TreePageSource& tree, const Vec3f& p, const Vec3f& n,
                                GatherStats* stats) {
  return walk_.run(
      tree, p, n, stats,
      [&](const NodeAttributes& a, const NodeBounds& bounds, const WaveletRadiance* w) {
        return splatNode(a, bounds, w, p, stats);
      },
      [&](const TreePage& page, const TreeNode& leaf) { gatherSurfels(page, leaf, p, n, stats); });
}

absl::Status gatherTogether(TreePageSource& tree, std::span<Gatherer> gatherers,
                            std::span<const Vec3f> positions, std::span<const Vec3f> normals,
                            std::span<Rgb> out, GatherStats* stats) {
  const size_t count = positions.size();
  PBGI_CHECK_EQ(normals.size(), count);
  PBGI_CHECK_EQ(out.size(), count);
  PBGI_CHECK_GE(gatherers.size(), count);
  thread_local std::vector<Vec3f> units;
  thread_local std::vector<GatherStats> local;
  units.resize(count);
  local.assign(count, GatherStats{});
  for (size_t i = 0; i < count; ++i) {
    absl::StatusOr<Vec3f> n = receiverNormal(positions[i], normals[i]);
    if (!n.ok()) return n.status();
    units[i] = *n;
    local[i].gathers = 1;
    gatherers[i].buffer_.clear(positions[i], *n);
    gatherers[i].swept_.begin(tree.root(), positions[i], *n);
  }
  // One page at a time, from the highest any walk waits on.
  for (;;) {
    std::optional<uint32_t> high;
    for (size_t i = 0; i < count; ++i) {
      const std::optional<uint32_t> next = gatherers[i].swept_.nextPage();
      if (next && (!high || *next > *high)) high = next;
    }
    if (!high) break;
    for (size_t i = 0; i < count; ++i) {
      Gatherer& g = gatherers[i];
      const Vec3f& p = positions[i];
      const Vec3f& n = units[i];
      GatherStats* s = &local[i];
      if (absl::Status status = g.swept_.sweep(
              tree, *high, s,
              [&](const NodeAttributes& a, const NodeBounds& b, const WaveletRadiance* w) {
                return g.splatNode(a, b, w, p, s);
              },
              [&](const TreePage& page, const TreeNode& leaf) { g.gatherSurfels(page, leaf, p, n, s); });
          !status.ok()) {
        return status;
      }
    }
  }
  for (size_t i = 0; i < count; ++i) {
    Gatherer& g = gatherers[i];
    local[i].facesSkipped = static_cast<uint64_t>(g.buffer_.skippedFaces());
    local[i].pixelsSkipped = static_cast<uint64_t>(g.buffer_.skippedPixels());
    if (stats != nullptr) *stats += local[i];
    out[i] = g.buffer_.irradiance(units[i]);
    if (!isFinite(out[i])) {
      return absl::DataLossError(fmt::format(
          "gather: irradiance {} at {} is not finite: the tree holds non-finite radiance", out[i],
          positions[i]));
    }
  }
  return absl::OkStatus();
}

absl::Status Gatherer::rasterize(TreePageSource& tree, const Vec3f& position, const Vec3f& normal,
                                 GatherStats* stats) {
  return rasterizeIn(tree, position, normal, nullptr, stats);
}

absl::Status Gatherer::rasterizeIn(TreePageSource& tree, const Vec3f& position, const Vec3f& normal,
                                   const Frame* frame, GatherStats* stats) {
  absl::StatusOr<Vec3f> n = receiverNormal(position, normal);
  if (!n.ok()) return n.status();
  GatherStats local;
  local.gathers = 1;
  // The buffer's horizon: the normal in its axes (+z in the receiver's own frame).
  buffer_.clear(position, frame != nullptr ? Vec3f(0.0f, 0.0f, 1.0f) : *n);
  local_ = frame;
  absl::Status status = traverse(tree, position, *n, &local);
  local_ = nullptr;
  local.facesSkipped = static_cast<uint64_t>(buffer_.skippedFaces());
  local.pixelsSkipped = static_cast<uint64_t>(buffer_.skippedPixels());
  if (stats != nullptr) *stats += local;
  return status;
}

absl::Status Gatherer::rasterizeLocal(TreePageSource& tree, const Vec3f& position,
                                      const Frame& frame, GatherStats* stats) {
  return rasterizeIn(tree, position, frame.n, &frame, stats);
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
