#include "core/render/pbgi_integrator.h"

#include <algorithm>
#include <numbers>
#include <vector>

#include "core/render/integrators.h"
#include "core/render/pbgi_receiver.h"

namespace pbgi {

namespace {

class PerPixelScratch final : public IntegratorScratch {
 public:
  explicit PerPixelScratch(const PbgiSettings& settings)
      : gatherer(settings.perPixel),
        pixel(settings.glossy, static_cast<size_t>(settings.maxGathersPerPixel)) {}
  Gatherer gatherer;
  PixelGathers pixel;
};

class PerPixelPbgi final : public PixelIntegrator {
 public:
  PerPixelPbgi(const Scene& scene, TreePageSource& tree, const PbgiSettings& settings)
      : scene_(scene), tree_(tree), settings_(settings) {}

  std::string name() const override { return "pbgi"; }
  std::span<const CounterSpec> counterSpecs() const override { return pbgiCounterSpecs(); }
  std::unique_ptr<IntegratorScratch> newScratch() const override {
    return std::make_unique<PerPixelScratch>(settings_);
  }

  absl::Status shadePixel(std::span<const Ray> rays, std::span<Rng> rngs,
                          std::span<PathSample> out, IntegratorScratch* scratch,
                          RenderCounters* counters) const override {
    auto& state = static_cast<PerPixelScratch&>(*scratch);
    state.pixel.newPixel();
    GatherStats stats;
    for (size_t s = 0; s < rays.size(); ++s) {
      const Receiver r = traceReceiver(scene_, rays[s], rngs[s], settings_.pathTracer, &out[s],
                                       counters);
      if (r.kind == ReceiverKind::kGlossy) {
        absl::StatusOr<Rgb> lo =
            state.pixel.reflect(tree_, scene_, r, out[s].albedo, rngs[s], &stats, counters);
        if (!lo.ok()) return lo.status();
        out[s].indirect = *lo;
        continue;
      }
      if (r.kind != ReceiverKind::kDiffuse) continue;
      Rgb e(0.0f);
      if (const SharedGather* g = state.pixel.shared().find(r.hit.p, r.n, r.wo, kNoMaterial)) {
        e = g->value;
        ++(*counters)[kGatherReuses];
      } else {
        absl::StatusOr<Rgb> gathered = state.gatherer.irradiance(tree_, r.hit.p, r.n, &stats);
        if (!gathered.ok()) return gathered.status();
        if (absl::Status st = checkGathered(*gathered); !st.ok()) return st;
        e = *gathered;
        ++(*counters)[kGathers];
        state.pixel.shared().add({.p = r.hit.p,
                                  .n = r.n,
                                  .reach = kReuseDistanceFraction * r.hit.t,
                                  .planeReach = kReusePlaneFraction * r.hit.t,
                                  .key = kNoMaterial,
                                  .wo = Vec3f(0.0f),
                                  .value = e});
      }
      out[s].indirect = out[s].albedo * e * std::numbers::inv_pi_v<float>;
    }
    addGatherStats(stats, counters);
    return absl::OkStatus();
  }

 private:
  const Scene& scene_;
  TreePageSource& tree_;
  PbgiSettings settings_;
};

class BidirectionalScratch final : public IntegratorScratch {
 public:
  explicit BidirectionalScratch(const PbgiSettings& settings)
      : pixel(settings.glossy, static_cast<size_t>(settings.maxGathersPerPixel)),
        cut(settings.cut) {}
  PixelGathers pixel;
  BidirectionalCut cut;
  std::vector<CutReceiver> receivers;
  std::vector<size_t> sampleOf;  // receiver -> sample
  std::vector<Rgb> irradiance;
};

class BidirectionalPbgi final : public Integrator {
 public:
  BidirectionalPbgi(const Scene& scene, TreePageSource& tree, const PbgiSettings& settings)
      : scene_(scene), tree_(tree), settings_(settings) {}

  std::string name() const override { return "pbgi"; }
  std::span<const CounterSpec> counterSpecs() const override { return pbgiCounterSpecs(); }
  std::unique_ptr<IntegratorScratch> newScratch() const override {
    return std::make_unique<BidirectionalScratch>(settings_);
  }
  int blockSize() const override { return settings_.blockSize; }

  absl::Status render(const TileSamples& samples, std::span<PathSample> out,
                      IntegratorScratch* scratch, RenderCounters* counters) const override {
    auto& state = static_cast<BidirectionalScratch&>(*scratch);
    state.receivers.clear();
    state.sampleOf.clear();
    GatherStats stats;
    const size_t spp = static_cast<size_t>(samples.spp);
    for (size_t i = 0; i < samples.pixelCount(); ++i) {
      state.pixel.newPixel();
      for (size_t k = i * spp; k < (i + 1) * spp; ++k) {
        const Receiver r = traceReceiver(scene_, samples.rays[k], samples.rngs[k],
                                         settings_.pathTracer, &out[k], counters);
        if (r.kind == ReceiverKind::kGlossy) {
          absl::StatusOr<Rgb> lo = state.pixel.reflect(tree_, scene_, r, out[k].albedo,
                                                       samples.rngs[k], &stats, counters);
          if (!lo.ok()) return lo.status();
          out[k].indirect = *lo;
        } else if (r.kind == ReceiverKind::kDiffuse) {
          state.receivers.push_back({.p = r.hit.p, .n = r.n, .ng = r.ng});
          state.sampleOf.push_back(k);
        }
      }
    }
    addGatherStats(stats, counters);
    state.irradiance.resize(state.receivers.size());
    CutStats cutStats;
    if (absl::Status s = state.cut.irradiance(tree_, scene_, state.receivers, samples.unitKey,
                                              state.irradiance, &cutStats);
        !s.ok()) {
      return s;
    }
    addCutStats(cutStats, counters);
    for (size_t j = 0; j < state.receivers.size(); ++j) {
      PathSample& ps = out[state.sampleOf[j]];
      ps.indirect = ps.albedo * state.irradiance[j] * std::numbers::inv_pi_v<float>;
    }
    return absl::OkStatus();
  }

 private:
  const Scene& scene_;
  TreePageSource& tree_;
  PbgiSettings settings_;
};

}  // namespace

WarpedGatherOptions glossyGatherOptions(const GatherOptions& gather) {
  WarpedGatherOptions o;
  o.resolution = std::clamp(gather.resolution * 4 / 3, 2, kMaxMicrobufferResolution);
  o.nearFieldFactor = gather.nearFieldFactor;
  o.selfSkipRadius = gather.selfSkipRadius;
  return o;
}

std::unique_ptr<Integrator> makePbgiIntegrator(const Scene& scene, TreePageSource& tree,
                                               const PbgiSettings& settings) {
  if (settings.gather == PbgiGatherKind::kPerPixel) {
    return std::make_unique<PerPixelPbgi>(scene, tree, settings);
  }
  return std::make_unique<BidirectionalPbgi>(scene, tree, settings);
}

}  // namespace pbgi
