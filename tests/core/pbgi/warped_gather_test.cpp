#include "core/pbgi/warped_gather.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <set>
#include <vector>

#include "core/pbgi/gather.h"
#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"
#include "core/scene/material.h"
#include "tests/support/bsdf_reference.h"
#include "tests/support/memory_tree.h"
#include "tests/support/surfel_shapes.h"

namespace pbgi {
namespace {

using testing::conductorMaterial;
using testing::dielectricMaterial;
using testing::diffuseMaterial;
using testing::directionalAlbedo;
using testing::DiskNearMirror;
using testing::disksNearMirror;
using testing::diskSurfels;
using testing::FailingPageSource;
using testing::memoryTree;
using testing::MemoryTreeSource;
using testing::RecordingSource;
using testing::referenceDiskReflection;
using testing::relativeError;
using testing::sphereSurfels;
using testing::treeOf;
using testing::unitWo;

// The pixels' regions tile the hemisphere: their solid angles add up to 2 pi, and directions
// drawn uniformly over it fall into the pixels in proportion to those solid angles.
TEST(WarpedGather, SolidAnglesTileTheHemisphere) {
  struct Case {
    const char* name;
    Material material;
  };
  const std::vector<Case> cases = {
      {"diffuse", diffuseMaterial(Rgb(0.8f))},
      {"ggx 0.05", conductorMaterial(0.05f, Rgb(0.9f))},
      {"ggx 0.1", conductorMaterial(0.1f, Rgb(0.9f))},
      {"ggx 0.3", conductorMaterial(0.3f, Rgb(0.9f))},
      {"ggx 0.7", conductorMaterial(0.7f, Rgb(0.9f))},
      {"beckmann 0.3", conductorMaterial(0.3f, Rgb(0.9f), MicrofacetDistribution::kBeckmann)},
      {"glass 0.2", dielectricMaterial(0.2f)},
  };
  const Frame frame(normalize(Vec3f(0.2f, -0.3f, 1.0f)));
  Rng rng(11);
  for (const Case& c : cases) {
    const Bsdf bsdf(c.material, c.material.albedo);
    for (const Vec3f& wo :
         {unitWo(0, 0, 1), unitWo(0.5f, 0.2f, 1), unitWo(1, -1, 0.4f), unitWo(1, 0.2f, 0.08f)}) {
      for (int resolution : {8, 16}) {
        WarpedGatherOptions options;
        options.resolution = resolution;
        WarpedGatherer g(options);
        ASSERT_TRUE(g.warp(frame, bsdf, wo, Vec2f(0.5f, 0.5f)).ok());
        const double total = g.coveredSolidAngle();
        // A pixel's sample lies in its own region, but for those that the geodesic edges of
        // the region cut off from the curved image of the stratum.
        int sampled = 0, home = 0;
        for (int k = 0; k < g.pixelCount(); ++k) {
          if (isBlack(g.pixelWeight(k))) continue;
          ++sampled;
          home += g.pixelOf(g.pixelDirection(k)) == k ? 1 : 0;
        }
        EXPECT_GE(home, 0.9 * sampled) << c.name << " wo " << fmt::format("{}", wo);
        EXPECT_NEAR(total / (2.0 * kPi), 1.0, 1e-4)
            << c.name << " wo " << fmt::format("{}", wo) << " N " << resolution;
        // Uniform directions over the hemisphere: each lands in one pixel, as often as its
        // solid angle says.
        const int draws = 200000;
        std::vector<int> hits(g.pixelCount(), 0);
        int missed = 0;
        for (int d = 0; d < draws; ++d) {
          Vec3f w = sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform()));
          w.z = std::abs(w.z);
          const int k = g.pixelOf(frame.toWorld(w));
          if (k < 0) {
            ++missed;
          } else {
            ++hits[k];
          }
        }
        double deviation = 0.0;
        for (int k = 0; k < g.pixelCount(); ++k) {
          deviation += std::abs(2.0 * kPi * hits[k] / draws - g.pixelSolidAngle(k));
        }
        deviation /= 2.0 * kPi;
        if (resolution == 16) {
          std::printf(
              "[ measured ] %-12s wo=%s N=%d: sum of solid angles / 2pi - 1 = %+.2e, "
              "missed %d of %d, sum |hits - solid angle| / 2pi = %.4f, samples in their pixel "
              "%d of %d\n",
              c.name, fmt::format("{}", wo).c_str(), resolution, total / (2.0 * kPi) - 1.0, missed,
              draws, deviation, home, sampled);
        }
        EXPECT_LE(missed, 2) << c.name;  // only where float rounding leaves a sliver
        // The statistical part alone is about sqrt(2 N^2 / (pi draws)) = 0.03 for N = 16.
        EXPECT_LT(deviation, 0.05) << c.name;
      }
    }
  }
}

// A receiver at the centre of a closed sphere of radiance L reflects L times the BSDF's
// directional albedo.
TEST(WarpedGather, FurnaceMatchesDirectionalAlbedo) {
  const Rgb radiance(1.0f, 0.5f, 0.25f);
  auto tree = treeOf(sphereSurfels(20000, 1.0f, radiance));
  struct Case {
    const char* name;
    Material material;
  };
  const std::vector<Case> cases = {
      {"diffuse", diffuseMaterial(Rgb(0.8f, 0.6f, 0.4f))},
      {"ggx 0.1", conductorMaterial(0.1f, Rgb(0.9f, 0.7f, 0.5f))},
      {"ggx 0.3", conductorMaterial(0.3f, Rgb(0.9f, 0.7f, 0.5f))},
  };
  WarpedGatherer g{WarpedGatherOptions{}};
  float worst = 0.0f;
  for (const Case& c : cases) {
    const Bsdf bsdf(c.material, c.material.albedo);
    for (const Vec3f& n : {Vec3f(0, 0, 1), normalize(Vec3f(0.3f, -0.5f, 0.8f)), Vec3f(-1, 0, 0)}) {
      const Frame frame(n);
      for (const Vec3f& wo : {unitWo(0, 0, 1), unitWo(0.6f, 0.3f, 1), unitWo(-1, 0.5f, 0.5f)}) {
        const Rgb albedo = directionalAlbedo(bsdf, wo);
        GatherStats stats;
        auto l = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo, Vec2f(0.37f, 0.61f), &stats);
        ASSERT_TRUE(l.ok()) << l.status();
        const float ratio = l->x / (radiance.x * albedo.x);
        worst = std::max(worst, std::abs(ratio - 1.0f));
        EXPECT_NEAR(l->y / (radiance.y * albedo.y), ratio, 0.01f) << c.name;
        EXPECT_LT(std::abs(ratio - 1.0f), 0.03f)
            << c.name << " n " << fmt::format("{}", n) << " wo " << fmt::format("{}", wo);
        std::printf("[ measured ] furnace %-8s n=%s wo=%s: L/(L_e albedo) = %.4f  %s\n", c.name,
                    fmt::format("{}", n).c_str(), fmt::format("{}", wo).c_str(), ratio,
                    stats.toString().c_str());
      }
    }
  }
  EXPECT_LT(worst, 0.03f);
}

// A rough dielectric's lobe choice picks reflection for few pixels (with probability R, a
// few percent), the rest are transmission and black: reflection comes out right on average
// over receivers (jitters), if noisy for each.
TEST(WarpedGather, DielectricReflectionIsRightOnAverage) {
  const Rgb radiance(1.0f);
  auto tree = treeOf(sphereSurfels(20000, 1.0f, radiance));
  const Material material = dielectricMaterial(0.2f);
  const Bsdf bsdf(material, material.albedo);
  WarpedGatherer g{WarpedGatherOptions{}};
  const Frame frame(normalize(Vec3f(0.3f, -0.5f, 0.8f)));
  for (const Vec3f& wo : {unitWo(0, 0, 1), unitWo(-1, 0.5f, 0.5f)}) {
    const float albedo = directionalAlbedo(bsdf, wo).x;
    Rng rng(29);
    const int receivers = 256;
    double mean = 0.0;
    for (int r = 0; r < receivers; ++r) {
      auto l = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo, Vec2f(rng.uniform(), rng.uniform()),
                         nullptr);
      ASSERT_TRUE(l.ok()) << l.status();
      mean += l->x / receivers;
    }
    std::printf("[ measured ] glass 0.2 wo=%s: mean over %d jitters L/(L_e albedo) = %.4f\n",
                fmt::format("{}", wo).c_str(), receivers, mean / albedo);
    EXPECT_NEAR(mean / albedo, 1.0, 0.03);
  }
}

// A small bright disk in the mirror direction of a sharp conductor: what warping is for. The
// cube buffer puts the whole lobe into a pixel or two, the warped one spreads the lobe over
// all of its pixels.
TEST(WarpedGather, GlossyReflectionBeatsTheCubeMicrobuffer) {
  const Material material = conductorMaterial(0.05f, Rgb(0.9f));
  const Bsdf bsdf(material, material.albedo);
  const Frame frame(Vec3f(0, 0, 1));
  const float emitted = 10.0f;
  GatherOptions cubeOptions;
  cubeOptions.resolution = 16;
  Gatherer cube(cubeOptions);
  WarpedGatherer warped{WarpedGatherOptions{}};
  double warpedError = 0.0, cubeError = 0.0, jitteredError = 0.0;
  int views = 0;
  for (const DiskNearMirror& disk : disksNearMirror()) {
    const Vec3f &wo = disk.wo, &center = disk.center, &normal = disk.normal;
    const float radius = 0.25f;
    auto tree = treeOf(diskSurfels(8000, center, normal, radius, Rgb(emitted)));
    const double reference =
        referenceDiskReflection(bsdf, frame, wo, center, normal, radius, emitted);

    auto l = warped.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo, Vec2f(0.5f, 0.5f), nullptr);
    ASSERT_TRUE(l.ok()) << l.status();
    double jittered = 0.0;
    Rng rng(9);
    for (int s = 0; s < 16; ++s) {
      auto lj = warped.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo,
                               Vec2f(rng.uniform(), rng.uniform()), nullptr);
      ASSERT_TRUE(lj.ok());
      jittered += std::abs(lj->x / reference - 1.0) / 16.0;
    }
    ASSERT_TRUE(cube.rasterize(*tree, Vec3f(0.0f), frame.n, nullptr).ok());
    const Rgb c = cube.microbuffer().convolve([&](const Vec3f& dir) {
      const Vec3f wi = frame.toLocal(dir);
      return wi.z > 0.0f ? bsdf.f(wo, wi).x * wi.z : 0.0f;
    });
    const double we = std::abs(l->x / reference - 1.0), ce = std::abs(c.x / reference - 1.0);
    std::printf(
        "[ measured ] glossy disk wo=%s: reference %.4f, warped N=16 %.4f (error %.1f %%, "
        "mean over 16 jitters %.1f %%), cube N=16 %.4f (error %.1f %%)\n",
        fmt::format("{}", wo).c_str(), reference, l->x, 100 * we, 100 * jittered, c.x, 100 * ce);
    warpedError += we;
    cubeError += ce;
    jitteredError += jittered;
    ++views;
  }
  warpedError /= views;
  cubeError /= views;
  jitteredError /= views;
  std::printf(
      "[ measured ] glossy disk mean error: warped %.1f %% (jittered %.1f %%), cube %.1f %%\n",
      100 * warpedError, 100 * jitteredError, 100 * cubeError);
  EXPECT_LT(warpedError, 0.5 * cubeError);
  EXPECT_LT(jitteredError, 0.5 * cubeError);
  EXPECT_LT(warpedError, 0.1);
}

TEST(WarpedGather, DeterministicAndJitterChangesLittle) {
  // Radiance that varies smoothly over the sphere: the jitter moves samples within their
  // pixels, which changes little.
  std::vector<Surfel> surfels = sphereSurfels(8000, 1.0f, Rgb(0.0f));
  for (Surfel& s : surfels) {
    const Vec3f& x = s.position;
    s.radiance = Rgb(1.0f + 0.5f * x.x, 1.0f + 0.5f * x.y * x.z, 1.0f - 0.5f * x.z);
  }
  auto onePage = treeOf(surfels);
  auto manyPages = treeOf(surfels, 3);
  ASSERT_GT(manyPages->pageCount(), 8u);
  const Material material = conductorMaterial(0.3f, Rgb(0.9f, 0.8f, 0.7f));
  const Bsdf bsdf(material, material.albedo);
  const Vec3f p(0.2f, -0.3f, 0.1f);
  const Frame frame(normalize(Vec3f(1, 2, 3)));
  const Vec3f wo = unitWo(0.3f, -0.2f, 1);
  WarpedGatherer g{WarpedGatherOptions{}};
  auto a = g.reflect(*onePage, p, frame, bsdf, wo, Vec2f(0.25f, 0.75f), nullptr);
  auto b = g.reflect(*onePage, p, frame, bsdf, wo, Vec2f(0.25f, 0.75f), nullptr);
  WarpedGatherer fresh{WarpedGatherOptions{}};
  auto c = fresh.reflect(*manyPages, p, frame, bsdf, wo, Vec2f(0.25f, 0.75f), nullptr);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  EXPECT_EQ(*a, *b);
  EXPECT_EQ(*a, *c);
  EXPECT_GT(a->x, 0.0f);
  // Other jitters: other samples of the same integral. Pixels near the horizon whose sample
  // falls below it are black for some jitters, which is most of the spread.
  std::vector<float> values;
  Rng rng(31);
  for (int i = 0; i < 16; ++i) {
    auto d = g.reflect(*onePage, p, frame, bsdf, wo, Vec2f(rng.uniform(), rng.uniform()), nullptr);
    ASSERT_TRUE(d.ok());
    EXPECT_NE(*d, *a);
    values.push_back(d->x);
  }
  float mean = 0.0f, worst = 0.0f;
  for (float v : values) mean += v / values.size();
  for (float v : values) worst = std::max(worst, relativeError(v, mean));
  std::printf("[ measured ] 16 jitters: the result is within %.2f %% of their mean\n", 100 * worst);
  EXPECT_LT(worst, 0.08f);
}

TEST(WarpedGather, RejectsBadOptionsAndReceivers) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  WarpedGatherOptions bad;
  bad.resolution = 0;
  EXPECT_EQ(bad.validate().code(), absl::StatusCode::kInvalidArgument);
  bad.resolution = 65;
  EXPECT_EQ(bad.validate().code(), absl::StatusCode::kInvalidArgument);
  bad = WarpedGatherOptions{};
  bad.nearFieldFactor = nan;
  EXPECT_EQ(bad.validate().code(), absl::StatusCode::kInvalidArgument);
  bad = WarpedGatherOptions{};
  bad.selfSkipRadius = -1.0f;
  EXPECT_EQ(bad.validate().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(WarpedGatherOptions{}.validate().ok());

  auto tree = treeOf(sphereSurfels(500, 1.0f, Rgb(1.0f)));
  const Material material = conductorMaterial(0.3f, Rgb(0.9f));
  const Bsdf bsdf(material, material.albedo);
  const Frame frame;
  WarpedGatherer g{WarpedGatherOptions{}};
  auto code = [&](const Vec3f& p, const Frame& f, const Vec3f& wo, const Vec2f& jitter) {
    return g.reflect(*tree, p, f, bsdf, wo, jitter, nullptr).status().code();
  };
  const Vec2f j(0.5f, 0.5f);
  EXPECT_EQ(code(Vec3f(nan, 0, 0), frame, Vec3f(0, 0, 1), j), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(code(Vec3f(0.0f), frame, Vec3f(0, nan, 1), j), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(code(Vec3f(0.0f), frame, Vec3f(0.0f), j), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(code(Vec3f(0.0f), Frame(Vec3f(nan, 0, 1)), Vec3f(0, 0, 1), j),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(code(Vec3f(0.0f), frame, Vec3f(0, 0, 1), Vec2f(nan, 0)),
            absl::StatusCode::kInvalidArgument);
  // wo below the shading hemisphere reflects nothing; a wo that is not unit is normalised.
  auto below = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, Vec3f(0, 0.5f, -1), j, nullptr);
  ASSERT_TRUE(below.ok());
  EXPECT_EQ(*below, Rgb(0.0f));
  auto unit = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, Vec3f(0, 0, 1), j, nullptr);
  auto longer = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, Vec3f(0, 0, 3), j, nullptr);
  ASSERT_TRUE(unit.ok() && longer.ok());
  EXPECT_EQ(*unit, *longer);
  EXPECT_GT(unit->x, 0.0f);
}

TEST(WarpedGather, DamagedPageFailsTheGather) {
  auto tree = treeOf(sphereSurfels(8000, 1.0f, Rgb(1.0f)), 2);
  ASSERT_GT(tree->pageCount(), 4u);
  const Material material = conductorMaterial(0.2f, Rgb(0.9f));
  const Bsdf bsdf(material, material.albedo);
  const Vec3f p(0.5f, 0, 0);
  const Frame frame(Vec3f(1, 0, 0));  // sees only part of the sphere
  const Vec3f wo = unitWo(0.2f, 0, 1);
  WarpedGatherer g{WarpedGatherOptions{}};
  RecordingSource recording(tree.get());
  ASSERT_TRUE(g.reflect(recording, p, frame, bsdf, wo, Vec2f(0.5f, 0.5f), nullptr).ok());
  ASSERT_LT(recording.ids.size(), tree->pageCount());
  int failed = 0;
  for (uint32_t id = 0; id < tree->pageCount(); ++id) {
    FailingPageSource damaged(tree.get(), id);
    auto l = g.reflect(damaged, p, frame, bsdf, wo, Vec2f(0.5f, 0.5f), nullptr);
    if (recording.ids.count(id) != 0) {
      ASSERT_FALSE(l.ok()) << "page " << id;
      EXPECT_EQ(l.status().code(), absl::StatusCode::kDataLoss);
      EXPECT_EQ(l.status().message(), fmt::format("test.pbgi: page {}: checksum mismatch", id));
      ++failed;
    } else {
      EXPECT_TRUE(l.ok()) << "page " << id << ": " << l.status();
    }
  }
  EXPECT_GT(failed, 1);
}

// Cost per receiver on a tree of 100k surfels, against the cube gather at its default
// resolution: printed, not asserted (machines differ).
TEST(WarpedGather, TimingAgainstTheCubeGather) {
  Rng rng(23);
  std::vector<Surfel> surfels = sphereSurfels(100000, 1.0f, Rgb(0.0f));
  for (Surfel& s : surfels) s.radiance = Rgb(rng.uniform(), rng.uniform(), rng.uniform());
  auto tree = treeOf(surfels);
  struct Receiver {
    Vec3f p;
    Frame frame;
    Vec3f wo;
    Vec2f jitter;
  };
  std::vector<Receiver> receivers;
  for (int i = 0; i < 300; ++i) {
    const Vec3f p =
        0.7f * std::cbrt(rng.uniform()) * sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform()));
    const Frame frame(sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform())));
    Vec3f wo = sampleCosineHemisphere(Vec2f(rng.uniform(), rng.uniform()));
    receivers.push_back({p, frame, wo, Vec2f(rng.uniform(), rng.uniform())});
  }
  using Clock = std::chrono::steady_clock;
  auto micros = [](Clock::duration d, size_t count) {
    return std::chrono::duration<double, std::micro>(d).count() / double(count);
  };
  GatherStats cubeStats;
  Gatherer cube{GatherOptions{}};
  const auto c0 = Clock::now();
  for (const Receiver& r : receivers) {
    ASSERT_TRUE(cube.irradiance(*tree, r.p, r.frame.n, &cubeStats).ok());
  }
  const double cubeMicros = micros(Clock::now() - c0, receivers.size());
  std::printf("[ measured ] cube gather N=12 (100k surfels): %.1f us per gather  %s\n", cubeMicros,
              cubeStats.toString().c_str());
  for (const Material& material : {diffuseMaterial(Rgb(0.8f)), conductorMaterial(0.3f, Rgb(0.9f)),
                                   conductorMaterial(0.05f, Rgb(0.9f))}) {
    const Bsdf bsdf(material, material.albedo);
    WarpedGatherer warped{WarpedGatherOptions{}};
    GatherStats stats;
    const auto w0 = Clock::now();
    for (const Receiver& r : receivers) {
      ASSERT_TRUE(warped.reflect(*tree, r.p, r.frame, bsdf, r.wo, r.jitter, &stats).ok());
    }
    const double warpedMicros = micros(Clock::now() - w0, receivers.size());
    const auto s0 = Clock::now();
    for (const Receiver& r : receivers) {
      ASSERT_TRUE(warped.warp(r.frame, bsdf, r.wo, r.jitter).ok());
    }
    const double warpMicros = micros(Clock::now() - s0, receivers.size());
    std::printf(
        "[ measured ] warped gather N=16 %s roughness %.2f: %.1f us per reflect (of which the "
        "warp %.1f us)  %s\n",
        material.type == MaterialType::kDiffuse ? "diffuse" : "conductor", material.roughness,
        warpedMicros, warpMicros, stats.toString().c_str());
  }
}

}  // namespace
}  // namespace pbgi
