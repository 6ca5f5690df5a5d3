// The cut's brute-force reference: every surfel against every receiver, each by a shadow ray.
#include <algorithm>

#include "core/pbgi/cut_internal.h"
#include "core/util/check.h"

namespace pbgi {

using namespace cut_internal;

absl::Status bruteForceIrradiance(TreePageSource& tree, const Scene& scene,
                                  std::span<const CutReceiver> receivers, const CutOptions& options,
                                  std::span<Rgb> out) {
  PBGI_CHECK_EQ(out.size(), receivers.size());
  std::fill(out.begin(), out.end(), Rgb(0.0f));
  CutStats stats;
  float nearRadius = 0.0f;
  if (options.nearRays > 0 && !receivers.empty()) {
    // The near field as the cut takes it, each hit read by a descent of its own.
    const NodeRef root = tree.root();
    absl::StatusOr<std::shared_ptr<const TreePage>> page = tree.page(root.page);
    if (!page.ok()) return page.status();
    absl::StatusOr<float> mean = rootSurfelRadius(**page, root);
    if (!mean.ok()) return mean.status();
    nearRadius = kNearFieldRadii * *mean;
    std::vector<NearHit> hits;
    traceNearField(scene, receivers, options.nearRays, nearRadius, &hits, &stats);
    for (NearHit& hit : hits) {
      if (absl::Status s = readHit(tree, scene, root, kNearReadRadii * *mean, hit, &stats);
          !s.ok()) {
        return s;
      }
    }
    addNearLight(hits, options.nearRays, out, &stats);
  }
  std::vector<std::pair<NodeRef, uint32_t>> stack = {{tree.root(), 0}};
  while (!stack.empty()) {
    const auto [ref, depth] = stack.back();
    stack.pop_back();
    absl::StatusOr<std::shared_ptr<const TreePage>> page = tree.page(ref.page);
    if (!page.ok()) return page.status();
    absl::StatusOr<const TreeNode*> node = nodeAt(**page, ref);
    if (!node.ok()) return node.status();
    if ((*node)->leaf()) {
      if (absl::Status s = checkLeaf(**page, **node, ref); !s.ok()) return s;
      for (const Surfel& s : (*page)->surfelsOf(**node)) {
        for (size_t r = 0; r < receivers.size(); ++r) {
          Rgb light;
          if (surfelLight(s, receivers[r], options.selfSkipRadius, nearRadius, &light) &&
              visibleSurfel(scene, receivers[r], s, &stats)) {
            out[r] += light;
          }
        }
      }
      continue;
    }
    if (absl::Status s = checkInterior(**page, **node, ref, depth); !s.ok()) return s;
    for (const NodeRef& child : (*page)->childrenOf(**node)) stack.push_back({child, depth + 1});
  }
  return absl::OkStatus();
}

}  // namespace pbgi
