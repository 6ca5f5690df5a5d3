// A glossy BSDF projected into Haar wavelets per outgoing elevation (wavelet_bsdf.h): its
// product with incoming radiance against the same integral summed texel by texel over the
// cube map, within the error the projection states, for GGX conductors of alpha 0.05, 0.15
// and 0.35 seen at three elevations.

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "core/pbgi/microbuffer.h"
#include "core/pbgi/wavelet_bsdf.h"

namespace pbgi {
namespace {

Material ggxConductor(float alpha) {
  Material m;
  m.name = "ggx";
  m.type = MaterialType::kConductor;
  m.roughness = alpha;
  m.distribution = MicrofacetDistribution::kGgx;
  m.albedo = Rgb(0.9f, 0.6f, 0.3f);  // Schlick's F0, coloured
  return m;
}

// Incoming light in the local frame: a dim sky over the upper hemisphere, brighter towards
// the zenith, and a small bright source in the direction `sun` (a lamp: what a glossy lobe
// picks out).
Rgb incoming(const Vec3f& wi, const Vec3f& sun) {
  const Rgb sky = wi.z > 0.0f ? Rgb(0.2f, 0.3f, 0.5f) * (0.5f + wi.z) : Rgb(0.05f);
  const float c = dot(wi, sun);
  return sky + (c > 0.995f ? Rgb(40.0f, 38.0f, 30.0f) : Rgb(0.0f));
}

double norm(const WaveletRadiance& w) {
  double sum = 0;
  for (float v : w.dense()) sum += double(v) * v;
  return std::sqrt(sum);
}

TEST(WaveletBsdf, TheProductIsTheTexelSumWithinTheStatedError) {
  const WaveletBsdfOptions options{.resolution = 16, .viewBins = 16, .relativeError = 0.01f};
  const auto tables = microbufferTables(options.resolution);
  for (const float alpha : {0.05f, 0.15f, 0.35f}) {
    const Material material = ggxConductor(alpha);
    const Bsdf bsdf(material, material.albedo);
    const auto projected = WaveletBsdf::project(material, material.albedo, options);
    ASSERT_TRUE(projected.ok()) << projected.status();
    EXPECT_LE(projected->maxRelativeError(), options.relativeError + 1e-6f);
    for (const int bin : {1, 8, 14}) {  // about 8, 47 and 82 degrees from the normal
      const float theta = projected->binElevation(bin);
      const Vec3f wo(std::sin(theta), 0.0f, std::cos(theta));
      // The light's highlight where the mirror direction is, and off it.
      const Vec3f sun = normalize(Vec3f(-wo.x, 0.1f, wo.z));
      std::vector<Rgb> texels(tables->directions.size());
      Rgb brute(0.0f);
      for (size_t t = 0; t < texels.size(); ++t) {
        const Vec3f& wi = tables->directions[t];
        texels[t] = incoming(wi, sun);
        brute += texels[t] * bsdf.f(wo, wi) * (std::abs(wi.z) * tables->solidAngles[t]);
      }
      const WaveletRadiance light = WaveletRadiance::fromTexels(texels, options.resolution, 0.0f);
      const Rgb product = projected->reflect(light, std::cos(theta));
      // The receivers' form: every incoming coefficient, the slice's kept ones summed.
      std::vector<float> coefficients;
      WaveletBsdf::incomingCoefficients(texels, options.resolution, &coefficients);
      const Rgb sparse = projected->reflect(coefficients, std::cos(theta));
      for (int c = 0; c < 3; ++c) EXPECT_NEAR(sparse[c], product[c], 1e-5f * std::abs(product[c]));
      // Cauchy-Schwarz: what the slice dropped, times the light's norm.
      // |g - g_kept| = e |g| with |g|^2 = |g_kept|^2 + |g - g_kept|^2 (orthonormal basis).
      const WaveletRadiance& slice = projected->slice(bin);
      const double e = slice.relativeError();
      const double bound = norm(light) * e * norm(slice) / std::sqrt(1.0 - e * e);
      for (int c = 0; c < 3; ++c) {
        EXPECT_NEAR(product[c], brute[c], bound + 1e-5 * std::abs(brute[c]))
            << "alpha " << alpha << " bin " << bin << " channel " << c << ": product "
            << product[c] << ", texel sum " << brute[c] << ", bound " << bound;
      }
      EXPECT_GT(average(brute), 0.0f);
      std::printf("alpha %.2f theta %4.1f deg: texel sum %.5f, product %.5f (%.3f %% off), "
                  "slice keeps %zu of %d coefficients\n",
                  alpha, degrees(theta), average(brute), average(product),
                  100.0 * std::abs(average(product) - average(brute)) / average(brute),
                  slice.keptCoefficients(), 6 * 3 * options.resolution * options.resolution);
    }
  }
}

// The product is sparse: a lobe is local on the sphere, so a slice keeps a fraction of the
// cube's coefficients (measured: about 5 % at alpha 0.05, 35 % at 0.35, at 1 % error), and
// what it dropped is measured, within the bound asked for.
TEST(WaveletBsdf, ASliceIsSparseAndItsErrorIsMeasured) {
  const WaveletBsdfOptions options{.resolution = 16, .viewBins = 8, .relativeError = 0.02f};
  const size_t dense = 6 * 3 * 16 * 16;
  for (const float alpha : {0.35f, 0.15f, 0.05f}) {
    const Material m = ggxConductor(alpha);
    const auto projected = WaveletBsdf::project(m, m.albedo, options);
    ASSERT_TRUE(projected.ok()) << projected.status();
    for (int b = 0; b < projected->bins(); ++b) {
      EXPECT_LT(projected->slice(b).keptCoefficients(), dense / 2) << "alpha " << alpha;
    }
    EXPECT_GT(projected->maxRelativeError(), 0.0f);
    EXPECT_LE(projected->maxRelativeError(), options.relativeError + 1e-6f);
  }
  // Below the surface nothing is reflected.
  const Material m = ggxConductor(0.15f);
  const auto projected = WaveletBsdf::project(m, m.albedo, options);
  ASSERT_TRUE(projected.ok());
  const WaveletRadiance white = WaveletRadiance::project(
      [](const Vec3f&) { return Rgb(1.0f); }, options.resolution, 0.0f);
  EXPECT_EQ(projected->reflect(white, -0.3f), Rgb(0.0f));
  EXPECT_GT(average(projected->reflect(white, 0.7f)), 0.0f);
}

// A lobe narrower than a texel: GGX alpha 0.05 and 0.01 on a 16^2 cube (7-degree texels).
// Integrated over the texels by sampling the lobe, a slice's sum (its product with unit radiance)
// is the directional albedo, the integral of f cos, which BSDF sampling measures; sampled at the
// texels' centres it is off by whatever the centres happen to hit. Slices are projected as they are
// used.
TEST(WaveletBsdf, LobeSampledSlicesHoldANarrowLobesEnergy) {
  for (const float alpha : {0.05f, 0.01f}) {
    const Material m = ggxConductor(alpha);
    const Bsdf bsdf(m, m.albedo);
    const auto centres = WaveletBsdf::project(m, m.albedo, {.viewBins = 16, .lobeSamples = 0});
    const auto integrated = WaveletBsdf::project(m, m.albedo, {.viewBins = 16, .lobeSamples = 64});
    ASSERT_TRUE(centres.ok() && integrated.ok());
    EXPECT_EQ(integrated->projectedBins(), 0);
    const auto tables = microbufferTables(16);
    std::vector<float> white;
    WaveletBsdf::incomingCoefficients(std::vector<Rgb>(tables->directions.size(), Rgb(1.0f)), 16,
                                      &white);
    double worstCentres = 0.0, worstIntegrated = 0.0;
    for (const int bin : {2, 7, 12}) {
      const float theta = integrated->binElevation(bin);
      const Vec3f wo(std::sin(theta), 0.0f, std::cos(theta));
      // The directional albedo by BSDF sampling, stratified.
      double albedo = 0.0;
      const int side = 256;
      for (int i = 0; i < side; ++i) {
        for (int j = 0; j < side; ++j) {
          const auto s = bsdf.sample(wo, 0.5f, Vec2f((i + 0.5f) / side, (j + 0.5f) / side));
          if (s && s->pdf > 0.0f) albedo += s->f.x * std::abs(s->wi.z) / s->pdf;
        }
      }
      albedo /= side * side;
      const double c = centres->reflect(white, std::cos(theta)).x / albedo - 1.0;
      const double g = integrated->reflect(white, std::cos(theta)).x / albedo - 1.0;
      std::printf(
          "[ measured ] alpha %.2f at %.1f deg: slice sum / albedo - 1: centres %+.1f %%, "
          "64^2 lobe samples %+.2f %%\n",
          alpha, degrees(theta), 100 * c, 100 * g);
      worstCentres = std::max(worstCentres, std::abs(c));
      worstIntegrated = std::max(worstIntegrated, std::abs(g));
    }
    EXPECT_LT(worstIntegrated, 0.02);
    EXPECT_LT(worstIntegrated, worstCentres);
    EXPECT_LE(integrated->projectedBins(), 6);  // the two around each elevation asked for
    EXPECT_GE(integrated->projectedBins(), 3);
  }
}

// What lets a receiver skip its product gather: a view below the surface (a shading normal
// turned from the camera), or slices that kept nothing (a BSDF that reflects nothing there).
TEST(WaveletBsdf, ReflectsNothingBelowTheSurfaceOrWhereNoCoefficientIsKept) {
  WaveletBsdfOptions options;
  options.resolution = 8;
  options.viewBins = 8;
  const Material glossy = ggxConductor(0.15f);
  auto bsdf = WaveletBsdf::project(glossy, glossy.albedo, options);
  ASSERT_TRUE(bsdf.ok()) << bsdf.status();
  EXPECT_TRUE(bsdf->reflectsNothing(-0.2f));
  EXPECT_TRUE(bsdf->reflectsNothing(0.0f));
  EXPECT_FALSE(bsdf->reflectsNothing(0.05f));
  EXPECT_FALSE(bsdf->reflectsNothing(0.7f));
  Material black = glossy;
  black.specular = Rgb(0.0f);
  black.tint = Rgb(0.0f);
  auto none = WaveletBsdf::project(black, Rgb(0.0f), options);
  ASSERT_TRUE(none.ok()) << none.status();
  for (const float c : {0.05f, 0.4f, 0.7f, 1.0f}) EXPECT_TRUE(none->reflectsNothing(c)) << c;
}

// How many texels a lobe spans (what decides whether the product resolves it): more for a
// rougher lobe and a finer cube, about one for a near mirror.
TEST(WaveletBsdf, ALobeSpansMoreTexelsTheRougherItIs) {
  for (const int n : {16, 32}) {
    WaveletBsdfOptions options;
    options.resolution = n;
    options.viewBins = 16;
    options.lobeSamples = 128;
    for (const float c : {0.95f, 0.5f}) {
      float last = 0.0f;
      std::printf("[ measured ] %d^2, view cosine %.2f: texels a GGX lobe spans:", n, c);
      for (const float alpha : {0.01f, 0.05f, 0.1f, 0.15f, 0.25f, 0.35f, 0.6f}) {
        const Material m = ggxConductor(alpha);
        auto bsdf = WaveletBsdf::project(m, m.albedo, options);
        ASSERT_TRUE(bsdf.ok()) << bsdf.status();
        const float texels = bsdf->lobeTexels(c);
        std::printf(" %.2f: %.1f", alpha, texels);
        EXPECT_GT(texels, last) << alpha;
        last = texels;
      }
      std::printf("\n");
    }
  }
  const Material mirrorLike = ggxConductor(0.01f);
  WaveletBsdfOptions options;
  options.lobeSamples = 128;
  auto bsdf = WaveletBsdf::project(mirrorLike, mirrorLike.albedo, options);
  ASSERT_TRUE(bsdf.ok());
  EXPECT_LT(bsdf->lobeTexels(0.9f), 4.0f);
}

TEST(WaveletBsdf, OneProjectionPerMaterialsParametersAndBadOptionsAreRefused) {
  WaveletBsdfCache cache;
  const WaveletBsdfOptions options{.resolution = 8, .viewBins = 4, .relativeError = 0.05f};
  Material a = ggxConductor(0.15f);
  Material b = a;
  b.name = "same parameters, another name";
  auto first = cache.get(a, options);
  auto second = cache.get(b, options);
  ASSERT_TRUE(first.ok() && second.ok());
  EXPECT_EQ(first->get(), second->get());
  EXPECT_EQ(cache.size(), 1u);
  b.roughness = 0.2f;
  ASSERT_TRUE(cache.get(b, options).ok());
  EXPECT_EQ(cache.size(), 2u);
  EXPECT_FALSE(WaveletBsdf::project(a, a.albedo, {.resolution = 12}).ok());
  EXPECT_FALSE(WaveletBsdf::project(a, a.albedo, {.viewBins = 1}).ok());
  EXPECT_FALSE(WaveletBsdf::project(a, a.albedo, {.relativeError = 1.5f}).ok());
  EXPECT_FALSE(WaveletBsdf::project(a, a.albedo, {.lobeSamples = -1}).ok());
}

}  // namespace
}  // namespace pbgi
