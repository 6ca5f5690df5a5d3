// `pbgi check` as users run it: the real binary on the sample and on crafted bad shots.

#include <gtest/gtest.h>

#include <nlohmann/json.hpp>

#include "core/pbgi/product_gather.h"
#include "tests/support/run_pbgi.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

using testing::runPbgi;
using testing::shellQuote;

std::string shotArg(const std::string& name) {
  return shellQuote((testing::testDataDir() / "shots" / name).string());
}
// The crafted shots that parse but cannot render.
std::string checkArg(const std::string& name) {
  return shellQuote((testing::testDataDir() / "check" / name).string());
}

TEST(CheckCliTest, TheSampleChecksFrameByFrameAsTextAndJson) {
  const auto shot = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";
  const auto text = runPbgi("check " + shellQuote(shot.string()));
  ASSERT_EQ(text.exitCode, 0) << text.output();
  for (const char* line : {"frame 1: 3 meshes, 30 triangles, 1 light",
                           "frame 3:", "ok: 3 frames can render", "(exr)"}) {
    EXPECT_NE(text.out.find(line), std::string::npos) << line << "\n" << text.output();
  }
  const auto json = runPbgi("check " + shellQuote(shot.string()) + " --frames 2 --json");
  ASSERT_EQ(json.exitCode, 0) << json.output();
  const auto parsed = nlohmann::json::parse(json.out);
  EXPECT_EQ(parsed["integrator"], "pbgi");
  EXPECT_EQ(parsed["output_format"], "exr");
  EXPECT_TRUE(parsed["bakes_tree"].get<bool>());
  ASSERT_EQ(parsed["frames"].size(), 1u);
  EXPECT_EQ(parsed["frames"][0]["frame"], 2);
  EXPECT_EQ(parsed["frames"][0]["triangles"], 30);
  EXPECT_TRUE(parsed["frames"][0]["warnings"].empty());
  EXPECT_TRUE(parsed["glossy_materials"].empty()) << "the sample is diffuse";
  EXPECT_TRUE(parsed["slower_than_path_traced"].empty()) << parsed;
}

// Glossy materials whose lobes are too narrow for the wavelet product: check says that PBGI
// would render frames of them slower than the path tracer, and why, once for each of them and
// for none of those the product holds.
TEST(CheckCliTest, NarrowLobesAreSaidToRenderFasterPathTraced) {
  const auto plates = testing::sourceDir() / "config/scenes/glossy-plates/plates.shot.toml";
  const auto text = runPbgi("check " + shellQuote(plates.string()));
  ASSERT_EQ(text.exitCode, 0) << text.output();
  EXPECT_NE(text.err.find("pbgi: note: glossy material"), std::string::npos) << text.output();
  EXPECT_NE(text.err.find("--integrator path"), std::string::npos) << text.output();
  const auto json = runPbgi("check " + shellQuote(plates.string()) + " --json");
  ASSERT_EQ(json.exitCode, 0) << json.output();
  const auto parsed = nlohmann::json::parse(json.out);
  size_t narrow = 0;
  for (const auto& g : parsed["glossy_materials"]) {
    narrow += g["lobe_texels"][0].get<double>() < kMinProductLobeTexels ? 1 : 0;
  }
  EXPECT_GT(narrow, 0u) << parsed;
  EXPECT_LT(narrow, parsed["glossy_materials"].size()) << parsed;
  EXPECT_EQ(parsed["slower_than_path_traced"].size(), narrow) << parsed;
}

// A glossy shot's materials as the wavelet product would reflect with them: their BSDFs'
// coefficients kept, and the error dropped, within the default 1 %; and which gather takes
// them: the GGX 0.05 block's lobe is too narrow for the product's cube (6 to 14 texels over
// the bins when written), the GGX 0.25 block's spans more than 100 at some views (67 to 171).
TEST(CheckCliTest, GlossyMaterialsReportTheirWaveletBsdfs) {
  const auto shot = testing::sourceDir() / "config/scenes/glossy-cornell/glossy-cornell.shot.toml";
  const auto r = runPbgi("check " + shellQuote(shot.string()) + " --frames 1 --json");
  ASSERT_EQ(r.exitCode, 0) << r.output();
  const auto parsed = nlohmann::json::parse(r.out);
  ASSERT_EQ(parsed["glossy_materials"].size(), 2u) << r.out;
  for (const auto& g : parsed["glossy_materials"]) {
    EXPECT_GT(g["wavelet_bsdf_coefficients"].get<size_t>(), 0u) << g;
    EXPECT_LT(g["wavelet_bsdf_coefficients"].get<size_t>(),
              g["wavelet_bsdf_dense_coefficients"].get<size_t>() / 2)
        << g;
    EXPECT_GT(g["wavelet_bsdf_error"].get<double>(), 0.0) << g;
    EXPECT_LE(g["wavelet_bsdf_error"].get<double>(), 0.01 + 1e-6) << g;
    const double least = g["lobe_texels"][0].get<double>(),
                 most = g["lobe_texels"][1].get<double>();
    EXPECT_LE(least, most) << g;
    if (g["roughness"].get<double>() < 0.1) {
      EXPECT_LT(most, kMinProductLobeTexels) << g;
      EXPECT_EQ(g["glossy_gather"], "adaptive") << g;
    } else {
      EXPECT_GE(most, kMinProductLobeTexels) << g;
      EXPECT_NE(g["glossy_gather"], "adaptive") << g;
    }
  }
}

// What the shot file parses but a frame cannot load: the geometry's own file and line.
TEST(CheckCliTest, GeometryThatDoesNotParseIsRefusedNamingTheFile) {
  const auto r = runPbgi("check " + checkArg("unparsable_geometry.toml"));
  EXPECT_EQ(r.exitCode, 2) << r.output();
  EXPECT_NE(r.err.find("unparsable_geometry.toml frame 1"), std::string::npos) << r.output();
  EXPECT_NE(r.err.find("bad_face_index.obj"), std::string::npos) << r.output();
  EXPECT_EQ(r.out.find("ok:"), std::string::npos) << r.output();
}

TEST(CheckCliTest, AMissingTextureAnUnknownOutputAndAFrameOutsideTheShotAreRefused) {
  const auto texture = runPbgi("check " + shotArg("missing_albedo_texture.toml"));
  EXPECT_EQ(texture.exitCode, 2) << texture.output();
  EXPECT_NE(texture.err.find("nowhere.png"), std::string::npos) << texture.output();
  const auto output = runPbgi("check " + checkArg("unknown_output_format.toml"));
  EXPECT_EQ(output.exitCode, 2) << output.output();
  EXPECT_NE(output.err.find("unknown image format '.bmp'"), std::string::npos) << output.output();
  const auto frame = runPbgi("check " + shotArg("minimal.shot.toml") + " --frames 8");
  EXPECT_EQ(frame.exitCode, 2) << frame.output();
  EXPECT_NE(frame.err.find("frame 8 is outside the shot's frames [7, 7]"), std::string::npos)
      << frame.output();
}

// A shot that loads but has nothing that emits renders black: said, not refused.
TEST(CheckCliTest, AShotWithNoLightIsWarnedOf) {
  const auto r = runPbgi("check " + shotArg("minimal.shot.toml"));
  EXPECT_EQ(r.exitCode, 0) << r.output();
  EXPECT_NE(r.err.find("warning: frame 7: nothing emits light"), std::string::npos) << r.output();
}

}  // namespace
}  // namespace pbgi
