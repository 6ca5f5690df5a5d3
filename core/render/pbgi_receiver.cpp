#include "core/render/pbgi_receiver.h"

#include <algorithm>
#include <cmath>

#include "core/bake/surfel_shading.h"
#include "core/pbgi/bidirectional_cut.h"
#include "core/sampling/rng.h"
#include "core/scene/material.h"
#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

constexpr float kReuseNormalCos = 0.95f;
constexpr float kReuseViewCos = 0.999f;
// The key of the product's gathers: the light arriving, which any glossy material reflects.
constexpr uint32_t kProductKey = kNoMaterial - 1;

// The directional albedo towards wo, by the BSDF's own samples on an n x n stratified grid
// (fixed: the same table every run).
Rgb directionalAlbedo(const Bsdf& bsdf, const Vec3f& wo, int n, Rng& rng) {
  Rgb sum(0.0f);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const Vec2f u((static_cast<float>(i) + rng.uniform()) / static_cast<float>(n),
                    (static_cast<float>(j) + rng.uniform()) / static_cast<float>(n));
      const std::optional<BsdfSample> s = bsdf.sample(wo, rng.uniform(), u);
      if (!s || s->delta || !(s->pdf > 0.0f) || s->wi.z <= 0.0f) continue;
      const Rgb w = s->f * (s->wi.z / s->pdf);
      if (isFinite(w)) sum += w;
    }
  }
  return vmin(sum / static_cast<float>(n * n), Rgb(1.0f));
}

}  // namespace

void addGatherStats(const GatherStats& s, RenderCounters* c) {
  (*c)[kNodesVisited] += s.nodesVisited;
  (*c)[kNodesCulledPlane] += s.nodesCulledPlane;
  (*c)[kClustersSplatted] += s.clustersSplatted;
  (*c)[kClustersInvisible] += s.clustersInvisible;
  (*c)[kDisksSplatted] += s.disksSplatted;
  (*c)[kNearFieldRayCasts] += s.nearFieldRayCasts;
  (*c)[kSurfelsSkipped] += s.surfelsSkipped;
  (*c)[kSurfelsBackFacing] += s.surfelsBackFacing;
  (*c)[kPagesTouched] += s.pagesTouched;
  (*c)[kFacesSkipped] += s.facesSkipped;
  (*c)[kPixelsSkipped] += s.pixelsSkipped;
}

void addCutStats(const CutStats& s, RenderCounters* c) {
#define PBGI_CUT_COUNTER_ADD(member, counter, name, what) (*c)[counter] += s.member;
  PBGI_CUT_COUNTERS(PBGI_CUT_COUNTER_ADD)
#undef PBGI_CUT_COUNTER_ADD
}

LambertianLobes::LambertianLobes(const Scene& scene) : tables_(scene.materials().size()) {
  constexpr int kSamplesASide = 32;
  for (size_t m = 0; m < tables_.size(); ++m) {
    const Material& material = scene.material(static_cast<uint32_t>(m));
    // Conductors only: the path tracer serves dielectrics (rough ones too) at the first hit,
    // and a smooth conductor is a delta lobe.
    if (material.type != MaterialType::kConductor || material.isEmissive()) continue;
    const Bsdf bsdf(material, untexturedAlbedo(material));
    if (bsdf.isDelta() || bsdf.isBlack() || needsWavelets(material)) continue;
    Rng rng = Rng::forKeys(0x4c414d42ull, m);
    std::vector<Rgb>& table = tables_[m];
    table.resize(kBins);
    for (int b = 0; b < kBins; ++b) {
      // Bin b at cosine b / (kBins - 1); grazing views at a small cosine, not an edge-on one.
      const float c = std::max(static_cast<float>(b) / static_cast<float>(kBins - 1), 1e-3f);
      const Vec3f wo(std::sqrt(std::max(0.0f, 1.0f - c * c)), 0.0f, c);
      table[b] = directionalAlbedo(bsdf, wo, kSamplesASide, rng);
    }
  }
}

Rgb LambertianLobes::albedo(uint32_t m, float cosTheta) const {
  const std::vector<Rgb>& table = tables_[m];
  const float x = std::clamp(cosTheta, 0.0f, 1.0f) * static_cast<float>(kBins - 1);
  const int b = std::min(static_cast<int>(x), kBins - 2);
  const float f = x - static_cast<float>(b);
  return table[b] * (1.0f - f) + table[b + 1] * f;
}

Receiver traceReceiver(const Scene& scene, const LambertianLobes& lobes, const Ray& ray, Rng& rng,
                       const PathTracerSettings& pathTracer, PathSample* out,
                       RenderCounters* counters) {
  Receiver r;
  const Rng start = rng;
  PathTracerSettings directOnly = pathTracer;
  directOnly.maxDepth = 1;
  *out = tracePath(scene, ray, rng, directOnly, &r.hit);
  if (!out->hit) return r;
  if (r.hit.material == kNoMaterial || isBlack(out->albedo)) {
    ++(*counters)[kBlackReceivers];
    r.kind = ReceiverKind::kBlack;
    return r;
  }
  const Material& material = scene.material(r.hit.material);
  const Bsdf bsdf(material, out->albedo);
  if (bsdf.isBlack()) {
    ++(*counters)[kBlackReceivers];
    r.kind = ReceiverKind::kBlack;
    return r;
  }
  if (bsdf.isDelta() || material.type == MaterialType::kDielectric) {
    // The same path as the path tracer's, from the same random numbers: its direct light is
    // the one just computed, and its indirect light is path traced.
    rng = start;
    *out = tracePath(scene, ray, rng, pathTracer);
    ++(*counters)[kPathTracedReceivers];
    r.kind = ReceiverKind::kPathTraced;
    return r;
  }
  r.wo = -ray.dir;
  const bool front = dot(r.hit.ng, r.wo) >= 0.0f;
  r.n = front ? r.hit.ns : -r.hit.ns;
  r.ng = front ? r.hit.ng : -r.hit.ng;
  if (material.type == MaterialType::kDiffuse) {
    r.kind = ReceiverKind::kDiffuse;
    r.reflectance = out->albedo;
    r.skyReflectance = out->albedo;
  } else if (lobes.has(r.hit.material)) {
    ++(*counters)[kGlossyAsDiffuse];
    r.kind = ReceiverKind::kDiffuse;
    r.reflectance = lobes.albedo(r.hit.material, dot(r.n, r.wo));
  } else {
    r.kind = ReceiverKind::kGlossy;
  }
  return r;
}

PixelGathers::PixelGathers(const PbgiSettings& settings, size_t maxGathersPerPixel,
                           std::shared_ptr<WaveletBsdfCache> bsdfs, int spacing)
    : bsdfs_(std::move(bsdfs)),
      spacing_(std::max(spacing, 1)),
      shared_(kReuseNormalCos, kReuseViewCos, maxGathersPerPixel) {
  switch (settings.glossyGather) {
    case GlossyGatherKind::kAdaptive:
      adaptive_.emplace(settings.adaptive);
      break;
    case GlossyGatherKind::kWarped:
      warped_.emplace(settings.glossy);
      break;
    case GlossyGatherKind::kProduct:
      PBGI_CHECK(bsdfs_ != nullptr);
      product_.emplace(settings.product);
      adaptive_.emplace(settings.adaptive);  // for lobes the product does not resolve
      break;
    case GlossyGatherKind::kTraced:
      tracedRays_ = std::max(settings.glossyRays, 1);
      break;
  }
}

void PixelGathers::newPixel(const Vec2i& pixel) {
  shared_.clear();
  if (spacing_ <= 1) {
    productsUsed_ = 0;
    return;
  }
  const int s = spacing_;
  const int ax = pixel.x - ((pixel.x % s) + s) % s;
  const int ay = pixel.y - ((pixel.y % s) + s) % s;
  if (ay != anchorRowY_) {
    anchorRowY_ = ay;
    anchorKept_.clear();
    anchorKeptX_.clear();
    anchorProducts_ = 0;
  }
  anchorX_ = ax;
  atAnchor_ = pixel.x == ax && pixel.y == ay;
  // A pixel between anchors keeps its own gathers for itself alone.
  productsUsed_ = anchorProducts_;
}

const SharedGather* PixelGathers::anchorGather(const Receiver& r, uint32_t key) const {
  if (atAnchor_) return nullptr;
  // The pixel's own square's anchor first, then the next one along the row.
  for (const int x : {anchorX_, anchorX_ + spacing_}) {
    for (size_t i = 0; i < anchorKept_.size(); ++i) {
      if (anchorKeptX_[i] != x) continue;
      const SharedGather* g = shared_.find(std::span(&anchorKept_[i], 1), r.hit.p, r.n, r.wo, key);
      if (g != nullptr) return g;
    }
  }
  return nullptr;
}

absl::StatusOr<const WaveletBsdf*> PixelGathers::productSlices(const Scene& scene,
                                                               uint32_t material) {
  if (slices_.size() <= material) slices_.resize(material + 1);
  if (slices_[material] == nullptr) {
    PBGI_ASSIGN_OR_RETURN(slices_[material],
                          bsdfs_->get(scene.material(material), product_->options().bsdf));
  }
  return slices_[material].get();
}

absl::StatusOr<Rgb> PixelGathers::reflectByProduct(TreePageSource& tree, const WaveletBsdf& slices,
                                                   const Receiver& r, GatherStats* stats,
                                                   RenderCounters* counters) {
  uint32_t slot = 0;
  if (const SharedGather* g = shared_.find(r.hit.p, r.n, r.wo, kProductKey)) {
    ++(*counters)[kGatherReuses];
    slot = g->slot;
  } else if (const SharedGather* a = anchorGather(r, kProductKey)) {
    ++(*counters)[kGatherReuses];
    slot = a->slot;
  } else {
    slot = static_cast<uint32_t>(productsUsed_++);
    if (products_.size() < productsUsed_) products_.emplace_back();
    ProductGather& gathered = products_[slot];
    gathered.frame = viewFrame(r.n, r.wo);
    if (absl::Status s = product_->gather(tree, r.hit.p, gathered.frame, &gathered.incoming, stats);
        !s.ok()) {
      return s;
    }
    keepForPixelsAfter(keep(r, kProductKey, Rgb(0.0f), slot, counters));
  }
  const ProductGather& gathered = products_[slot];
  ++(*counters)[kGlossyProducts];
  const Rgb lo = slices.reflect(gathered.incoming, dot(r.wo, gathered.frame.n));
  if (absl::Status s = checkGathered(lo); !s.ok()) return s;
  return lo;
}

absl::StatusOr<Rgb> PixelGathers::reflectByRays(TreePageSource& tree, const Scene& scene,
                                                const Receiver& r, const Rgb& albedo, Rng& rng,
                                                RenderCounters* counters) {
  if (readRadius_ < 0.0f) {
    PBGI_ASSIGN_OR_RETURN(readRadius_, surfaceReadRadius(tree));
  }
  const Bsdf bsdf(scene.material(r.hit.material), albedo);
  const Frame frame(r.n);
  const Vec3f wo = frame.toLocal(r.wo);
  Rgb sum(0.0f);
  for (int k = 0; k < tracedRays_; ++k) {
    // Stratified in the first dimension of the lobe's own sampling.
    const Vec2f u((static_cast<float>(k) + rng.uniform()) / static_cast<float>(tracedRays_),
                  rng.uniform());
    const std::optional<BsdfSample> s = bsdf.sample(wo, rng.uniform(), u);
    if (!s || s->delta || !(s->pdf > 0.0f) || isBlack(s->f)) continue;
    const Vec3f wi = frame.toWorld(s->wi);
    ++(*counters)[kGlossyTracedRays];
    SurfaceHit hit;
    // What escapes is the environment's, and what meets a light is the light's: the samples'
    // direct light takes both.
    if (!scene.intersect(scene.spawnRay(r.hit.p, r.ng, wi), &hit) || hit.light >= 0) continue;
    std::optional<Rgb> sent;
    if (hit.material != kNoMaterial && !Bsdf(scene.material(hit.material), Rgb(1.0f)).isDelta()) {
      PBGI_ASSIGN_OR_RETURN(sent, readSurfaceRadiance(tree, scene, readRadius_, hit.p, hit.ng, wi));
    }
    if (!sent) {
      ++(*counters)[kGlossyTracedUnread];
      continue;
    }
    sum += s->f * (std::abs(s->wi.z) / s->pdf) * *sent;
  }
  const Rgb lo = sum / static_cast<float>(tracedRays_);
  if (absl::Status st = checkGathered(lo); !st.ok()) return st;
  return lo;
}

absl::StatusOr<Rgb> PixelGathers::reflect(TreePageSource& tree, const Scene& scene,
                                          const Receiver& r, const Rgb& albedo, Rng& rng,
                                          GatherStats* stats, RenderCounters* counters) {
  if (tracedRays_ > 0) return reflectByRays(tree, scene, r, albedo, rng, counters);
  if (product_) {
    PBGI_ASSIGN_OR_RETURN(const WaveletBsdf* slices, productSlices(scene, r.hit.material));
    const float cosThetaO = dot(r.wo, r.n);
    if (slices->reflectsNothing(cosThetaO)) {
      ++(*counters)[kGlossyProductsSkipped];
      return Rgb(0.0f);
    }
    // A lobe the cube resolves; a narrower one's receiver takes the adaptive gather below.
    if (slices->lobeTexels(cosThetaO) >= kMinProductLobeTexels) {
      return reflectByProduct(tree, *slices, r, stats, counters);
    }
    ++(*counters)[kGlossyNarrowLobes];
  }
  if (const SharedGather* g = shared_.find(r.hit.p, r.n, r.wo, r.hit.material)) {
    ++(*counters)[kGatherReuses];
    return g->value;
  }
  if (const SharedGather* g = anchorGather(r, r.hit.material)) {
    ++(*counters)[kGatherReuses];
    return g->value;
  }
  const Bsdf bsdf(scene.material(r.hit.material), albedo);
  const Frame frame(r.n);
  const Vec2f jitter(rng.uniform(), rng.uniform());
  absl::StatusOr<Rgb> lo =
      adaptive_ ? adaptive_->reflect(tree, r.hit.p, frame, bsdf, frame.toLocal(r.wo), jitter, stats)
                : warped_->reflect(tree, r.hit.p, frame, bsdf, frame.toLocal(r.wo), jitter, stats);
  if (!lo.ok()) return lo.status();
  if (absl::Status s = checkGathered(*lo); !s.ok()) return s;
  keepForPixelsAfter(keep(r, r.hit.material, *lo, 0, counters));
  return *lo;
}

SharedGather PixelGathers::keep(const Receiver& r, uint32_t key, const Rgb& value, uint32_t slot,
                                RenderCounters* counters) {
  ++(*counters)[kGathers];
  ++(*counters)[kGlossyGathers];
  const SharedGather g{.p = r.hit.p,
                       .n = r.n,
                       .reach = kReuseDistanceFraction * r.hit.t,
                       .planeReach = kReusePlaneFraction * r.hit.t,
                       .key = key,
                       .wo = r.wo,
                       .value = value,
                       .slot = slot};
  shared_.add(g);
  return g;
}

void PixelGathers::keepForPixelsAfter(const SharedGather& g) {
  if (spacing_ <= 1 || !atAnchor_) return;
  anchorKept_.push_back(g);
  anchorKeptX_.push_back(anchorX_);
  anchorProducts_ = productsUsed_;  // an anchor's product gathers stay while its row lasts
}

absl::Status checkGathered(const Rgb& value) {
  if (isFinite(value)) return absl::OkStatus();
  return absl::DataLossError(
      "the tree's radiance made a gather non-finite (a damaged or hostile tree)");
}

}  // namespace pbgi
