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
// Only the Lambertian part of a material reflects into this radiance: diffuse materials', and
// rough conductors and dielectrics that the sampler made diffuse surfels of their
// hemispherical albedo (materialClassOf). Glossy and transmissive surfels reflect nothing
// here (they still occlude, and emit if their material emits); their view-dependent radiance
// is the wavelet stage's (GlossyLeafBaker below), which only scenes with such materials pay
// for.

#include <cstdint>
#include <span>

#include "core/pbgi/pair_gather.h"
#include "core/pbgi/surfel.h"
#include "core/pbgi/tree_page.h"
#include "core/pbgi/tree_writer.h"
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
// (wavelet.h): `lightSamples` samples of the scene's lights at its
// centre (each lighting the side it arrives on, with its shadow ray), and the material's BSDF
// (albedo looked up) from each towards every texel of an n x n cube map, in the frame of the
// surfel's normal (its winding side: a dielectric's outside). Rough lobes only: a smooth
// (delta) BSDF sends out nothing here, and its mirror images need rays, not light samples.
// `rng` is the surfel's own stream (shadeSurfelsDirect's key).
WaveletRadiance glossyDirectRadiance(const Scene& scene, const Surfel& surfel,
                                     const Material& material, const Rgb& albedo, int n,
                                     float threshold, int lightSamples, Rng& rng);

struct GlossyBakeOptions {
  int resolution = 16;   // n: the cube map's faces are n x n (the paper uses 32)
  int lightSamples = 4;  // per glossy surfel; a leaf of m surfels takes m times as many
  float tolerance = kShLobeTolerance;  // needsWavelets'
  uint64_t seed = 0;
  int frame = 0;
  // With an incoming-light tree (GlossyLeafBaker::setIncoming): BSDF samples per glossy surfel
  // and outgoing texel of the indirect light it reflects, and the resolution of the
  // microbuffers that gather that light at the leaf.
  int indirectSamples = 8;
  // Whether the leaf's vector holds the lights' direct light (false: only what it reflects of
  // the incoming tree, for the trees of a bake's bounces, which hold the light a bounce adds).
  bool directLight = true;
  // Whether mirrors and glass trace their specular chains to the lights (with directLight):
  // a bake does it in the tree it ends with alone, the chains being its dearest part.
  bool specularChains = true;
  int incomingResolution = 16;
  // bakeLeaves: the receiver threshold of the pair refinement that gathers a batch's glossy
  // leaves together (pair_gather.h; 0: each leaf gathers alone, as operator() does).
  float pairReceiverSolidAngle = 0.0f;
};

// What the tree writer asks of the bake for each leaf holding glossy or refractive surfels
// (TreeWaveletOptions::leaf): the leaf's direct glossy light as wavelet intensity, the sum over
// its surfels whose material needsWavelets of area x |cos| x outgoing radiance towards every
// texel of the cube map (light samples and BSDF as glossyDirectRadiance), and each such
// surfel's radiance and back radiance set to its mean outgoing radiance over that side (the
// cosine-weighted average: what a gather that sees it as a disk uses). Materials of one scene
// are measured once, here. Thread-safe; the same leaf and key give the same bits.
class GlossyLeafBaker {
 public:
  static constexpr int kReflectionSets = 16;
  GlossyLeafBaker(const Scene& scene, const GlossyBakeOptions& options);

  // Whether any material of the scene needs wavelets: a scene without one bakes none.
  bool anyWavelets() const { return any_; }
  // Glossy surfels then also reflect the light of `tree` (a bake's tree of every diffuse
  // bounce): gathered at each glossy leaf's centroid into two microbuffers, one a side of the
  // leaf's mean normal, and sent out through the BSDF by importance sampling it (a Monte Carlo
  // wavelet product; Wang et al. section 3.3 do it in the wavelet domain). Null: direct light
  // alone. `tree` must be thread-safe (a PageCache) and outlive the calls.
  void setIncoming(TreePageSource* tree) { incoming_ = tree; }
  WaveletRadiance operator()(std::span<Surfel> surfels, uint64_t leafKey) const;
  // The same for a batch of leaves (TreeWaveletOptions::leaves), their incoming light gathered
  // by pair refinement over the batch's glossy leaves (pair_gather.h), both sides of each, so
  // that a cluster that looks alike from a group of leaves is splatted once for the group. With
  // pairReceiverSolidAngle 0 each job's vector is operator()'s, bit for bit; the same batch
  // gives the same bits whatever the threads. The refinement's counters add to `stats` (may be
  // null).
  void bakeLeaves(std::span<WaveletLeafJob> jobs, PairGatherStats* stats) const;

 private:
  const Scene* scene_;
  GlossyBakeOptions options_;
  TreePageSource* incoming_ = nullptr;

  std::vector<uint64_t> bases_;     // first global triangle id of each mesh
  std::vector<uint8_t> needs_;      // per scene material: needsWavelets
  bool any_ = false;
  // Per rough material that needs wavelets, kReflectionSets sets of indirectSamples BSDF
  // samples for each texel of a cube in the material's local frame (z the normal): direction
  // in and f cos / pdf, drawn once, so that a leaf's reflected light costs lookups, not BSDF
  // sampling. A leaf takes set leafKey % kReflectionSets: neighbours' samples differ.
  struct ReflectionSamples {
    std::vector<Vec3f> wi;
    std::vector<Rgb> weight;  // black where the sample failed
  };
  std::vector<std::vector<ReflectionSamples>> reflection_;  // by material, then set

  // One leaf's bake, in steps (surfel_shading.cpp): its glossy surfels and their direct light,
  // the indirect light arriving at it, what each material reflects of that towards every
  // texel, the lights seen through mirrors and glass, then each surfel's outgoing radiance.
  struct Leaf;
  Leaf collectGlossy(std::span<Surfel> surfels, uint64_t leafKey) const;
  // The leaf's centre and mean normal, where its incoming light is gathered.
  static void locate(Leaf& leaf);
  void gatherIncoming(Leaf& leaf) const;
  void reflectIncoming(Leaf& leaf, uint64_t leafKey) const;
  void traceSpecularChains(Leaf& leaf, uint64_t leafKey) const;
  WaveletRadiance radiate(Leaf& leaf) const;
};

}  // namespace pbgi
