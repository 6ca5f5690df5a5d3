#include "core/render/pbgi_integrator.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <vector>

#include "core/pbgi/gather_reuse.h"
#include "core/scene/material.h"

namespace pbgi {

namespace {

// How near a sample's first hit must lie to an earlier gather of its pixel to share it, as
// fractions of that gather's distance from the camera: along the gather's normal (the same
// plane), and in all (the same neighbourhood; a pixel spans about 1/500 of its distance).
constexpr float kReusePlaneFraction = 0.005f;
constexpr float kReuseDistanceFraction = 0.05f;
constexpr float kReuseNormalCos = 0.95f;
constexpr float kReuseViewCos = 0.999f;

class PbgiScratch final : public IntegratorScratch {
 public:
  PbgiScratch(const PbgiIntegratorSettings& settings)
      : gatherer(settings.gather),
        warped(settings.glossy),
        shared(kReuseNormalCos, kReuseViewCos, static_cast<size_t>(settings.maxGathersPerPixel)) {}
  Gatherer gatherer;
  WarpedGatherer warped;
  // The pixel's gathers: irradiance for diffuse receivers (key kNoMaterial: any diffuse
  // material shares it), reflected radiance for glossy ones (their own material and view).
  GatherReuse shared;
};

}  // namespace

WarpedGatherOptions glossyGatherOptions(const GatherOptions& gather) {
  WarpedGatherOptions o;
  o.resolution = std::clamp(gather.resolution * 4 / 3, 2, kMaxMicrobufferResolution);
  o.nearFieldFactor = gather.nearFieldFactor;
  o.selfSkipRadius = gather.selfSkipRadius;
  return o;
}

PbgiIntegrator::PbgiIntegrator(const Scene& scene, TreePageSource& tree,
                               const PbgiIntegratorSettings& settings)
    : scene_(scene), tree_(tree), settings_(settings) {}

std::unique_ptr<IntegratorScratch> PbgiIntegrator::newScratch() const {
  return std::make_unique<PbgiScratch>(settings_);
}

absl::Status PbgiIntegrator::shadePixel(std::span<const Ray> rays, std::span<Rng> rngs,
                                        std::span<PathSample> out, IntegratorScratch* scratch,
                                        RenderCounters* counters) const {
  auto& state = static_cast<PbgiScratch&>(*scratch);
  state.shared.clear();
  PathTracerSettings directOnly = settings_.pathTracer;
  directOnly.maxDepth = 1;
  for (size_t s = 0; s < rays.size(); ++s) {
    const Rng start = rngs[s];
    SurfaceHit hit;
    out[s] = tracePath(scene_, rays[s], rngs[s], directOnly, &hit);
    if (!out[s].hit) continue;
    if (hit.material == kNoMaterial || isBlack(out[s].albedo)) {
      ++counters->blackReceivers;
      continue;
    }
    const Material& material = scene_.material(hit.material);
    const Bsdf bsdf(material, out[s].albedo);
    if (bsdf.isBlack()) {
      ++counters->blackReceivers;
      continue;
    }
    if (bsdf.isDelta() || material.type == MaterialType::kDielectric) {
      // The same path as the path tracer's, from the same random numbers: its direct light
      // is the one just computed, and its indirect light is path traced.
      rngs[s] = start;
      out[s] = tracePath(scene_, rays[s], rngs[s], settings_.pathTracer);
      ++counters->pathTracedReceivers;
      continue;
    }
    // Two-sided surfaces gather on the side the camera sees.
    const Vec3f wo = -rays[s].dir;
    const Vec3f n = dot(hit.ng, wo) >= 0.0f ? hit.ns : -hit.ns;
    const bool diffuse = material.type == MaterialType::kDiffuse;
    const uint32_t key = diffuse ? kNoMaterial : hit.material;
    Rgb value(0.0f);
    if (const SharedGather* r = state.shared.find(hit.p, n, wo, key)) {
      value = r->value;
      ++counters->gatherReuses;
    } else {
      if (diffuse) {
        absl::StatusOr<Rgb> e = state.gatherer.irradiance(tree_, hit.p, n, &counters->gather);
        if (!e.ok()) return e.status();
        value = *e;
      } else {
        const Frame frame(n);
        const Vec2f jitter(rngs[s].uniform(), rngs[s].uniform());
        absl::StatusOr<Rgb> lo = state.warped.reflect(tree_, hit.p, frame, bsdf,
                                                      frame.toLocal(wo), jitter, &counters->gather);
        if (!lo.ok()) return lo.status();
        value = *lo;
        ++counters->glossyGathers;
      }
      ++counters->gathers;
      if (!isFinite(value)) {
        return absl::DataLossError(
            "the tree's radiance made a gather non-finite (a damaged or hostile tree)");
      }
      state.shared.add({.p = hit.p,
                        .n = n,
                        .reach = kReuseDistanceFraction * hit.t,
                        .planeReach = kReusePlaneFraction * hit.t,
                        .key = key,
                        .wo = diffuse ? Vec3f(0.0f) : wo,
                        .value = value});
    }
    out[s].indirect = diffuse ? out[s].albedo * value * std::numbers::inv_pi_v<float> : value;
  }
  return absl::OkStatus();
}

}  // namespace pbgi
