#pragma once
// Places surfels on every triangle of a scene, in proportion to area, and streams them out
// one at a time in a fixed order (mesh order, then triangle order, then a triangle's own
// sequence), so that a bake of 10^8 surfels never holds them all.
//
// Counts per triangle: systematic sampling along the cumulative area. Surfel k of N sits at
// (k + u) * totalArea / N on the line that lays the triangles end to end, u in [0, 1) drawn
// from (seed, frame); a triangle receives the surfels whose positions fall inside its own
// stretch. The total is exactly N, every triangle gets floor or ceil of its share, and a
// triangle smaller than a surfel gets one with probability equal to its share.
//
// Within a triangle: the Hammersley set of the triangle's count, Cranley-Patterson rotated by
// a random shift keyed (seed, frame, triangle id), mapped through Heitz's area-preserving
// square-to-triangle warp (sampleUniformTriangle). Stratified whatever the count, and each
// triangle's points depend only on its own key, never on the triangles before it.
//
// Radius: every surfel stands for the same share of the total area, so the radius is uniform:
// r = sqrt(totalArea / (pi N)) and the disks' areas add up to the scene's area exactly.
//
// Normal: the geometric normal, the front side by the triangle's winding, not the interpolated
// shading normal. The disks then lie in their triangles' planes: they tile the surface without
// tilting into neighbours, a receiver's shadow rays leave from the side they face, and the
// front side is the one the path tracer's geometric normal names.

#include <cstdint>
#include <functional>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/pbgi/surfel.h"
#include "core/scene/scene.h"

namespace pbgi {

struct SurfelSamplingOptions {
  // Exactly one of the two is positive: a surfel count, or a radius the count follows from
  // (N = round(totalArea / (pi r^2)), at least 1).
  uint64_t targetCount = 0;
  float targetRadius = 0.0f;
  uint64_t seed = 0;
  int frame = 0;
};

struct SurfelSamplingStats {
  double totalArea = 0.0;
  uint64_t triangles = 0;
  uint64_t surfels = 0;
  uint64_t trianglesWithoutSurfel = 0;  // smaller than their share of one surfel
  float radius = 0.0f;                  // of every surfel
};

// The class a material's surfels carry: kEmissive for any material that emits (as the scene
// makes a light of it), else by BSDF: diffuse, glossy (conductor), transmissive (dielectric),
// except that a rough conductor or dielectric whose lobes the tree's SH hold (needsWavelets
// false, e.g. GGX alpha 1) is diffuse: its surfels then take its hemispherical albedo and
// reflect like a Lambertian surface of that albedo, paying for no wavelets.
MaterialClass materialClassOf(const Material& material);
// The albedo of a Lambertian surface that reflects as much of uniform light as the material:
// the BSDF's hemispherical-hemispherical reflectance (its own albedo for diffuse materials),
// by a fixed set of 4,096 cosine-weighted directions in and one BSDF sample out each.
Rgb hemisphericalAlbedo(const Material& material);

// The number of surfels a sampling with these options places on `scene`, and their radius,
// without placing them (for progress and memory estimates).
absl::Status planSurfels(const Scene& scene, const SurfelSamplingOptions& options,
                         SurfelSamplingStats* plan);

// Calls `sink` once per surfel in the fixed order above; the surfel's index in the stream is
// its identity for the shading that follows (shadeSurfelsDirect keys its random numbers by
// it). Radiance is left black. Stops at the first error the sink returns and returns it.
// Fails with InvalidArgument when the options do not name exactly one target, or when the
// scene has no area to place surfels on. `stats` may be null.
absl::Status sampleSurfels(const Scene& scene, const SurfelSamplingOptions& options,
                           const std::function<absl::Status(const Surfel&)>& sink,
                           SurfelSamplingStats* stats);

// sampleSurfels into memory, for clouds known to be small (tests, previews); a bake streams.
absl::StatusOr<std::vector<Surfel>> collectSurfels(const Scene& scene,
                                                   const SurfelSamplingOptions& options,
                                                   SurfelSamplingStats* stats = nullptr);

}  // namespace pbgi
