// The cut's near field: rays from each receiver, read where they hit from the surfels there.
#include "core/pbgi/cut_internal.h"

#include <algorithm>
#include <cmath>

#include "core/sampling/low_discrepancy.h"
#include "core/sampling/sampling.h"

namespace pbgi::cut_internal {

namespace {

using namespace gather_internal;

}  // namespace

// The tree's mean surfel radius, from its root node in `page`.
absl::StatusOr<float> rootSurfelRadius(const TreePage& page, NodeRef root) {
  absl::StatusOr<const TreeNode*> node = nodeAt(page, root);
  if (!node.ok()) return node.status();
  return meanSurfelRadius((*node)->attributes);
}

// The squared gap between a box and another box around `center` (half-size `halfExtent`).
float boxGap2(const Bounds3f& b, const Vec3f& center, const Vec3f& halfExtent) {
  const Vec3f c = b.center(), h = b.diagonal() * 0.5f;
  float g2 = 0.0f;
  for (int a = 0; a < 3; ++a)
    g2 += sqr(std::max(0.0f, std::abs(c[a] - center[a]) - h[a] - halfExtent[a]));
  return g2;
}

absl::Status readHit(TreePageSource& tree, const Scene& scene, NodeRef root, float radius,
                     NearHit& hit, CutStats* stats) {
  thread_local std::vector<NearStep> steps, stack;
  steps.assign(1, NearStep{.at = root, .depth = 0, .hit = 0});
  while (!steps.empty()) {
    const NearStep step = steps.back();
    steps.pop_back();
    absl::StatusOr<std::shared_ptr<const TreePage>> page = tree.page(step.at.page);
    if (!page.ok()) return page.status();
    if (absl::Status s = readNearSurface(
            scene, **page, step, radius, hit, stack,
            [&](const NearStep& next) { steps.push_back(next); }, stats);
        !s.ok()) {
      return s;
    }
  }
  return absl::OkStatus();
}

// Each receiver's near-field rays, `rays` of them cosine-weighted about its normal and as long
// as `radius`, and the hits (on surfaces that are not lights'). A ray below the receiver's
// geometric surface sees nothing.
void traceNearField(const Scene& scene, std::span<const CutReceiver> receivers, int rays,
                    float radius, std::vector<NearHit>* hits, CutStats* stats) {
  for (uint32_t r = 0; r < receivers.size(); ++r) {
    const CutReceiver& rec = receivers[r];
    const uint64_t seed = hashPoint(rec.p, rec.n);
    const Frame frame(rec.n);
    for (int i = 0; i < rays; ++i) {
      const Vec3f dir =
          frame.toWorld(sampleCosineHemisphere(owenSobol2D(static_cast<uint32_t>(i), seed)));
      if (!(dot(dir, rec.ng) > 0.0f)) continue;
      Ray ray = scene.spawnRay(rec.p, rec.ng, dir);
      ray.tMax = radius;
      ++stats->nearRays;
      SurfaceHit h;
      if (!scene.intersect(ray, &h) || h.material == kNoMaterial) continue;
      ++stats->nearHits;
      hits->push_back({.x = h.p, .n = h.ng, .w = dir, .receiver = r});
    }
  }
}

// Adds each hit's radiance, pi / rays of it (a cosine-weighted estimate), to its receiver. A hit
// where no surfel was read (a corner the reading radius does not fit, a sliver of geometry the
// surfels missed) takes the mean of its receiver's other hits, or nothing when it has none.
// Hits come grouped by receiver (traceNearField).
void addNearLight(std::span<const NearHit> hits, int rays, std::span<Rgb> out, CutStats* stats) {
  const float scale = kPi / static_cast<float>(rays);
  for (size_t first = 0, end = 0; first < hits.size(); first = end) {
    const uint32_t r = hits[first].receiver;
    Rgb sum(0.0f);
    uint32_t read = 0;
    for (end = first; end < hits.size() && hits[end].receiver == r; ++end) {
      if (!(hits[end].weight > 0.0f)) continue;
      sum += hits[end].sum / hits[end].weight;
      ++read;
    }
    const uint32_t unread = static_cast<uint32_t>(end - first) - read;
    stats->nearUnread += unread;
    if (read > 0) {
      out[r] += sum * (scale * (1.0f + static_cast<float>(unread) / static_cast<float>(read)));
    }
  }
}

}  // namespace pbgi::cut_internal

namespace pbgi {

absl::StatusOr<float> surfaceReadRadius(TreePageSource& tree) {
  using namespace cut_internal;
  const NodeRef root = tree.root();
  absl::StatusOr<std::shared_ptr<const TreePage>> rootPage = tree.page(root.page);
  if (!rootPage.ok()) return rootPage.status();
  absl::StatusOr<float> mean = rootSurfelRadius(**rootPage, root);
  if (!mean.ok()) return mean.status();
  return kNearReadRadii * *mean;
}

absl::StatusOr<std::optional<Rgb>> readSurfaceRadiance(TreePageSource& tree, const Scene& scene,
                                                       float radius, const Vec3f& x, const Vec3f& n,
                                                       const Vec3f& w) {
  using namespace cut_internal;
  NearHit hit{.x = x, .n = n, .w = w};
  CutStats stats;
  if (absl::Status s = readHit(tree, scene, tree.root(), radius, hit, &stats); !s.ok()) {
    return s;
  }
  if (!(hit.weight > 0.0f)) return std::nullopt;
  return hit.sum / hit.weight;
}

}  // namespace pbgi
