#include "core/pbgi/bidirectional_cut.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "core/bake/surfel_sampler.h"
#include "core/bake/surfel_shading.h"
#include "core/math/solid_angle.h"
#include "core/pbgi/page_cache.h"
#include "core/sampling/rng.h"
#include "tests/core/render/test_scenes.h"
#include "tests/support/memory_tree.h"
#include "tests/support/surfel_shapes.h"

namespace pbgi {
namespace {

using testing::FailingPageSource;
using testing::memoryTree;
using testing::MemoryTreeSource;

// The box scene's surfels, lit directly, and receivers on its floor, walls and block (points
// where camera rays from the open side land, facing the camera).
struct BoxCase {
  std::unique_ptr<Scene> scene;
  std::vector<Surfel> surfels;
  std::vector<CutReceiver> receivers;
};

// `count` surfels of a scene, sampled as a bake does.
absl::StatusOr<std::vector<Surfel>> surfelsOf(const Scene& scene, uint64_t count) {
  SurfelSamplingOptions sampling;
  sampling.targetCount = count;
  return collectSurfels(scene, sampling);
}

BoxCase boxCase(uint64_t surfelCount, int receiverCount) {
  BoxCase c;
  c.scene = testing::makeBoxScene();
  PBGI_CHECK(c.scene != nullptr);
  auto surfels = surfelsOf(*c.scene, surfelCount);
  PBGI_CHECK(surfels.ok());
  c.surfels = *std::move(surfels);
  shadeSurfelsDirect(*c.scene, c.surfels, 0, {});
  Rng rng(7);
  while (static_cast<int>(c.receivers.size()) < receiverCount) {
    // Rays from in front of the box's open side, towards the inside.
    const Vec3f origin(0.5f, 0.5f, -1.0f);
    const Vec3f target(rng.uniform(), rng.uniform(), 0.8f + 0.2f * rng.uniform());
    Ray ray{origin, normalize(target - origin)};
    SurfaceHit hit;
    if (!c.scene->intersect(ray, &hit) || hit.material == kNoMaterial) continue;
    const bool front = dot(hit.ng, ray.dir) < 0.0f;
    c.receivers.push_back({hit.p, front ? hit.ns : -hit.ns, front ? hit.ng : -hit.ng});
  }
  return c;
}

CutOptions zeroThresholds() {
  CutOptions o;
  o.lightSolidAngle = 0.0f;
  o.lightBound = 0.0f;
  o.receiverBound = 0.0f;
  o.normalAngle = 0.0f;
  return o;
}

double meanLuminance(const std::vector<Rgb>& v) {
  double sum = 0.0;
  for (const Rgb& e : v) sum += luminance(e);
  return sum / static_cast<double>(v.size());
}

// With every threshold at zero the cut refines down to every surfel against every receiver,
// which is the brute force sum (the same visibility rays), whatever pages the tree is in.
// With the near field's rays too: the cut reads their hits in its page sweep, the brute force
// by a descent of its own, and both leave out the same surfels.
TEST(BidirectionalCut, ZeroThresholdsEqualBruteForce) {
  BoxCase c = boxCase(3000, 64);
  for (const auto& [splitDepth, nearRays] : {std::pair{0, 0}, {2, 0}, {4, 0}, {0, 16}, {4, 16}}) {
    auto tree = memoryTree(c.surfels, kDefaultLeafSize, splitDepth);
    ASSERT_TRUE(tree.ok()) << tree.status();
    CutOptions options = zeroThresholds();
    options.nearRays = nearRays;
    std::vector<Rgb> brute(c.receivers.size()), cut(c.receivers.size());
    ASSERT_TRUE(bruteForceIrradiance(**tree, *c.scene, c.receivers, options, brute).ok());
    BidirectionalCut bc(options);
    CutStats stats;
    ASSERT_TRUE(bc.irradiance(**tree, *c.scene, c.receivers, 1, cut, &stats).ok());
    if (nearRays > 0) {
      EXPECT_GT(stats.nearHits, 0u) << stats.toString();  // the block is near the floor
      EXPECT_EQ(stats.nearRays, uint64_t{c.receivers.size()} * nearRays) << stats.toString();
    }
    int lit = 0;
    for (size_t i = 0; i < c.receivers.size(); ++i) {
      for (int ch = 0; ch < 3; ++ch) {
        EXPECT_NEAR(cut[i][ch], brute[i][ch], 1e-4f * std::max(1.0f, std::abs(brute[i][ch])))
            << "receiver " << i << " channel " << ch << " split " << splitDepth << " near rays "
            << nearRays;
      }
      lit += luminance(brute[i]) > 0.0f;
    }
    EXPECT_GT(lit, 48);  // the test sees light, not zeros
    // Nothing was evaluated as a cluster: every light surfel met every receiver.
    EXPECT_EQ(stats.clusterPairs, 0u);
    EXPECT_LE(stats.leafPairs, uint64_t{c.surfels.size()} * c.receivers.size());
    // Each page is asked for at most once (pages whose light is all culled, black or below
    // every receiver's horizon, not at all).
    EXPECT_LE(stats.pageRequests, (*tree)->pageCount()) << stats.toString();
    EXPECT_GT(stats.pageRequests, (*tree)->pageCount() / 2) << stats.toString();
  }
}

// One surfel, one receiver: the cut is a single shadow connection, the virtual spherical
// light's value.
TEST(BidirectionalCut, OneLeafAgainstOneReceiverIsOneShadowConnection) {
  auto scene = testing::makeBoxScene();
  ASSERT_NE(scene, nullptr);
  Surfel s;
  s.position = {0.5f, 0.5f, 0.999f};  // on the back wall, facing -z
  s.normal = {0.0f, 0.0f, -1.0f};
  s.radius = 0.01f;
  s.radiance = Rgb(2.0f, 1.0f, 0.5f);
  auto tree = memoryTree(std::vector<Surfel>{s});
  ASSERT_TRUE(tree.ok());
  // On the floor behind the block, in view of the surfel.
  const CutReceiver r{{0.5f, 0.0f, 0.95f}, {0.0f, 1.0f, 0.0f}, {0.0f, 1.0f, 0.0f}};
  std::vector<Rgb> out(1);
  BidirectionalCut cut(CutOptions{});
  CutStats stats;
  ASSERT_TRUE(cut.irradiance(**tree, *scene, std::vector<CutReceiver>{r}, 3, out, &stats).ok());
  EXPECT_EQ(stats.shadowRays, 1u) << stats.toString();
  EXPECT_EQ(stats.occluded, 0u) << stats.toString();
  EXPECT_EQ(stats.leafPairs + stats.clusterPairs, 1u) << stats.toString();
  const Vec3f v = s.position - r.p;
  const float d2 = v.length2();
  const Vec3f w = v / std::sqrt(d2);
  const Rgb expected = s.radiance * (s.area() * -dot(s.normal, w) * dot(r.n, w) /
                                     (d2 + s.radius * s.radius));
  // The leaf is small from the receiver: a cluster of one, a point source (no softening, r^2
  // against d^2 = 0.3 here).
  for (int ch = 0; ch < 3; ++ch) EXPECT_NEAR(out[0][ch], expected[ch], 1e-3f * expected[ch]);
}


// A closed white box whose surfels all send radiance 1 from both sides: every point inside
// sees radiance 1 over its whole hemisphere and gathers pi. Near the edges three things
// matter (surfelLight): the part of a wall's disk hanging below a floor receiver's horizon is
// folded back above it, a near disk's light is its polygon's exact projected solid angle, and
// a wall's disk that reaches a floor receiver is gathered, not skipped as the receiver's own.
// Measured within a surfel radius of an edge: 0.88 of pi with none of them, 0.94 with the
// fold, 0.97 with all three (0.97 to 1.04 over five placements of the surfels: which disks
// lie next to a receiver varies).
// Wherever the box stands: 100 units from the origin, where a ray's offset off its surface is
// 100 times larger and a segment aimed from the offset origin at a surfel on the far side
// (rather than from one offset end to the other) met the surfel's plane before its centre, the
// ceiling's light at the floor lost to its own surface.
TEST(BidirectionalCut, AClosedBoxOfUnitRadianceGathersPiUpToItsEdges) {
  for (const float x0 : {0.0f, 100.0f}) {
    SCOPED_TRACE(::testing::Message() << "box at x = " << x0);
    SceneBuilder b;
    Material white;
    white.albedo = Rgb(0.5f);
    testing::addClosedBox(b, x0, b.addMaterial(white));
    auto scene = b.build();
    ASSERT_TRUE(scene.ok()) << scene.status();
    auto surfels = surfelsOf(**scene, 24000);
    ASSERT_TRUE(surfels.ok()) << surfels.status();
    for (Surfel& s : *surfels) s.radiance = s.backRadiance = Rgb(1.0f);
    auto tree = memoryTree(*surfels);
    ASSERT_TRUE(tree.ok()) << tree.status();
    const float radius = surfels->front().radius;
    const Vec3f centre(x0 + 0.5f, 0.5f, 0.5f);
    // Every fourth surfel gathers on the inner side, as a bounce does.
    std::vector<CutReceiver> receivers;
    for (size_t i = 0; i < surfels->size(); i += 4) {
      const Surfel& s = (*surfels)[i];
      const Vec3f n = dot(centre - s.position, s.normal) > 0.0f ? s.normal : -s.normal;
      receivers.push_back({s.position, n, n});
    }
    // And with the near field by rays (CutOptions::nearRays), whose hits read radiance 1
    // wherever they land, in place of the disks within four radii.
    for (int nearRays : {0, 64}) {
      SCOPED_TRACE(::testing::Message() << "near rays " << nearRays);
      std::vector<Rgb> out(receivers.size());
      CutOptions options;
      options.nearRays = nearRays;
      BidirectionalCut cut(options);
      CutStats stats;
      ASSERT_TRUE(cut.irradiance(**tree, **scene, receivers, 5, out, &stats).ok());
      double all = 0.0, nearEdge = 0.0;
      int nearCount = 0;
      for (size_t i = 0; i < receivers.size(); ++i) {
        const Vec3f p = receivers[i].p - Vec3f(x0, 0.0f, 0.0f);
        float edge = 1.0f;  // distance to the nearest edge of the receiver's face
        for (int a = 0; a < 3; ++a) {
          if (std::abs(receivers[i].n[a]) < 0.5f) edge = std::min({edge, p[a], 1.0f - p[a]});
        }
        const double e = out[i].x / kPi;
        EXPECT_NEAR(out[i].y, out[i].x, 1e-5f * out[i].x);
        all += e;
        if (edge < radius) nearEdge += e, ++nearCount;
      }
      all /= static_cast<double>(receivers.size());
      nearEdge /= nearCount;
      std::printf(
          "[ measured ] closed box at x = %g, %zu surfels of radius %.4f: E / pi %.4f, within "
          "a radius of an edge %.4f (%d receivers)  %s\n",
          x0, surfels->size(), radius, all, nearEdge, nearCount, stats.toString().c_str());
      EXPECT_GT(nearCount, 100);
      EXPECT_NEAR(all, 1.0, 0.01);
      EXPECT_GT(nearEdge, 0.95);
      EXPECT_LT(nearEdge, 1.07);
      // Nothing inside the box hides anything (far from the origin, a near-field ray in a
      // corner may graze a wall in a million).
      EXPECT_LE(stats.occluded * 1000000, x0 == 0.0f ? 0 : stats.shadowRays) << stats.toString();
      // Hits where no surfel is read (in the corners) are few.
      if (nearRays > 0) {
        EXPECT_LT(stats.nearUnread * 100, stats.nearHits) << stats.toString();
      }
    }
  }
}

// A floor receiver next to a wall of radiance 1 (a contact, as at the foot of every wall and
// column): the wall's light is its projected solid angle (Lambert's formula), exact at any
// distance. The near field by rays within a quarter of a surfel radius to three radii from the
// wall, the mean over receivers along it; printed against the disks (nearRays 0), which
// measured 0.98, 0.97, 0.955 and 0.96 and would fail the bound from one radius out. The floor
// is dark and runs on under the wall, as scenes model it.
TEST(BidirectionalCut, TheNearFieldByRaysGathersAWallAtItsFoot) {
  SceneBuilder b;
  Material white;
  white.albedo = Rgb(0.5f);
  const uint32_t m = b.addMaterial(white);
  b.addMesh(testing::makeQuadMesh({-1, 0, -1}, {0, 0, 2}, {2, 0, 0}, m));  // floor, facing +y
  b.addMesh(testing::makeQuadMesh({0, 0, -1}, {0, 0, 2}, {0, 1, 0}, m));   // wall x = 0, facing -x
  auto scene = b.build();
  ASSERT_TRUE(scene.ok()) << scene.status();
  auto surfels = surfelsOf(**scene, 30000);
  ASSERT_TRUE(surfels.ok()) << surfels.status();
  for (Surfel& s : *surfels) {
    const bool wall = std::abs(s.normal.x) > 0.5f;
    s.radiance = Rgb(wall ? 1.0f : 0.0f);
    s.backRadiance = Rgb(0.0f);
  }
  auto tree = memoryTree(*surfels);
  ASSERT_TRUE(tree.ok()) << tree.status();
  const float radius = surfels->front().radius;
  const std::array<Vec3d, 4> wall = {Vec3d{0, 0, -1}, Vec3d{0, 1, -1}, Vec3d{0, 1, 1},
                                     Vec3d{0, 0, 1}};
  Rng rng(3);
  for (float radii : {0.25f, 0.5f, 1.0f, 3.0f}) {
    std::vector<CutReceiver> receivers;
    double exact = 0.0;
    for (int i = 0; i < 64; ++i) {
      const Vec3f p(-radii * radius, 0.0f, 0.6f * rng.uniform() - 0.3f);
      receivers.push_back({p, {0, 1, 0}, {0, 1, 0}});
      std::array<Vec3d, 4> v;
      for (int k = 0; k < 4; ++k) {
        for (int a = 0; a < 3; ++a) v[k][a] = wall[k][a] - p[a];
      }
      exact += vectorSolidAngle(v, Vec3d{0, 1, 0})[1];
    }
    double got[2] = {};
    for (int nearRays : {0, 64}) {
      CutOptions options = *cutPreset("default");
      options.nearRays = nearRays;
      BidirectionalCut cut(options);
      std::vector<Rgb> out(receivers.size());
      CutStats stats;
      ASSERT_TRUE(cut.irradiance(**tree, **scene, receivers, 9, out, &stats).ok());
      got[nearRays > 0] = meanLuminance(out) * static_cast<double>(receivers.size()) / exact;
    }
    std::printf(
        "[ measured ] a wall %.2f surfel radii away: gathered / exact %.4f by disks, "
        "%.4f by the near field's rays\n",
        radii, got[0], got[1]);
    EXPECT_NEAR(got[1], 1.0, 0.03) << radii << " radii";
  }
}

// Two closed rooms either side of a wall 1 cm thick, a light in one: the other stays dark.
// A cluster of the wall's two faces can send, by its SH, a little light towards the dark room
// that none of its children does (its lit face looks the other way); deposited unseen, with no
// shadow ray ("nothing to hide"), it would light the dark room and the sides of surfels that
// face into the wall (surfels gather on both sides).
TEST(BidirectionalCut, NoLightThroughAThinWall) {
  auto scene = testing::makeTwoRoomsScene();
  ASSERT_NE(scene, nullptr);
  auto surfels = surfelsOf(*scene, 20000);
  ASSERT_TRUE(surfels.ok()) << surfels.status();
  shadeSurfelsDirect(*scene, *surfels, 0, {});
  for (Surfel& s : *surfels) facingBrighterSide(s);
  auto tree = memoryTree(*surfels);
  ASSERT_TRUE(tree.ok()) << tree.status();
  // Floor points of each room, and points on the wall's faces looking into the wall.
  std::vector<CutReceiver> dark, lit, inside;
  Rng rng(3);
  for (int i = 0; i < 400; ++i) {
    const float u = 0.05f + 0.9f * rng.uniform(), v = 0.05f + 0.9f * rng.uniform();
    dark.push_back({{u, 0.0f, v}, {0, 1, 0}, {0, 1, 0}});
    lit.push_back({{1.01f + u, 0.0f, v}, {0, 1, 0}, {0, 1, 0}});
    inside.push_back({{1.0f, u, v}, {1, 0, 0}, {1, 0, 0}});
  }
  auto gathered = [&](const std::vector<CutReceiver>& receivers) {
    std::vector<Rgb> out(receivers.size());
    BidirectionalCut cut(CutOptions{});
    CutStats stats;
    EXPECT_TRUE(cut.irradiance(**tree, *scene, receivers, 9, out, &stats).ok());
    return meanLuminance(out);
  };
  const double litFloor = gathered(lit), darkFloor = gathered(dark), inWall = gathered(inside);
  std::printf("[ measured ] thin wall: lit room's floor %.5g, dark room's %.5g, inside the wall "
              "%.5g\n", litFloor, darkFloor, inWall);
  // Every path from the light to them crosses the wall: not a photon (deposited unseen, the
  // dark floor got 1.7e-5 and the wall's inside 4.6e-6).
  EXPECT_GT(litFloor, 0.1);
  EXPECT_EQ(darkFloor, 0.0);
  EXPECT_EQ(inWall, 0.0);
}

// A blocker between the surfel and the receiver: the shadow ray sees it.
TEST(BidirectionalCut, AnOccluderBlocksALeafConnection) {
  SceneBuilder b;
  const uint32_t m = b.addMaterial(Material{});
  b.addMesh(testing::makeQuadMesh({-1, 0.5f, -1}, {0, 0, 2}, {2, 0, 0}, m));  // y = 0.5 plane
  auto scene = b.build();
  ASSERT_TRUE(scene.ok());
  Surfel s;
  s.position = {0.0f, 1.0f, 0.0f};
  s.normal = {0.0f, -1.0f, 0.0f};
  s.radius = 0.01f;
  s.radiance = Rgb(1.0f);
  auto tree = memoryTree(std::vector<Surfel>{s});
  ASSERT_TRUE(tree.ok());
  const CutReceiver r{{0.0f, 0.0f, 0.0f}, {0.0f, 1.0f, 0.0f}, {0.0f, 1.0f, 0.0f}};
  std::vector<Rgb> out(1);
  BidirectionalCut cut(CutOptions{});
  CutStats stats;
  ASSERT_TRUE(cut.irradiance(**tree, **scene, std::vector<CutReceiver>{r}, 3, out, &stats).ok());
  EXPECT_EQ(stats.occluded, 1u);
  EXPECT_EQ(out[0], Rgb(0.0f));
}

// A light patch over a floor, half of which an occluder shades: receiver nodes wide enough
// to straddle the shadow's edge. With recordVisibility every receiver traces its own ray, so
// none in the full shadow gets any light and every one in the full light gets some; with one
// ray a node, the nodes across the edge are all lit or all dark (the negative control).
TEST(BidirectionalCut, RecordVisibilityGivesEachReceiverItsOwnShadow) {
  SceneBuilder b;
  const uint32_t m = b.addMaterial(Material{});
  b.addMesh(testing::makeQuadMesh({-2, 0.5f, -2}, {0, 0, 4}, {2, 0, 0}, m));  // x < 0, y = 0.5
  auto scene = b.build();
  ASSERT_TRUE(scene.ok());
  std::vector<Surfel> patch;
  for (int i = 0; i < 20; ++i) {
    for (int j = 0; j < 20; ++j) {
      Surfel s;
      s.position = {-0.1f + 0.01f * (static_cast<float>(i) + 0.5f), 1.0f,
                    -0.1f + 0.01f * (static_cast<float>(j) + 0.5f)};
      s.normal = {0.0f, -1.0f, 0.0f};
      s.radius = 0.006f;
      s.radiance = Rgb(1.0f);
      patch.push_back(s);
    }
  }
  auto tree = memoryTree(patch);
  ASSERT_TRUE(tree.ok()) << tree.status();
  std::vector<CutReceiver> floor;
  Rng rng(5);
  for (int i = 0; i < 3000; ++i) {
    floor.push_back({{2.0f * rng.uniform() - 1.0f, 0.0f, 2.0f * rng.uniform() - 1.0f},
                     {0.0f, 1.0f, 0.0f},
                     {0.0f, 1.0f, 0.0f}});
  }
  // Coarse, so that receiver nodes reach across the shadow's edge (at x = -0.1 .. 0.1).
  CutOptions options;
  options.lightSolidAngle = 0.05f;
  options.lightBound = 0.5f;
  options.receiverBound = 0.5f;
  const auto run = [&](bool perRecord, int* litInShadow, int* darkInLight) {
    CutOptions o = options;
    o.recordVisibility = perRecord;
    std::vector<Rgb> out(floor.size());
    BidirectionalCut cut(o);
    CutStats stats;
    EXPECT_TRUE(cut.irradiance(**tree, **scene, floor, 11, out, &stats).ok());
    *litInShadow = *darkInLight = 0;
    for (size_t i = 0; i < floor.size(); ++i) {
      if (floor[i].p.x < -0.15f && luminance(out[i]) > 0.0f) ++*litInShadow;
      if (floor[i].p.x > 0.15f && !(luminance(out[i]) > 0.0f)) ++*darkInLight;
    }
    return stats;
  };
  int litInShadow = 0, darkInLight = 0, nodeLitInShadow = 0, nodeDarkInLight = 0;
  const CutStats perRecord = run(true, &litInShadow, &darkInLight);
  const CutStats perNode = run(false, &nodeLitInShadow, &nodeDarkInLight);
  std::printf("[ measured ] of 3000 floor receivers, lit in the full shadow / dark in the full "
              "light: %d / %d by a ray each, %d / %d by a ray a node (%llu against %llu rays)\n",
              litInShadow, darkInLight, nodeLitInShadow, nodeDarkInLight,
              static_cast<unsigned long long>(perRecord.shadowRays),
              static_cast<unsigned long long>(perNode.shadowRays));
  EXPECT_GT(perNode.clusterPairs, 0u) << "the nodes must take clusters whole";
  EXPECT_EQ(litInShadow, 0);
  EXPECT_EQ(darkInLight, 0);
  EXPECT_GT(nodeLitInShadow + nodeDarkInLight, 0);
}

// The preset thresholds stay close to the brute force on average, with far fewer pairs, and
// smaller thresholds come closer.
TEST(BidirectionalCut, ThresholdsTradePairsForError) {
  BoxCase c = boxCase(20000, 2000);
  auto tree = memoryTree(c.surfels, kDefaultLeafSize, 3);
  ASSERT_TRUE(tree.ok());
  std::vector<Rgb> brute(c.receivers.size());
  ASSERT_TRUE(bruteForceIrradiance(**tree, *c.scene, c.receivers, CutOptions{}, brute).ok());
  const double reference = meanLuminance(brute);
  // Descents weighed by SH, and by normal cones (the bake's first bounce; its finest scale is
  // the most costly, and cones and SH differ least there).
  for (const bool cones : {false, true}) {
    double previousError = 1e30;
    uint64_t previousPairs = 0;
    for (const float scale : {16.0f, 4.0f, 1.0f, 0.25f}) {
      if (cones && scale < 1.0f) continue;
      CutOptions o;
      o.lightSolidAngle *= scale;
      o.lightBound *= scale;
      o.receiverBound *= scale;
      o.coneDescent = cones;
      std::vector<Rgb> out(c.receivers.size());
      BidirectionalCut cut(o);
      CutStats stats;
      ASSERT_TRUE(cut.irradiance(**tree, *c.scene, c.receivers, 11, out, &stats).ok());
      double sq = 0.0;
      for (size_t i = 0; i < out.size(); ++i) {
        const double d = luminance(out[i]) - luminance(brute[i]);
        sq += d * d;
      }
      const double rmse = std::sqrt(sq / out.size()) / reference;
      const double meanError = std::abs(meanLuminance(out) / reference - 1.0);
      std::printf(
          "%s, scale %.2f: mean %+.4f, relative RMSE %.4f, %llu pairs (%llu clusters, "
          "%llu leaves), %llu shadow rays; brute force %zu pairs\n",
          cones ? "cones" : "SH", scale, meanLuminance(out) / reference - 1.0, rmse,
          static_cast<unsigned long long>(stats.pairs),
          static_cast<unsigned long long>(stats.clusterPairs),
          static_cast<unsigned long long>(stats.leafPairs),
          static_cast<unsigned long long>(stats.shadowRays), c.surfels.size() * out.size());
      // A cluster's light is its estimate times the corrections its shadow ray's descent met,
      // so coarse cuts keep the surfels' light: their mean stays on the brute force's. Without
      // the corrections the mean fell 3.5 % below it at 16 times the default thresholds and
      // 1.5 % at 4 times (the factor the bake's later bounces apply: bounceCutOptions).
      EXPECT_LT(meanError, 0.005) << "scale " << scale << (cones ? " cones" : " SH");
      EXPECT_LT(stats.shadowRays, c.surfels.size() * out.size() / 8);
      EXPECT_LT(rmse, previousError * 1.05);
      EXPECT_GT(stats.pairs, previousPairs);
      previousError = rmse;
      previousPairs = stats.pairs;
    }
  }
}

// The same receivers, the same key: the same bits; another key: other visibility samples.
TEST(BidirectionalCut, DeterministicInItsKey) {
  BoxCase c = boxCase(5000, 500);
  auto tree = memoryTree(c.surfels, kDefaultLeafSize, 2);
  ASSERT_TRUE(tree.ok());
  std::vector<Rgb> a(c.receivers.size()), b(c.receivers.size()), d(c.receivers.size());
  BidirectionalCut cut(CutOptions{});
  ASSERT_TRUE(cut.irradiance(**tree, *c.scene, c.receivers, 5, a, nullptr).ok());
  BidirectionalCut other(CutOptions{});
  ASSERT_TRUE(other.irradiance(**tree, *c.scene, c.receivers, 5, b, nullptr).ok());
  ASSERT_TRUE(cut.irradiance(**tree, *c.scene, c.receivers, 6, d, nullptr).ok());
  EXPECT_EQ(a, b);
  EXPECT_NE(a, d);
}

// With default thresholds clusters are evaluated and their shadow rays descend to surfels in
// lower pages; those descents wait for the sweep, so the cut still asks for each page at most
// once, and every page it asks for is one it sweeps.
TEST(BidirectionalCut, ShadowRayDescentsStayInTheSweep) {
  BoxCase c = boxCase(20000, 2000);
  auto tree = memoryTree(c.surfels, kDefaultLeafSize, 3);
  ASSERT_TRUE(tree.ok());
  ASSERT_GT((*tree)->pageCount(), 50u);
  std::vector<Rgb> out(c.receivers.size());
  BidirectionalCut cut(CutOptions{});
  CutStats stats;
  ASSERT_TRUE(cut.irradiance(**tree, *c.scene, c.receivers, 3, out, &stats).ok());
  EXPECT_GT(stats.clusterPairs, 1000u) << stats.toString();
  EXPECT_EQ((*tree)->fetches(), stats.pageRequests) << stats.toString();
  EXPECT_LE(stats.pageRequests, (*tree)->pageCount()) << stats.toString();
}

// Cuts run together give each cut's result alone, bit for bit, with the same counts, and ask
// for each page about once for all of them (a source that counts: per cut, a page at most
// once, so together at most the cuts' sum, and here far fewer loads than that through a cache
// of two pages).
TEST(BidirectionalCut, CutsTogetherEqualCutsAloneAndShareTheirPages) {
  BoxCase c = boxCase(20000, 1600);
  auto tree = memoryTree(c.surfels, kDefaultLeafSize, 3);
  ASSERT_TRUE(tree.ok());
  constexpr size_t kCuts = 4;
  const size_t per = c.receivers.size() / kCuts;
  std::vector<std::vector<Rgb>> alone(kCuts, std::vector<Rgb>(per));
  CutStats aloneStats;
  for (size_t k = 0; k < kCuts; ++k) {
    BidirectionalCut cut(CutOptions{});
    ASSERT_TRUE(cut.irradiance(**tree, *c.scene,
                               std::span(c.receivers).subspan(k * per, per), 100 + k, alone[k],
                               &aloneStats)
                    .ok());
  }
  const uint64_t fetchesAlone = (*tree)->fetches();
  PageCache cache(**tree, {.budgetBytes = 1, .policy = PageCachePolicy::kLeastRecent});
  std::vector<std::vector<Rgb>> together(kCuts, std::vector<Rgb>(per));
  std::vector<BidirectionalCut> cuts;
  for (size_t k = 0; k < kCuts; ++k) cuts.emplace_back(CutOptions{});
  std::vector<BidirectionalCut*> pointers;
  std::vector<CutJob> jobs;
  for (size_t k = 0; k < kCuts; ++k) {
    pointers.push_back(&cuts[k]);
    jobs.push_back({.receivers = std::span(c.receivers).subspan(k * per, per),
                    .key = 100 + k,
                    .out = together[k]});
  }
  CutStats togetherStats;
  ASSERT_TRUE(cutTogether(cache, *c.scene, pointers, jobs, &togetherStats).ok());
  EXPECT_EQ(alone, together);
  EXPECT_EQ(aloneStats.toString(), togetherStats.toString());
  // A cache that holds one page at a time (a budget of one byte) loads each page once for
  // the four cuts: they sweep in step.
  const uint64_t loads = cache.counters().misses;
  EXPECT_LE(loads, (*tree)->pageCount());
  EXPECT_LT(loads * 2, fetchesAlone) << cache.counters().toString();
}

TEST(BidirectionalCut, BadInputAndDamagedPagesAreErrors) {
  BoxCase c = boxCase(2000, 8);
  auto tree = memoryTree(c.surfels, kDefaultLeafSize, 2);
  ASSERT_TRUE(tree.ok());
  std::vector<Rgb> out(c.receivers.size());
  BidirectionalCut cut(CutOptions{});
  std::vector<CutReceiver> bad = c.receivers;
  bad[3].p.x = std::nanf("");
  absl::Status s = cut.irradiance(**tree, *c.scene, bad, 1, out, nullptr);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument) << s;
  EXPECT_NE(s.message().find("receiver 3"), std::string::npos) << s;
  FailingPageSource failing(tree->get(), 1);
  s = cut.irradiance(failing, *c.scene, c.receivers, 1, out, nullptr);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_NE(s.message().find("page 1"), std::string::npos) << s;
  CutOptions o;
  o.normalAngle = -1.0f;
  EXPECT_EQ(o.validate().code(), absl::StatusCode::kInvalidArgument);
  for (int rays : {-1, kMaxNearRays + 1}) {
    CutOptions near;
    near.nearRays = rays;
    const absl::Status v = near.validate();
    EXPECT_EQ(v.code(), absl::StatusCode::kInvalidArgument) << rays;
    EXPECT_NE(v.message().find("nearRays"), std::string::npos) << v;
  }
  // The page source failing under the near field's readings is the cut's error too.
  CutOptions withNear;
  withNear.nearRays = 8;
  BidirectionalCut nearCut(withNear);
  s = nearCut.irradiance(failing, *c.scene, c.receivers, 1, out, nullptr);
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
}

}  // namespace
}  // namespace pbgi
