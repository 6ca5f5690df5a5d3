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
