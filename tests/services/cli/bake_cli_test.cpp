// `pbgi bake` and `pbgi inspect` as users run them: the real binary on the sample shot.

#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>

#include "formats/pbgi/tree_file.h"
#include "formats/vdb/surfel_vdb.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
using testing::runPbgi;
using testing::shellQuote;
using testing::slurpFile;

const fs::path kShot = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";

std::string bake(const fs::path& out, const std::string& extra, int points = 30000) {
  const testing::RunResult r =
      runPbgi("bake " + shellQuote(kShot.string()) + " --frame 2 --out " +
              shellQuote(out.string()) + " --points " + std::to_string(points) + " " + extra);
  EXPECT_EQ(r.exitCode, 0) << r.output();
  return (out / "cornell.0002.pbgi").string();
}

TEST(BakeCli, WritesATreeAndAPointCloudThatInspectAccepts) {
  const fs::path dir = testing::makeTempDir("bake-cli");
  const std::string tree = bake(dir, "");
  ASSERT_TRUE(fs::exists(tree));
  ASSERT_TRUE(fs::exists(dir / "cornell.0002.vdb"));
  auto cloud = readSurfelVdb((dir / "cornell.0002.vdb").string());
  ASSERT_TRUE(cloud.ok()) << cloud.status();
  EXPECT_EQ(cloud->size(), 30000u);
  auto file = TreeFile::open(tree);
  ASSERT_TRUE(file.ok()) << file.status();
  EXPECT_EQ((*file)->container().info().pointCount, 30000u);
  EXPECT_EQ((*file)->description().encoding, TreeEncoding::kQuantized);

  const testing::RunResult inspect = runPbgi("inspect " + shellQuote(tree));
  EXPECT_EQ(inspect.exitCode, 0) << inspect.output();
  EXPECT_NE(inspect.out.find("points 30000"), std::string::npos) << inspect.out;
  EXPECT_NE(inspect.out.find("depth histogram"), std::string::npos) << inspect.out;
  EXPECT_NE(inspect.out.find("every page's checksum verified"), std::string::npos);
  const testing::RunResult vdb = runPbgi("inspect " + shellQuote((dir / "cornell.0002.vdb").string()));
  EXPECT_EQ(vdb.exitCode, 0) << vdb.output();
  EXPECT_NE(vdb.out.find("points: 30000"), std::string::npos) << vdb.out;
}

// A scene whose glossy light the tree cannot carry yet says so, naming each material and what
// SH miss of its lobes; a diffuse scene says nothing of it.
// Progress names each stage, bounces counted out of their number, in plain lines when stderr
// is not a terminal (as here).
TEST(BakeCli, ProgressNamesItsStages) {
  const fs::path dir = testing::makeTempDir("bake-cli-progress");
  const testing::RunResult r =
      runPbgi("bake " + shellQuote(kShot.string()) + " --frame 2 --out " +
              shellQuote(dir.string()) + " --points 30000 --bounces 2");
  ASSERT_EQ(r.exitCode, 0) << r.output();
  for (const char* stage : {"bake cornell frame 2: sample and shade surfels 100%",
                            "bake cornell frame 2: bounce 1 of 2 ",
                            "bake cornell frame 2: bounce 2 of 2 ",
                            "bake cornell frame 2: merge the sorted runs and build the tree 100%"}) {
    EXPECT_NE(r.err.find(stage), std::string::npos) << stage << " not in:\n" << r.err;
  }
}

TEST(BakeCli, BakesWaveletsOnlyForScenesWithGlossyMaterials) {
  const fs::path dir = testing::makeTempDir("bake-cli-glossy");
  const fs::path plates = testing::sourceDir() / "config/scenes/glossy-plates/plates.shot.toml";
  const testing::RunResult glossy = runPbgi("bake " + shellQuote(plates.string()) + " --out " +
                                            shellQuote((dir / "plates").string()) +
                                            " --points 5000 --bounces 1");
  EXPECT_EQ(glossy.exitCode, 0) << glossy.output();
  EXPECT_NE(glossy.out.find("wavelets (glossy light): "), std::string::npos) << glossy.out;
  // pbgi inspect reports the glossy materials' wavelet BSDFs, from the shot the header names
  // (the four plates: GGX 0.01 to 0.35), and says so when that shot cannot be read any more.
  const std::string tree = (dir / "plates" / "plates.0001.pbgi").string();
  const testing::RunResult inspected = runPbgi("inspect " + shellQuote(tree));
  EXPECT_EQ(inspected.exitCode, 0) << inspected.output();
  size_t materials = 0;
  for (size_t at = inspected.out.find("  glossy material '"); at != std::string::npos;
       at = inspected.out.find("  glossy material '", at + 1)) {
    ++materials;
  }
  EXPECT_EQ(materials, 4u) << inspected.out;
  EXPECT_NE(inspected.out.find("its BSDF in wavelets keeps "), std::string::npos) << inspected.out;
  const fs::path moved = dir / "moved";
  fs::create_directories(moved);
  fs::copy_file(plates, moved / "plates.shot.toml");
  fs::copy_file(plates.parent_path() / "plates.obj", moved / "plates.obj");
  for (const auto& e : fs::directory_iterator(plates.parent_path())) {
    if (e.path().extension() == ".mtl") fs::copy_file(e.path(), moved / e.path().filename());
  }
  const testing::RunResult movedBake =
      runPbgi("bake " + shellQuote((moved / "plates.shot.toml").string()) + " --out " +
              shellQuote((moved / "bake").string()) + " --points 3000 --bounces 0");
  ASSERT_EQ(movedBake.exitCode, 0) << movedBake.output();
  fs::remove(moved / "plates.shot.toml");
  const testing::RunResult orphan =
      runPbgi("inspect " + shellQuote((moved / "bake" / "plates.0001.pbgi").string()));
  EXPECT_EQ(orphan.exitCode, 0) << orphan.output();
  EXPECT_NE(
      orphan.out.find("glossy BSDFs: not reported, the shot it was baked from cannot be read"),
      std::string::npos)
      << orphan.out;
  const testing::RunResult diffuse = runPbgi("bake " + shellQuote(kShot.string()) + " --out " +
                                             shellQuote((dir / "cornell").string()) +
                                             " --points 5000 --bounces 1");
  EXPECT_EQ(diffuse.exitCode, 0) << diffuse.output();
  EXPECT_NE(diffuse.out.find("wavelets: none"), std::string::npos) << diffuse.out;
}

// The glossy stage too: its leaves' vectors are keyed by the leaf, whatever the threads or
// the budget.
TEST(BakeCli, GlossyBakesGiveTheSameBytesForAnyThreadsAndBudget) {
  const fs::path dir = testing::makeTempDir("bake-cli-glossy-same");
  const fs::path shot =
      testing::sourceDir() / "config/scenes/glossy-cornell/glossy-cornell.shot.toml";
  std::vector<std::string> trees;
  for (const char* flags : {"--threads 1", "--threads 2", "--threads 2 --mem-budget 1M"}) {
    const fs::path out = dir / std::to_string(trees.size());
    const testing::RunResult r =
        runPbgi("bake " + shellQuote(shot.string()) + " --out " + shellQuote(out.string()) +
                " --points 8000 --point-cloud never " + flags);
    ASSERT_EQ(r.exitCode, 0) << r.output();
    EXPECT_NE(r.out.find("wavelets (glossy light): "), std::string::npos) << r.out;
    trees.push_back(slurpFile((out / "glossy-cornell.0001.pbgi").string()));
  }
  ASSERT_GT(trees[0].size(), 1000u);
  EXPECT_TRUE(trees[0] == trees[1]) << "1 and 2 threads differ";
  EXPECT_TRUE(trees[1] == trees[2]) << "in core and out of core differ";
}

TEST(BakeCli, InCoreOutOfCoreAndThreadCountsGiveTheSameBytes) {
  const fs::path dir = testing::makeTempDir("bake-cli-same");
  const std::string inCore = bake(dir / "a", "--mem-budget 1G --threads 2");
  // 1 MiB: the sort spills runs and merges them.
  const std::string outOfCore = bake(dir / "b", "--mem-budget 1M --threads 1 --point-cloud never");
  const std::string twoThreadsSmall = bake(dir / "c", "--mem-budget 1M --threads 2 --point-cloud never");
  const std::string a = slurpFile(inCore), b = slurpFile(outOfCore), c = slurpFile(twoThreadsSmall);
  ASSERT_GT(a.size(), 1000u);
  EXPECT_TRUE(a == b) << "in-core and out-of-core trees differ";
  EXPECT_TRUE(b == c) << "1 and 2 threads differ";
  EXPECT_FALSE(fs::exists(dir / "b" / "cornell.0002.vdb"));
}

TEST(BakeCli, InspectFindsADamagedPageAndExitsOne) {
  const fs::path dir = testing::makeTempDir("bake-cli-damage");
  const std::string tree = bake(dir, "--point-cloud never");
  auto file = TreeFile::open(tree);
  ASSERT_TRUE(file.ok());
  const PageEntry entry = (*file)->container().directory().back();
  file->reset();
  {
    std::fstream f(tree, std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(static_cast<std::streamoff>(entry.offset + 3));
    const char x = 0x33;
    f.write(&x, 1);
  }
  const testing::RunResult r = runPbgi("inspect " + shellQuote(tree));
  EXPECT_EQ(r.exitCode, 1) << r.output();
  EXPECT_NE(r.err.find("page"), std::string::npos) << r.err;
  EXPECT_NE(r.err.find(tree), std::string::npos) << r.err;
}

TEST(BakeCli, InspectRefusesWhatItCannotRead) {
  const fs::path dir = testing::makeTempDir("bake-cli-refuse");
  std::ofstream(dir / "notes.txt") << "hello, not a tree\n";
  testing::RunResult r = runPbgi("inspect " + shellQuote((dir / "notes.txt").string()));
  EXPECT_EQ(r.exitCode, 2) << r.output();
  EXPECT_NE(r.err.find("neither a PBGI tree"), std::string::npos) << r.err;
  r = runPbgi("inspect " + shellQuote((dir / "missing.pbgi").string()));
  EXPECT_EQ(r.exitCode, 2) << r.output();
}

TEST(BakeCli, BadFlagsAreUsageErrors) {
  const fs::path dir = testing::makeTempDir("bake-cli-flags");
  const std::string base = "bake " + shellQuote(kShot.string()) + " --out " + shellQuote(dir.string());
  testing::RunResult r = runPbgi(base + " --mem-budget lots");
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_NE(r.err.find("--mem-budget lots"), std::string::npos) << r.err;
  r = runPbgi(base + " --page-size 3000");
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_NE(r.err.find("power of two"), std::string::npos) << r.err;
  r = runPbgi(base + " --frame 40");
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_NE(r.err.find("outside the shot's frames"), std::string::npos) << r.err;
  r = runPbgi(base + " --mem-budget 100K");
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_NE(r.err.find("too small"), std::string::npos) << r.err;
  // The wavelet settings are checked whether or not the scene has glossy materials.
  r = runPbgi(base + " --wavelet-error 1.5");
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_NE(r.err.find("wavelet error 1.5"), std::string::npos) << r.err;
  r = runPbgi(base + " --wavelet-resolution 12");
  EXPECT_EQ(r.exitCode, 2);
  EXPECT_NE(r.err.find("wavelet resolution 12"), std::string::npos) << r.err;
}

}  // namespace
}  // namespace pbgi

namespace pbgi {
namespace {

// The root's outgoing power (DC of the radiant intensity, luminance) of a baked tree.
float rootPower(const std::string& path) {
  auto file = TreeFile::open(path);
  EXPECT_TRUE(file.ok()) << file.status();
  if (!file.ok()) return 0.0f;
  auto page = (*file)->page((*file)->root().page);
  EXPECT_TRUE(page.ok());
  return luminance((*page)->nodes[(*file)->root().index].attributes.powerSh.c[0]);
}

TEST(BakeCli, BouncesAddLessAndLessLight) {
  const fs::path dir = testing::makeTempDir("bake-cli-bounces");
  float power[3];
  for (int k = 0; k < 3; ++k) {
    const std::string tree = bake(
        dir / std::to_string(k),
        fmt::format("--bounces {} --bounce-quality draft --point-cloud never --no-tail", k), 8000);
    power[k] = rootPower(tree);
    // No temporary tree of an earlier bounce is left behind.
    EXPECT_EQ(testing::filesIn(dir / std::to_string(k)).size(), 1u);
  }
  // The Cornell box's walls reflect about half: each bounce adds light, less than the last.
  EXPECT_GT(power[1], power[0] * 1.1f) << power[0] << " " << power[1];
  EXPECT_GT(power[2], power[1]) << power[1] << " " << power[2];
  EXPECT_LT(power[2] - power[1], power[1] - power[0]);
  std::cout << "root power by bounces, no tail: " << power[0] << " " << power[1] << " "
            << power[2] << "\n";
}

// With the light past the last bounce estimated, one, two and three bounces make nearly the
// same tree: the estimate stands in for the bounces not baked. Without it, three bounces fall
// short by what the fourth and later would add.
TEST(BakeCli, TheTailEstimatesTheBouncesNotBaked) {
  const fs::path dir = testing::makeTempDir("bake-cli-tail");
  float withTail[4] = {};
  for (int k = 1; k <= 3; ++k) {
    withTail[k] = rootPower(bake(
        dir / std::to_string(k),
        fmt::format("--bounces {} --bounce-quality draft --point-cloud never", k), 8000));
  }
  const float withoutTail = rootPower(bake(
      dir / "notail", "--bounces 3 --bounce-quality draft --point-cloud never --no-tail", 8000));
  std::cout << "root power with the tail after 1, 2, 3 bounces: " << withTail[1] << " "
            << withTail[2] << " " << withTail[3] << "; 3 without: " << withoutTail << "\n";
  EXPECT_NEAR(withTail[2], withTail[3], 0.03f * withTail[3]);
  EXPECT_NEAR(withTail[1], withTail[3], 0.08f * withTail[3]);
  EXPECT_GT(withTail[3], withoutTail * 1.02f);
}

}  // namespace
}  // namespace pbgi

namespace pbgi {
namespace {

TEST(BakeCli, EmittersAreInTheCloudButSendNothingFromTheTree) {
  const fs::path dir = testing::makeTempDir("bake-cli-emissive");
  // A floor and a small emissive panel above it, both from one OBJ.
  std::ofstream(dir / "scene.obj") << "mtllib scene.mtl\n"
                                      "v -1 0 -1\nv 1 0 -1\nv 1 0 1\nv -1 0 1\n"
                                      "v -0.2 1 -0.2\nv 0.2 1 -0.2\nv 0.2 1 0.2\nv -0.2 1 0.2\n"
                                      "usemtl floor\nf 1 3 2\nf 1 4 3\n"
                                      "usemtl lamp\nf 5 6 7\nf 5 7 8\n";
  std::ofstream(dir / "scene.mtl") << "newmtl floor\nKd 0.5 0.5 0.5\nnewmtl lamp\nKd 0 0 0\n";
  std::ofstream(dir / "scene.shot.toml")
      << "version = 1\n[shot]\nname = \"lamp\"\nframes = [1, 1]\nresolution = [16, 16]\n"
         "output = \"out/lamp.#.exr\"\n[camera]\nposition = [0.0, 0.5, -3.0]\n"
         "look_at = [0.0, 0.5, 0.0]\nup = [0.0, 1.0, 0.0]\nfov_y_deg = 40.0\n"
         "[[geometry]]\nfile = \"scene.obj\"\n"
         "[[material]]\nname = \"floor\"\ntype = \"diffuse\"\nalbedo = [0.5, 0.5, 0.5]\n"
         "[[material]]\nname = \"lamp\"\ntype = \"emissive\"\nradiance = [5.0, 5.0, 5.0]\n"
         "[render]\nintegrator = \"path\"\nspp = 1\nseed = 0\n";
  const testing::RunResult r =
      runPbgi("bake " + shellQuote((dir / "scene.shot.toml").string()) + " --out " +
              shellQuote(dir.string()) + " --points 4000 --point-cloud always");
  ASSERT_EQ(r.exitCode, 0) << r.output();
  auto cloud = readSurfelVdb((dir / "lamp.1.vdb").string());
  ASSERT_TRUE(cloud.ok()) << cloud.status();
  size_t emissive = 0;
  for (const Surfel& s : *cloud) {
    if (s.materialClass != MaterialClass::kEmissive) continue;
    ++emissive;
    EXPECT_NEAR(s.radiance.x, 5.0f, 1e-5f);
    EXPECT_NEAR(s.backRadiance.x, 5.0f, 1e-5f);
  }
  EXPECT_GT(emissive, 0u);
  auto tree = TreeFile::open((dir / "lamp.1.pbgi").string());
  ASSERT_TRUE(tree.ok()) << tree.status();
  size_t treeEmissive = 0, litFloor = 0;
  for (uint32_t id = 0; id < (*tree)->container().info().pageCount; ++id) {
    auto page = (*tree)->page(id);
    ASSERT_TRUE(page.ok());
    for (const Surfel& s : (*page)->surfels) {
      if (s.materialClass == MaterialClass::kEmissive) {
        ++treeEmissive;
        EXPECT_EQ(s.radiance, Rgb(0.0f));
        EXPECT_EQ(s.backRadiance, Rgb(0.0f));  // emitters emit on both sides
      } else if (s.radiance.x > 0.0f) {
        ++litFloor;
      }
    }
  }
  EXPECT_EQ(treeEmissive, emissive);
  EXPECT_GT(litFloor, 0u) << "the panel lights the floor";
}

}  // namespace
}  // namespace pbgi
