#include "core/render/pbgi_integrator.h"

#include <algorithm>
#include <cstdint>
#include <numbers>
#include <optional>
#include <tuple>
#include <unordered_map>
#include <vector>

#include <fmt/format.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "core/render/integrators.h"
#include "core/render/pbgi_receiver.h"
#include "core/render/sky_irradiance.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

// The settings an integrator runs with: where records take the environment's light, the
// samples' own direct light leaves it out.
PbgiSettings withSky(const Scene& scene, PbgiSettings settings) {
  if (settings.skyAtRecords && hasSkyLight(scene)) {
    settings.pathTracer.skyAtDiffuseFirstHit = false;
  } else {
    settings.skyAtRecords = false;
  }
  return settings;
}

// The settings as a PBGI integrator over `tree` runs them: the sky where the records take it
// (withSky), and camera paths through mirrors and glass that end on a diffuse surface taking
// the light it sends back from the tree's surfels there (PathTracerSettings::specularChainEnd),
// so that what they show is as smooth as the rest of the image; where no surfel is read there
// (or the tree cannot give a page, which the cut then reports), the path goes on.
PbgiSettings forTree(const Scene& scene, TreePageSource& tree, const PbgiSettings& settings) {
  PbgiSettings s = withSky(scene, settings);
  const absl::StatusOr<float> radius = surfaceReadRadius(tree);
  if (!radius.ok() || !(*radius > 0.0f)) return s;
  s.pathTracer.specularChainEnd = [&scene, &tree, r = *radius](
                                      const SurfaceHit& hit,
                                      const Vec3f& towardsViewer) -> std::optional<Rgb> {
    const absl::StatusOr<std::optional<Rgb>> sent =
        readSurfaceRadiance(tree, scene, r, hit.p, hit.ng, -towardsViewer);
    return sent.ok() ? *sent : std::nullopt;
  };
  return s;
}

// The environment's irradiance at each of `count` gathers, gather(i) giving where gather i
// lies and how it faces (black when the samples take the environment themselves). Counts its
// rays.
template <typename Gather>
void gatherSky(const std::optional<SkyIrradiance>& sky, size_t count, Gather&& gather,
               std::vector<Rgb>* out, RenderCounters* counters) {
  out->assign(count, Rgb(0.0f));
  if (!sky) return;
  uint64_t rays = 0;
  for (size_t i = 0; i < count; ++i) {
    const CutReceiver r = gather(i);
    (*out)[i] = sky->at(r.p, r.n, r.ng, skyKey(r.p), &rays);
  }
  (*counters)[kSkyRays] += rays;
}

// The first hits of pixels [firstPixel, endPixel) of a unit, as both gathers take them: each
// pixel's glossy samples gather here through its warped microbuffer (shared within the pixel),
// and each diffuse one goes to diffuse(k, receiver) for the caller's gather. Errors name the
// pixel.
template <typename Diffuse>
absl::Status traceFirstHits(const Scene& scene, const LambertianLobes& lobes, TreePageSource& tree,
                            const PbgiSettings& settings, const TileSamples& samples,
                            size_t firstPixel, size_t endPixel, std::span<PathSample> out,
                            PixelGathers& pixel, GatherStats* stats, RenderCounters* counters,
                            Diffuse&& diffuse) {
  const size_t spp = static_cast<size_t>(samples.spp);
  for (size_t i = firstPixel; i < endPixel; ++i) {
    if (samples.cancelled()) return cancelledError();
    pixel.newPixel(samples.pixels[i]);
    for (size_t k = i * spp; k < (i + 1) * spp; ++k) {
      const Receiver r = traceReceiver(scene, lobes, samples.rays[k], samples.rngs[k],
                                       settings.pathTracer, &out[k], counters);
      if (r.kind == ReceiverKind::kGlossy) {
        absl::StatusOr<Rgb> lo =
            pixel.reflect(tree, scene, r, out[k].albedo, samples.rngs[k], stats, counters);
        if (!lo.ok()) {
          return absl::Status(lo.status().code(),
                              fmt::format("pixel ({}, {}): {}", samples.pixels[i].x,
                                          samples.pixels[i].y, std::string(lo.status().message())));
        }
        out[k].indirect = *lo;
      } else if (r.kind == ReceiverKind::kDiffuse) {
        diffuse(k, r);
      }
    }
  }
  return absl::OkStatus();
}

// What a diffuse sample's first hit is to the records: where it lies, how it faces, how it is
// seen and how far from the camera.
struct DiffuseHit {
  Vec3f p, n, ng, wo;
  float t = 0.0f;
  static DiffuseHit of(const Receiver& r) { return {r.hit.p, r.n, r.ng, r.wo, r.hit.t}; }
};

// What a diffuse sample makes of its gathers' irradiance and sky light (Receiver's).
struct DiffuseReflectance {
  Rgb indirect, sky;
  static DiffuseReflectance of(const Receiver& r) { return {r.reflectance, r.skyReflectance}; }
  void apply(const Rgb& irradiance, const Rgb& skyIrradiance, float weight, PathSample& out) const {
    // In the order a diffuse material's albedo always took: the same bits.
    out.indirect += indirect * irradiance * std::numbers::inv_pi_v<float> * weight;
    out.direct += sky * skyIrradiance * std::numbers::inv_pi_v<float> * weight;
  }
};

// The diffuse gather a sample takes: an earlier one of its pixel that lies on the same surface
// nearby (its footprint's light, shared by the pixel's samples: receivers are gathers, not
// samples), or, when there is none, `next`, which the caller then gathers at the sample.
uint32_t sharedSlot(GatherReuse& pixel, const DiffuseHit& r, uint32_t next,
                    RenderCounters* counters) {
  if (const SharedGather* g = pixel.find(r.p, r.n, r.wo, kNoMaterial)) {
    ++(*counters)[kGatherReuses];
    return g->slot;
  }
  ++(*counters)[kGathers];
  pixel.add({.p = r.p,
             .n = r.n,
             .reach = kReuseDistanceFraction * r.t,
             .planeReach = kReusePlaneFraction * r.t,
             .key = kNoMaterial,
             .wo = Vec3f(0.0f),
             .slot = next});
  return next;
}

// sharedSlot for the bidirectional cut: a new record becomes one of `records`, the cut's
// receivers.
uint32_t sharedRecord(GatherReuse& pixel, const DiffuseHit& r, std::vector<CutReceiver>* records,
                      RenderCounters* counters) {
  const auto next = static_cast<uint32_t>(records->size());
  const uint32_t slot = sharedSlot(pixel, r, next, counters);
  if (slot == next) records->push_back({.p = r.p, .n = r.n, .ng = r.ng});
  return slot;
}

// How far a record may lie from a sample of another pixel that interpolates it, as a fraction
// of the sample's distance from the camera: a few pixels at film resolutions (a pixel spans
// about 1/500 of its distance at 1080p), so that a coarse image, whose pixels are wide in the
// scene, gathers per pixel rather than stretch records over light that changes between them.
constexpr float kInterpolationReachFraction = 0.02f;

// How many per-pixel gathers of a tile walk the tree together (gatherTogether): enough that
// each page a small cache loads serves many of them, few enough that their microbuffers stay
// bounded (512 of 12^2 x 6 pixels: about 21 MB a thread).
constexpr size_t kGathersTogether = 512;

class PerPixelScratch final : public IntegratorScratch {
 public:
  PerPixelScratch(const PbgiSettings& settings, std::shared_ptr<WaveletBsdfCache> bsdfs)
      : pixel(settings, static_cast<size_t>(settings.maxGathersPerPixel), std::move(bsdfs)) {
    gatherers.reserve(kGathersTogether);  // Gatherers stay where they are
  }
  PixelGathers pixel;
  std::vector<Gatherer> gatherers;
  std::vector<Vec3f> positions, normals, geometric;  // the tile's gathers
  std::vector<Rgb> values, sky;
  // Each diffuse sample's: its gather and how it reflects it.
  struct Use {
    size_t sample;
    uint32_t slot;
    DiffuseReflectance reflectance;
  };
  std::vector<Use> uses;
};

// The per-pixel gather: every diffuse camera sample takes a gather of its own or shares one
// of its pixel's earlier samples'; the tile's gathers then walk the tree together, in batches
// (gatherTogether), so that a small page cache loads a page once for many of them.
class PerPixelPbgi final : public Integrator {
 public:
  PerPixelPbgi(const Scene& scene, TreePageSource& tree, const PbgiSettings& settings)
      : scene_(scene), lobes_(scene), tree_(tree), settings_(forTree(scene, tree, settings)) {
    if (settings_.skyAtRecords) sky_.emplace(scene);
  }

  std::string name() const override { return "pbgi"; }
  std::span<const CounterSpec> counterSpecs() const override { return pbgiCounterSpecs(); }
  std::unique_ptr<IntegratorScratch> newScratch() const override {
    return std::make_unique<PerPixelScratch>(settings_, bsdfs_);
  }

  absl::Status render(const TileSamples& samples, std::span<PathSample> out,
                      IntegratorScratch* scratch, RenderCounters* counters) const override {
    auto& state = static_cast<PerPixelScratch&>(*scratch);
    state.positions.clear();
    state.normals.clear();
    state.geometric.clear();
    state.uses.clear();
    GatherStats stats;
    if (absl::Status s =
            traceFirstHits(scene_, lobes_, tree_, settings_, samples, 0, samples.pixelCount(), out,
                           state.pixel, &stats, counters,
                           [&](size_t k, const Receiver& r) {
                             const auto next = static_cast<uint32_t>(state.positions.size());
                             const uint32_t slot = sharedSlot(state.pixel.shared(),
                                                              DiffuseHit::of(r), next, counters);
                             if (slot == next) {
                               state.positions.push_back(r.hit.p);
                               state.normals.push_back(r.n);
                               state.geometric.push_back(r.ng);
                             }
                             state.uses.push_back({k, slot, DiffuseReflectance::of(r)});
                           });
        !s.ok()) {
      return s;
    }
    const size_t gathers = state.positions.size();
    state.values.resize(gathers);
    for (size_t first = 0; first < gathers; first += kGathersTogether) {
      const size_t count = std::min(kGathersTogether, gathers - first);
      while (state.gatherers.size() < count) state.gatherers.emplace_back(settings_.perPixel);
      if (absl::Status s =
              gatherTogether(tree_, std::span(state.gatherers).first(count),
                             std::span<const Vec3f>(state.positions).subspan(first, count),
                             std::span<const Vec3f>(state.normals).subspan(first, count),
                             std::span(state.values).subspan(first, count), &stats);
          !s.ok()) {
        return s;
      }
    }
    for (const Rgb& e : state.values) {
      if (absl::Status s = checkGathered(e); !s.ok()) return s;
    }
    gatherSky(
        sky_, gathers,
        [&](size_t i) {
          return CutReceiver{state.positions[i], state.normals[i], state.geometric[i]};
        },
        &state.sky, counters);
    for (const PerPixelScratch::Use& u : state.uses) {
      out[u.sample].indirect = Rgb(0.0f);
      u.reflectance.apply(state.values[u.slot], state.sky[u.slot], 1.0f, out[u.sample]);
    }
    addGatherStats(stats, counters);
    return absl::OkStatus();
  }

 private:
  const Scene& scene_;
  LambertianLobes lobes_;
  TreePageSource& tree_;
  PbgiSettings settings_;
  std::optional<SkyIrradiance> sky_;
  // The product gather's BSDF slices, projected once per material for every thread.
  std::shared_ptr<WaveletBsdfCache> bsdfs_ = std::make_shared<WaveletBsdfCache>();
};

// One block's state: its receivers, its cut's buffers, what it counted.
struct BidirectionalBlock {
  BidirectionalBlock(const PbgiSettings& settings, std::shared_ptr<WaveletBsdfCache> bsdfs)
      : pixel(settings, static_cast<size_t>(settings.maxGathersPerPixel), std::move(bsdfs),
              settings.recordSpacing),
        cut(settings.cut) {}
  PixelGathers pixel;
  BidirectionalCut cut;
  std::vector<CutReceiver> receivers;
  // What each diffuse sample takes: records and their weights, a sample's entries one after
  // another, weights summing to 1.
  struct Use {
    size_t sample;
    uint32_t record;
    float weight;
    DiffuseReflectance reflectance;
  };
  std::vector<Use> uses;
  std::vector<Rgb> irradiance;
  std::vector<Rgb> sky;  // the environment's irradiance at each receiver
  RenderCounters counters;
  // With records spaced out: the records of each pixel of the block that holds them (a range
  // of `anchorRecords`), the samples that interpolate them, and pixels by position.
  std::vector<SharedGather> anchorRecords;
  std::vector<std::pair<uint32_t, uint32_t>> anchorRange;  // by pixel - the block's first
  std::vector<std::tuple<size_t, DiffuseHit, DiffuseReflectance>> between;
  std::unordered_map<uint64_t, uint32_t> pixelAt;  // (y << 32 | x) -> pixel - the block's first
};

class BidirectionalScratch final : public IntegratorScratch {
 public:
  std::vector<std::unique_ptr<BidirectionalBlock>> blocks;
};

class BidirectionalPbgi final : public Integrator {
 public:
  BidirectionalPbgi(const Scene& scene, TreePageSource& tree, const PbgiSettings& settings)
      : scene_(scene), lobes_(scene), tree_(tree), settings_(forTree(scene, tree, settings)) {
    if (settings_.skyAtRecords) sky_.emplace(scene);
  }

  std::string name() const override { return "pbgi"; }
  std::span<const CounterSpec> counterSpecs() const override { return pbgiCounterSpecs(); }
  std::unique_ptr<IntegratorScratch> newScratch() const override {
    return std::make_unique<BidirectionalScratch>();
  }
  int blockSize() const override { return settings_.blockSize; }
  int blocksPerUnit() const override { return settings_.blocksPerUnit; }
  // The record pixels past a block's far borders: its last pixels interpolate towards them as
  // every other pixel between records does, so the border is not a seam.
  int blockHalo() const override { return settings_.recordSpacing > 1 ? settings_.recordSpacing : 0; }

  // Each block: its camera samples traced to their first hits (glossy ones gather there), its
  // diffuse ones the receivers of its cut; the unit's cuts then run together (cutTogether),
  // sharing the page cache's pages, each keyed by its own block.
  absl::Status render(const TileSamples& samples, std::span<PathSample> out,
                      IntegratorScratch* scratch, RenderCounters* counters) const override {
    auto& state = static_cast<BidirectionalScratch&>(*scratch);
    const size_t count = samples.blocks.size();
    PBGI_CHECK_GT(count, size_t{0});
    while (state.blocks.size() < count) {
      state.blocks.push_back(std::make_unique<BidirectionalBlock>(settings_, bsdfs_));
    }
    std::vector<absl::Status> errors(count);
    tbb::this_task_arena::isolate([&] {
      tbb::parallel_for(size_t{0}, count, [&](size_t b) {
        errors[b] =
            traceBlock(samples, samples.blocks[b], out, *state.blocks[b], counters->values.size());
      });
    });
    for (size_t b = 0; b < count; ++b) {
      counters->add(state.blocks[b]->counters);
      if (!errors[b].ok()) return errors[b];
    }
    std::vector<BidirectionalCut*> cuts(count);
    std::vector<CutJob> jobs(count);
    for (size_t b = 0; b < count; ++b) {
      BidirectionalBlock& block = *state.blocks[b];
      cuts[b] = &block.cut;
      jobs[b] = {.receivers = block.receivers,
                 .key = samples.blocks[b].key,
                 .out = block.irradiance,
                 .lightKey = samples.frameKey};
    }
    CutStats cutStats;
    if (absl::Status s = cutTogether(tree_, scene_, cuts, jobs, &cutStats); !s.ok()) return s;
    addCutStats(cutStats, counters);
    for (size_t b = 0; b < count; ++b) {
      const BidirectionalBlock& block = *state.blocks[b];
      size_t last = SIZE_MAX;
      for (const BidirectionalBlock::Use& u : block.uses) {
        PathSample& ps = out[u.sample];
        if (u.sample != last) ps.indirect = Rgb(0.0f);
        last = u.sample;
        u.reflectance.apply(block.irradiance[u.record], block.sky[u.record], u.weight, ps);
      }
    }
    return absl::OkStatus();
  }

 private:
  absl::Status traceBlock(const TileSamples& samples, const UnitBlock& unitBlock,
                          std::span<PathSample> out, BidirectionalBlock& block,
                          size_t counterCount) const {
    block.receivers.clear();
    block.uses.clear();
    block.pixel.newBlock();
    block.counters = RenderCounters{};
    block.counters.values.assign(counterCount, 0);
    GatherStats stats;
    const int spacing = settings_.recordSpacing;
    const size_t spp = static_cast<size_t>(samples.spp);
    const size_t first = unitBlock.firstPixel;
    // The block's pixels and its halo's (record pixels only: their records serve the block).
    const size_t pixels = unitBlock.pixelCount + unitBlock.haloCount;
    block.anchorRecords.clear();
    block.anchorRange.assign(pixels, {0, 0});
    block.between.clear();
    const auto isAnchor = [&](const Vec2i& p) { return p.x % spacing == 0 && p.y % spacing == 0; };
    if (absl::Status s = traceFirstHits(
            scene_, lobes_, tree_, settings_, samples, first, first + pixels, out,
            block.pixel, &stats, &block.counters,
            [&](size_t k, const Receiver& r) {
              if (spacing > 1 && !isAnchor(samples.pixels[k / spp])) {
                block.between.push_back({k, DiffuseHit::of(r), DiffuseReflectance::of(r)});
                return;
              }
              block.uses.push_back({k,
                                    sharedRecord(block.pixel.shared(), DiffuseHit::of(r),
                                                 &block.receivers, &block.counters),
                                    1.0f, DiffuseReflectance::of(r)});
              if (spacing > 1) {
                // The pixel's records so far, kept for the pixels between (in place of the
                // copy its earlier sample left at the end).
                auto& range = block.anchorRange[k / spp - first];
                const std::span<const SharedGather> kept = block.pixel.shared().kept();
                if (range.second > range.first && range.second == block.anchorRecords.size()) {
                  block.anchorRecords.resize(range.first);
                }
                range.first = static_cast<uint32_t>(block.anchorRecords.size());
                block.anchorRecords.insert(block.anchorRecords.end(), kept.begin(), kept.end());
                range.second = static_cast<uint32_t>(block.anchorRecords.size());
              }
            });
        !s.ok()) {
      return s;
    }
    if (spacing > 1) interpolateBetween(samples, unitBlock, block);
    addGatherStats(stats, &block.counters);
    block.irradiance.resize(block.receivers.size());
    gatherSky(
        sky_, block.receivers.size(), [&](size_t i) { return block.receivers[i]; }, &block.sky,
        &block.counters);
    return absl::OkStatus();
  }

  // The samples of pixels between the records' (recordSpacing > 1): each takes the records of
  // the four record pixels around it that lie on its surface (the test a pixel's samples share
  // by), weighted bilinearly by its place among them; a sample that finds none, at an edge or
  // a crease, or whose record pixels are not all there (past the image's edge), gathers its own
  // record, shared within its pixel. Only the block's own pixels and its halo's count (the
  // record pixels past its far borders, whose records its own cut gathers), so a block's
  // records and pixels depend on the block alone, and its last pixels interpolate as the rest.
  void interpolateBetween(const TileSamples& samples, const UnitBlock& unitBlock,
                          BidirectionalBlock& block) const {
    const int spacing = settings_.recordSpacing;
    const size_t spp = static_cast<size_t>(samples.spp);
    const size_t first = unitBlock.firstPixel;
    const auto key = [](int x, int y) {
      return (uint64_t{static_cast<uint32_t>(y)} << 32) | static_cast<uint32_t>(x);
    };
    block.pixelAt.clear();
    for (size_t i = 0; i < unitBlock.pixelCount + unitBlock.haloCount; ++i) {
      block.pixelAt.emplace(key(samples.pixels[first + i].x, samples.pixels[first + i].y),
                            static_cast<uint32_t>(i));
    }
    GatherReuse& own = block.pixel.shared();
    size_t ownPixel = SIZE_MAX;
    for (const auto& [k, r, reflectance] : block.between) {
      const Vec2i p = samples.pixels[k / spp];
      const int ax = p.x - ((p.x % spacing) + spacing) % spacing;
      const int ay = p.y - ((p.y % spacing) + spacing) % spacing;
      const float fx = static_cast<float>(p.x - ax) / static_cast<float>(spacing);
      const float fy = static_cast<float>(p.y - ay) / static_cast<float>(spacing);
      const size_t firstUse = block.uses.size();
      float total = 0.0f;
      bool enclosed = true;
      for (int corner = 0; corner < 4 && enclosed; ++corner) {
        const int cx = corner & 1, cy = corner >> 1;
        const float w = (cx ? fx : 1.0f - fx) * (cy ? fy : 1.0f - fy);
        if (!(w > 0.0f)) continue;
        const auto at = block.pixelAt.find(key(ax + cx * spacing, ay + cy * spacing));
        if (at == block.pixelAt.end()) {
          // A record pixel outside the block and its halo (past the image's edge): the records
          // on this side would stand for light they were not gathered for. The pixel gathers
          // its own.
          block.uses.resize(firstUse);
          total = 0.0f;
          enclosed = false;
          continue;
        }
        const auto [begin, end] = block.anchorRange[at->second];
        const std::span<const SharedGather> records(block.anchorRecords.data() + begin,
                                                    end - begin);
        const SharedGather* g = own.find(records, r.p, r.n, r.wo, kNoMaterial);
        if (g != nullptr && length(r.p - g->p) <= kInterpolationReachFraction * r.t) {
          block.uses.push_back({k, g->slot, w, reflectance});
          total += w;
        }
      }
      if (total > 0.0f) {
        for (size_t u = firstUse; u < block.uses.size(); ++u) block.uses[u].weight /= total;
        ++block.counters[kGatherReuses];
        continue;
      }
      if (k / spp != ownPixel) {
        own.clear();
        ownPixel = k / spp;
      }
      block.uses.push_back(
          {k, sharedRecord(own, r, &block.receivers, &block.counters), 1.0f, reflectance});
    }
  }

  const Scene& scene_;
  LambertianLobes lobes_;
  TreePageSource& tree_;
  PbgiSettings settings_;
  std::optional<SkyIrradiance> sky_;
  // The product gather's BSDF slices, projected once per material for every thread.
  std::shared_ptr<WaveletBsdfCache> bsdfs_ = std::make_shared<WaveletBsdfCache>();
};

}  // namespace

WarpedGatherOptions glossyGatherOptions(const GatherOptions& gather) {
  WarpedGatherOptions o;
  o.resolution = std::clamp(gather.resolution * 4 / 3, 2, kMaxMicrobufferResolution);
  o.nearFieldFactor = gather.nearFieldFactor;
  o.selfSkipRadius = gather.selfSkipRadius;
  return o;
}

AdaptiveGatherOptions adaptiveGatherOptions(const GatherOptions& gather) {
  AdaptiveGatherOptions o;
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
