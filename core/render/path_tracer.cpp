#include "core/render/path_tracer.h"

#include <algorithm>
#include <span>

namespace pbgi {

namespace {

// Seeds the first hit's light samples past the first ("FIRSTLGT").
constexpr uint64_t kFirstHitLightDomain = 0x46495253544c4754ull;
constexpr uint64_t kFirstHitBsdfDomain = 0x4649525342534446ull;
// Random numbers a light sample draws (sampleUnoccludedLight): the light, a point on it.
constexpr int kLightSampleNumbers = 3;

Vec2f next2(Rng& rng) {
  const float a = rng.uniform();
  return {a, rng.uniform()};
}

// The shading frame, with the normal on the side the dielectric convention expects (the
// geometric front); two-sided BSDFs handle either side themselves.
Frame shadingFrame(const SurfaceHit& hit) { return Frame(hit.ns); }

}  // namespace

std::optional<LightSample> sampleUnoccludedLight(const Scene& scene, const Vec3f& p,
                                                 const Vec3f& ng, Rng& rng, float* selectPdf,
                                                 bool skipSky) {
  // A fixed count of random numbers whatever happens (kLightSampleNumbers), so that later
  // decisions of the same path use the same numbers whichever branch this one took.
  const float uLight = rng.uniform();
  const Vec2f u = next2(rng);
  const Light* light = scene.sampleLight(uLight, selectPdf, skipSky);
  if (light == nullptr || *selectPdf <= 0.0f) return std::nullopt;
  std::optional<LightSample> ls = light->sample(p, u);
  if (!ls || ls->pdf <= 0.0f || isBlack(ls->radiance)) return std::nullopt;
  if (scene.occluded(scene.spawnShadowRay(p, ng, *ls))) return std::nullopt;
  return ls;
}

Rgb sampleIrradiance(const Scene& scene, const Vec3f& p, const Vec3f& n, const Vec3f& ng,
                     Rng& rng) {
  float selectPdf = 0.0f;
  const std::optional<LightSample> ls = sampleUnoccludedLight(scene, p, dot(ng, n) >= 0.0f ? ng : -ng, rng, &selectPdf);
  if (!ls) return Rgb(0.0f);
  const float cosTheta = dot(ls->wi, n);
  if (cosTheta <= 0.0f) return Rgb(0.0f);
  return ls->radiance * (cosTheta / (ls->pdf * selectPdf));
}

TwoSidedIrradiance sampleIrradianceBothSides(const Scene& scene, const Vec3f& p, const Vec3f& ng,
                                             Rng& rng) {
  TwoSidedIrradiance e;
  const float uLight = rng.uniform();
  const Vec2f u = next2(rng);
  float selectPdf = 0.0f;
  const Light* light = scene.sampleLight(uLight, &selectPdf);
  if (light == nullptr || selectPdf <= 0.0f) return e;
  std::optional<LightSample> ls = light->sample(p, u);
  if (!ls || ls->pdf <= 0.0f || isBlack(ls->radiance)) return e;
  const float cosTheta = dot(ls->wi, ng);
  if (cosTheta == 0.0f) return e;
  // spawnShadowRay leaves on the side the sample arrives from.
  if (scene.occluded(scene.spawnShadowRay(p, ng, *ls))) return e;
  const Rgb value = ls->radiance * (std::abs(cosTheta) / (ls->pdf * selectPdf));
  (cosTheta > 0.0f ? e.front : e.back) = value;
  return e;
}

// What the BSDF reflects of an unoccluded light sample, picked with probability selectPdf
// among the lights (MIS-weighted against the BSDF's own sampling unless a delta).
Rgb reflectedLight(const SurfaceHit& hit, const Frame& frame, const Bsdf& bsdf,
                   const Vec3f& woLocal, const LightSample& sample, float selectPdf) {
  const Vec3f wiLocal = frame.toLocal(sample.wi);
  // Reflection or transmission must agree between the shading and geometric normals, or
  // light leaks through the surface.
  const float cosGeo = dot(sample.wi, hit.ng);
  const float cosGeoOut = dot(frame.toWorld(woLocal), hit.ng);
  const bool reflectGeo = cosGeo * cosGeoOut > 0.0f;
  const bool reflectShading = wiLocal.z * woLocal.z > 0.0f;
  if (reflectGeo != reflectShading) return Rgb(0.0f);
  const Rgb f = bsdf.f(woLocal, wiLocal);
  if (isBlack(f)) return Rgb(0.0f);
  const float lightPdf = sample.pdf * selectPdf;
  const float weight = sample.delta ? 1.0f : powerHeuristic(lightPdf, bsdf.pdf(woLocal, wiLocal));
  return f * sample.radiance * (std::abs(wiLocal.z) * weight / lightPdf);
}

Rgb sampleDirectLight(const Scene& scene, const SurfaceHit& hit, const Frame& frame,
                      const Bsdf& bsdf, const Vec3f& woLocal, Rng& rng, bool skipSky) {
  float selectPdf = 0.0f;
  const std::optional<LightSample> ls =
      sampleUnoccludedLight(scene, hit.p, hit.ng, rng, &selectPdf, skipSky);
  return ls ? reflectedLight(hit, frame, bsdf, woLocal, *ls, selectPdf) : Rgb(0.0f);
}

// The light of each of `deltas` (delta lights: no sample to draw), a shadow ray each.
Rgb deltaLightsExactly(const Scene& scene, std::span<const int> deltas, const SurfaceHit& hit,
                       const Frame& frame, const Bsdf& bsdf, const Vec3f& woLocal) {
  Rgb sum(0.0f);
  for (const int i : deltas) {
    const std::optional<LightSample> ls = scene.lights()[i]->sample(hit.p, Vec2f(0.5f));
    if (!ls || ls->pdf <= 0.0f || isBlack(ls->radiance)) continue;
    if (scene.occluded(scene.spawnShadowRay(hit.p, hit.ng, *ls))) continue;
    sum += reflectedLight(hit, frame, bsdf, woLocal, *ls, 1.0f);
  }
  return sum;
}

// The MIS weight, against light sampling, of the emission a BSDF sample from p along dir (of
// pdf bsdfPdf; delta: weight 1) meets: that of infinite light `index` when it escapes, or of
// the emitter it hits at `at`.
float escapedWeight(const Scene& scene, int index, const Vec3f& p, const Vec3f& dir, bool delta,
                    float bsdfPdf) {
  if (delta) return 1.0f;
  const float lightPdf =
      scene.lightProbability(index) * scene.lights()[index]->pdf(p, dir, Vec3f(0.0f), Vec3f(0.0f));
  return powerHeuristic(bsdfPdf, lightPdf);
}
float emitterWeight(const Scene& scene, const SurfaceHit& at, const Vec3f& p, const Vec3f& dir,
                    bool delta, float bsdfPdf, bool skipSky) {
  if (delta) return 1.0f;
  const float lightPdf = scene.lightProbability(at.light, skipSky) *
                         scene.lights()[at.light]->pdf(p, dir, at.p, at.ng);
  return powerHeuristic(bsdfPdf, lightPdf);
}

// The emission one BSDF sample from `hit` meets (an emitter, or the infinite lights it escapes
// to, less the sky with skipSky), MIS-weighted against light sampling as the path weighs the
// emission it meets: what an extra BSDF sample at the first hit adds.
Rgb bsdfSampledEmission(const Scene& scene, const SurfaceHit& hit, const Frame& frame,
                        const Bsdf& bsdf, const Vec3f& woLocal, Rng& rng, bool skipSky) {
  const float uc = rng.uniform();
  const Vec2f u = next2(rng);
  const std::optional<BsdfSample> bs = bsdf.sample(woLocal, uc, u);
  if (!bs || bs->pdf <= 0.0f || isBlack(bs->f)) return Rgb(0.0f);
  const Vec3f wi = frame.toWorld(bs->wi);
  const Vec3f wo = frame.toWorld(woLocal);
  if ((bs->wi.z * woLocal.z > 0.0f) != (dot(wi, hit.ng) * dot(wo, hit.ng) > 0.0f)) {
    return Rgb(0.0f);
  }
  const Rgb beta = bs->f * (std::abs(bs->wi.z) / bs->pdf);
  if (!isFinite(beta)) return Rgb(0.0f);
  const Ray ray = scene.spawnRay(hit.p, hit.ng, wi);
  SurfaceHit next;
  Rgb sum(0.0f);
  if (!scene.intersect(ray, &next)) {
    for (const int index : scene.infiniteLights()) {
      const Light* light = scene.lights()[index].get();
      if (skipSky && isSkyLight(*light)) continue;
      const Rgb Le = light->escaped(ray.dir);
      if (isBlack(Le)) continue;
      sum += beta * Le * escapedWeight(scene, index, hit.p, ray.dir, bs->delta, bs->pdf);
    }
    return sum;
  }
  if (next.light < 0) return sum;
  const Rgb Le = scene.lights()[next.light]->emitted(next.ng, -ray.dir);
  if (isBlack(Le)) return sum;
  return beta * Le * emitterWeight(scene, next, hit.p, ray.dir, bs->delta, bs->pdf, skipSky);
}

PathSample tracePath(const Scene& scene, const Ray& cameraRay, Rng& rng,
                     const PathTracerSettings& settings, SurfaceHit* firstHit) {
  PathSample out;
  Rgb beta(1.0f);
  Ray ray = cameraRay;
  float prevBsdfPdf = 0.0f;
  bool prevDelta = true;  // the camera ray: emission seen directly counts in full
  Vec3f prevP = ray.origin;
  Rgb* sink = &out.direct;  // emission found at bounce <= 1 is direct light
  bool skipSky = false;     // the last vertex left the environment's light to the records
  float emissionScale = 1.0f;  // of the emission the path meets next (firstHitBsdfSamples)
  bool specularSoFar = true;   // every scattering since the camera was a delta one

  for (int bounce = 0;; ++bounce) {
    if (bounce >= 2) sink = &out.indirect;
    SurfaceHit hit;
    if (!scene.intersect(ray, &hit)) {
      for (const int index : scene.infiniteLights()) {
        const Light* light = scene.lights()[index].get();
        if (skipSky && isSkyLight(*light)) continue;
        const Rgb Le = light->escaped(ray.dir);
        if (isBlack(Le)) continue;
        const float weight = escapedWeight(scene, index, prevP, ray.dir, prevDelta, prevBsdfPdf);
        *sink += beta * Le * (weight * emissionScale);
      }
      break;
    }
    if (bounce == 0) {
      out.hit = true;
      out.depth = hit.t;
      out.normal = hit.ns;
      if (firstHit) *firstHit = hit;
    }
    const Vec3f wo = -ray.dir;
    if (hit.light >= 0) {
      const Light& light = *scene.lights()[hit.light];
      const Rgb Le = light.emitted(hit.ng, wo);
      if (!isBlack(Le)) {
        const float weight =
            emitterWeight(scene, hit, prevP, ray.dir, prevDelta, prevBsdfPdf, skipSky);
        *sink += beta * Le * (weight * emissionScale);
      }
    }
    emissionScale = 1.0f;
    // One texture lookup serves the albedo AOV and the BSDF.
    const bool scatter = hit.material != kNoMaterial && bounce < settings.maxDepth;
    const Rgb albedo = scatter || bounce == 0 ? scene.albedoAt(hit) : Rgb(0.0f);
    if (bounce == 0) out.albedo = albedo;
    if (!scatter) break;
    const Material& material = scene.material(hit.material);
    const Bsdf bsdf(material, albedo);
    if (bsdf.isBlack()) break;
    // Not on an emitter: its surfels' radiance holds the emission just added.
    if (bounce >= 1 && specularSoFar && settings.specularChainEnd && hit.light < 0 &&
        material.type == MaterialType::kDiffuse) {
      if (const std::optional<Rgb> sent = settings.specularChainEnd(hit, wo)) {
        out.indirect += beta * *sent;
        break;
      }
    }

    const Frame frame = shadingFrame(hit);
    const Vec3f woLocal = frame.toLocal(wo);
    skipSky = bounce == 0 && !settings.skyAtDiffuseFirstHit &&
              material.type == MaterialType::kDiffuse;
    // Light arriving at this vertex belongs to the next bounce's sink.
    Rgb* nextSink = bounce + 1 >= 2 ? &out.indirect : &out.direct;
    const bool severalSamples = bounce == 0 && settings.firstHitLightSamples > 1;
    std::span<const int> deltas;
    if (severalSamples) deltas = scene.deltaLightsOnly(skipSky);
    if (!bsdf.isDelta() && !deltas.empty() &&
        deltas.size() <= static_cast<size_t>(settings.firstHitLightSamples)) {
      // Several light samples where every light they could pick is a delta (a sun, with the
      // sky taken by the records): each delta light once, exactly, instead of samples that
      // repeat its shadow ray. The path draws the numbers one sample would have.
      for (int k = 0; k < kLightSampleNumbers; ++k) rng.uniform();
      *nextSink += beta * deltaLightsExactly(scene, deltas, hit, frame, bsdf, woLocal);
    } else if (!bsdf.isDelta()) {
      Rgb light = sampleDirectLight(scene, hit, frame, bsdf, woLocal, rng, skipSky);
      if (severalSamples) {
        // Keyed by the number the path draws next: its own stream, the path's untouched.
        Rng peek = rng;
        Rng more = Rng::forKeys(uint64_t{peek.nextU32()}, kFirstHitLightDomain);
        for (int k = 1; k < settings.firstHitLightSamples; ++k) {
          light += sampleDirectLight(scene, hit, frame, bsdf, woLocal, more, skipSky);
        }
        light /= static_cast<float>(settings.firstHitLightSamples);
      }
      *nextSink += beta * light;
    } else {
      rng.uniform();
      rng.uniform();
      rng.uniform();
    }

    if (bounce == 0 && settings.firstHitBsdfSamples > 1 && !bsdf.isDelta() &&
        material.type == MaterialType::kConductor) {
      Rng peek = rng;
      Rng more = Rng::forKeys(uint64_t{peek.nextU32()}, kFirstHitBsdfDomain);
      const int n = settings.firstHitBsdfSamples;
      Rgb caught(0.0f);
      for (int k = 1; k < n; ++k) {
        caught += bsdfSampledEmission(scene, hit, frame, bsdf, woLocal, more, skipSky);
      }
      *nextSink += beta * caught / static_cast<float>(n);
      emissionScale = 1.0f / static_cast<float>(n);
    }

    const float uc = rng.uniform();
    const Vec2f u = next2(rng);
    const std::optional<BsdfSample> bs = bsdf.sample(woLocal, uc, u);
    if (!bs || bs->pdf <= 0.0f || isBlack(bs->f)) break;
    const Vec3f wi = frame.toWorld(bs->wi);
    // Reject samples whose side disagrees between shading and geometric normals.
    const bool reflectShading = bs->wi.z * woLocal.z > 0.0f;
    const bool reflectGeo = dot(wi, hit.ng) * dot(wo, hit.ng) > 0.0f;
    if (reflectShading != reflectGeo) break;
    beta *= bs->f * (std::abs(bs->wi.z) / bs->pdf);
    if (!isFinite(beta)) break;
    prevBsdfPdf = bs->pdf;
    prevDelta = bs->delta;
    specularSoFar = specularSoFar && bs->delta;
    prevP = hit.p;
    ray = scene.spawnRay(hit.p, hit.ng, wi);

    if (bounce + 1 >= settings.rouletteDepth) {
      const float q = std::min(0.95f, maxComponent(beta));
      const float ur = rng.uniform();
      if (ur >= q) break;
      beta /= q;
    }
  }
  return out;
}

}  // namespace pbgi
