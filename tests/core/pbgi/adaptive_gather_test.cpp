#include "core/pbgi/adaptive_gather.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <vector>

#include <fmt/format.h>

#include "core/pbgi/warped_gather.h"
#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"
#include "core/scene/material.h"
#include "tests/support/bsdf_reference.h"
#include "tests/support/memory_tree.h"
#include "tests/support/surfel_shapes.h"

namespace pbgi {
namespace {

using testing::conductorMaterial;
using testing::diffuseMaterial;
using testing::directionalAlbedo;
using testing::DiskNearMirror;
using testing::disksNearMirror;
using testing::diskSurfels;
using testing::FailingPageSource;
using testing::RecordingSource;
using testing::referenceDiskReflection;
using testing::relativeError;
using testing::sphereSurfels;
using testing::treeOf;
using testing::unitWo;

// The leaf cells tile the whole sphere, however the BSDF and the light refined them: their
// solid angles add up to 4 pi, and directions drawn uniformly fall into them in proportion.
TEST(AdaptiveGather, CellsTileTheSphere) {
  const Vec3f center(0.3f, 0.2f, 2.0f);
  auto tree = treeOf(diskSurfels(4000, center, -normalize(center), 0.2f, Rgb(50.0f)));
  const Frame frame(Vec3f(0, 0, 1));
  AdaptiveGatherer g{AdaptiveGatherOptions{}};
  for (const Material& m : {diffuseMaterial(Rgb(0.8f)), conductorMaterial(0.3f, Rgb(0.9f)),
                            conductorMaterial(0.05f, Rgb(0.9f))}) {
    const Bsdf bsdf(m, m.albedo);
    auto l = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, unitWo(0.3f, 0.1f, 1), Vec2f(0.3f, 0.6f),
                       nullptr);
    ASSERT_TRUE(l.ok()) << l.status();
    double total = 0.0;
    int levels[16] = {};
    for (int k = 0; k < g.cellCount(); ++k) {
      total += g.cellSolidAngle(k);
      ++levels[g.cellLevel(k)];
    }
    EXPECT_NEAR(total, 4.0 * kPi, 1e-3) << m.roughness;
    // Uniform directions: the share that falls in each cell is its solid angle's share.
    std::vector<int> hits(g.cellCount(), 0);
    Rng rng(7);
    const int draws = 200000;
    for (int i = 0; i < draws; ++i) {
      const int k = g.cellOf(sampleUniformSphere(Vec2f(rng.uniform(), rng.uniform())));
      ASSERT_GE(k, 0);
      ++hits[k];
    }
    double chi = 0.0;
    for (int k = 0; k < g.cellCount(); ++k) {
      const double expected = draws * g.cellSolidAngle(k) / (4.0 * kPi);
      chi += (hits[k] - expected) * (hits[k] - expected) / expected;
    }
    std::printf("[ measured ] roughness %.2f: %d cells (levels 0..5: %d %d %d %d %d %d), "
                "%d split by the light, chi^2/cells %.2f\n",
                m.roughness, g.cellCount(), levels[0], levels[1], levels[2], levels[3], levels[4],
                levels[5], g.lightSplits(), chi / g.cellCount());
    EXPECT_LT(chi / g.cellCount(), 1.5);
  }
}

// A receiver at the centre of a closed sphere of radiance L reflects L times the BSDF's
// directional albedo, for lobes wide and narrower than the finest cell.
TEST(AdaptiveGather, FurnaceMatchesDirectionalAlbedo) {
  const Rgb radiance(1.0f, 0.5f, 0.25f);
  auto tree = treeOf(sphereSurfels(20000, 1.0f, radiance));
  AdaptiveGatherer g{AdaptiveGatherOptions{}};
  float worst = 0.0f;
  for (const Material& m : {diffuseMaterial(Rgb(0.8f, 0.6f, 0.4f)),
                            conductorMaterial(0.01f, Rgb(0.9f, 0.7f, 0.5f)),
                            conductorMaterial(0.05f, Rgb(0.9f, 0.7f, 0.5f)),
                            conductorMaterial(0.1f, Rgb(0.9f, 0.7f, 0.5f)),
                            conductorMaterial(0.3f, Rgb(0.9f, 0.7f, 0.5f))}) {
    const Bsdf bsdf(m, m.albedo);
    for (const Vec3f& n : {Vec3f(0, 0, 1), normalize(Vec3f(0.3f, -0.5f, 0.8f))}) {
      const Frame frame(n);
      for (const Vec3f& wo : {unitWo(0, 0, 1), unitWo(0.6f, 0.3f, 1), unitWo(-1, 0.5f, 0.5f)}) {
        const Rgb albedo = directionalAlbedo(bsdf, wo);
        GatherStats stats;
        auto l = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo, Vec2f(0.37f, 0.61f), &stats);
        ASSERT_TRUE(l.ok()) << l.status();
        const float ratio = l->x / (radiance.x * albedo.x);
        worst = std::max(worst, std::abs(ratio - 1.0f));
        EXPECT_NEAR(l->y / (radiance.y * albedo.y), ratio, 0.01f);
        // A lobe of alpha 0.05 or less covers a few tens of the sphere's disks: what each cell's few
        // footprints leave open or overlap weighs more than in a wider lobe.
        EXPECT_LT(std::abs(ratio - 1.0f), m.roughness < 0.1f ? 0.05f : 0.03f)
            << "roughness " << m.roughness << " n " << fmt::format("{}", n) << " wo "
            << fmt::format("{}", wo);
      }
    }
  }
  std::printf("[ measured ] adaptive furnace: worst |L/(L_e albedo) - 1| = %.4f\n", worst);
}

// A glossy receiver facing a single bright node refines towards it: the cells around the
// node's direction end deeper than those around the mirror image of that direction, which the
// BSDF weighs alike but which holds no light, and the light made the difference.
TEST(AdaptiveGather, AGlossyReceiverRefinesTowardsABrightNode) {
  const Material m = conductorMaterial(0.3f, Rgb(0.9f));
  const Bsdf bsdf(m, m.albedo);
  const Frame frame(Vec3f(0, 0, 1));
  const Vec3f wo = unitWo(0, 0, 1);  // the lobe is symmetric about the normal
  const Vec3f toLight = normalize(Vec3f(0.5f, 0.0f, 1.0f));
  const Vec3f mirrorImage = normalize(Vec3f(-0.5f, 0.0f, 1.0f));
  auto tree = treeOf(diskSurfels(2000, 4.0f * toLight, -toLight, 0.05f, Rgb(1000.0f)));
  AdaptiveGatherer g{AdaptiveGatherOptions{}};
  GatherStats stats;
  auto l = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo, Vec2f(0.5f, 0.5f), &stats);
  ASSERT_TRUE(l.ok()) << l.status();
  // The deepest cells within the disk's cone (half-angle 0.05 / 4), and within the same cone
  // around the mirror image.
  auto deepest = [&](const Vec3f& axis, Rgb* light) {
    const Frame around(axis);
    int level = 0;
    *light = Rgb(0.0f);
    for (int i = 0; i < 400; ++i) {
      const float r = 0.0125f * std::sqrt((i + 0.5f) / 400.0f), phi = 2.4f * i;
      const int k =
          g.cellOf(around.toWorld(Vec3f(r * std::cos(phi), r * std::sin(phi), 1.0f)));
      level = std::max(level, g.cellLevel(k));
      *light += g.cellRadiance(k);
    }
    return level;
  };
  Rgb litLight, darkLight;
  const int lit = deepest(toLight, &litLight), dark = deepest(mirrorImage, &darkLight);
  std::printf("[ measured ] deepest cell towards the light: level %d; towards its mirror image: "
              "level %d; %d cells split by the light  %s\n",
              lit, dark, g.lightSplits(), stats.toString().c_str());
  EXPECT_GT(g.lightSplits(), 0);
  EXPECT_GE(lit, dark + 2);
  EXPECT_EQ(lit, g.options().maxLevel);
  EXPECT_GT(luminance(litLight), 0.0f);
  EXPECT_EQ(darkLight, Rgb(0.0f));
  // Refining by the light makes the answer right where the BSDF's cells alone are too coarse.
  const double reference = referenceDiskReflection(bsdf, frame, wo, 4.0f * toLight, -toLight,
                                                   0.05f, 1000.0f);
  AdaptiveGatherOptions noLight;
  noLight.lightFraction = 1.0f;
  AdaptiveGatherer coarse(noLight);
  auto c = coarse.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo, Vec2f(0.5f, 0.5f), nullptr);
  ASSERT_TRUE(c.ok());
  std::printf("[ measured ] small bright disk off the lobe's centre: reference %.4f, adaptive "
              "%.4f (error %.1f %%), BSDF refinement alone %.4f (error %.1f %%)\n",
              reference, l->x, 100 * relativeError(l->x, reference), c->x,
              100 * relativeError(c->x, reference));
  EXPECT_LT(relativeError(l->x, reference), 0.05f);
  EXPECT_LT(relativeError(l->x, reference), relativeError(c->x, reference));
}

// A small bright disk in the mirror direction of a sharp conductor (the warped gather's own
// test case): the adaptive buffer is as right as the warped one, and right for every jitter.
TEST(AdaptiveGather, GlossyReflectionOfASmallDisk) {
  const Material m = conductorMaterial(0.05f, Rgb(0.9f));
  const Bsdf bsdf(m, m.albedo);
  const Frame frame(Vec3f(0, 0, 1));
  AdaptiveGatherer adaptive{AdaptiveGatherOptions{}};
  WarpedGatherer warped{WarpedGatherOptions{}};
  double adaptiveError = 0.0, warpedError = 0.0;
  int views = 0;
  for (const DiskNearMirror& disk : disksNearMirror()) {
    const Vec3f &wo = disk.wo, &center = disk.center, &normal = disk.normal;
    auto tree = treeOf(diskSurfels(8000, center, normal, 0.25f, Rgb(10.0f)));
    const double reference = referenceDiskReflection(bsdf, frame, wo, center, normal, 0.25f, 10.0f);
    Rng rng(9);
    for (int s = 0; s < 8; ++s) {
      const Vec2f jitter(rng.uniform(), rng.uniform());
      auto a = adaptive.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo, jitter, nullptr);
      auto w = warped.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo, jitter, nullptr);
      ASSERT_TRUE(a.ok() && w.ok());
      adaptiveError += relativeError(a->x, reference);
      warpedError += relativeError(w->x, reference);
      ++views;
    }
  }
  adaptiveError /= views;
  warpedError /= views;
  std::printf("[ measured ] glossy disk, mean error over 4 views x 8 jitters: adaptive %.1f %%, "
              "warped %.1f %%\n",
              100 * adaptiveError, 100 * warpedError);
  EXPECT_LT(adaptiveError, 0.05);
}

// A sharp lobe facing a wall of disks each far larger than the lobe's cells: a disk whose
// centre falls in a coarse cell beside (or around) the lobe must still be cut to, or ray-cast
// at, the lobe's cells, not placed as a few footprint pieces that leave most of them black (it
// reflected 0.29 of the wall before). The reference ray-casts the BSDF's samples against the
// disks near the lobe: a lobe this sharp sees where the disks leave holes or overlap.
TEST(AdaptiveGather, ASharpLobeSeesAWallOfLargeDisks) {
  const std::vector<Surfel> wall =
      diskSurfels(40000, Vec3f(0, 0, 1), Vec3f(0, 0, -1), 30.0f, Rgb(1.0f));
  auto tree = treeOf(wall);
  AdaptiveGatherer g{AdaptiveGatherOptions{}};
  for (const Vec3f& n : {Vec3f(0, 0, 1), normalize(Vec3f(0.3f, -0.5f, 0.8f))}) {
    const Frame frame(n);
    for (const float alpha : {0.01f, 0.05f}) {
      const Material m = conductorMaterial(alpha, Rgb(0.9f));
      const Bsdf bsdf(m, m.albedo);
      for (const Vec3f& wo : {unitWo(0, 0, 1), unitWo(0.6f, 0.3f, 1), unitWo(-0.2f, 0.7f, 1)}) {
        const Vec3f mirror = frame.toWorld(Vec3f(-wo.x, -wo.y, wo.z));
        std::vector<Surfel> near;
        for (const Surfel& s : wall) {
          if (dot(normalize(s.position), mirror) > std::cos(0.4f)) near.push_back(s);
        }
        const double reference = testing::referenceDisksReflection(bsdf, frame, wo, near, 128);
        auto l = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, wo, Vec2f(0.37f, 0.61f), nullptr);
        ASSERT_TRUE(l.ok()) << l.status();
        // Disks far enough to be splatted as square footprints blur where the holes are:
        // up to their share of the wall (about a tenth).
        EXPECT_NEAR(l->x / reference, 1.0, alpha < 0.02f ? 0.06 : 0.1)
            << "alpha " << alpha << " n " << fmt::format("{}", n) << " wo "
            << fmt::format("{}", wo) << ": reference " << reference;
      }
    }
  }
}

TEST(AdaptiveGather, DeterministicWhateverThePaging) {
  std::vector<Surfel> surfels = sphereSurfels(8000, 1.0f, Rgb(0.0f));
  for (Surfel& s : surfels) {
    const Vec3f& x = s.position;
    s.radiance = Rgb(1.0f + 0.5f * x.x, 1.0f + 0.5f * x.y * x.z, 1.0f - 0.5f * x.z);
  }
  surfels[17].radiance = Rgb(400.0f);  // a bright spot to refine towards
  auto onePage = treeOf(surfels);
  auto manyPages = treeOf(surfels, 3);
  ASSERT_GT(manyPages->pageCount(), 8u);
  const Material m = conductorMaterial(0.2f, Rgb(0.9f, 0.8f, 0.7f));
  const Bsdf bsdf(m, m.albedo);
  const Vec3f p(0.2f, -0.3f, 0.1f);
  const Frame frame(normalize(Vec3f(1, 2, 3)));
  const Vec3f wo = unitWo(0.3f, -0.2f, 1);
  AdaptiveGatherer g{AdaptiveGatherOptions{}};
  auto a = g.reflect(*onePage, p, frame, bsdf, wo, Vec2f(0.25f, 0.75f), nullptr);
  auto b = g.reflect(*onePage, p, frame, bsdf, wo, Vec2f(0.25f, 0.75f), nullptr);
  AdaptiveGatherer fresh{AdaptiveGatherOptions{}};
  auto c = fresh.reflect(*manyPages, p, frame, bsdf, wo, Vec2f(0.25f, 0.75f), nullptr);
  ASSERT_TRUE(a.ok() && b.ok() && c.ok());
  EXPECT_EQ(*a, *b);
  EXPECT_EQ(*a, *c);
  EXPECT_GT(a->x, 0.0f);
}

TEST(AdaptiveGather, RejectsBadOptionsAndReceivers) {
  const float nan = std::numeric_limits<float>::quiet_NaN();
  auto rejects = [](auto change) {
    AdaptiveGatherOptions o;
    change(o);
    return o.validate().code() == absl::StatusCode::kInvalidArgument;
  };
  EXPECT_TRUE(rejects([](auto& o) { o.baseResolution = 0; }));
  EXPECT_TRUE(rejects([](auto& o) { o.baseResolution = 17; }));
  EXPECT_TRUE(rejects([](auto& o) { o.maxLevel = -1; }));
  EXPECT_TRUE(rejects([](auto& o) { o.maxLevel = 11; }));
  EXPECT_TRUE(rejects([](auto& o) { o.brdfSamples = 0; }));
  EXPECT_TRUE(rejects([](auto& o) { o.brdfCells = 0; }));
  EXPECT_TRUE(rejects([nan](auto& o) { o.lightFraction = nan; }));
  EXPECT_TRUE(rejects([](auto& o) { o.lightFraction = 0.0f; }));
  EXPECT_TRUE(rejects([](auto& o) { o.maxCells = 95; }));  // fewer than the base cells
  EXPECT_TRUE(rejects([nan](auto& o) { o.nearFieldFactor = nan; }));
  EXPECT_TRUE(AdaptiveGatherOptions{}.validate().ok());

  auto tree = treeOf(sphereSurfels(500, 1.0f, Rgb(1.0f)));
  const Material m = conductorMaterial(0.3f, Rgb(0.9f));
  const Bsdf bsdf(m, m.albedo);
  const Frame frame;
  AdaptiveGatherer g{AdaptiveGatherOptions{}};
  auto code = [&](const Vec3f& p, const Frame& f, const Vec3f& wo, const Vec2f& jitter) {
    return g.reflect(*tree, p, f, bsdf, wo, jitter, nullptr).status().code();
  };
  const Vec2f j(0.5f, 0.5f);
  EXPECT_EQ(code(Vec3f(nan, 0, 0), frame, Vec3f(0, 0, 1), j), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(code(Vec3f(0.0f), frame, Vec3f(0, nan, 1), j), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(code(Vec3f(0.0f), frame, Vec3f(0.0f), j), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(code(Vec3f(0.0f), frame, Vec3f(0, 0, 1), Vec2f(nan, 0)),
            absl::StatusCode::kInvalidArgument);
  auto below = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, Vec3f(0, 0.5f, -1), j, nullptr);
  ASSERT_TRUE(below.ok());
  EXPECT_EQ(*below, Rgb(0.0f));
  auto unit = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, Vec3f(0, 0, 1), j, nullptr);
  auto longer = g.reflect(*tree, Vec3f(0.0f), frame, bsdf, Vec3f(0, 0, 3), j, nullptr);
  ASSERT_TRUE(unit.ok() && longer.ok());
  EXPECT_EQ(*unit, *longer);
  EXPECT_GT(unit->x, 0.0f);
}

TEST(AdaptiveGather, DamagedPageFailsTheGather) {
  auto tree = treeOf(sphereSurfels(8000, 1.0f, Rgb(1.0f)), 2);
  ASSERT_GT(tree->pageCount(), 4u);
  const Material m = conductorMaterial(0.2f, Rgb(0.9f));
  const Bsdf bsdf(m, m.albedo);
  const Vec3f p(0.5f, 0, 0);
  const Frame frame(Vec3f(1, 0, 0));  // sees only part of the sphere
  const Vec3f wo = unitWo(0.2f, 0, 1);
  AdaptiveGatherer g{AdaptiveGatherOptions{}};
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
      ++failed;
    } else {
      EXPECT_TRUE(l.ok()) << "page " << id << ": " << l.status();
    }
  }
  EXPECT_GT(failed, 1);
}

}  // namespace
}  // namespace pbgi
