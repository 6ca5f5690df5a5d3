#pragma once
// The unbiased reference: unidirectional path tracing with next-event estimation and
// multiple importance sampling (power heuristic), Russian roulette after a set depth.
// Every other integrator is measured against this one.

#include <functional>
#include <optional>

#include "core/math/vec.h"
#include "core/sampling/rng.h"
#include "core/scene/scene.h"

namespace pbgi {

struct PathTracerSettings {
  int maxDepth = 64;      // scattering vertices after the camera; 1 = direct light only
  int rouletteDepth = 3;  // Russian roulette from this many bounces on
  // Light samples at the first hit, averaged (the light-sampling half of its MIS estimate):
  // PBGI's direct light, where one camera sample costs a gather and a light sample is cheap.
  // Samples past the first draw from a stream of their own, so 1 leaves the path unchanged.
  int firstHitLightSamples = 1;
  // BSDF samples at a first hit on a rough conductor, averaged (the BSDF-sampling half of its
  // MIS estimate of direct light): a near-mirror lobe reflects a small light through its BSDF
  // samples, which light samples almost never find. Only the emission they meet counts; the
  // path goes on from the first as before, its emission at the next vertex weighted 1 / n.
  // Samples past the first draw from a stream of their own, so 1 leaves the path unchanged.
  int firstHitBsdfSamples = 1;
  // Whether a first hit on a diffuse material takes the environment's light (isSkyLight) from
  // its own light and BSDF samples. PBGI's records take it instead (sky_irradiance.h): they
  // clear this, and the path tracer keeps it.
  bool skyAtDiffuseFirstHit = true;
  // When set: where a path that has only scattered specularly since the camera (mirrors,
  // smooth glass) meets a diffuse surface, the light that surface sends back along the path
  // (all of it: its direct light and every bounce's), or nullopt to trace on. PBGI reads it
  // from its tree, so that what glass and mirrors show is as smooth as the rest of its image.
  // Must be safe to call from many threads.
  std::function<std::optional<Rgb>(const SurfaceHit& hit, const Vec3f& towardsViewer)>
      specularChainEnd;
};

// What one camera sample brings back: radiance split into direct (emitters seen directly
// and light after one bounce) and indirect (the rest), and first-hit AOVs.
struct PathSample {
  Rgb direct{0.0f};
  Rgb indirect{0.0f};
  Rgb albedo{0.0f};
  Vec3f normal{0.0f};
  float depth = 0.0f;  // distance along the primary ray; 0 where it escapes
  bool hit = false;    // the primary ray hit a surface
  Rgb radiance() const { return direct + indirect; }
};

// One light sample towards surface point p (geometric normal ng) that nothing occludes, with
// the probability of having picked its light; nullopt when it is blocked or carries nothing.
// Draws exactly three random numbers whatever happens.
// With skipSky, it picks among the lights that are not environments (Scene::sampleLight).
std::optional<LightSample> sampleUnoccludedLight(const Scene& scene, const Vec3f& p,
                                                 const Vec3f& ng, Rng& rng, float* selectPdf,
                                                 bool skipSky = false);

// Irradiance at p on the side of unit normal n from one light sample (light sampling alone:
// every light of the scene can be sampled). The surfel baker's estimator.
Rgb sampleIrradiance(const Scene& scene, const Vec3f& p, const Vec3f& n, const Vec3f& ng,
                     Rng& rng);

// Irradiance on both sides of a surface point with unit geometric normal ng from one light
// sample (light sampling alone): the front (the side ng points to) and the back. The sample
// arrives on one side; its shadow ray leaves from that side. The same three random numbers as
// sampleIrradiance, so the front equals its result for the same stream.
struct TwoSidedIrradiance {
  Rgb front{0.0f};
  Rgb back{0.0f};
};
TwoSidedIrradiance sampleIrradianceBothSides(const Scene& scene, const Vec3f& p, const Vec3f& ng,
                                             Rng& rng);

// Direct light arriving at a surface point from one light sample, MIS-weighted against
// BSDF sampling. Shared with the PBGI integrators and the surfel baker, so that they differ
// from the path tracer only in indirect light.
Rgb sampleDirectLight(const Scene& scene, const SurfaceHit& hit, const Frame& frame,
                      const Bsdf& bsdf, const Vec3f& woLocal, Rng& rng, bool skipSky = false);

// One camera path. `firstHit`, when given, receives the primary ray's hit (untouched when
// the ray escapes): what an integrator that replaces the indirect light shades from.
PathSample tracePath(const Scene& scene, const Ray& ray, Rng& rng,
                     const PathTracerSettings& settings, SurfaceHit* firstHit = nullptr);

}  // namespace pbgi
