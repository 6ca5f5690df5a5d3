#include "core/pbgi/quantize.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cstring>
#include <set>
#include <vector>

#include <tbb/task_arena.h>

#include "core/pbgi/sh.h"
#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"
#include "tests/support/sh_lobes.h"

namespace pbgi {
namespace {

constexpr int kDim = Sh9Rgb::kFloats;

// `clusters` well-separated centres in 27-D (coordinates in [-100, 100]), `perCluster`
// points each, jittered by at most `noise`, interleaved so that any sample sees them all.
std::vector<float> clusteredData(int clusters, int perCluster, float noise,
                                 std::vector<float>* truth) {
  Rng rng(5);
  truth->resize(static_cast<size_t>(clusters) * kDim);
  for (float& x : *truth) x = 200.0f * rng.uniform() - 100.0f;
  std::vector<float> data;
  for (int p = 0; p < perCluster; ++p) {
    for (int c = 0; c < clusters; ++c) {
      for (int j = 0; j < kDim; ++j)
        data.push_back((*truth)[c * kDim + j] + noise * (2.0f * rng.uniform() - 1.0f));
    }
  }
  return data;
}

std::span<const float> row(const std::vector<float>& data, size_t i) {
  return std::span<const float>(data).subspan(i * kDim, kDim);
}

TEST(QuantizeTest, RecoversIdenticalClustersExactly) {
  std::vector<float> truth;
  const std::vector<float> data = clusteredData(7, 300, 0.0f, &truth);
  KMeansOptions o;
  o.centres = 7;
  o.seed = 3;
  const Codebook book = trainCodebook(data, kDim, o);
  ASSERT_EQ(book.size(), 8);
  for (int j = 0; j < kDim; ++j) EXPECT_EQ(book.entry(0)[j], 0.0f);
  std::set<uint32_t> used;
  for (int c = 0; c < 7; ++c) {
    const std::span<const float> t(truth.data() + c * kDim, kDim);
    const uint32_t e = nearestEntry(book, t);
    used.insert(e);
    EXPECT_TRUE(std::equal(t.begin(), t.end(), book.entry(static_cast<int>(e)).begin()))
        << "cluster " << c;
  }
  EXPECT_EQ(used.size(), 7u);
  const QuantizationError err = measureError(book, data);
  EXPECT_EQ(err.count, 2100u);
  EXPECT_EQ(err.rms, 0.0);
  EXPECT_EQ(err.maxRelative, 0.0);
}

TEST(QuantizeTest, RecoversJitteredClusters) {
  std::vector<float> truth;
  const std::vector<float> data = clusteredData(12, 1000, 1.0f, &truth);
  KMeansOptions o;
  o.centres = 12;
  o.seed = 8;
  o.sampleFraction = 0.25;
  const Codebook book = trainCodebook(data, kDim, o);
  ASSERT_EQ(book.size(), 13);
  // Every point maps to the entry of its own cluster, and that entry sits at the cluster's
  // centre within the noise averaged over its share of the sample (about 250 points).
  std::vector<uint32_t> entryOf(12);
  std::set<uint32_t> used;
  for (int c = 0; c < 12; ++c) {
    entryOf[c] = nearestEntry(book, std::span<const float>(truth.data() + c * kDim, kDim));
    used.insert(entryOf[c]);
    const std::span<const float> e = book.entry(static_cast<int>(entryOf[c]));
    for (int j = 0; j < kDim; ++j) EXPECT_NEAR(e[j], truth[c * kDim + j], 0.15f) << c << " " << j;
  }
  EXPECT_EQ(used.size(), 12u);
  EXPECT_EQ(used.count(0), 0u);
  for (size_t i = 0; i < data.size() / kDim; ++i) {
    ASSERT_EQ(nearestEntry(book, row(data, i)), entryOf[i % 12]) << "point " << i;
  }
}

TEST(QuantizeTest, BlackMapsToEntryZeroAndIsNotTrained) {
  std::vector<float> data = testing::lambertianLobeVectors(2000);
  // Half the nodes are dark: they must not pull centres towards zero.
  data.resize(data.size() * 2, 0.0f);
  KMeansOptions o;
  o.centres = 20;
  const Codebook book = trainCodebook(data, kDim, o);
  ASSERT_EQ(book.size(), 21);
  const std::vector<float> black(kDim, 0.0f);
  EXPECT_EQ(nearestEntry(book, black), 0u);
  for (int e = 1; e < book.size(); ++e) {
    const std::span<const float> v = book.entry(e);
    EXPECT_TRUE(std::any_of(v.begin(), v.end(), [](float x) { return x != 0.0f; })) << e;
  }
  // A vector that is only a whisper maps to black too.
  std::vector<float> faint(kDim, 0.0f);
  faint[0] = 1e-6f;
  EXPECT_EQ(nearestEntry(book, faint), 0u);
}

TEST(QuantizeTest, EmptyAndTinyInputs) {
  KMeansOptions o;
  const Codebook empty = trainCodebook({}, kDim, o);
  EXPECT_EQ(empty.size(), 1);
  EXPECT_EQ(empty.dimension, kDim);
  EXPECT_EQ(measureError(empty, {}).count, 0u);
  EXPECT_EQ(measureError(empty, {}).rms, 0.0);

  const std::vector<float> allBlack(10 * kDim, 0.0f);
  EXPECT_EQ(trainCodebook(allBlack, kDim, o).size(), 1);

  // Three distinct vectors, repeated, and 100 centres asked for: three entries besides black.
  std::vector<float> few;
  for (int i = 0; i < 50; ++i) {
    for (int v = 1; v <= 3; ++v) {
      for (int j = 0; j < kDim; ++j) few.push_back(static_cast<float>(v * (j + 1)));
    }
  }
  const Codebook book = trainCodebook(few, kDim, o);
  EXPECT_EQ(book.size(), 4);
  const QuantizationError err = measureError(book, few);
  EXPECT_EQ(err.rms, 0.0);
  EXPECT_EQ(err.maxRelative, 0.0);
}

// A NaN in one node must neither poison the codebook nor the error measures.
TEST(QuantizeTest, NonFiniteVectorsStayOutOfTrainingAndMeasures) {
  std::vector<float> data = testing::lambertianLobeVectors(3000);
  for (size_t i = 0; i < 3000; i += 3) data[i * kDim + 5] = std::numeric_limits<float>::quiet_NaN();
  data[7 * kDim] = std::numeric_limits<float>::infinity();
  KMeansOptions o;
  o.centres = 10;
  const Codebook book = trainCodebook(data, kDim, o);
  ASSERT_EQ(book.size(), 11);
  for (float x : book.entries) ASSERT_TRUE(std::isfinite(x));
  EXPECT_EQ(nearestEntry(book, row(data, 0)), 0u);
  const QuantizationError err = measureError(book, data);
  EXPECT_EQ(err.nonFinite, 1001u);
  EXPECT_EQ(err.count, 1999u);
  EXPECT_TRUE(std::isfinite(err.rms));
  EXPECT_TRUE(std::isfinite(err.relativeRms));
  EXPECT_GT(err.rms, 0.0);
}

TEST(QuantizeTest, NearestEntryAndErrorByHand) {
  Codebook book;
  book.dimension = 2;
  book.entries = {0, 0, 1, 0, 3, 0};
  EXPECT_EQ(nearestEntry(book, std::vector<float>{2.0f, 0.0f}), 1u);  // a tie: the lower index
  EXPECT_EQ(nearestEntry(book, std::vector<float>{2.1f, 0.0f}), 2u);
  EXPECT_EQ(nearestEntry(book, std::vector<float>{0.4f, 0.1f}), 0u);
  const std::vector<float> v = {1, 0, 2, 0, 0, 0, 4, 0};
  const QuantizationError err = measureError(book, v);
  EXPECT_EQ(err.count, 4u);
  EXPECT_DOUBLE_EQ(err.rms, std::sqrt((0.0 + 1.0 + 0.0 + 1.0) / 4.0));
  EXPECT_DOUBLE_EQ(err.relativeRms, std::sqrt(2.0 / (1.0 + 4.0 + 16.0)));
  EXPECT_DOUBLE_EQ(err.maxRelative, 0.5);
}

TEST(QuantizeTest, IdenticalWithOneAndTwoThreads) {
  const std::vector<float> data = testing::lambertianLobeVectors(60000);
  KMeansOptions o;
  o.centres = 50;
  o.seed = 21;
  o.sampleFraction = 0.5;  // 30000 points: 30 blocks of sums
  Codebook one, two;
  tbb::task_arena(1).execute([&] { one = trainCodebook(data, kDim, o); });
  tbb::task_arena(2).execute([&] { two = trainCodebook(data, kDim, o); });
  ASSERT_EQ(one.size(), 51);
  ASSERT_EQ(one.entries.size(), two.entries.size());
  EXPECT_EQ(std::memcmp(one.entries.data(), two.entries.data(), one.entries.size() * sizeof(float)),
            0);
  QuantizationError e1, e2;
  tbb::task_arena(1).execute([&] { e1 = measureError(one, data); });
  tbb::task_arena(2).execute([&] { e2 = measureError(one, data); });
  EXPECT_EQ(e1.rms, e2.rms);
  EXPECT_EQ(e1.maxRelative, e2.maxRelative);
  // A different seed trains a different codebook.
  o.seed = 22;
  const Codebook other = trainCodebook(data, kDim, o);
  EXPECT_NE(other.entries, one.entries);
}

TEST(QuantizeTest, ErrorFallsWithMoreCentres) {
  const std::vector<float> data = testing::lambertianLobeVectors(20000);
  double previous = std::numeric_limits<double>::infinity();
  for (const int centres : {4, 16, 64, 128}) {
    KMeansOptions o;
    o.centres = centres;
    o.seed = 1;
    const Codebook book = trainCodebook(data, kDim, o);
    ASSERT_EQ(book.size(), centres + 1);
    const QuantizationError err = measureError(book, data);
    EXPECT_LT(err.relativeRms, previous) << centres << " centres";
    EXPECT_GT(err.relativeRms, 0.0);
    previous = err.relativeRms;
  }
  // Lloyd's iterations improve on the k-means++ seeding alone.
  KMeansOptions seedingOnly;
  seedingOnly.centres = 64;
  seedingOnly.seed = 1;
  seedingOnly.iterations = 0;
  KMeansOptions lloyd = seedingOnly;
  lloyd.iterations = 10;
  EXPECT_LT(measureError(trainCodebook(data, kDim, lloyd), data).rms,
            measureError(trainCodebook(data, kDim, seedingOnly), data).rms);
}

}  // namespace
}  // namespace pbgi
