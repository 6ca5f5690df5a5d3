// `pbgi render` as users run it: the real binary, real files, exit codes per the CLI spec.

#include <gtest/gtest.h>

#include <array>
#include <cstdio>
#include <cstring>
#include <fstream>

#include <fmt/format.h>
#include <nlohmann/json.hpp>

#include "formats/image/image_io.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

using testing::runPbgi;
using Result = testing::RunResult;

TEST(RenderCliTest, RendersTheSampleShotWithMetadataAndPreview) {
  const auto dir = testing::makeTempDir("render-cli");
  const auto out = dir / "frame.exr";
  const auto shot = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";
  const Result r = runPbgi(shot.string() + " --frame 2 --spp 2 --threads 2 --out " + out.string());
  // The subcommand name goes first.
  EXPECT_EQ(r.exitCode, 2) << r.output();
  // The sample renders with PBGI: its bake, smaller (the sample's 250,000 surfels take half a
  // minute), lands beside the frame.
  const Result ok =
      runPbgi("render " + shot.string() +
              " --frame 2 --spp 2 --threads 2 --set bake_points=20000 --out " + out.string());
  ASSERT_EQ(ok.exitCode, 0) << ok.output();
  EXPECT_NE(ok.output().find("render"), std::string::npos);
  EXPECT_NE(ok.output().find("wall time"), std::string::npos);
  auto image = readImage(out.string());
  ASSERT_TRUE(image.ok()) << image.status();
  EXPECT_EQ(image->width(), 256);
  EXPECT_GE(image->channelIndex("indirect.B"), 0);
  bool sawFrame = false;
  for (const auto& m : image->metadata()) {
    if (m.name == "pbgi/frame") sawFrame = std::get<int>(m.value) == 2;
  }
  EXPECT_TRUE(sawFrame);
  EXPECT_TRUE(std::filesystem::exists(dir / "frame.png"));
  std::filesystem::remove_all(dir);
}

// --out names the format; the preview never takes the output's place; an unknown extension
// is refused before the render, naming what is known.
TEST(RenderCliTest, TheOutputsExtensionChoosesItsFormatAndThePreviewNeverOverwritesIt) {
  const auto dir = testing::makeTempDir("render-cli");
  const auto shot = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";
  const std::string args = "render " + shot.string() + " --integrator path --spp 1 --threads 2 ";
  const Result png = runPbgi(args + "--out " + (dir / "x.png").string());
  ASSERT_EQ(png.exitCode, 0) << png.output();
  EXPECT_NE(png.output().find("8-bit"), std::string::npos) << png.output();
  std::ifstream f(dir / "x.png", std::ios::binary);
  std::string head(4, '\0');
  f.read(head.data(), 4);
  EXPECT_EQ(head, "\x89PNG");
  auto read = readImage((dir / "x.png").string());
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->channelCount(), 3);

  const Result tif = runPbgi(args + "--out " + (dir / "z.tif").string());
  ASSERT_EQ(tif.exitCode, 0) << tif.output();
  auto tiff = readImage((dir / "z.tif").string());
  ASSERT_TRUE(tiff.ok()) << tiff.status();
  EXPECT_TRUE(std::filesystem::exists(dir / "z.png")) << "the preview beside it";

  const Result bad = runPbgi(args + "--out " + (dir / "w.xyz").string());
  EXPECT_EQ(bad.exitCode, 2) << bad.output();
  EXPECT_NE(bad.output().find("unknown image format '.xyz'"), std::string::npos) << bad.output();
  EXPECT_EQ(bad.output().find("render sponza"), std::string::npos);
  EXPECT_FALSE(std::filesystem::exists(dir / "w.xyz"));
  std::filesystem::remove_all(dir);
}

// --resolution and --scale size each view without editing the shot; --seed picks the
// samples: the same seed the same bits, another seed other noise.
TEST(RenderCliTest, ResolutionScaleAndSeedFlagsShapeTheRender) {
  const auto dir = testing::makeTempDir("render-cli");
  const auto shot = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";
  const std::string args = "render " + shot.string() + " --integrator path --spp 1 --threads 2 ";
  const auto render = [&](const std::string& name, const std::string& flags) {
    const Result r = runPbgi(args + flags + " --out " + (dir / name).string());
    EXPECT_EQ(r.exitCode, 0) << r.output();
    auto image = readImage((dir / name).string());
    EXPECT_TRUE(image.ok()) << image.status();
    return image.ok() ? *image : Image();
  };
  const Image a = render("a.exr", "--resolution 40,30 --seed 7");
  EXPECT_EQ(a.width(), 40);
  EXPECT_EQ(a.height(), 30);
  const Image same = render("b.exr", "--resolution 40,30 --seed 7");
  const Image other = render("c.exr", "--resolution 40,30 --seed 8");
  ASSERT_EQ(same.pixels().size(), a.pixels().size());
  EXPECT_EQ(std::memcmp(same.pixels().data(), a.pixels().data(), a.pixels().size() * 4), 0);
  ASSERT_EQ(other.pixels().size(), a.pixels().size());
  EXPECT_NE(std::memcmp(other.pixels().data(), a.pixels().data(), a.pixels().size() * 4), 0);
  const Image quarter = render("q.exr", "--scale 0.25");
  EXPECT_EQ(quarter.width(), 64);  // the sample is 256 x 256
  EXPECT_EQ(quarter.height(), 64);
  const Result both = runPbgi(args + "--scale 0.5 --resolution 4,4");
  EXPECT_EQ(both.exitCode, 2) << both.output();
  const Result bad = runPbgi(args + "--resolution 40");
  EXPECT_EQ(bad.exitCode, 2) << bad.output();
  EXPECT_NE(bad.err.find("expected W,H"), std::string::npos) << bad.err;
  // A side of 0 (or less) is refused, not taken as "the shot's".
  const Result zero = runPbgi(args + "--resolution 0,30");
  EXPECT_EQ(zero.exitCode, 2) << zero.output();
  EXPECT_NE(zero.err.find("each side must be from 1 to"), std::string::npos) << zero.err;
  std::filesystem::remove_all(dir);
}

// The EXR header's compression attribute (OpenEXR's enum: 3 ZIP, 4 PIZ), read from the bytes.
int exrCompressionByte(const std::filesystem::path& path) {
  const std::string bytes = testing::slurpFile(path);
  const std::string key("compression\0compression\0", 24);
  const size_t at = bytes.find(key);
  if (at == std::string::npos || at + key.size() + 5 > bytes.size()) return -1;
  return static_cast<unsigned char>(bytes[at + key.size() + 4]);
}

// --frames renders a list of frames into a #### pattern; --aovs chooses the layers the EXR
// keeps; --exr-compression its compression; --json the statistics, one object per frame.
TEST(RenderCliTest, FramesAovsCompressionAndJsonStatistics) {
  const auto dir = testing::makeTempDir("render-frames");
  const auto shot = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";
  const std::string common = "render " + shot.string() +
                             " --integrator path --spp 1 --scale 0.125 --threads 2 --no-preview";
  const Result r = runPbgi(common + " --frames 1-2 --aovs albedo,depth --exr-compression piz " +
                           "--json --out " + (dir / "f.####.exr").string());
  ASSERT_EQ(r.exitCode, 0) << r.output();
  const auto json = nlohmann::json::parse(r.out);
  ASSERT_EQ(json["frames"].size(), 2u) << r.out;
  for (int i = 0; i < 2; ++i) {
    const auto& f = json["frames"][i];
    EXPECT_EQ(f["frame"], i + 1);
    EXPECT_EQ(f["image"], (dir / fmt::format("f.{:04d}.exr", i + 1)).string());
    EXPECT_EQ(f["samples"], 32 * 32);
    EXPECT_TRUE(f["stages"].contains("render")) << f;
    EXPECT_TRUE(f["tree"].is_null()) << "the path tracer reads no tree";
    EXPECT_TRUE(f["preview"].is_null());
    auto image = readImage(f["image"].get<std::string>());
    ASSERT_TRUE(image.ok()) << image.status();
    EXPECT_EQ(image->channels(), (std::vector<std::string>{"R", "G", "B", "A", "albedo.R",
                                                           "albedo.G", "albedo.B", "depth.Z"}));
    EXPECT_EQ(exrCompressionByte(f["image"].get<std::string>()), 4) << "PIZ";
  }
  const Result plain = runPbgi(common + " --aovs none --out " + (dir / "plain.exr").string());
  ASSERT_EQ(plain.exitCode, 0) << plain.output();
  auto image = readImage((dir / "plain.exr").string());
  ASSERT_TRUE(image.ok()) << image.status();
  EXPECT_EQ(image->channelCount(), 4);
  EXPECT_EQ(exrCompressionByte(dir / "plain.exr"), 3) << "ZIP by default";
  // Refused before anything renders, naming the flag.
  for (const auto& [flags, says] : std::vector<std::pair<std::string, std::string>>{
           {"--frames 1-2 --out " + (dir / "one.exr").string(), "put #### in it"},
           {"--aovs albedo,specular", "--aovs albedo,specular: AOV 'specular'"},
           {"--exr-compression lzma", "--exr-compression 'lzma'"},
           {"--frames 1-9", "frame 4 is outside the shot's frames [1, 3]"}}) {
    const Result bad = runPbgi(common + " " + flags);
    EXPECT_EQ(bad.exitCode, 2) << flags << "\n" << bad.output();
    EXPECT_NE(bad.err.find(says), std::string::npos) << flags << "\n" << bad.output();
  }
  std::filesystem::remove_all(dir);
}

TEST(RenderCliTest, BadInputExitsTwoWithFileAndLine) {
  const auto dir = testing::makeTempDir("render-cli-bad");
  const auto shot = dir / "bad.toml";
  std::ofstream(shot) << "version = 1\n[shot]\nname = \"x\"\nframes = [1, 1]\nresolution = [8, 8]\n"
                         "output = \"o.exr\"\nbogus = 3\n";
  const Result r = runPbgi("render " + shot.string());
  EXPECT_EQ(r.exitCode, 2) << r.output();
  EXPECT_NE(r.output().find("pbgi: error: "), std::string::npos) << r.output();
  EXPECT_NE(r.output().find("bad.toml:7"), std::string::npos) << r.output();
  const Result missing = runPbgi("render " + (dir / "nope.toml").string());
  EXPECT_EQ(missing.exitCode, 2) << missing.output();
  const Result frame = runPbgi(
      "render " + (testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml").string() +
      " --frame 9");
  EXPECT_EQ(frame.exitCode, 2) << frame.output();
  EXPECT_NE(frame.output().find("outside"), std::string::npos) << frame.output();
  const Result integrator = runPbgi(
      "render " + (testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml").string() +
      " --integrator nonsense");
  EXPECT_EQ(integrator.exitCode, 2) << integrator.output();
  // A range error in words, not CLI11's "in range 2.22507e-308 to 1.79769e+308".
  const Result spp = runPbgi(
      "render " + (testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml").string() +
      " --spp 0");
  EXPECT_EQ(spp.exitCode, 2) << spp.output();
  EXPECT_NE(spp.output().find("expected a number above 0, found 0"), std::string::npos)
      << spp.output();
  EXPECT_EQ(spp.output().find("e+308"), std::string::npos) << spp.output();
  // Global flags after the subcommand too; -q keeps the progress off stderr.
  const Result quiet = runPbgi(
      "render " + (testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml").string() +
      " --integrator path --spp 1 --out " + (dir / "q.exr").string() + " -q");
  EXPECT_EQ(quiet.exitCode, 0) << quiet.output();
  EXPECT_EQ(quiet.err.find("tiles"), std::string::npos) << quiet.err;
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace pbgi

namespace pbgi {
namespace {

TEST(RenderCliTest, AnEditedMeshIsBakedAgainAndAnUntouchedOneReused) {
  const auto dir = testing::makeTempDir("render-rebake");
  const auto sample = testing::sourceDir() / "config/scenes/cornell";
  std::filesystem::copy_file(sample / "cornell_box.obj", dir / "cornell_box.obj");
  const std::string shot = testing::slurpFile(sample / "cornell.shot.toml");
  const std::filesystem::path shotPath = dir / "cornell.shot.toml";
  std::ofstream(shotPath) << shot;
  const std::string args = "render " + shotPath.string() +
                           " --frame 1 --spp 1 --threads 2 --set bake_points=2000 --out " +
                           (dir / "f.exr").string();
  const Result first = runPbgi(args);
  ASSERT_EQ(first.exitCode, 0) << first.output();
  EXPECT_NE(first.out.find("(baked now)"), std::string::npos) << first.out;
  const Result again = runPbgi(args);
  ASSERT_EQ(again.exitCode, 0) << again.output();
  EXPECT_NE(again.out.find("(reused)"), std::string::npos) << again.out;
  // The mesh changes (a comment is enough to say so): the tree is not the scene's any more.
  std::ofstream(dir / "cornell_box.obj", std::ios::app) << "\n# edited\n";
  const Result edited = runPbgi(args);
  ASSERT_EQ(edited.exitCode, 0) << edited.output();
  EXPECT_NE(edited.out.find("(baked now)"), std::string::npos) << edited.out;
  std::filesystem::remove_all(dir);
}

// The same for what the mesh names: a material library of another name than the OBJ's and a
// texture that library names. Either edited, the frame is baked again.
TEST(RenderCliTest, AnEditedMaterialLibraryOrTextureIsBakedAgain) {
  const auto dir = testing::makeTempDir("render-rebake-mtl");
  const auto sample = testing::sourceDir() / "config/scenes/cornell";
  std::string obj = testing::slurpFile(sample / "cornell_box.obj");
  const size_t at = obj.find("mtllib cornell_box.mtl");
  ASSERT_NE(at, std::string::npos);
  obj.replace(at, std::string("mtllib cornell_box.mtl").size(), "mtllib looks.mtl");
  std::ofstream(dir / "cornell_box.obj") << obj;
  std::ofstream(dir / "looks.mtl") << testing::slurpFile(sample / "cornell_box.mtl")
                                   << "\nnewmtl extra\nKd 0.5 0.5 0.5\nmap_Kd -s 1 1 1 wall.exr\n";
  const auto writeTexture = [&](float value) {
    Image texture(2, 2, {"R", "G", "B"});
    for (float& v : texture.pixels()) v = value;
    ASSERT_TRUE(writeExr(texture, (dir / "wall.exr").string()).ok());
  };
  writeTexture(0.5f);
  std::ofstream(dir / "cornell.shot.toml") << testing::slurpFile(sample / "cornell.shot.toml");
  const std::string args = "render " + (dir / "cornell.shot.toml").string() +
                           " --frame 1 --spp 1 --threads 2 --set bake_points=2000 --out " +
                           (dir / "f.exr").string();
  const auto bakedNow = [&] {
    const Result r = runPbgi(args);
    EXPECT_EQ(r.exitCode, 0) << r.output();
    return r.out.find("(baked now)") != std::string::npos;
  };
  EXPECT_TRUE(bakedNow());
  EXPECT_FALSE(bakedNow()) << "nothing changed: the tree is reused";
  writeTexture(0.25f);
  EXPECT_TRUE(bakedNow()) << "the texture changed";
  std::ofstream(dir / "looks.mtl", std::ios::app) << "# edited\n";
  EXPECT_TRUE(bakedNow()) << "the material library changed";
  EXPECT_FALSE(bakedNow());
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace pbgi

namespace pbgi {
namespace {

// --crop: the EXR holds the region as its data window inside the full frame's display
// window, and its pixels are the full render's there, bit for bit; a window the frame cannot
// hold, or an empty or malformed one, is refused before anything renders.
TEST(RenderCliTest, ACropIsTheFullRendersPixelsInADataWindow) {
  const auto dir = testing::makeTempDir("render-crop");
  const auto shot = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";
  const std::string common = "render " + shot.string() +
                             " --spp 2 --threads 2 --no-preview --set bake_points=5000 " +
                             "--bake-dir " + (dir / "bake").string() + " --out ";
  // Both integrators: the path tracer's tiles and the cut's fixed blocks (a crop renders the
  // blocks it touches and keeps its own pixels).
  for (const std::string integrator : {"path", "pbgi"}) {
    const std::string args = common + (dir / "X.exr").string() + " --integrator " + integrator;
    const auto run = [&](const std::string& name, const std::string& extra) {
      std::string a = args;
      a.replace(a.find("X.exr"), 5, name);
      return runPbgi(a + extra);
    };
    const Result full = run("full.exr", "");
    ASSERT_EQ(full.exitCode, 0) << full.output();
    const Result crop = run("crop.exr", " --crop 37,101,131,180");
    ASSERT_EQ(crop.exitCode, 0) << crop.output();
    auto a = readImage((dir / "full.exr").string());
    auto b = readImage((dir / "crop.exr").string());
    ASSERT_TRUE(a.ok()) << a.status();
    ASSERT_TRUE(b.ok()) << b.status();
    ASSERT_EQ(b->width(), 94);
    ASSERT_EQ(b->height(), 79);
    const ImageWindow w = b->window();
    EXPECT_EQ(w.x, 37);
    EXPECT_EQ(w.y, 101);
    EXPECT_EQ(w.fullWidth, 256);
    EXPECT_EQ(w.fullHeight, 256);
    ASSERT_EQ(a->channelCount(), b->channelCount());
    for (int y = 0; y < b->height(); ++y)
      for (int x = 0; x < b->width(); ++x)
        for (int c = 0; c < b->channelCount(); ++c)
          ASSERT_EQ(b->at(x, y, c), a->at(x + 37, y + 101, c))
              << integrator << ": " << x << ", " << y << ", channel " << c;
  }

  for (const std::string bad :
       {"0,0,257,10", "10,10,10,20", "-1,0,5,5", "1,2,3", "1,2,3,4x", "a"}) {
    const Result r =
        runPbgi(common + (dir / "bad.exr").string() + " --integrator path --crop " + bad);
    EXPECT_EQ(r.exitCode, 2) << bad << ": " << r.output();
    EXPECT_NE(r.output().find("--crop"), std::string::npos) << r.output();
    EXPECT_FALSE(std::filesystem::exists(dir / "bad.exr")) << bad;
  }
  std::filesystem::remove_all(dir);
}

}  // namespace
}  // namespace pbgi
