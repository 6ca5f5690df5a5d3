#include "core/pbgi/tree_build.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <vector>

#include "core/pbgi/morton.h"
#include "core/sampling/rng.h"
#include "tests/support/surfel_clouds.h"

namespace pbgi {
namespace {

using testing::makeSorted;

int extendedLevel(const SortedSurfel& a, const SortedSurfel& b) {
  if (a.key != b.key) return commonLevel(a.key, b.key);
  return kMortonLevels + commonLevel(a.sequence, b.sequence);
}

// The same tree built top-down, recursively, from the definition: a range of more than m
// points splits at the deepest level holding all of it.
void referenceBuild(std::span<const SortedSurfel> range, int m, std::vector<InMemoryNode>* out,
                    NodeAttributes* attributes) {
  if (range.size() <= static_cast<size_t>(m)) {
    InMemoryNode leaf;
    for (const SortedSurfel& p : range) leaf.surfels.push_back(p.surfel);
    leaf.attributes = leafAttributes(leaf.surfels);
    *attributes = leaf.attributes;
    out->push_back(std::move(leaf));
    return;
  }
  const int level = extendedLevel(range.front(), range.back());
  std::vector<NodeAttributes> children;
  size_t start = 0;
  for (size_t i = 1; i <= range.size(); ++i) {
    if (i < range.size() && extendedLevel(range[start], range[i]) > level) continue;
    NodeAttributes child;
    referenceBuild(range.subspan(start, i - start), m, out, &child);
    children.push_back(child);
    start = i;
  }
  InMemoryNode node;
  node.attributes = mergeAttributes(children);
  node.childCount = static_cast<uint32_t>(children.size());
  *attributes = node.attributes;
  out->push_back(std::move(node));
}

void expectSameTrees(const std::vector<InMemoryNode>& a, const std::vector<InMemoryNode>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    EXPECT_EQ(a[i].childCount, b[i].childCount) << "node " << i;
    EXPECT_EQ(a[i].surfels.size(), b[i].surfels.size()) << "node " << i;
    EXPECT_TRUE(a[i].attributes == b[i].attributes)
        << "node " << i << ": " << a[i].attributes.toString() << " vs "
        << b[i].attributes.toString();
  }
}

class TreeBuildSizes : public ::testing::TestWithParam<std::tuple<size_t, int>> {};

TEST_P(TreeBuildSizes, SweepMatchesTopDownDefinition) {
  const auto [n, m] = GetParam();
  const auto sorted = makeSorted(n, 7 + n);
  TreeBuildOptions options;
  options.leafSize = m;
  auto built = buildTreeInMemory(sorted, options);
  ASSERT_TRUE(built.ok()) << built.status();
  std::vector<InMemoryNode> expected;
  NodeAttributes root;
  referenceBuild(sorted, m, &expected, &root);
  expectSameTrees(*built, expected);
}

INSTANTIATE_TEST_SUITE_P(Sizes, TreeBuildSizes,
                         ::testing::Values(std::tuple<size_t, int>{1, 16},
                                         std::tuple<size_t, int>{16, 16},
                                         std::tuple<size_t, int>{17, 16},
                                         std::tuple<size_t, int>{1000, 1},
                                         std::tuple<size_t, int>{5000, 8},
                                         std::tuple<size_t, int>{20000, 16},
                                         std::tuple<size_t, int>{3000, 255}));

// Checks the post-order stream's shape, leaf sizes and the sums of every node, and returns
// the depth of the tree.
int checkStructure(const std::vector<InMemoryNode>& nodes, int m, size_t n) {
  struct Entry {
    NodeAttributes attributes;
    int depth;
  };
  std::vector<Entry> stack;
  size_t surfels = 0;
  for (const InMemoryNode& node : nodes) {
    if (node.childCount == 0) {
      EXPECT_GE(node.surfels.size(), 1u);
      EXPECT_LE(node.surfels.size(), static_cast<size_t>(m));
      surfels += node.surfels.size();
      stack.push_back({node.attributes, 0});
      continue;
    }
    EXPECT_GE(node.childCount, 2u);
    EXPECT_LE(node.childCount, 8u);
    EXPECT_GT(node.attributes.pointCount, static_cast<uint64_t>(m));
    EXPECT_GE(stack.size(), node.childCount);
    if (stack.size() < node.childCount) return -1;
    uint64_t points = 0;
    int depth = 0;
    for (size_t i = stack.size() - node.childCount; i < stack.size(); ++i) {
      const NodeAttributes& c = stack[i].attributes;
      points += c.pointCount;
      depth = std::max(depth, stack[i].depth + 1);
      EXPECT_LE(node.attributes.bounds.min.x, c.bounds.min.x);
      EXPECT_GE(node.attributes.bounds.max.z, c.bounds.max.z);
      // The parent's cone holds the child's axis.
      EXPECT_GE(dot(c.cone.axis, node.attributes.cone.axis), node.attributes.cone.cosAngle - 1e-5f);
    }
    EXPECT_EQ(points, node.attributes.pointCount);
    stack.resize(stack.size() - node.childCount);
    stack.push_back({node.attributes, depth});
  }
  EXPECT_EQ(stack.size(), 1u) << "exactly one root";
  EXPECT_EQ(surfels, n);
  return stack.empty() ? -1 : stack.back().depth;
}

TEST(TreeBuild, PostOrderStreamFormsOneTreeWithBoundedLeaves) {
  const auto sorted = makeSorted(30000, 3);
  std::vector<InMemoryNode> nodes;
  TreeBuildOptions options;
  options.leafSize = 16;
  TreeBuilder builder(options, [&](const BuiltNode& n) {
    nodes.push_back({n.attributes, n.childCount, {n.surfels.begin(), n.surfels.end()}});
    return absl::OkStatus();
  });
  for (const auto& p : sorted) ASSERT_TRUE(builder.add(p).ok());
  ASSERT_TRUE(builder.finish().ok());
  const int depth = checkStructure(nodes, 16, sorted.size());
  EXPECT_GT(depth, 2);
  EXPECT_LE(builder.stats().peakBufferedPoints, 17u);
  EXPECT_EQ(builder.stats().points, sorted.size());
  EXPECT_EQ(builder.stats().nodes, nodes.size());
  // The root's sums are those of all the surfels.
  const NodeAttributes& root = nodes.back().attributes;
  std::vector<Surfel> all;
  for (const auto& p : sorted) all.push_back(p.surfel);
  const NodeAttributes flat = leafAttributes(all);
  EXPECT_NEAR(root.area, flat.area, 1e-4 * flat.area);
  for (int i = 0; i < kShCoefficients; ++i) {
    EXPECT_NEAR(root.powerSh.c[i].x, flat.powerSh.c[i].x, 1e-3 * std::abs(flat.powerSh.c[0].x));
    EXPECT_NEAR(root.areaSh.c[i], flat.areaSh.c[i], 1e-3 * std::abs(flat.areaSh.c[0]));
  }
  for (const Surfel& s : all) {
    EXPECT_GE(dot(s.normal, root.cone.axis), root.cone.cosAngle - 1e-5f);
  }
}

TEST(TreeBuild, IdenticalPositionsStillSplitIntoSmallLeaves) {
  // Hostile input: every surfel in one finest cell. The sequence numbers split them.
  const auto sorted = makeSorted(20000, 5, /*allSamePosition=*/true);
  TreeBuildOptions options;
  options.leafSize = 8;
  auto nodes = buildTreeInMemory(sorted, options);
  ASSERT_TRUE(nodes.ok());
  const int depth = checkStructure(*nodes, 8, sorted.size());
  EXPECT_GT(depth, 0);
  EXPECT_LE(depth, kMaxTreeLevels);
}

TEST(TreeBuild, SinkErrorStopsTheBuildAndSticks) {
  const auto sorted = makeSorted(1000, 9);
  int calls = 0;
  TreeBuilder builder({}, [&](const BuiltNode&) {
    return ++calls == 3 ? absl::DataLossError("disk full") : absl::OkStatus();
  });
  absl::Status status;
  for (const auto& p : sorted) {
    status = builder.add(p);
    if (!status.ok()) break;
  }
  EXPECT_EQ(status.code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(builder.finish().code(), absl::StatusCode::kDataLoss);
  EXPECT_EQ(calls, 3);
}

TEST(TreeBuild, EmptyStreamEmitsNothing) {
  auto nodes = buildTreeInMemory({}, {});
  ASSERT_TRUE(nodes.ok());
  EXPECT_TRUE(nodes->empty());
}

TEST(TreeAttributes, MeanRadianceOfAUniformDiskIsItsRadiance) {
  Surfel s;
  s.normal = Vec3f(0, 0, 1);
  s.radius = 0.1f;
  s.radiance = Rgb(2.0f, 1.0f, 0.5f);
  const NodeAttributes node = leafAttributes(std::span(&s, 1));
  const Rgb seen = meanRadiance(node, Vec3f(0, 0, 1));
  // SH of order 2 reproduces the clamped cosine only approximately, but the ratio of two
  // functions of the same shape is exact.
  EXPECT_NEAR(seen.x, 2.0f, 1e-4f);
  EXPECT_NEAR(seen.z, 0.5f, 1e-4f);
  EXPECT_EQ(node.cone.cosAngle, 1.0f);
  EXPECT_NEAR(node.area, kPi * 0.01f, 1e-7f);
}

}  // namespace
}  // namespace pbgi
