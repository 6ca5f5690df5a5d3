#pragma once
// Direct lighting of surfels: the outgoing diffuse radiance that the PBGI tree aggregates.
//
// radiance = emitted + diffuseAlbedo / pi * E_front, backRadiance = emitted + diffuseAlbedo /
// pi * E_back, where E_front and E_back are the irradiance on the surfel's two sides (surfaces
// are two-sided, as for the path tracer) estimated with the path tracer's own light sampling
// (sampleIrradianceBothSides: every light type, Embree shadow rays; each sample lights the side
// it arrives on), so that the PBGI integrators differ from the reference only in how they
// gather indirect light.
//
// Only the Lambertian part of a material reflects into this radiance. Conductors and
// dielectrics have no Lambertian lobe, so glossy and transmissive surfels reflect nothing
// here (they still occlude, and emit if their material emits); their view-dependent radiance
// belongs to the wavelet stage, which only scenes with such materials pay for.

#include <cstdint>
#include <span>

#include "core/pbgi/surfel.h"
#include "core/pbgi/wavelet.h"
#include "core/sampling/rng.h"
#include "core/scene/scene.h"

namespace pbgi {

struct SurfelShadingOptions {
  int lightSamples = 16;  // light samples per surfel
  uint64_t seed = 0;
  int frame = 0;
};

struct SurfelShadingStats {
  uint64_t surfels = 0;
  uint64_t emissive = 0;          // surfels whose material emits
  uint64_t discardedSamples = 0;  // light samples that came back NaN or infinite (dropped)
  uint64_t nonFiniteSurfels = 0;  // radiance NaN or infinite (bad albedo or emission): set black
};

// Sets `radiance` of each surfel; surfels[i] is surfel number firstSurfelIndex + i of the
// sampler's stream, the key of its random numbers (seed, frame, surfel), so a surfel's
// radiance does not depend on how the stream was cut into chunks or on the thread count.
// Runs in parallel (TBB). Surfels must come from sampleSurfels on the same scene.
SurfelShadingStats shadeSurfelsDirect(const Scene& scene, std::span<Surfel> surfels,
                                      uint64_t firstSurfelIndex,
                                      const SurfelShadingOptions& options);

// Whether a material's surfels need wavelets: its light leaves in lobes that the tree's
// spherical harmonics (bands 0-2) hold to within `tolerance` (shProjectionError of the
// intensity a surfel sends out, BSDF times both cosines, for light arriving at 0, 40, 70 and
// 85 degrees; the largest counts) or not. Diffuse and emissive materials never do; a smooth
// (delta) conductor or dielectric always does; a rough one by its lobes, so that a glossy
// material rough enough for SH is treated as diffuse and pays for no wavelets. The default
// tolerance is about 3.4 times what SH miss of a diffuse surfel's own lobe (a clamped cosine:
// 0.088); measured, GGX conductors of alpha 0.05 / 0.15 / 0.35 / 0.6 / 1.0 miss 0.97 / 0.91 /
// 0.72 / 0.38 / 0.27 (the grazing lobes decide), so alpha 1 passes as diffuse and 0.6 does not.
inline constexpr float kShLobeTolerance = 0.3f;
bool needsWavelets(const Material& material, float tolerance = kShLobeTolerance);
// The largest shProjectionError of the material's lobes, as needsWavelets measures it (0 for
// diffuse and emissive materials, 1 for delta ones).
float shLobeError(const Material& material);

// The direct light a glossy or refractive surfel sends out, in every direction, as wavelets
// (issue 14's first stage; wavelet.h): `lightSamples` samples of the scene's lights at its
// centre (each lighting the side it arrives on, with its shadow ray), and the material's BSDF
// (albedo looked up) from each towards every texel of an n x n cube map, in the frame of the
// surfel's normal (its winding side: a dielectric's outside). Rough lobes only: a smooth
// (delta) BSDF sends out nothing here, and its mirror images need rays, not light samples.
// `rng` is the surfel's own stream (shadeSurfelsDirect's key).
WaveletRadiance glossyDirectRadiance(const Scene& scene, const Surfel& surfel,
                                     const Material& material, const Rgb& albedo, int n,
                                     float threshold, int lightSamples, Rng& rng);

}  // namespace pbgi
