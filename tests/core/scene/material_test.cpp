// Tests of the BSDFs: sampling against the stated density (chi-square), sample weights
// against f()/pdf(), energy conservation, reciprocity, two-sidedness and robustness.

#include "core/scene/material.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <string>
#include <vector>

#include <gtest/gtest.h>

#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"
#include "core/scene/microfacet.h"

namespace pbgi {
namespace {

using Dist = MicrofacetDistribution;

Material diffuse(const Rgb& albedo) {
  Material m;
  m.name = "diffuse";
  m.type = MaterialType::kDiffuse;
  m.albedo = albedo;
  return m;
}

Material schlickConductor(Dist dist, float alpha, const Rgb& f0 = Rgb(1.0f)) {
  Material m;
  m.name = "conductor";
  m.type = MaterialType::kConductor;
  m.distribution = dist;
  m.roughness = alpha;
  m.specular = f0;
  return m;
}

// Gold at roughly 650 / 550 / 450 nm.
Material goldConductor(Dist dist, float alpha) {
  Material m = schlickConductor(dist, alpha);
  m.complexIor = true;
  m.eta = Rgb(0.143f, 0.374f, 1.442f);
  m.k = Rgb(3.983f, 2.385f, 1.603f);
  m.tint = Rgb(1.0f, 0.9f, 0.8f);
  return m;
}

Material dielectric(Dist dist, float alpha, float ior = 1.5f) {
  Material m;
  m.name = "dielectric";
  m.type = MaterialType::kDielectric;
  m.distribution = dist;
  m.roughness = alpha;
  m.ior = ior;
  return m;
}

Material emissive() {
  Material m;
  m.name = "light";
  m.type = MaterialType::kEmissive;
  m.radiance = Rgb(10.0f);
  return m;
}

Vec3f direction(float thetaDeg, float phiDeg) {
  const float t = radians(thetaDeg);
  const float p = radians(phiDeg);
  return {std::sin(t) * std::cos(p), std::sin(t) * std::sin(p), std::cos(t)};
}
Vec3f flipZ(const Vec3f& v) { return {v.x, v.y, -v.z}; }

std::optional<BsdfSample> draw(const Bsdf& bsdf, const Vec3f& wo, Rng& rng) {
  const float uc = rng.uniform();
  const float u0 = rng.uniform();
  const float u1 = rng.uniform();
  return bsdf.sample(wo, uc, Vec2f(u0, u1));
}

// max |a - b| / max(|a|, |b|) over channels, with an absolute floor for values near zero.
float relativeError(const Rgb& a, const Rgb& b) {
  float worst = 0.0f;
  for (int c = 0; c < 3; ++c) {
    const float scale = std::max({std::abs(a[c]), std::abs(b[c]), 1e-6f});
    worst = std::max(worst, std::abs(a[c] - b[c]) / scale);
  }
  return worst;
}
float relativeError(float a, float b) { return relativeError(Rgb(a), Rgb(b)); }

std::string describe(const Material& m) {
  const char* dist = m.distribution == Dist::kGgx ? "ggx" : "beckmann";
  return fmt::format("{} {} alpha={}", m.name, dist, m.roughness);
}

// ---------------------------------------------------------------------------------------
// Chi-square goodness of fit (pbrt-v3 / Mitsuba): histogram sample() in (cos theta, phi)
// over the whole sphere, integrate pdf() over the same cells, pool cells expecting fewer than
// 5 samples, and test at 1% significance, Sidak-corrected for the number of tests run.

constexpr int kCosBins = 10;
constexpr int kPhiBins = 20;
constexpr int kChi2Samples = 1000000;
constexpr double kMinExpected = 5.0;

// Adaptive Simpson with Lyness' stopping rule and Richardson extrapolation. The interval is
// first cut into kSplits pieces so that a narrow lobe cannot hide between the first points.
double adaptiveSimpson(const std::function<double(double)>& f, double x0, double x1, double eps,
                       int maxDepth) {
  std::function<double(double, double, double, double, double, double, double, double, int)>
      recurse = [&](double a, double b, double c, double fa, double fb, double fc, double whole,
                    double tol, int depth) {
        const double d = 0.5 * (a + b);
        const double e = 0.5 * (b + c);
        const double fd = f(d);
        const double fe = f(e);
        const double h = c - a;
        const double left = h / 12.0 * (fa + 4.0 * fd + fb);
        const double right = h / 12.0 * (fb + 4.0 * fe + fc);
        const double both = left + right;
        if (depth <= 0 || std::abs(both - whole) <= 15.0 * tol) return both + (both - whole) / 15.0;
        return recurse(a, d, b, fa, fd, fb, left, 0.5 * tol, depth - 1) +
               recurse(b, e, c, fb, fe, fc, right, 0.5 * tol, depth - 1);
      };
  constexpr int kSplits = 4;
  double sum = 0.0;
  for (int i = 0; i < kSplits; ++i) {
    const double a = x0 + (x1 - x0) * i / kSplits;
    const double c = x0 + (x1 - x0) * (i + 1) / kSplits;
    const double b = 0.5 * (a + c);
    const double fa = f(a), fb = f(b), fc = f(c);
    const double whole = (c - a) / 6.0 * (fa + 4.0 * fb + fc);
    sum += recurse(a, b, c, fa, fb, fc, whole, eps / kSplits, maxDepth);
  }
  return sum;
}

// Regularised upper incomplete gamma Q(a, x) (Numerical Recipes: series below a + 1,
// continued fraction above), enough for chi-square p-values.
double gammaQ(double a, double x) {
  if (x <= 0.0) return 1.0;
  const double lnPrefix = -x + a * std::log(x) - std::lgamma(a);
  if (x < a + 1.0) {
    double term = 1.0 / a;
    double sum = term;
    for (int n = 1; n < 10000; ++n) {
      term *= x / (a + n);
      sum += term;
      if (std::abs(term) < std::abs(sum) * 1e-15) break;
    }
    return 1.0 - sum * std::exp(lnPrefix);
  }
  constexpr double kTiny = 1e-300;
  double b = x + 1.0 - a;
  double c = 1.0 / kTiny;
  double d = 1.0 / b;
  double h = d;
  for (int i = 1; i < 10000; ++i) {
    const double an = -i * (i - a);
    b += 2.0;
    d = an * d + b;
    if (std::abs(d) < kTiny) d = kTiny;
    c = b + an / c;
    if (std::abs(c) < kTiny) c = kTiny;
    d = 1.0 / d;
    const double delta = d * c;
    h *= delta;
    if (std::abs(delta - 1.0) < 1e-15) break;
  }
  return std::exp(lnPrefix) * h;
}

struct Chi2Result {
  double pValue = 0.0;
  double statistic = 0.0;
  int dof = 0;
  std::string failure;  // set when the test fails for a reason other than the statistic
};

// Histograms sampler.sample() and compares it with density.pdf() (the same BSDF, except
// where a test checks that a mismatch is caught).
Chi2Result chi2Test(const Bsdf& sampler, const Bsdf& density, const Vec3f& wo, uint64_t seed) {
  std::vector<double> observed(kCosBins * kPhiBins, 0.0);
  Rng rng(seed);
  for (int i = 0; i < kChi2Samples; ++i) {
    const auto s = draw(sampler, wo, rng);
    if (!s || s->delta) continue;
    const Vec3f wi = normalize(s->wi);
    const float cosTheta = std::clamp(wi.z, -1.0f, 1.0f);
    float phi = std::atan2(wi.y, wi.x);
    if (phi < 0.0f) phi += 2.0f * kPi;
    const int ci =
        std::clamp(static_cast<int>((cosTheta + 1.0f) * 0.5f * kCosBins), 0, kCosBins - 1);
    const int pi = std::clamp(static_cast<int>(phi / (2.0f * kPi) * kPhiBins), 0, kPhiBins - 1);
    observed[ci * kPhiBins + pi] += 1.0;
  }

  auto pdfAt = [&](double cosTheta, double phi) {
    const double sinTheta = std::sqrt(std::max(0.0, 1.0 - cosTheta * cosTheta));
    const Vec3f wi(static_cast<float>(sinTheta * std::cos(phi)),
                   static_cast<float>(sinTheta * std::sin(phi)), static_cast<float>(cosTheta));
    return static_cast<double>(density.pdf(wo, wi));
  };
  std::vector<double> expected(observed.size());
  const double dCos = 2.0 / kCosBins;
  const double dPhi = 2.0 * kPi / kPhiBins;
  for (int ci = 0; ci < kCosBins; ++ci) {
    for (int pi = 0; pi < kPhiBins; ++pi) {
      const double c0 = -1.0 + ci * dCos;
      const double p0 = pi * dPhi;
      const double integral = adaptiveSimpson(
          [&](double c) {
            // The density jumps at the horizon, a cell edge: evaluating a hair inside the
            // cell takes the one-sided limit instead of the other side's value.
            const double inside = std::clamp(c, c0 + 1e-6, c0 + dCos - 1e-6);
            return adaptiveSimpson([&](double p) { return pdfAt(inside, p); }, p0, p0 + dPhi, 1e-7,
                                   7);
          },
          c0, c0 + dCos, 1e-7, 7);
      expected[ci * kPhiBins + pi] = integral * kChi2Samples;
    }
  }

  std::vector<int> order(observed.size());
  for (size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  std::sort(order.begin(), order.end(), [&](int a, int b) { return expected[a] < expected[b]; });
  Chi2Result result;
  double pooledObserved = 0.0;
  double pooledExpected = 0.0;
  int cells = 0;
  for (int i : order) {
    if (expected[i] <= 0.0) {
      if (observed[i] > kChi2Samples * 1e-5) {
        result.failure =
            fmt::format("{} samples in cell {} where pdf() integrates to 0", observed[i], i);
        return result;
      }
      pooledObserved += observed[i];
    } else if (expected[i] < kMinExpected ||
               (pooledExpected > 0.0 && pooledExpected < kMinExpected)) {
      pooledObserved += observed[i];
      pooledExpected += expected[i];
    } else {
      result.statistic += sqr(observed[i] - expected[i]) / expected[i];
      ++cells;
    }
  }
  if (pooledExpected > 0.0) {
    result.statistic += sqr(pooledObserved - pooledExpected) / pooledExpected;
    ++cells;
  } else if (pooledObserved > kChi2Samples * 1e-5) {
    result.failure = fmt::format("{} samples where pdf() integrates to 0", pooledObserved);
    return result;
  }
  result.dof = cells - 1;
  if (result.dof < 1) {
    result.failure = "fewer than two cells: the binning cannot resolve this density";
    return result;
  }
  result.pValue = gammaQ(0.5 * result.dof, 0.5 * result.statistic);
  return result;
}

struct Chi2Case {
  std::string name;
  Material material;
  Vec3f wo;
  uint64_t seed = 0;
};

// Keeps gtest from dumping the case's bytes in failure reports.
void PrintTo(const Chi2Case& c, std::ostream* os) {
  *os << c.name << " wo=" << fmt::format("{}", c.wo);
}

std::vector<Chi2Case> chi2Cases() {
  std::vector<Chi2Case> cases;
  const float angles[] = {10.0f, 50.0f, 80.0f};
  auto addAngles = [&](const std::string& name, const Material& m, bool inside) {
    for (const float theta : angles) {
      const Vec3f wo = direction(inside ? 180.0f - theta : theta, 37.0f);
      cases.push_back({fmt::format("{}_{}{}", name, inside ? "inside" : "theta", int(theta)), m, wo,
                       hashKeys(cases.size(), 0x6368693275ull)});
    }
  };
  addAngles("Diffuse", diffuse(Rgb(0.5f)), false);
  addAngles("DiffuseBack", diffuse(Rgb(0.5f)), true);
  addAngles("GgxConductor005", schlickConductor(Dist::kGgx, 0.05f), false);
  addAngles("GgxConductor03", schlickConductor(Dist::kGgx, 0.3f), false);
  addAngles("GgxConductor08", schlickConductor(Dist::kGgx, 0.8f), false);
  addAngles("GgxConductorBack03", schlickConductor(Dist::kGgx, 0.3f), true);
  addAngles("GgxConductorBack08", schlickConductor(Dist::kGgx, 0.8f), true);
  addAngles("BeckmannConductor03", schlickConductor(Dist::kBeckmann, 0.3f), false);
  addAngles("BeckmannConductor08", schlickConductor(Dist::kBeckmann, 0.8f), false);
  addAngles("GgxDielectric01", dielectric(Dist::kGgx, 0.1f), false);
  addAngles("GgxDielectric01", dielectric(Dist::kGgx, 0.1f), true);
  addAngles("GgxDielectric05", dielectric(Dist::kGgx, 0.5f), false);
  addAngles("GgxDielectric05", dielectric(Dist::kGgx, 0.5f), true);
  addAngles("BeckmannDielectric03", dielectric(Dist::kBeckmann, 0.3f), false);
  addAngles("BeckmannDielectric03", dielectric(Dist::kBeckmann, 0.3f), true);
  return cases;
}

class BsdfChi2Test : public ::testing::TestWithParam<Chi2Case> {};

TEST_P(BsdfChi2Test, SamplesFollowPdf) {
  const Chi2Case& c = GetParam();
  const Bsdf bsdf(c.material, c.material.albedo);
  const Chi2Result r = chi2Test(bsdf, bsdf, c.wo, c.seed);
  ASSERT_TRUE(r.failure.empty()) << describe(c.material) << ": " << r.failure;
  // Sidak: the chance that any of the tests fails by accident stays at 1%.
  const double alpha = 1.0 - std::pow(1.0 - 0.01, 1.0 / static_cast<double>(chi2Cases().size()));
  EXPECT_GT(r.pValue, alpha) << describe(c.material) << " wo=" << fmt::format("{}", c.wo)
                             << " chi2=" << r.statistic << " dof=" << r.dof;
}

INSTANTIATE_TEST_SUITE_P(All, BsdfChi2Test, ::testing::ValuesIn(chi2Cases()),
                         [](const ::testing::TestParamInfo<Chi2Case>& info) {
                           return info.param.name;
                         });

// The test must be able to fail: samples of a GGX alpha = 0.3 conductor judged against the
// pdf of alpha = 0.33 are rejected.
TEST(BsdfChi2Test, DetectsAWrongDensity) {
  const Material sampled = schlickConductor(Dist::kGgx, 0.3f);
  const Material claimed = schlickConductor(Dist::kGgx, 0.33f);
  const Bsdf sampledBsdf(sampled, sampled.albedo);
  const Bsdf claimedBsdf(claimed, claimed.albedo);
  const Chi2Result r = chi2Test(sampledBsdf, claimedBsdf, direction(40.0f, 10.0f), 7);
  ASSERT_TRUE(r.failure.empty()) << r.failure;
  EXPECT_LT(r.pValue, 1e-6) << "chi2=" << r.statistic << " dof=" << r.dof;
}

// ---------------------------------------------------------------------------------------

// The materials every property test runs over: all types, both distributions, a range of
// roughness including the delta limit.
std::vector<Material> allMaterials() {
  std::vector<Material> out;
  out.push_back(diffuse(Rgb(0.5f, 0.7f, 0.9f)));
  for (const float alpha : {0.0f, 0.01f, 0.1f, 0.3f, 0.6f, 1.0f}) {
    for (const Dist dist : {Dist::kGgx, Dist::kBeckmann}) {
      out.push_back(schlickConductor(dist, alpha, Rgb(1.0f, 0.8f, 0.3f)));
      out.push_back(goldConductor(dist, alpha));
      out.push_back(dielectric(dist, alpha, 1.5f));
      out.push_back(dielectric(dist, alpha, 2.4f));
    }
  }
  return out;
}

const float kAngles[] = {0.0f, 20.0f, 45.0f, 70.0f, 85.0f};

TEST(BsdfTest, SampleWeightsMatchEvaluation) {
  int compared = 0;
  for (const Material& m : allMaterials()) {
    for (const TransportMode mode : {TransportMode::kRadiance, TransportMode::kImportance}) {
      const Bsdf bsdf(m, m.albedo, mode);
      for (const float theta : kAngles) {
        for (const bool inside : {false, true}) {
          const Vec3f wo = direction(inside ? 180.0f - theta : theta, 123.0f);
          Rng rng(hashKeys(compared, theta, inside));
          int mismatches = 0;
          std::string first;
          for (int i = 0; i < 2000; ++i) {
            const auto s = draw(bsdf, wo, rng);
            if (!s || s->delta) continue;
            ++compared;
            const Rgb f = bsdf.f(wo, s->wi);
            const float pdf = bsdf.pdf(wo, s->wi);
            if (relativeError(s->f, f) > 1e-3f || relativeError(s->pdf, pdf) > 1e-3f) {
              if (mismatches++ == 0) {
                first = fmt::format("wi={} sample f={} pdf={} vs f={} pdf={}", s->wi, s->f, s->pdf,
                                    f, pdf);
              }
            }
          }
          EXPECT_EQ(mismatches, 0)
              << describe(m) << " wo=" << fmt::format("{}", wo) << ": " << first;
        }
      }
    }
  }
  EXPECT_GT(compared, 100000);
}

// Mean and standard error of a Monte Carlo estimate.
struct Estimate {
  double mean = 0.0;
  double error = 0.0;
};
Estimate estimate(double sum, double sumSq, int n) {
  const double mean = sum / n;
  return {mean, std::sqrt(std::max(0.0, sumSq / n - mean * mean) / n)};
}

// E(wo) = E[f |cos| / pdf]; with importance transport this is the fraction of energy the
// surface scatters, which can never exceed 1.
Estimate directionalAlbedo(const Bsdf& bsdf, const Vec3f& wo, int n, uint64_t seed,
                           double* maxWeight = nullptr) {
  Rng rng(seed);
  double sum = 0.0;
  double sumSq = 0.0;
  double worst = 0.0;
  for (int i = 0; i < n; ++i) {
    const auto s = draw(bsdf, wo, rng);
    if (!s) continue;
    const double w = maxComponent(s->f) * std::abs(s->wi.z) / s->pdf;
    sum += w;
    sumSq += w * w;
    worst = std::max(worst, w);
  }
  if (maxWeight) *maxWeight = worst;
  return estimate(sum, sumSq, n);
}

// The same integral estimated by uniform sphere sampling, which depends on f() alone.
Estimate directionalAlbedoUniform(const Bsdf& bsdf, const Vec3f& wo, int n, uint64_t seed) {
  Rng rng(seed);
  double sum = 0.0;
  double sumSq = 0.0;
  for (int i = 0; i < n; ++i) {
    const Vec3f wi = sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform()));
    const double w = maxComponent(bsdf.f(wo, wi)) * std::abs(wi.z) / uniformSpherePdf();
    sum += w;
    sumSq += w * w;
  }
  return estimate(sum, sumSq, n);
}

TEST(BsdfTest, EnergyIsConserved) {
  std::vector<Material> materials;
  materials.push_back(diffuse(Rgb(1.0f)));
  for (const float alpha : {0.01f, 0.1f, 0.3f, 0.6f, 1.0f}) {
    for (const Dist dist : {Dist::kGgx, Dist::kBeckmann}) {
      materials.push_back(schlickConductor(dist, alpha, Rgb(1.0f)));
      materials.push_back(goldConductor(dist, alpha));
      materials.push_back(dielectric(dist, alpha, 1.5f));
      materials.push_back(dielectric(dist, alpha, 1.33f));
    }
  }
  int index = 0;
  for (const Material& m : materials) {
    const Bsdf bsdf(m, m.albedo, TransportMode::kImportance);
    for (const float theta : kAngles) {
      for (const bool inside : {false, true}) {
        if (inside && m.type != MaterialType::kDielectric) continue;
        const Vec3f wo = direction(inside ? 180.0f - theta : theta, 30.0f);
        double maxWeight = 0.0;
        const Estimate e = directionalAlbedo(bsdf, wo, 20000, hashKeys(++index), &maxWeight);
        EXPECT_LE(e.mean, 1.0 + 3.0 * e.error + 1e-4)
            << describe(m) << " theta=" << theta << " inside=" << inside;
        // Importance sampling visible normals makes each weight G2 / G1 (times Fresnel).
        EXPECT_LE(maxWeight, 1.0 + 1e-3) << describe(m) << " theta=" << theta;
        // f() integrated independently of sample(); only where uniform sampling converges.
        if (m.roughness >= 0.3f && theta <= 70.0f) {
          const Estimate eu = directionalAlbedoUniform(bsdf, wo, 60000, hashKeys(++index));
          EXPECT_NEAR(eu.mean, e.mean, 5.0 * (eu.error + e.error) + 2e-3)
              << describe(m) << " theta=" << theta << " inside=" << inside;
        }
      }
    }
  }
}

TEST(BsdfTest, WhiteFurnaceNearSmoothConductorReflectsEverything) {
  for (const Dist dist : {Dist::kGgx, Dist::kBeckmann}) {
    const Material m = schlickConductor(dist, 0.01f, Rgb(1.0f));
    const Bsdf bsdf(m, m.albedo);
    const double e = directionalAlbedo(bsdf, Vec3f(0, 0, 1), 20000, 11).mean;
    EXPECT_NEAR(e, 1.0, 0.02) << describe(m);
  }
}

TEST(BsdfTest, DiffuseAlbedo) {
  const Material m = diffuse(Rgb(0.5f));
  for (const float theta : kAngles) {
    for (const bool back : {false, true}) {
      const Bsdf bsdf(m, m.albedo);
      const Vec3f wo = direction(back ? 180.0f - theta : theta, 0.0f);
      EXPECT_NEAR(directionalAlbedo(bsdf, wo, 20000, 3).mean, 0.5, 0.005);
      EXPECT_NEAR(directionalAlbedoUniform(bsdf, wo, 400000, 5).mean, 0.5, 0.005);
    }
  }
  // The texture-looked-up albedo wins over the material's.
  const Bsdf textured(m, Rgb(0.2f, 0.4f, 0.6f));
  EXPECT_NEAR(textured.f(Vec3f(0, 0, 1), normalize(Vec3f(1, 0, 1))).y, 0.4f * kInvPi, 1e-6f);
}

TEST(BsdfTest, SmoothDielectricFresnelAtNormalIncidence) {
  for (const float ior : {1.33f, 1.5f, 2.4f}) {
    const Material m = dielectric(Dist::kGgx, 0.0f, ior);
    const float r = sqr((ior - 1.0f) / (ior + 1.0f));
    for (const TransportMode mode : {TransportMode::kRadiance, TransportMode::kImportance}) {
      const Bsdf bsdf(m, m.albedo, mode);
      EXPECT_TRUE(bsdf.isDelta());
      for (const bool inside : {false, true}) {
        const Vec3f wo(0.0f, 0.0f, inside ? -1.0f : 1.0f);
        const auto refl = bsdf.sample(wo, 0.5f * r, Vec2f(0.5f, 0.5f));
        ASSERT_TRUE(refl);
        EXPECT_TRUE(refl->delta);
        EXPECT_FALSE(refl->transmission);
        EXPECT_NEAR(refl->wi.z, wo.z, 1e-6f);
        EXPECT_NEAR(refl->f.x * std::abs(refl->wi.z), r, 1e-6f) << "ior=" << ior;
        EXPECT_NEAR(refl->pdf, r, 1e-6f);
        const auto trans = bsdf.sample(wo, 0.5f + 0.5f * r, Vec2f(0.5f, 0.5f));
        ASSERT_TRUE(trans);
        EXPECT_TRUE(trans->transmission);
        EXPECT_NEAR(trans->wi.z, -wo.z, 1e-6f);
        EXPECT_NEAR(trans->pdf, 1.0f - r, 1e-6f);
        // Radiance crossing into the denser medium is compressed into a smaller solid angle.
        const float etap = inside ? 1.0f / ior : ior;
        const float expected = mode == TransportMode::kRadiance ? (1.0f - r) / sqr(etap) : 1.0f - r;
        EXPECT_NEAR(trans->f.x * std::abs(trans->wi.z), expected, 1e-5f);
      }
    }
  }
}

TEST(BsdfTest, SmoothDielectricSnellAndTotalInternalReflection) {
  const float ior = 1.5f;
  const Material m = dielectric(Dist::kGgx, 0.0f, ior);
  const Bsdf bsdf(m, m.albedo);
  const Vec3f wo = direction(60.0f, 0.0f);
  const auto t = bsdf.sample(wo, 0.999f, Vec2f(0.0f, 0.0f));
  ASSERT_TRUE(t && t->transmission);
  const float sinO = std::sqrt(1.0f - wo.z * wo.z);
  const float sinI = std::sqrt(1.0f - t->wi.z * t->wi.z);
  EXPECT_NEAR(sinO, ior * sinI, 1e-5f);
  EXPECT_LT(t->wi.x, 0.0f);  // continues on the far side of the normal
  // Beyond the critical angle (41.8 deg for 1.5) from inside, everything reflects.
  const Vec3f inside = direction(180.0f - 50.0f, 0.0f);
  for (const float uc : {0.0f, 0.5f, 0.999f}) {
    const auto s = bsdf.sample(inside, uc, Vec2f(0.3f, 0.3f));
    ASSERT_TRUE(s);
    EXPECT_FALSE(s->transmission);
    EXPECT_NEAR(s->pdf, 1.0f, 1e-6f);
    EXPECT_NEAR(s->f.x * std::abs(s->wi.z), 1.0f, 1e-5f);
  }
  // A rough dielectric from inside beyond the critical angle: still R + T <= 1, mostly R.
  const Material rough = dielectric(Dist::kGgx, 0.05f, ior);
  const Bsdf roughBsdf(rough, rough.albedo, TransportMode::kImportance);
  const double e = directionalAlbedo(roughBsdf, direction(180.0f - 60.0f, 0.0f), 20000, 9).mean;
  EXPECT_LE(e, 1.0 + 1e-3);
  EXPECT_GT(e, 0.95);
}

TEST(BsdfTest, RoughDielectricNearlySmoothKeepsAllEnergy) {
  for (const Dist dist : {Dist::kGgx, Dist::kBeckmann}) {
    const Material m = dielectric(dist, 0.01f, 1.5f);
    const Bsdf bsdf(m, m.albedo, TransportMode::kImportance);
    for (const float theta : {0.0f, 30.0f, 60.0f}) {
      EXPECT_NEAR(directionalAlbedo(bsdf, direction(theta, 0.0f), 20000, 5).mean, 1.0, 0.02)
          << describe(m) << " theta=" << theta;
      EXPECT_NEAR(directionalAlbedo(bsdf, direction(180.0f - theta, 0.0f), 20000, 6).mean, 1.0,
                  0.02)
          << describe(m) << " inside theta=" << theta;
    }
  }
}

TEST(BsdfTest, SmoothConductorIsAMirror) {
  const Material gold = goldConductor(Dist::kGgx, 0.0f);
  const Bsdf bsdf(gold, gold.albedo);
  EXPECT_TRUE(bsdf.isDelta());
  for (const bool back : {false, true}) {
    const Vec3f wo = back ? Vec3f(0, 0, -1) : Vec3f(0, 0, 1);
    const auto s = bsdf.sample(wo, 0.5f, Vec2f(0.5f, 0.5f));
    ASSERT_TRUE(s);
    EXPECT_TRUE(s->delta);
    EXPECT_EQ(s->pdf, 1.0f);
    EXPECT_NEAR(s->wi.z, wo.z, 1e-6f);
    // Conductor Fresnel at normal incidence: ((n - 1)^2 + k^2) / ((n + 1)^2 + k^2).
    for (int c = 0; c < 3; ++c) {
      const float n = gold.eta[c];
      const float k = gold.k[c];
      const float f0 = (sqr(n - 1.0f) + k * k) / (sqr(n + 1.0f) + k * k);
      EXPECT_NEAR(s->f[c] * std::abs(s->wi.z), f0 * gold.tint[c], 1e-5f) << "channel " << c;
    }
  }
  EXPECT_EQ(bsdf.f(Vec3f(0, 0, 1), Vec3f(0, 0, 1)), Rgb(0.0f));
  EXPECT_EQ(bsdf.pdf(Vec3f(0, 0, 1), Vec3f(0, 0, 1)), 0.0f);
  // Schlick at grazing goes to 1 whatever F0.
  const Material schlick = schlickConductor(Dist::kGgx, 0.0f, Rgb(0.04f));
  const Bsdf sb(schlick, schlick.albedo);
  const Vec3f grazing = direction(89.9f, 0.0f);
  const auto g = sb.sample(grazing, 0.5f, Vec2f(0.5f, 0.5f));
  ASSERT_TRUE(g);
  EXPECT_GT(g->f.x * g->wi.z, 0.99f);
  const auto n = sb.sample(Vec3f(0, 0, 1), 0.5f, Vec2f(0.5f, 0.5f));
  ASSERT_TRUE(n);
  EXPECT_NEAR(n->f.x, 0.04f, 1e-6f);
}

TEST(BsdfTest, ReflectionIsReciprocal) {
  Rng rng(42);
  int nonzero = 0;
  for (const Material& m : allMaterials()) {
    if (m.type == MaterialType::kDielectric) continue;
    const Bsdf bsdf(m, m.albedo);
    for (int i = 0; i < 500; ++i) {
      const Vec3f wo = sampleCosineHemisphere(Vec2f(rng.uniform(), rng.uniform()));
      const Vec3f wi = sampleCosineHemisphere(Vec2f(rng.uniform(), rng.uniform()));
      const Rgb a = bsdf.f(wo, wi);
      const Rgb b = bsdf.f(wi, wo);
      if (maxComponent(a) > 0.0f) ++nonzero;
      EXPECT_LE(relativeError(a, b), 1e-4f)
          << describe(m) << " wo=" << fmt::format("{}", wo) << " wi=" << fmt::format("{}", wi);
    }
  }
  EXPECT_GT(nonzero, 5000);
}

TEST(BsdfTest, DielectricGeneralisedReciprocity) {
  Rng rng(43);
  int transmissions = 0;
  for (const Material& m : allMaterials()) {
    if (m.type != MaterialType::kDielectric || m.roughness == 0.0f) continue;
    const Bsdf radiance(m, m.albedo, TransportMode::kRadiance);
    const Bsdf importance(m, m.albedo, TransportMode::kImportance);
    for (int i = 0; i < 500; ++i) {
      const Vec3f wo = sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform()));
      const Vec3f wi = sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform()));
      const Rgb forward = radiance.f(wo, wi);
      const Rgb backward = radiance.f(wi, wo);
      if (wo.z * wi.z > 0.0f) {
        EXPECT_LE(relativeError(forward, backward), 1e-4f) << describe(m);
        continue;
      }
      if (maxComponent(forward) > 0.0f) ++transmissions;
      // f(wo, wi) / eta_o^2 = f(wi, wo) / eta_i^2, and radiance transport is the adjoint of
      // importance transport.
      const float etaO = wo.z > 0.0f ? 1.0f : m.ior;
      const float etaI = wi.z > 0.0f ? 1.0f : m.ior;
      EXPECT_LE(relativeError(forward / sqr(etaO), backward / sqr(etaI)), 2e-4f)
          << describe(m) << " wo=" << fmt::format("{}", wo) << " wi=" << fmt::format("{}", wi);
      EXPECT_LE(relativeError(forward, importance.f(wi, wo)), 2e-4f) << describe(m);
    }
  }
  EXPECT_GT(transmissions, 500);
}

TEST(BsdfTest, DiffuseAndConductorAreTwoSided) {
  Rng rng(44);
  for (const Material& m : allMaterials()) {
    if (m.type == MaterialType::kDielectric) continue;
    const Bsdf bsdf(m, m.albedo);
    for (int i = 0; i < 200; ++i) {
      const Vec3f wo = sampleCosineHemisphere(Vec2f(rng.uniform(), rng.uniform()));
      const Vec3f wi = sampleCosineHemisphere(Vec2f(rng.uniform(), rng.uniform()));
      EXPECT_LE(relativeError(bsdf.f(flipZ(wo), flipZ(wi)), bsdf.f(wo, wi)), 1e-6f) << describe(m);
      EXPECT_LE(relativeError(bsdf.pdf(flipZ(wo), flipZ(wi)), bsdf.pdf(wo, wi)), 1e-6f);
      // Nothing goes through.
      EXPECT_EQ(bsdf.f(flipZ(wo), wi), Rgb(0.0f)) << describe(m);
      EXPECT_EQ(bsdf.pdf(wo, flipZ(wi)), 0.0f) << describe(m);
      // The same random numbers give the mirrored sample.
      const float uc = rng.uniform();
      const Vec2f u(rng.uniform(), rng.uniform());
      const auto front = bsdf.sample(wo, uc, u);
      const auto back = bsdf.sample(flipZ(wo), uc, u);
      ASSERT_EQ(front.has_value(), back.has_value()) << describe(m);
      if (front) {
        EXPECT_LT(back->wi.z, 0.0f);
        EXPECT_LE(length(back->wi - flipZ(front->wi)), 1e-6f);
        EXPECT_LE(relativeError(back->f, front->f), 1e-6f);
        EXPECT_LE(relativeError(back->pdf, front->pdf), 1e-6f);
      }
    }
  }
}

TEST(BsdfTest, EmissiveReflectsNothing) {
  const Material m = emissive();
  const Bsdf bsdf(m, m.albedo);
  EXPECT_TRUE(bsdf.isBlack());
  EXPECT_FALSE(bsdf.isDelta());
  Rng rng(45);
  for (int i = 0; i < 100; ++i) {
    const Vec3f wo = sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform()));
    const Vec3f wi = sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform()));
    EXPECT_EQ(bsdf.f(wo, wi), Rgb(0.0f));
    EXPECT_EQ(bsdf.pdf(wo, wi), 0.0f);
    EXPECT_FALSE(bsdf.sample(wo, rng.uniform(), Vec2f(rng.uniform(), rng.uniform())));
  }
  EXPECT_FALSE(Bsdf(diffuse(Rgb(0.5f)), Rgb(0.5f)).isBlack());
}

TEST(BsdfTest, NoNanForDegenerateInput) {
  std::vector<Material> materials = allMaterials();
  for (const float alpha :
       {0.0f, 1e-7f, 1.1e-3f, 50.0f, 1e6f, 1e30f, std::numeric_limits<float>::infinity()}) {
    for (const Dist dist : {Dist::kGgx, Dist::kBeckmann}) {
      materials.push_back(schlickConductor(dist, alpha));
      materials.push_back(goldConductor(dist, alpha));
      materials.push_back(dielectric(dist, alpha));
    }
  }
  materials.push_back(dielectric(Dist::kGgx, 0.3f, 1.0f));  // an invisible interface
  materials.push_back(emissive());
  const float zs[] = {1e-8f, 0.0f, -1e-8f, 1e-30f, 1.0f, -1.0f, 0.5f};
  Rng rng(46);
  int samples = 0;
  for (const Material& m : materials) {
    for (const TransportMode mode : {TransportMode::kRadiance, TransportMode::kImportance}) {
      const Bsdf bsdf(m, m.albedo, mode);
      for (const float z : zs) {
        const Vec3f wo(std::sqrt(1.0f - z * z), 0.0f, z);
        for (int i = 0; i < 300; ++i) {
          const auto s = draw(bsdf, wo, rng);
          if (s) {
            ++samples;
            ASSERT_TRUE(isFinite(s->f) && std::isfinite(s->pdf) && s->pdf > 0.0f)
                << describe(m) << " z=" << z << " f=" << fmt::format("{}", s->f)
                << " pdf=" << s->pdf;
            ASSERT_TRUE(isFinite(s->wi));
            ASSERT_GE(minComponent(s->f), 0.0f);
          }
          for (const Vec3f& wi :
               {sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform())), Vec3f(-wo.x, -wo.y, wo.z),
                Vec3f(-wo.x, 0.0f, -wo.z), -wo, wo, Vec3f(0.0f, 1.0f, 0.0f)}) {
            const Rgb f = bsdf.f(wo, wi);
            const float pdf = bsdf.pdf(wo, wi);
            ASSERT_TRUE(isFinite(f) && minComponent(f) >= 0.0f)
                << describe(m) << " z=" << z << " wi=" << fmt::format("{}", wi);
            ASSERT_TRUE(std::isfinite(pdf) && pdf >= 0.0f)
                << describe(m) << " z=" << z << " wi=" << fmt::format("{}", wi);
          }
        }
      }
    }
  }
  EXPECT_GT(samples, 10000);
}

TEST(BsdfTest, DeltaClassification) {
  EXPECT_FALSE(Bsdf(diffuse(Rgb(0.5f)), Rgb(0.5f)).isDelta());
  const Material smooth = schlickConductor(Dist::kGgx, 5e-4f);
  const Material rough = schlickConductor(Dist::kGgx, 2e-3f);
  EXPECT_TRUE(Bsdf(smooth, smooth.albedo).isDelta());
  EXPECT_FALSE(Bsdf(rough, rough.albedo).isDelta());
  const Material glass = dielectric(Dist::kBeckmann, 0.2f);
  EXPECT_FALSE(Bsdf(glass, glass.albedo).isDelta());
  const auto s = Bsdf(glass, glass.albedo).sample(direction(30, 0), 0.9f, Vec2f(0.3f, 0.6f));
  ASSERT_TRUE(s);
  EXPECT_FALSE(s->delta);
  EXPECT_TRUE(s->transmission);
}

TEST(BsdfMicrofacetTest, DistributionsAreNormalised) {
  // The projected area of the microfacets is the macro-surface's: int D(wm) cos dwm = 1,
  // and the visible normals from any direction integrate to 1.
  for (const Dist dist : {Dist::kGgx, Dist::kBeckmann}) {
    for (const float alpha : {0.1f, 0.5f, 1.0f}) {
      const Microfacet mf(dist, alpha);
      for (const float theta : {0.0f, 45.0f, 80.0f}) {
        const Vec3f w = direction(theta, 20.0f);
        const int n = 400;
        double projected = 0.0;
        double visible = 0.0;
        // Midpoint rule in (cos theta, phi) over the upper hemisphere.
        for (int i = 0; i < n; ++i) {
          const double c = (i + 0.5) / n;
          const double s = std::sqrt(1.0 - c * c);
          for (int j = 0; j < n; ++j) {
            const double p = 2.0 * kPi * (j + 0.5) / n;
            const Vec3f wm(float(s * std::cos(p)), float(s * std::sin(p)), float(c));
            const double area = (1.0 / n) * (2.0 * kPi / n);
            projected += mf.d(wm) * c * area;
            visible += mf.visibleDensity(w, wm) * area;
          }
        }
        const double tol = alpha < 0.2f ? 0.02 : 0.005;
        EXPECT_NEAR(projected, 1.0, tol) << describe(schlickConductor(dist, alpha));
        EXPECT_NEAR(visible, 1.0, tol)
            << describe(schlickConductor(dist, alpha)) << " theta=" << theta;
      }
    }
  }
}

TEST(BsdfMicrofacetTest, ErfInvInvertsErf) {
  for (float x = -0.999f; x < 0.999f; x += 0.0137f) {
    EXPECT_NEAR(std::erf(erfInv(x)), x, 2e-6f) << "x=" << x;
  }
}

TEST(BsdfMicrofacetTest, FresnelLimits) {
  EXPECT_NEAR(frDielectric(1.0f, 1.5f), 0.04f, 1e-6f);
  EXPECT_NEAR(frDielectric(-1.0f, 1.5f), 0.04f, 1e-6f);  // symmetric at normal incidence
  EXPECT_EQ(frDielectric(-0.5f, 1.5f), 1.0f);            // inside, past the critical angle
  EXPECT_NEAR(frDielectric(0.0f, 1.5f), 1.0f, 1e-6f);
  EXPECT_NEAR(frDielectric(0.7f, 1.0f), 0.0f, 1e-7f);
  // A conductor with k = 0 is a dielectric.
  for (const float c : {0.1f, 0.5f, 0.9f})
    EXPECT_NEAR(frComplex(c, 1.5f, 0.0f), frDielectric(c, 1.5f), 1e-5f);
  EXPECT_NEAR(frSchlick(1.0f, 0.3f), 0.3f, 1e-7f);
  EXPECT_NEAR(frSchlick(0.0f, 0.3f), 1.0f, 1e-7f);
}

}  // namespace
}  // namespace pbgi
