// Wavelets in the tree (glossy light): the writer's sums, the pages' hierarchical coding, and what
// a page's wavelet section refuses.
#include <gtest/gtest.h>

#include <atomic>
#include <cmath>
#include <functional>
#include <map>

#include "core/pbgi/tree_writer.h"
#include "core/util/bytes.h"
#include "tests/support/surfel_clouds.h"

namespace pbgi {
namespace {

using testing::makeSorted;

constexpr int kN = 8;

// A leaf's wavelet intensity that depends only on how many of its surfels are glossy (so the
// sums can be recomputed from decoded leaves, whose positions are quantized): a lobe whose
// axis and strength follow that count.
WaveletRadiance leafIntensity(std::span<const Surfel> surfels) {
  int glossy = 0;
  for (const Surfel& s : surfels) glossy += s.materialClass == MaterialClass::kGlossy ? 1 : 0;
  if (glossy == 0) return WaveletRadiance();
  const Vec3f axes[3] = {normalize(Vec3f(0.2f, 0.3f, 1.0f)), normalize(Vec3f(-1.0f, 0.5f, 0.1f)),
                         normalize(Vec3f(0.1f, -1.0f, -0.4f))};
  const Vec3f axis = axes[glossy % 3];
  return WaveletRadiance::project(
      [&](const Vec3f& d) {
        const float v = glossy * std::exp(40.0f * (dot(normalize(d), axis) - 1.0f)) + 0.05f * glossy;
        return Rgb(v, 0.7f * v, 0.4f * v);
      },
      kN, 0.0f);
}

std::vector<SortedSurfel> withGlossy(std::vector<SortedSurfel> points, int every) {
  for (size_t i = 0; i < points.size(); ++i) {
    if (i % every == 0) points[i].surfel.materialClass = MaterialClass::kGlossy;
  }
  return points;
}

TreeWriteOptions options(TreeEncoding encoding, std::atomic<int>* calls) {
  TreeWriteOptions o = testing::smallTreeOptions(encoding, 16384);
  o.wavelets.leaf = [calls](std::span<Surfel> surfels, uint64_t) {
    ++*calls;
    return leafIntensity(surfels);
  };
  o.wavelets.relativeError = 0.1f;
  return o;
}

TEST(TreeWavelets, ATreeWithoutGlossySurfelsIsByteForByteATreeWithoutWavelets) {
  const std::vector<SortedSurfel> points = makeSorted(3000, 41);
  for (TreeEncoding e : {TreeEncoding::kFloat, TreeEncoding::kQuantized}) {
    std::atomic<int> calls{0};
    TreeWriteOptions with = options(e, &calls);
    TreeWriteOptions without = with;
    without.wavelets.leaf = nullptr;
    TreeWriteResult result;
    auto a = buildMemoryTree(points, with, &result);
    auto b = buildMemoryTree(points, without);
    ASSERT_TRUE(a.ok() && b.ok());
    EXPECT_EQ(calls.load(), 0);
    EXPECT_EQ(result.wavelets.nodes, 0u);
    EXPECT_TRUE((*a)->payloads() == (*b)->payloads()) << static_cast<int>(e);
  }
}

// Walks the tree; for every node, the exact sum of its leaves' vectors (recomputed from the
// decoded leaves) against the vector its page decodes.
struct Check {
  size_t nodes = 0, withVector = 0;
  double worst = 0.0;
};

std::vector<float> checkNode(TreePageSource& tree, NodeRef ref, Check* check) {
  auto page = tree.page(ref.page);
  EXPECT_TRUE(page.ok()) << page.status();
  const TreeNode& node = (*page)->nodes[ref.index];
  std::vector<float> exact;
  auto add = [&](const std::vector<float>& v) {
    if (v.empty()) return;
    if (exact.empty()) exact.assign(v.size(), 0.0f);
    for (size_t k = 0; k < v.size(); ++k) exact[k] += v[k];
  };
  if (node.leaf()) {
    const WaveletRadiance w = leafIntensity((*page)->surfelsOf(node));
    if (!w.empty()) add(w.dense());
  } else {
    for (const NodeRef& c : (*page)->childrenOf(node)) add(checkNode(tree, c, check));
  }
  ++check->nodes;
  const WaveletRadiance* got = (*page)->waveletOf(node);
  EXPECT_EQ(got != nullptr, !exact.empty()) << "page " << ref.page << " node " << ref.index;
  if (got != nullptr && !exact.empty()) {
    ++check->withVector;
    const std::vector<float> decoded = got->dense();
    double d2 = 0.0, n2 = 0.0;
    for (size_t k = 0; k < exact.size(); ++k) {
      d2 += double(decoded[k] - exact[k]) * (decoded[k] - exact[k]);
      n2 += double(exact[k]) * exact[k];
    }
    check->worst = std::max(check->worst, std::sqrt(d2 / n2));
  }
  return exact;
}

TEST(TreeWavelets, EveryNodeDecodesTheSumOfItsLeavesWithinTheErrorItWasCodedWith) {
  for (TreeEncoding e : {TreeEncoding::kFloat, TreeEncoding::kQuantized}) {
    std::atomic<int> calls{0};
    TreeWriteResult result;
    auto tree = buildMemoryTree(withGlossy(makeSorted(4000, 42), 3), options(e, &calls), &result);
    ASSERT_TRUE(tree.ok()) << tree.status();
    Check check;
    checkNode(**tree, (*tree)->root(), &check);
    std::printf("[ measured ] %s: %zu of %zu nodes with vectors, %llu stored as differences, "
                "%llu bytes, worst relative error %.4f (reported %.4f)\n",
                e == TreeEncoding::kFloat ? "float" : "quantized", check.withVector, check.nodes,
                static_cast<unsigned long long>(result.wavelets.differences),
                static_cast<unsigned long long>(result.wavelets.bytes), check.worst,
                result.wavelets.maxRelativeError);
    EXPECT_EQ(static_cast<uint64_t>(calls.load()), result.wavelets.leaves);
    EXPECT_GT(check.withVector, check.nodes / 2);
    EXPECT_GT(result.wavelets.differences, 0u);
    // The writer holds vectors within a fifth of the error, the pages within the error; half
    // floats add a little.
    EXPECT_LE(check.worst, 0.1 * 1.2 + 2e-3);
    EXPECT_LE(result.wavelets.maxRelativeError, 0.1 + 1e-4);
  }
}

// ---- A page's wavelet section, damaged ------------------------------------------------------

class WaveletSectionDamage : public ::testing::Test {
 protected:
  void SetUp() override {
    std::atomic<int> calls{0};
    TreeWriteOptions o = options(TreeEncoding::kFloat, &calls);
    o.pageSize = 1 << 20;  // one page: every node has its parent in it
    auto tree = buildMemoryTree(withGlossy(makeSorted(300, 43), 2), o);
    ASSERT_TRUE(tree.ok());
    tree_ = std::move(*tree);
    ASSERT_EQ(tree_->payloads().size(), 1u);
    bytes_ = tree_->payloads().front();
    auto page = decodeTreePage(0, bytes_, nullptr);
    ASSERT_TRUE(page.ok()) << page.status();
    section_ = bytes_.size() - (*page)->waveletSectionBytes;
    ASSERT_GT((*page)->waveletSectionBytes, 0u);
    // The first entry's first face with a kept node.
    size_t at = section_ + 10 + 10;
    for (int f = 0; f < 6; ++f) {
      const uint16_t count = loadU16(bytes_.data() + at + 16);
      if (count > 0 && firstNode_ == 0) firstNode_ = at + 18;
      at += 18 + size_t{count} * 21;
    }
    ASSERT_GT(firstNode_, 0u);
    // An entry coded as a difference.
    for (size_t e = 0, p = section_ + 10; e < loadU32(bytes_.data() + section_ + 6); ++e) {
      if (bytes_[p + 5] == 1 && difference_ == 0) difference_ = p;
      if (bytes_[p + 5] == 0 && whole_ == 0 && e > 0) whole_ = p;
      size_t q = p + 10;
      for (int f = 0; f < 6; ++f) q += 18 + size_t{loadU16(bytes_.data() + q + 16)} * 21;
      p = q;
    }
  }
  void expectRefused(std::vector<uint8_t> b, const std::string& text) {
    const absl::Status s = decodeTreePage(0, b, nullptr).status();
    EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << text;
    EXPECT_NE(s.message().find("wavelet section"), std::string::npos) << s;
    EXPECT_NE(s.message().find(text), std::string::npos) << s;
  }
  std::unique_ptr<MemoryTree> tree_;
  std::vector<uint8_t> bytes_;
  size_t section_ = 0, firstNode_ = 0, difference_ = 0, whole_ = 0;
};

TEST_F(WaveletSectionDamage, EachDamageIsRefusedByName) {
  {
    auto b = bytes_;
    storeU32(b.data() + section_, 0x12345678u);
    expectRefused(b, "not a wavelet section");
  }
  {
    auto b = bytes_;
    b[section_ + 4] = 9;
    expectRefused(b, "version 9, this build reads version 1");
  }
  {
    auto b = bytes_;
    storeU32(b.data() + section_ + 6, 1u << 30);
    expectRefused(b, "entries for");
  }
  {
    auto b = bytes_;
    storeU32(b.data() + section_ + 10, 77777);
    expectRefused(b, "names node 77777");
  }
  {
    auto b = bytes_;
    b[section_ + 14] = 9;  // 2^9 texels a side
    expectRefused(b, "resolution 2^9");
  }
  {
    auto b = bytes_;
    b[section_ + 15] = 7;
    expectRefused(b, "coding 7");
  }
  {
    auto b = bytes_;
    storeU32(b.data() + section_ + 16, 0x7fc00000u);  // a NaN factor
    expectRefused(b, "finite factor");
  }
  {
    auto b = bytes_;
    b[firstNode_] = 5;  // level 5 of an 8-texel face
    expectRefused(b, "outside the 3 levels");
  }
  {
    auto b = bytes_;
    storeU16(b.data() + firstNode_ + 3, 0x7e00);  // a NaN detail
    expectRefused(b, "not finite");
  }
  {
    auto b = bytes_;
    b.push_back(0);
    expectRefused(b, "1 bytes left over");
  }
  {
    auto b = bytes_;
    b.resize(b.size() - 3);
    expectRefused(b, "cut short");
  }
  if (whole_ != 0) {
    // The root comes first and has no parent: a difference there has nothing to add to.
    auto b = bytes_;
    b[section_ + 10 + 5] = 1;
    expectRefused(b, "has no in-page parent");
  }
}

}  // namespace
}  // namespace pbgi
