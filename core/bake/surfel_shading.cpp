#include "core/bake/surfel_shading.h"

#include <algorithm>
#include <atomic>
#include <optional>
#include <vector>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/pbgi/gather.h"
#include "core/render/path_tracer.h"
#include "core/sampling/rng.h"
#include "core/scene/material.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

// Keeps the surfels' light samples apart from every other stream keyed (seed, frame, n).
constexpr uint64_t kSurfelDirectLightDomain = 0x5355524644495245ull;
// And the glossy materials' reflection samples.
constexpr uint64_t kReflectionDomain = 0x5245464c53455453ull;

// The first global triangle id of each of the scene's meshes, for materialOfTriangle.
std::vector<uint64_t> meshBases(const Scene& scene) {
  std::vector<uint64_t> bases(scene.meshes().size());
  for (size_t m = 0; m < bases.size(); ++m) bases[m] = scene.triangleIdBase(m);
  return bases;
}

// The material index of a surfel's triangle (a global triangle id, Scene::globalTriangleId).
uint32_t materialOfTriangle(const Scene& scene, std::span<const uint64_t> bases,
                            uint32_t triangle) {
  const auto it = std::upper_bound(bases.begin(), bases.end(), uint64_t{triangle});
  PBGI_CHECK(it != bases.begin());
  const size_t m = static_cast<size_t>(it - bases.begin()) - 1;
  const uint64_t local = triangle - bases[m];
  PBGI_CHECK_LT(local, scene.meshes()[m].triangleCount());
  return scene.meshes()[m].materials[local];
}

// A light sample arriving at a surfel, in the frame of its normal: direction and radiance over
// its densities (light choice and solid angle), what the BSDF then sends each way.
struct Arrival {
  Vec3f wiLocal;
  Rgb value;
};

// `count` light samples at a surfel (each lighting the side it arrives on, with its shadow
// ray), the blocked and the non-finite left out, each weighted by `weight`.
void sampleArrivals(const Scene& scene, const Surfel& surfel, const Frame& frame, int count,
                    float weight, Rng& rng, std::vector<Arrival>* out) {
  for (int k = 0; k < count; ++k) {
    float selectPdf = 0.0f;
    const std::optional<LightSample> ls =
        sampleUnoccludedLight(scene, surfel.position, surfel.normal, rng, &selectPdf);
    if (!ls) continue;
    const Rgb value = ls->radiance * (weight / (ls->pdf * selectPdf));
    if (isFinite(value)) out->push_back({frame.toLocal(ls->wi), value});
  }
}

}  // namespace

SurfelShadingStats shadeSurfelsDirect(const Scene& scene, std::span<Surfel> surfels,
                                      uint64_t firstSurfelIndex,
                                      const SurfelShadingOptions& options) {
  PBGI_CHECK_GT(options.lightSamples, 0);
  const std::vector<uint64_t> bases = meshBases(scene);
  const float invSamples = 1.0f / static_cast<float>(options.lightSamples);

  std::atomic<uint64_t> emissive{0}, discarded{0}, nonFinite{0};
  tbb::parallel_for(
      tbb::blocked_range<size_t>(0, surfels.size(), 256),
      [&](const tbb::blocked_range<size_t>& range) {
        uint64_t localEmissive = 0, localDiscarded = 0, localNonFinite = 0;
        for (size_t i = range.begin(); i != range.end(); ++i) {
          Surfel& surfel = surfels[i];
          const Material& material =
              scene.material(materialOfTriangle(scene, bases, surfel.triangle));

          // Emissive materials emit on both sides, as the scene's triangle lights do.
          Rgb radiance(0.0f), backRadiance(0.0f);
          if (!isBlack(material.radiance) && isFinite(material.radiance)) {
            radiance += material.radiance;
            backRadiance += material.radiance;
            ++localEmissive;
          }
          // Rough glossy materials whose lobes the SH hold are diffuse surfels too
          // (materialClassOf), of their hemispherical albedo.
          const Rgb diffuse = material.type == MaterialType::kDiffuse ||
                                      surfel.materialClass == MaterialClass::kDiffuse
                                  ? surfel.albedo
                                  : Rgb(0.0f);
          if (!isBlack(diffuse)) {
            // Two-sided, as for the path tracer: each light sample lights the side it arrives
            // on, so a wall wound the wrong way is lit on the side the light reaches.
            Rng rng = Rng::forKeys(options.seed, options.frame, firstSurfelIndex + i,
                                   kSurfelDirectLightDomain);
            Rgb front(0.0f), back(0.0f);
            for (int s = 0; s < options.lightSamples; ++s) {
              const TwoSidedIrradiance e =
                  sampleIrradianceBothSides(scene, surfel.position, surfel.normal, rng);
              if (isFinite(e.front) && isFinite(e.back)) {
                front += e.front;
                back += e.back;
              } else {
                ++localDiscarded;
              }
            }
            radiance += diffuse * (front * (invSamples * kInvPi));
            backRadiance += diffuse * (back * (invSamples * kInvPi));
          }
          // A NaN albedo (a broken texture) must not reach the tree's sums.
          if (!isFinite(radiance) || !isFinite(backRadiance)) {
            radiance = Rgb(0.0f);
            backRadiance = Rgb(0.0f);
            ++localNonFinite;
          }
          surfel.radiance = radiance;
          surfel.backRadiance = backRadiance;
        }
        emissive.fetch_add(localEmissive, std::memory_order_relaxed);
        discarded.fetch_add(localDiscarded, std::memory_order_relaxed);
        nonFinite.fetch_add(localNonFinite, std::memory_order_relaxed);
      });

  SurfelShadingStats stats;
  stats.surfels = surfels.size();
  stats.emissive = emissive.load();
  stats.discardedSamples = discarded.load();
  stats.nonFiniteSurfels = nonFinite.load();
  return stats;
}

float shLobeError(const Material& material) {
  if (material.type == MaterialType::kDiffuse || material.type == MaterialType::kEmissive) {
    return 0.0f;
  }
  const Bsdf bsdf(material, Rgb(1.0f));
  if (bsdf.isDelta()) return 1.0f;
  float worst = 0.0f;
  for (const float degrees : {0.0f, 40.0f, 70.0f, 85.0f}) {
    const float theta = radians(degrees);
    const Vec3f wi(std::sin(theta), 0.0f, std::cos(theta));  // local frame, z the normal
    worst = std::max(worst, shProjectionError(
                                [&](const Vec3f& wo) {
                                  return luminance(bsdf.f(wo, wi)) * wi.z * std::abs(wo.z);
                                },
                                16));
  }
  return worst;
}

bool needsWavelets(const Material& material, float tolerance) {
  return shLobeError(material) > tolerance;
}

GlossyLeafBaker::GlossyLeafBaker(const Scene& scene, const GlossyBakeOptions& options)
    : scene_(&scene), options_(options) {
  PBGI_CHECK_GT(options.lightSamples, 0);
  bases_ = meshBases(scene);
  needs_.resize(scene.materials().size());
  reflection_.resize(needs_.size());
  const std::shared_ptr<const MicrobufferTables> cube = microbufferTables(options.resolution);
  const size_t texels = cube->directions.size();
  const int k = std::max(options.indirectSamples, 1);
  for (size_t i = 0; i < needs_.size(); ++i) {
    const Material& material = scene.material(static_cast<uint32_t>(i));
    needs_[i] = needsWavelets(material, options.tolerance);
    any_ = any_ || needs_[i];
    const Bsdf bsdf(material, untexturedAlbedo(material));
    if (!needs_[i] || bsdf.isDelta() || options.indirectSamples < 1) continue;
    for (int set = 0; set < kReflectionSets; ++set) {
      ReflectionSamples& s = reflection_[i].emplace_back();
      s.wi.assign(texels * k, Vec3f(0.0f, 0.0f, 1.0f));
      s.weight.assign(texels * k, Rgb(0.0f));
      // The same stratified uniforms for every direction out: the reflected light is then a
      // smooth function of the direction (each sample's half vector fixed), which the wavelets
      // hold in few coefficients, where fresh samples per texel would be white noise.
      Rng rng = Rng::forKeys(options.seed, i, static_cast<uint64_t>(set), kReflectionDomain);
      std::vector<std::pair<float, Vec2f>> uniforms(k);
      for (int j = 0; j < k; ++j) {
        uniforms[j] = {rng.uniform(),
                       Vec2f((static_cast<float>(j) + rng.uniform()) / k, rng.uniform())};
      }
      for (size_t t = 0; t < texels; ++t) {
        for (int j = 0; j < k; ++j) {
          const std::optional<BsdfSample> bs =
              bsdf.sample(cube->directions[t], uniforms[j].first, uniforms[j].second);
          if (!bs || bs->delta || !(bs->pdf > 0.0f)) continue;
          const Rgb w = bs->f * (std::abs(bs->wi.z) / (bs->pdf * k));
          if (!isFinite(w)) continue;
          s.wi[t * k + j] = bs->wi;
          s.weight[t * k + j] = w;
        }
      }
    }
  }
}

namespace {

// Keeps the glossy surfels' light samples apart from every other stream.
constexpr uint64_t kGlossyLeafDomain = 0x474c4f5353594c46ull;

constexpr int kMaxSpecularChain = 8;
constexpr int kSmoothRays = 1;

// The light leaving a smooth (delta) surface at p towards unit world direction `out`: the
// BSDF sampled at the surface (lobe by uc), the ray traced on through every smooth surface it
// meets, and the emission of the light it ends on (lights hit or escaped to), times the
// chain's throughput. Black when it ends on a rough surface or goes on too long.
Rgb specularChainRadiance(const Scene& scene, const Vec3f& p, const Frame& frame, const Bsdf& bsdf,
                          const Vec3f& out, float uc, Rng& rng) {
  const std::optional<BsdfSample> first =
      bsdf.sample(frame.toLocal(out), uc, Vec2f(rng.uniform(), rng.uniform()));
  if (!first || !(first->pdf > 0.0f) || isBlack(first->f)) return Rgb(0.0f);
  Rgb beta = first->f * (std::abs(first->wi.z) / first->pdf);
  Vec3f dir = frame.toWorld(first->wi);
  Ray ray = scene.spawnRay(p, dot(dir, frame.n) > 0.0f ? frame.n : -frame.n, dir);
  for (int depth = 0; depth < kMaxSpecularChain; ++depth) {
    SurfaceHit hit;
    if (!scene.intersect(ray, &hit)) {
      Rgb sky(0.0f);
      for (const int index : scene.infiniteLights()) sky += scene.lights()[index]->escaped(dir);
      return beta * sky;
    }
    if (hit.light >= 0) return beta * scene.lights()[hit.light]->emitted(hit.ng, -dir);
    if (hit.material == kNoMaterial) return Rgb(0.0f);
    const Bsdf next(scene.material(hit.material), scene.albedoAt(hit));
    if (!next.isDelta()) return Rgb(0.0f);
    const Frame at(hit.ns);
    const std::optional<BsdfSample> bs =
        next.sample(at.toLocal(-dir), rng.uniform(), Vec2f(rng.uniform(), rng.uniform()));
    if (!bs || !(bs->pdf > 0.0f) || isBlack(bs->f)) return Rgb(0.0f);
    beta *= bs->f * (std::abs(bs->wi.z) / bs->pdf);
    dir = at.toWorld(bs->wi);
    ray = scene.spawnRay(hit.p, hit.ng, dir);
    if (!isFinite(beta)) return Rgb(0.0f);
  }
  return Rgb(0.0f);
}

}  // namespace

// A leaf's glossy and transmissive surfels as its bake goes: each with its BSDF and direct light
// (glossy), mirrors and glass apart (smooth); the indirect light arriving at the leaf, a
// microbuffer on each side of the glossy surfels' mean normal; and per material, what it
// reflects towards every texel of the cube.
struct GlossyLeafBaker::Leaf {
  struct Glossy {
    Surfel* surfel;
    uint32_t material;
    Frame frame;
    Bsdf bsdf;
    std::vector<Arrival> arrivals;
    Rgb front{0.0f}, back{0.0f};  // cosine-weighted sums of outgoing radiance per side
  };
  std::vector<Glossy> glossy, smooth;
  const Microbuffer* sides[2] = {nullptr, nullptr};
  Vec3f mean{0.0f}, centre{0.0f};
  std::shared_ptr<const MicrobufferTables> cube;
  std::vector<std::pair<uint32_t, std::vector<Rgb>>> reflected;  // by material, per texel

  Rgb incomingRadiance(const Vec3f& wi) const {
    const Microbuffer* buffer = sides[dot(wi, mean) > 0.0f ? 0 : 1];
    if (buffer == nullptr) return Rgb(0.0f);
    const int k = buffer->pixelIndex(wi);
    return buffer->covered(k) ? buffer->radiance(k) : Rgb(0.0f);
  }
  bool reflects(uint32_t material) const {
    return std::any_of(reflected.begin(), reflected.end(),
                       [&](const auto& r) { return r.first == material; });
  }
};

GlossyLeafBaker::Leaf GlossyLeafBaker::collectGlossy(std::span<Surfel> surfels,
                                                     uint64_t leafKey) const {
  Leaf leaf;
  const float invSamples = 1.0f / static_cast<float>(options_.lightSamples);
  for (size_t j = 0; j < surfels.size(); ++j) {
    Surfel& s = surfels[j];
    if (s.materialClass != MaterialClass::kGlossy &&
        s.materialClass != MaterialClass::kTransmissive) {
      continue;
    }
    const uint32_t id = materialOfTriangle(*scene_, bases_, s.triangle);
    if (!needs_[id]) continue;
    const Material& material = scene_->material(id);
    Leaf::Glossy g{&s, id, Frame(s.normal), Bsdf(material, s.albedo), {}};
    if (g.bsdf.isDelta()) {
      // Mirrors and glass: their light is traced back through them (traceSpecularChains).
      if (options_.directLight && options_.specularChains) leaf.smooth.push_back(std::move(g));
      continue;
    }
    if (options_.directLight) {
      Rng rng = Rng::forKeys(options_.seed, options_.frame, leafKey * 256 + j, kGlossyLeafDomain);
      sampleArrivals(*scene_, s, g.frame, options_.lightSamples, invSamples, rng, &g.arrivals);
    }
    if (!g.arrivals.empty() || incoming_ != nullptr) leaf.glossy.push_back(std::move(g));
  }
  return leaf;
}

void GlossyLeafBaker::locate(Leaf& leaf) {
  float area = 0.0f;
  for (const Leaf::Glossy& g : leaf.glossy) {
    leaf.mean += g.surfel->normal * g.surfel->area();
    leaf.centre += g.surfel->position * g.surfel->area();
    area += g.surfel->area();
  }
  leaf.centre = leaf.centre / area;
  leaf.mean =
      leaf.mean.length2() > 0.0f ? normalize(leaf.mean) : leaf.glossy.front().surfel->normal;
}

void GlossyLeafBaker::gatherIncoming(Leaf& leaf) const {
  thread_local std::optional<std::array<Gatherer, 2>> gatherers;
  if (incoming_ == nullptr || leaf.glossy.empty()) return;
  GatherOptions gather;
  gather.resolution = options_.incomingResolution;
  if (!gatherers || gatherers->front().options() != gather) {
    gatherers.emplace(std::array<Gatherer, 2>{Gatherer(gather), Gatherer(gather)});
  }
  locate(leaf);
  GatherStats stats;
  for (int side = 0; side < 2; ++side) {
    const Vec3f n = side == 0 ? leaf.mean : -leaf.mean;
    if ((*gatherers)[side].rasterize(*incoming_, leaf.centre, n, &stats).ok()) {
      leaf.sides[side] = &(*gatherers)[side].microbuffer();
    }
  }
}

// The indirect light reflected towards every texel, once per material of the leaf, in the frame
// of the leaf's mean normal (its surfels' own differ little): the same BSDF samples for every
// direction out, so that the reflected light is a smooth function of the direction (each
// sample's half vector fixed), which the wavelets hold in few coefficients, where fresh samples
// per texel would be white noise.
void GlossyLeafBaker::reflectIncoming(Leaf& leaf, uint64_t leafKey) const {
  if (incoming_ == nullptr) return;
  const size_t texels = leaf.cube->directions.size();
  const Frame frame(leaf.mean);
  for (const Leaf::Glossy& g : leaf.glossy) {
    if (leaf.reflects(g.material) || reflection_[g.material].empty()) continue;
    const ReflectionSamples& set = reflection_[g.material][leafKey % kReflectionSets];
    const size_t k = static_cast<size_t>(std::max(options_.indirectSamples, 1));
    // The reflected light by texel of the material's local cube, then resampled to the
    // world's texels (the nearest local one).
    std::vector<Rgb> local(texels, Rgb(0.0f));
    for (size_t t = 0; t < texels; ++t) {
      Rgb sum(0.0f);
      for (size_t j = t * k; j < (t + 1) * k; ++j) {
        if (!isBlack(set.weight[j])) {
          sum += set.weight[j] * leaf.incomingRadiance(frame.toWorld(set.wi[j]));
        }
      }
      if (isFinite(sum)) local[t] = sum;
    }
    std::vector<Rgb> table(texels);
    for (size_t t = 0; t < texels; ++t) {
      table[t] = local[static_cast<size_t>(
          cubePixelIndex(frame.toLocal(leaf.cube->directions[t]), options_.resolution))];
    }
    leaf.reflected.emplace_back(g.material, std::move(table));
  }
}

// Mirrors and glass (delta BSDFs): the lights seen through them, each texel's direction traced
// back through their specular chain (up to kMaxSpecularChain surfaces, each lobe picked by the
// BSDF's own sampling) to the light it ends on, from the centroid of the leaf's smooth surfels,
// kSmoothRays jittered rays a texel. A chain that ends on a rough surface brings nothing here:
// that light is the tree's. This is what puts a glass sphere's caustic on the floor under it.
void GlossyLeafBaker::traceSpecularChains(Leaf& leaf, uint64_t leafKey) const {
  const size_t texels = leaf.cube->directions.size();
  for (const Leaf::Glossy& g : leaf.smooth) {
    if (leaf.reflects(g.material)) continue;
    Vec3f n(0.0f), p(0.0f);
    float area = 0.0f;
    for (const Leaf::Glossy& h : leaf.smooth) {
      if (h.material != g.material) continue;
      n += h.surfel->normal * h.surfel->area();
      p += h.surfel->position * h.surfel->area();
      area += h.surfel->area();
    }
    p = p / area;
    n = n.length2() > 0.0f ? normalize(n) : g.surfel->normal;
    const Frame frame(n);
    Rng rng = Rng::forKeys(options_.seed, options_.frame, leafKey,
                           kGlossyLeafDomain + 0x10000 + g.material);
    const float jitter = 2.0f * std::tan(0.25f * kPi / static_cast<float>(options_.resolution));
    std::vector<Rgb> table(texels, Rgb(0.0f));
    for (size_t t = 0; t < texels; ++t) {
      Rgb sum(0.0f);
      for (int k = 0; k < kSmoothRays; ++k) {
        const Vec3f d = normalize(
            leaf.cube->directions[t] +
            Vec3f(rng.uniform() - 0.5f, rng.uniform() - 0.5f, rng.uniform() - 0.5f) * jitter);
        const float uc = (static_cast<float>(k) + rng.uniform()) / kSmoothRays;
        sum += specularChainRadiance(*scene_, p, frame, g.bsdf, d, uc, rng);
      }
      if (isFinite(sum)) table[t] = sum / static_cast<float>(kSmoothRays);
    }
    leaf.reflected.emplace_back(g.material, std::move(table));
  }
  for (Leaf::Glossy& g : leaf.smooth) leaf.glossy.push_back(std::move(g));
}

// Each surfel's outgoing radiance towards every texel (its direct light through its BSDF plus
// what its material reflects), summed as the leaf's intensity, and each side's mean radiance.
WaveletRadiance GlossyLeafBaker::radiate(Leaf& leaf) const {
  const MicrobufferTables& cube = *leaf.cube;
  std::vector<Rgb> intensity(cube.directions.size(), Rgb(0.0f));
  for (Leaf::Glossy& g : leaf.glossy) {
    const float area = g.surfel->area();
    const std::vector<Rgb>* indirect = nullptr;
    for (const auto& r : leaf.reflected) {
      if (r.first == g.material) indirect = &r.second;
    }
    for (size_t t = 0; t < cube.directions.size(); ++t) {
      const Vec3f wo = g.frame.toLocal(cube.directions[t]);
      Rgb radiance(0.0f);
      for (const Arrival& a : g.arrivals) {
        radiance += g.bsdf.f(wo, a.wiLocal) * a.value * std::abs(a.wiLocal.z);
      }
      if (indirect != nullptr) radiance += (*indirect)[t];
      if (!isFinite(radiance)) continue;
      const float cosine = std::abs(wo.z);
      intensity[t] += radiance * (area * cosine);
      (wo.z > 0.0f ? g.front : g.back) += radiance * (cosine * cube.solidAngles[t]);
    }
    // The texels' cosine-weighted solid angles sum to pi over each side.
    g.surfel->radiance = g.front * kInvPi;
    g.surfel->backRadiance = g.back * kInvPi;
  }
  return WaveletRadiance::fromTexels(intensity, options_.resolution, 0.0f);
}

WaveletRadiance GlossyLeafBaker::operator()(std::span<Surfel> surfels, uint64_t leafKey) const {
  Leaf leaf = collectGlossy(surfels, leafKey);
  if (leaf.glossy.empty() && leaf.smooth.empty()) return WaveletRadiance();
  gatherIncoming(leaf);
  leaf.cube = microbufferTables(options_.resolution);
  reflectIncoming(leaf, leafKey);
  traceSpecularChains(leaf, leafKey);
  return radiate(leaf);
}

void GlossyLeafBaker::bakeLeaves(std::span<WaveletLeafJob> jobs, PairGatherStats* stats) const {
  std::vector<Leaf> leaves(jobs.size());
  tbb::parallel_for(size_t{0}, jobs.size(),
                    [&](size_t j) { leaves[j] = collectGlossy(jobs[j].surfels, jobs[j].key); });
  const std::shared_ptr<const MicrobufferTables> cube = microbufferTables(options_.resolution);
  if (incoming_ != nullptr) {
    // Each glossy leaf a receiver of both sides, at its centre, facing its mean normal.
    std::vector<PairReceiver> receivers;
    std::vector<size_t> leafOf;
    for (size_t j = 0; j < leaves.size(); ++j) {
      if (leaves[j].glossy.empty()) continue;
      locate(leaves[j]);
      receivers.push_back({leaves[j].centre, leaves[j].mean, true});
      leafOf.push_back(j);
    }
    PairGatherOptions pair;
    pair.gather.resolution = options_.incomingResolution;
    pair.receiverSolidAngle = options_.pairReceiverSolidAngle;
    // As gatherIncoming: a leaf whose gather fails reflects no incoming light.
    (void)pairGather(
        *incoming_, receivers, pair,
        [&](size_t i, const Microbuffer& above, const Microbuffer* below) {
          const size_t j = leafOf[i];
          Leaf& leaf = leaves[j];
          leaf.sides[0] = &above;
          leaf.sides[1] = below;
          leaf.cube = cube;
          reflectIncoming(leaf, jobs[j].key);
          leaf.sides[0] = leaf.sides[1] = nullptr;
        },
        nullptr, stats);
  }
  tbb::parallel_for(size_t{0}, jobs.size(), [&](size_t j) {
    Leaf& leaf = leaves[j];
    if (leaf.glossy.empty() && leaf.smooth.empty()) {
      jobs[j].out = WaveletRadiance();
      return;
    }
    leaf.cube = cube;
    traceSpecularChains(leaf, jobs[j].key);
    jobs[j].out = radiate(leaf);
  });
}

WaveletRadiance glossyDirectRadiance(const Scene& scene, const Surfel& surfel,
                                     const Material& material, const Rgb& albedo, int n,
                                     float threshold, int lightSamples, Rng& rng) {
  PBGI_CHECK_GT(lightSamples, 0);
  // The light samples first, shared by every direction out.
  std::vector<Arrival> arrivals;
  const Frame frame(surfel.normal);
  sampleArrivals(scene, surfel, frame, lightSamples, 1.0f / static_cast<float>(lightSamples), rng,
                 &arrivals);
  const Bsdf bsdf(material, albedo);
  return WaveletRadiance::project(
      [&](const Vec3f& wo) {
        const Vec3f woLocal = frame.toLocal(wo);
        Rgb sum(0.0f);
        for (const Arrival& a : arrivals) {
          sum += bsdf.f(woLocal, a.wiLocal) * a.value * std::abs(a.wiLocal.z);
        }
        return sum;
      },
      n, threshold);
}

}  // namespace pbgi
