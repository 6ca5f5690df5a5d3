#include "formats/pbgi/tree_file.h"

#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <memory>

#include "core/util/bytes.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/surfel_clouds.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

TreeFileWriteOptions smallTree(TreeEncoding encoding) {
  TreeFileWriteOptions o;
  o.tree.encoding = encoding;
  o.tree.pageSize = 4096;
  o.tree.build.leafSize = 8;
  o.tree.powerCentres = 32;
  o.tree.areaCentres = 8;
  o.sceneBounds.extend(Vec3f(-1.0f));
  o.sceneBounds.extend(Vec3f(1.0f));
  o.bakeInfo = {{"shot", "test"}, {"frame", "7"}};
  return o;
}

absl::StatusOr<TreeWriteResult> writeTree(const std::string& path, const TreeFileWriteOptions& o,
                                          size_t points = 5000) {
  auto writer = TreeFileWriter::create(path, o);
  if (!writer.ok()) return writer.status();
  for (const SortedSurfel& p : testing::makeSorted(points, 21)) {
    if (auto s = (*writer)->add(p); !s.ok()) return s;
  }
  return (*writer)->finish();
}

TEST(TreeFile, WritesAndReadsBackEveryEncoding) {
  const fs::path dir = testing::makeTempDir("tree-file");
  for (TreeEncoding e : {TreeEncoding::kFloat, TreeEncoding::kQuantized, TreeEncoding::kQuantized8}) {
    const std::string path = (dir / fmt::format("{}.pbgi", treeEncodingName(e))).string();
    auto written = writeTree(path, smallTree(e));
    ASSERT_TRUE(written.ok()) << written.status();
    auto file = TreeFile::open(path);
    ASSERT_TRUE(file.ok()) << file.status();
    EXPECT_EQ((*file)->description().encoding, e);
    EXPECT_EQ((*file)->description().leafSize, 8);
    EXPECT_EQ((*file)->root(), written->root);
    EXPECT_EQ((*file)->container().info().nodeCount, written->build.nodes);
    EXPECT_EQ((*file)->container().info().pageCount, written->pages.pages);
    ASSERT_EQ((*file)->bakeInfo().size(), 2u);
    EXPECT_EQ((*file)->bakeInfo()[1].second, "7");
    auto root = (*file)->page(written->root.page);
    ASSERT_TRUE(root.ok()) << root.status();
    const NodeAttributes& a = (*root)->nodes[written->root.index].attributes;
    EXPECT_EQ(a.pointCount, 5000u);
    EXPECT_EQ(a.powerSh.c[0], written->rootAttributes.powerSh.c[0]);
  }
}

TEST(TreeFile, DamagedPageFailsWithFileAndPage) {
  const fs::path dir = testing::makeTempDir("tree-file-damage");
  const std::string path = (dir / "t.pbgi").string();
  ASSERT_TRUE(writeTree(path, smallTree(TreeEncoding::kQuantized)).ok());
  {
    auto file = TreeFile::open(path);
    ASSERT_TRUE(file.ok());
    const PageEntry& e = (*file)->container().directory()[1];
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(static_cast<std::streamoff>(e.offset + e.compressedSize / 2));
    const char x = 0x5a;
    f.write(&x, 1);
  }
  auto file = TreeFile::open(path);
  ASSERT_TRUE(file.ok());
  auto page = (*file)->page(1);
  EXPECT_EQ(page.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(page.status().message().find("page 1"), std::string::npos) << page.status();
  EXPECT_NE(page.status().message().find(path), std::string::npos) << page.status();
  EXPECT_TRUE((*file)->page(0).ok());
}

// ---- Crafted files: valid containers whose tree content is wrong ----------------------------
//
// Made by the code below; PBGI_REGENERATE_TEST_DATA=1 rewrites them into tests/data/pbgi_tree.

std::vector<uint8_t> text(const std::string& s) { return {s.begin(), s.end()}; }

std::string treeSection(const std::string& version, const std::string& encoding) {
  return fmt::format(
      "payload_version = {}\nencoding = {}\nleaf_size = 8\nexact_from_points = 0\nnodes = 3\n"
      "leaves = 1\npoints = 1\npower_codebook_entries = 0\narea_codebook_entries = 0\n",
      version, encoding);
}

// A float page of `nodes` interior nodes, each with the given children.
std::vector<uint8_t> floatPage(uint32_t id, const std::vector<std::vector<NodeRef>>& children) {
  std::vector<PageNode> nodes;
  for (const auto& c : children) {
    PageNode n;
    n.attributes.bounds.extend(Vec3f(0.0f));
    n.attributes.bounds.extend(Vec3f(1.0f));
    n.attributes.pointCount = 1;
    n.children = c;
    if (c.empty()) {
      Surfel s;
      s.radius = 0.1f;
      n.surfels.push_back(s);
    }
    nodes.push_back(n);
  }
  return encodeTreePage(id, TreeEncoding::kFloat, nodes, nullptr);
}

// A one-leaf float page whose leaf has a wavelet vector (a lobe on a 4-texel cube), with
// `damage` applied to the bytes of its wavelet section (which starts at the offset given).
std::vector<uint8_t> waveletPage(const std::function<void(std::vector<uint8_t>&, size_t)>& damage) {
  PageNode n;
  n.attributes.bounds.extend(Vec3f(0.0f));
  n.attributes.bounds.extend(Vec3f(1.0f));
  n.attributes.pointCount = 1;
  Surfel s;
  s.radius = 0.1f;
  s.materialClass = MaterialClass::kGlossy;
  n.surfels.push_back(s);
  n.wavelet = std::make_shared<const WaveletRadiance>(WaveletRadiance::project(
      [](const Vec3f& d) { return Rgb(std::exp(8.0f * (normalize(d).z - 1.0f))); }, 4, 0.0f));
  const std::vector<PageNode> nodes{n};
  std::vector<uint8_t> bytes = encodeTreePage(0, TreeEncoding::kFloat, nodes, nullptr);
  damage(bytes, treePageBytes(TreeEncoding::kFloat, 1, 0, 1, 0));
  return bytes;
}

void writeCrafted(const std::string& path, const std::vector<std::vector<uint8_t>>& pages,
                  const std::vector<PageFileSection>& sections) {
  auto writer = PageFileWriter::create(path, {.pageSize = 4096});
  ASSERT_TRUE(writer.ok());
  for (const auto& p : pages) ASSERT_TRUE(writer->appendPage(p).ok());
  PageFileMetadata meta;
  meta.nodeCount = 3;
  meta.leafCount = 1;
  meta.pointCount = 1;
  meta.sections = sections;
  ASSERT_TRUE(writer->finish(meta).ok());
}

struct Crafted {
  std::string name;
  int exitCode;
  std::string message;
};

const std::vector<Crafted>& craftedTrees() {
  static const std::vector<Crafted> files = {
      {"future_payload.pbgi", 2, "tree payload version 99, this build reads version 3"},
      {"old_payload.pbgi", 2,
       "tree payload version 1, this build reads version 3: the tree was written by an older "
       "pbgi (one-sided surfels); bake it again"},
      {"ghostless_payload.pbgi", 2,
       "tree payload version 2, this build reads version 3: the tree was written by an older "
       "pbgi (pages without ghosts); bake it again"},
      {"no_tree_section.pbgi", 1, "no \"tree\" section"},
      {"unknown_encoding.pbgi", 1, "encoding \"fancy\""},
      {"reference_loop.pbgi", 1, "the file's references loop"},
      {"reference_to_nowhere.pbgi", 1, "reference to node 9 of page 1"},
      {"quantized_without_codebooks.pbgi", 1, "quantized tree without a \"codebook.power\""},
      {"wavelet_future_section.pbgi", 1,
       "page 0: wavelet section: version 9, this build reads version 1"},
      {"wavelet_nan_scaling.pbgi", 1, "wavelet section: entry 0 (node 0): wavelet face 0: scaling "
                                       "not finite"},
  };
  return files;
}

// Seeds for tests/fuzz/tree_page_fuzz.cpp: pages of small trees in every encoding.
void makeFuzzSeeds(const fs::path& dir) {
  fs::create_directories(dir);
  for (TreeEncoding e : {TreeEncoding::kFloat, TreeEncoding::kQuantized, TreeEncoding::kQuantized8}) {
    TreeWriteOptions o = smallTree(e).tree;
    o.exactNodes = 3;
    auto tree = buildMemoryTree(testing::makeSorted(600, 23), o);
    ASSERT_TRUE(tree.ok());
    const auto& pages = (*tree)->payloads();
    for (size_t i = 0; i < std::min<size_t>(pages.size(), 3); ++i) {
      std::ofstream(dir / fmt::format("{}_{}.page", treeEncodingName(e), i), std::ios::binary)
          .write(reinterpret_cast<const char*>(pages[i].data()),
                 static_cast<std::streamsize>(pages[i].size()));
    }
  }
}

void makeCraftedTrees(const fs::path& dir) {
  makeFuzzSeeds(dir / "fuzz_corpus");
  {
    const std::vector<uint8_t> page = waveletPage([](std::vector<uint8_t>&, size_t) {});
    std::ofstream(dir / "fuzz_corpus" / "float_wavelets.page", std::ios::binary)
        .write(reinterpret_cast<const char*>(page.data()), static_cast<std::streamsize>(page.size()));
  }
  const std::vector<uint8_t> leafPage = floatPage(0, {{}});
  writeCrafted((dir / "future_payload.pbgi").string(), {leafPage},
               {{"tree", text(treeSection("99", "float"))}});
  writeCrafted((dir / "old_payload.pbgi").string(), {leafPage},
               {{"tree", text(treeSection("1", "float"))}});
  writeCrafted((dir / "ghostless_payload.pbgi").string(), {leafPage},
               {{"tree", text(treeSection("2", "float"))}});
  const std::string version = std::to_string(kTreePayloadVersion);
  writeCrafted((dir / "no_tree_section.pbgi").string(), {leafPage}, {{"bake", text("a = b\n")}});
  writeCrafted((dir / "unknown_encoding.pbgi").string(), {leafPage},
               {{"tree", text(treeSection(version, "fancy"))}});
  // Page 0's node 0 has page 1's node 0 as child, which has page 0's node 0 as child.
  writeCrafted((dir / "reference_loop.pbgi").string(),
               {floatPage(0, {{NodeRef{1, 0}, NodeRef{0, 1}}, {}}),
                floatPage(1, {{NodeRef{0, 0}, NodeRef{1, 1}}, {}})},
               {{"tree", text(treeSection(version, "float"))}});
  writeCrafted((dir / "reference_to_nowhere.pbgi").string(),
               {floatPage(0, {{NodeRef{0, 1}, NodeRef{1, 9}}, {}}), floatPage(1, {{}})},
               {{"tree", text(treeSection(version, "float"))}});
  writeCrafted((dir / "quantized_without_codebooks.pbgi").string(), {leafPage},
               {{"tree", text(treeSection(version, "quantized"))}});
  writeCrafted((dir / "wavelet_future_section.pbgi").string(),
               {waveletPage([](std::vector<uint8_t>& b, size_t section) { b[section + 4] = 9; })},
               {{"tree", text(treeSection(version, "float"))}});
  writeCrafted((dir / "wavelet_nan_scaling.pbgi").string(),
               {waveletPage([](std::vector<uint8_t>& b, size_t section) {
                 storeU32(b.data() + section + 20, 0x7fc00000u);  // face 0's red scaling
               })},
               {{"tree", text(treeSection(version, "float"))}});
}

TEST(TreeFileCrafted, EachBadFileIsRefusedWithItsReason) {
  const fs::path data = testing::testDataDir() / "pbgi_tree";
  if (std::getenv("PBGI_REGENERATE_TEST_DATA") != nullptr) makeCraftedTrees(data);
  for (const Crafted& c : craftedTrees()) {
    const fs::path path = data / c.name;
    ASSERT_TRUE(fs::exists(path)) << path;
    const testing::RunResult r = testing::runPbgi("inspect " + testing::shellQuote(path.string()));
    EXPECT_EQ(r.exitCode, c.exitCode) << c.name << "\n" << r.output();
    EXPECT_NE(r.err.find(c.message), std::string::npos) << c.name << "\n" << r.output();
  }
}

}  // namespace
}  // namespace pbgi
