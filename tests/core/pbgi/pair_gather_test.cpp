#include "core/pbgi/pair_gather.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <mutex>
#include <vector>

#include <tbb/global_control.h>

#include "core/sampling/rng.h"
#include "tests/support/memory_tree.h"
#include "tests/support/surfel_shapes.h"

namespace pbgi {
namespace {

using testing::diskSurfels;
using testing::FailingPageSource;
using testing::sphereSurfels;
using testing::treeOf;

// A closed sphere whose light varies smoothly with direction (so that clusters differ from
// their neighbours and a misplaced splat shows), a bright disk hanging inside it and a dark
// one below that (an occluder some receivers see and some do not), over many pages.
std::unique_ptr<testing::MemoryTreeSource> scene() {
  std::vector<Surfel> surfels = sphereSurfels(12000, 1.0f, Rgb(0.0f));
  for (Surfel& s : surfels) {
    const Vec3f d = -s.normal;
    s.radiance = Rgb(0.6f + 0.4f * d.x, 0.5f + 0.5f * d.y * d.y, 0.3f + 0.3f * d.z);
  }
  for (const Surfel& s :
       diskSurfels(800, Vec3f(0.3f, 0.0f, 0.6f), Vec3f(0, 0, -1), 0.25f, Rgb(6.0f, 5.0f, 3.0f))) {
    surfels.push_back(s);
  }
  for (const Surfel& s :
       diskSurfels(800, Vec3f(-0.2f, 0.1f, 0.0f), normalize(Vec3f(0.2f, 0, 1)), 0.2f, Rgb(0.05f))) {
    surfels.push_back(s);
  }
  return treeOf(surfels, 3);
}

// Receivers on a patch of floor inside the sphere: two-sided ones (a glossy leaf's two sides)
// and one-sided ones, tilted a little each.
std::vector<PairReceiver> floorReceivers(int n, uint64_t seed) {
  Rng rng(seed);
  std::vector<PairReceiver> receivers;
  for (int i = 0; i < n; ++i) {
    PairReceiver r;
    r.position = Vec3f(0.8f * rng.uniform() - 0.4f, 0.8f * rng.uniform() - 0.4f,
                       -0.5f + 0.05f * rng.uniform());
    r.normal = normalize(Vec3f(0.2f * rng.uniform() - 0.1f, 0.2f * rng.uniform() - 0.1f, 1.0f));
    r.twoSided = i % 3 != 0;
    receivers.push_back(r);
  }
  return receivers;
}

// What pairGather handed out: each receiver's buffers' pixels.
struct Pictures {
  struct Pixel {
    Rgb radiance;
    float coverage, depth;
    bool operator==(const Pixel&) const = default;
  };
  std::vector<std::vector<Pixel>> above, below;
  std::mutex mutex;

  explicit Pictures(size_t n) : above(n), below(n) {}
  static std::vector<Pixel> of(const Microbuffer& b) {
    std::vector<Pixel> out(static_cast<size_t>(b.pixelCount()));
    for (int k = 0; k < b.pixelCount(); ++k) {
      out[static_cast<size_t>(k)] = {b.radiance(k), b.coverage(k), b.depth(k)};
    }
    return out;
  }
  PairGatherUse use() {
    return [this](size_t i, const Microbuffer& a, const Microbuffer* b) {
      std::lock_guard lock(mutex);
      EXPECT_TRUE(above[i].empty()) << "receiver " << i << " handed out twice";
      above[i] = of(a);
      if (b != nullptr) below[i] = of(*b);
    };
  }
};

// The irradiance a picture gives a receiver facing n.
Rgb irradianceOf(const std::vector<Pictures::Pixel>& pixels, const Microbuffer& tables,
                 const Vec3f& n) {
  Rgb sum(0.0f);
  for (size_t k = 0; k < pixels.size(); ++k) {
    const float c = dot(tables.direction(static_cast<int>(k)), n);
    if (c > 0.0f) sum += pixels[k].radiance * (c * tables.solidAngle(static_cast<int>(k)));
  }
  return sum;
}

// A glossy lobe's response (a cosine power about a direction tilted off the normal): what a
// splat moved by the group's parallax would change most.
Rgb lobeOf(const std::vector<Pictures::Pixel>& pixels, const Microbuffer& tables, const Vec3f& n) {
  const Vec3f axis = normalize(n + Vec3f(0.5f, 0.2f, 0.0f));
  Rgb sum(0.0f);
  for (size_t k = 0; k < pixels.size(); ++k) {
    const Vec3f d = tables.direction(static_cast<int>(k));
    const float c = dot(d, axis);
    if (c > 0.0f && dot(d, n) > 0.0f) {
      sum += pixels[k].radiance * (std::pow(c, 10.0f) * tables.solidAngle(static_cast<int>(k)));
    }
  }
  return sum;
}

// Algorithm 1 with the receiver threshold at zero refines every group down to its single
// receivers, so each receiver walks the tree from the root: its buffers are
// Gatherer::rasterize's, bit for bit, and no group keeps a splat.
TEST(PairGather, ReceiverThresholdZeroIsPerReceiverEvaluation) {
  auto tree = scene();
  ASSERT_GT(tree->pageCount(), 8u);
  const std::vector<PairReceiver> receivers = floorReceivers(150, 5);
  PairGatherOptions options;
  options.receiverSolidAngle = 0.0f;
  Pictures pictures(receivers.size());
  GatherStats gatherStats;
  PairGatherStats stats;
  ASSERT_TRUE(pairGather(*tree, receivers, options, pictures.use(), &gatherStats, &stats).ok());
  EXPECT_EQ(stats.receivers, receivers.size());
  EXPECT_EQ(stats.groupSplats, 0u);
  EXPECT_EQ(stats.groupBuffers, 0u);
  EXPECT_EQ(stats.composed, 0u);
  Gatherer alone(options.gather);
  GatherStats aloneStats;
  for (size_t i = 0; i < receivers.size(); ++i) {
    const PairReceiver& r = receivers[i];
    ASSERT_TRUE(alone.rasterize(*tree, r.position, r.normal, &aloneStats).ok());
    ASSERT_EQ(pictures.above[i], Pictures::of(alone.microbuffer())) << "receiver " << i;
    if (r.twoSided) {
      ASSERT_TRUE(alone.rasterize(*tree, r.position, -r.normal, &aloneStats).ok());
      ASSERT_EQ(pictures.below[i], Pictures::of(alone.microbuffer())) << "receiver " << i;
    } else {
      EXPECT_TRUE(pictures.below[i].empty());
    }
  }
  EXPECT_EQ(gatherStats.clustersSplatted, aloneStats.clustersSplatted);
  EXPECT_EQ(gatherStats.disksSplatted, aloneStats.disksSplatted);
}

// With the default threshold, far clusters are splatted once per group: fewer splats than the
// receivers' own walks make, at the accuracy of those walks. Both are measured against a fine
// gather (32^2 pixels a face, clusters of a tenth of the solid angle): a receiver's irradiance
// and its response to a glossy lobe tilted off the normal (what the group's parallax would
// move). A layered pixel depends on the order pieces arrive in, so the shared buffers are not
// the walks' bits; their error may grow a little over the walks' (parallax, and layers composed
// as whole pieces), not more.
TEST(PairGather, GroupsShareFarClustersAtTheWalksAccuracy) {
  auto tree = scene();
  const std::vector<PairReceiver> receivers = floorReceivers(400, 9);
  PairGatherOptions options;
  Pictures pictures(receivers.size());
  GatherStats gatherStats;
  PairGatherStats stats;
  ASSERT_TRUE(pairGather(*tree, receivers, options, pictures.use(), &gatherStats, &stats).ok());
  GatherOptions fineOptions = options.gather;
  fineOptions.resolution = 32;
  fineOptions.maxSolidAngle = options.gather.maxSolidAngle / 10.0f;
  Gatherer alone(options.gather), fine(fineOptions);
  GatherStats aloneStats;
  struct Errors {
    double sum = 0.0, worst = 0.0;
    int count = 0;
    void add(float value, float expected) {
      const double e = std::abs(double(value) / expected - 1.0);
      sum += e;
      worst = std::max(worst, e);
      ++count;
    }
    double mean() const { return sum / count; }
  } eAlone, ePair, lAlone, lPair;
  for (size_t i = 0; i < receivers.size(); ++i) {
    const PairReceiver& r = receivers[i];
    for (int side = 0; side < (r.twoSided ? 2 : 1); ++side) {
      const Vec3f n = side == 0 ? r.normal : -r.normal;
      ASSERT_TRUE(alone.rasterize(*tree, r.position, n, &aloneStats).ok());
      ASSERT_TRUE(fine.rasterize(*tree, r.position, n, nullptr).ok());
      const auto own = Pictures::of(alone.microbuffer());
      const auto reference = Pictures::of(fine.microbuffer());
      const auto& shared = side == 0 ? pictures.above[i] : pictures.below[i];
      const Microbuffer& t = alone.microbuffer();
      const Microbuffer& ft = fine.microbuffer();
      const float e = luminance(irradianceOf(reference, ft, n));
      eAlone.add(luminance(irradianceOf(own, t, n)), e);
      ePair.add(luminance(irradianceOf(shared, t, n)), e);
      const float l = luminance(lobeOf(reference, ft, n));
      if (l > 1e-3f * e) {
        lAlone.add(luminance(lobeOf(own, t, n)), l);
        lPair.add(luminance(lobeOf(shared, t, n)), l);
      }
    }
  }
  const uint64_t shared = gatherStats.clustersSplatted + gatherStats.disksSplatted;
  const uint64_t unshared = aloneStats.clustersSplatted + aloneStats.disksSplatted;
  std::printf(
      "[ measured ] pair gather, %zu receivers, receiverSolidAngle %g: splats %llu against %llu "
      "alone (%.2fx fewer)\n  against a fine gather: irradiance mean %.4f worst %.4f (alone "
      "%.4f, %.4f); lobe mean %.4f worst %.4f (alone %.4f, %.4f; %d lobes)\n  %s\n",
      receivers.size(), options.receiverSolidAngle, static_cast<unsigned long long>(shared),
      static_cast<unsigned long long>(unshared), double(unshared) / double(shared), ePair.mean(),
      ePair.worst, eAlone.mean(), eAlone.worst, lPair.mean(), lPair.worst, lAlone.mean(),
      lAlone.worst, lPair.count, stats.toString().c_str());
  EXPECT_GT(stats.groupSplats, 0u);
  EXPECT_GT(stats.splatsServed, 2 * stats.groupSplats);
  EXPECT_LT(shared, unshared);
  // Measured: irradiance mean 0.0093 (alone 0.0069), worst 0.036 (0.020); lobes 0.016 (0.011),
  // 0.093 (0.067). At receiverSolidAngle 0.05 (the paper's epsilon) the irradiance's mean error
  // is 0.021, which the first bound refuses.
  EXPECT_LT(ePair.mean(), 1.6 * eAlone.mean() + 0.002);
  EXPECT_LT(ePair.worst, 2.0 * eAlone.worst + 0.005);
  EXPECT_LT(lPair.mean(), 1.6 * lAlone.mean() + 0.002);
  EXPECT_LT(lPair.worst, 2.0 * lAlone.worst + 0.01);
}

// A receiver's buffers depend on the receivers given, never on the threads.
TEST(PairGather, TheSameBitsWithOneThread) {
  auto tree = scene();
  const std::vector<PairReceiver> receivers = floorReceivers(200, 3);
  PairGatherOptions options;
  Pictures many(receivers.size()), one(receivers.size());
  PairGatherStats statsMany, statsOne;
  ASSERT_TRUE(pairGather(*tree, receivers, options, many.use(), nullptr, &statsMany).ok());
  {
    tbb::global_control single(tbb::global_control::max_allowed_parallelism, 1);
    ASSERT_TRUE(pairGather(*tree, receivers, options, one.use(), nullptr, &statsOne).ok());
  }
  EXPECT_EQ(many.above, one.above);
  EXPECT_EQ(many.below, one.below);
  EXPECT_EQ(statsMany.toString(), statsOne.toString());
}

TEST(PairGather, BadInputIsAnErrorAndAMissingPageFailsTheGather) {
  auto tree = scene();
  std::vector<PairReceiver> receivers = floorReceivers(20, 1);
  Pictures pictures(receivers.size());
  PairGatherOptions bad;
  bad.receiverSolidAngle = -1.0f;
  EXPECT_EQ(pairGather(*tree, receivers, bad, pictures.use(), nullptr, nullptr).code(),
            absl::StatusCode::kInvalidArgument);
  bad = PairGatherOptions{};
  bad.gather.resolution = 0;
  EXPECT_EQ(pairGather(*tree, receivers, bad, pictures.use(), nullptr, nullptr).code(),
            absl::StatusCode::kInvalidArgument);
  receivers[7].normal = Vec3f(0.0f);
  const absl::Status zero = pairGather(*tree, receivers, {}, pictures.use(), nullptr, nullptr);
  EXPECT_EQ(zero.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(zero.message().find("receiver 7"), std::string_view::npos) << zero;
  receivers[7].normal = Vec3f(0, 0, 1);
  receivers[3].position.x = std::nanf("");
  EXPECT_EQ(pairGather(*tree, receivers, {}, pictures.use(), nullptr, nullptr).code(),
            absl::StatusCode::kInvalidArgument);
  receivers[3].position.x = 0.0f;
  // Nothing was handed out by the calls that failed their checks.
  for (const auto& a : pictures.above) EXPECT_TRUE(a.empty());
  FailingPageSource damaged(tree.get(), tree->root().page);
  const absl::Status lost = pairGather(damaged, receivers, {}, pictures.use(), nullptr, nullptr);
  EXPECT_EQ(lost.code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(pairGather(*tree, {}, {}, pictures.use(), nullptr, nullptr).code(),
            absl::StatusCode::kOk);
}

}  // namespace
}  // namespace pbgi
