#include "formats/shot/shot_file.h"

#include <absl/status/status.h>
#include <fmt/format.h>
#include <gtest/gtest.h>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <vector>

#include "core/scene/shot.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

fs::path shotsDir() { return testing::testDataDir() / "shots"; }
std::string shotPath(const std::string& name) { return (shotsDir() / name).string(); }
std::string resolved(const fs::path& p) { return p.lexically_normal().string(); }

void expectVec(const Vec3f& v, float x, float y, float z) {
  EXPECT_FLOAT_EQ(v.x, x);
  EXPECT_FLOAT_EQ(v.y, y);
  EXPECT_FLOAT_EQ(v.z, z);
}

// ---- malformed files: each breaks exactly one rule, on the line marked "<- error" ----

struct Malformed {
  const char* file;
  absl::StatusCode code;
  int line;            // where the message must point
  const char* phrase;  // what it must say
};

// gtest prints parameters on failure; the file name says which one.
void PrintTo(const Malformed& m, std::ostream* os) { *os << m.file; }

const Malformed kMalformed[] = {
    {"syntax_error.toml", absl::StatusCode::kInvalidArgument, 12, "TOML syntax error"},
    {"unknown_key_camera.toml", absl::StatusCode::kInvalidArgument, 14,
     "[camera]: unknown key 'fov' (expected one of: position, look_at, up, fov_y_deg"},
    {"unknown_table.toml", absl::StatusCode::kInvalidArgument, 19, "unknown key 'renderer'"},
    {"unknown_key_render.toml", absl::StatusCode::kInvalidArgument, 20,
     "[render]: unknown key 'samples'"},
    {"wrong_type_fov.toml", absl::StatusCode::kInvalidArgument, 14,
     "'fov_y_deg': expected a number, found string \"wide\""},
    {"float_for_int.toml", absl::StatusCode::kInvalidArgument, 20,
     "'spp': expected an integer, found float 4.0"},
    {"nan_position.toml", absl::StatusCode::kInvalidArgument, 11,
     "'position'[1]: expected a finite number, found float nan"},
    {"inf_radius.toml", absl::StatusCode::kInvalidArgument, 22,
     "'radius': expected a finite number, found float inf"},
    {"negative_fov.toml", absl::StatusCode::kInvalidArgument, 14,
     "'fov_y_deg' must be in (0, 180), found -10.0"},
    {"fov_180.toml", absl::StatusCode::kInvalidArgument, 14,
     "'fov_y_deg' must be in (0, 180), found 180"},
    {"missing_geometry_file.toml", absl::StatusCode::kNotFound, 17,
     "file \"missing.obj\" not found (resolved to "},
    {"geometry_format.toml", absl::StatusCode::kInvalidArgument, 17,
     "expected a Wavefront OBJ (.obj) or glTF 2.0 (.gltf, .glb) file, found \"tri.fbx\""},
    {"absurd_resolution.toml", absl::StatusCode::kInvalidArgument, 7,
     "'resolution'[0] must be in [1, 16384], found 1000000"},
    {"too_many_pixels.toml", absl::StatusCode::kInvalidArgument, 7,
     "'resolution' 16384 x 16384 is 268435456 pixels; at most 67108864"},
    {"up_parallel.toml", absl::StatusCode::kInvalidArgument, 13,
     "is parallel to the view direction"},
    {"position_is_look_at.toml", absl::StatusCode::kInvalidArgument, 12,
     "position and look_at coincide"},
    {"aperture_without_focus.toml", absl::StatusCode::kInvalidArgument, 15,
     "needs 'focus_distance' (> 0), which is missing"},
    {"camera_key_degenerate.toml", absl::StatusCode::kInvalidArgument, 16,
     "the camera at frame 2 is degenerate: up"},
    {"camera_key_float_frame.toml", absl::StatusCode::kInvalidArgument, 17,
     "[[camera.key]] #1: 'frame': expected an integer, found float 1.5"},
    {"camera_key_duplicate.toml", absl::StatusCode::kInvalidArgument, 21,
     "frame 2 already has a key at line 16"},
    {"camera_key_empty.toml", absl::StatusCode::kInvalidArgument, 16,
     "key at frame 2 sets nothing"},
    {"unknown_material_type.toml", absl::StatusCode::kInvalidArgument, 21,
     "unknown material type \"plastic\" (expected one of: diffuse, conductor, dielectric, "
     "emissive)"},
    {"material_foreign_key.toml", absl::StatusCode::kInvalidArgument, 23,
     "unknown key 'ior' for a conductor material: it belongs to dielectric materials"},
    {"albedo_out_of_range.toml", absl::StatusCode::kInvalidArgument, 22,
     "'albedo'[1] must be in [0, 1], found 1.2"},
    {"diffuse_both_albedos.toml", absl::StatusCode::kInvalidArgument, 23,
     "takes 'albedo' or 'albedo_texture', not both"},
    {"missing_albedo_texture.toml", absl::StatusCode::kNotFound, 22,
     "file \"textures/nowhere.png\" not found (resolved to "},
    {"conductor_both_fresnels.toml", absl::StatusCode::kInvalidArgument, 23,
     "either 'specular' or 'eta' and 'k', not both"},
    {"conductor_no_fresnel.toml", absl::StatusCode::kInvalidArgument, 19,
     "a conductor needs 'specular' = [r, g, b] or both 'eta' and 'k'"},
    {"dielectric_ior.toml", absl::StatusCode::kInvalidArgument, 22, "'ior' must be > 1, found 1"},
    {"duplicate_material.toml", absl::StatusCode::kInvalidArgument, 25,
     "material \"white\" is already defined at line 19"},
    {"unknown_light_type.toml", absl::StatusCode::kInvalidArgument, 20,
     "unknown light type \"area\" (expected one of: quad, sphere, point, spot, directional, "
     "environment)"},
    {"light_foreign_key.toml", absl::StatusCode::kInvalidArgument, 23,
     "unknown key 'radiance' for a point light: it belongs to quad and sphere lights (expected one "
     "of: type, position, intensity)"},
    {"light_missing_type.toml", absl::StatusCode::kInvalidArgument, 19,
     "[[light]] #1: missing required key 'type'"},
    {"degenerate_quad.toml", absl::StatusCode::kInvalidArgument, 23,
     "are parallel or zero: the quad has no area"},
    {"zero_direction.toml", absl::StatusCode::kInvalidArgument, 21,
     "'direction' must be a non-zero vector"},
    {"spot_cone.toml", absl::StatusCode::kInvalidArgument, 23,
     "'cone_deg' must be in (0, 90], found 120.0"},
    {"negative_radiance.toml", absl::StatusCode::kInvalidArgument, 24,
     "'radiance'[1] must be >= 0, found -1.0"},
    {"missing_environment_map.toml", absl::StatusCode::kNotFound, 21,
     "file \"maps/nowhere.exr\" not found (resolved to "},
    {"two_environments.toml", absl::StatusCode::kInvalidArgument, 23,
     "at most one environment light; another is at line 19"},
    {"future_version.toml", absl::StatusCode::kInvalidArgument, 2,
     "'version' 2 is newer than this build of pbgi reads (1)"},
    {"missing_version.toml", absl::StatusCode::kInvalidArgument, 1,
     "missing required key 'version'"},
    {"frames_reversed.toml", absl::StatusCode::kInvalidArgument, 6,
     "'frames' must be [first, last] with first <= last, found [5, 2]"},
    {"missing_required_key.toml", absl::StatusCode::kInvalidArgument, 10,
     "[camera]: missing required key 'up'"},
    {"missing_shot_table.toml", absl::StatusCode::kInvalidArgument, 1,
     "missing required table [shot]"},
    {"no_geometry.toml", absl::StatusCode::kInvalidArgument, 1, "missing required [[geometry]]"},
    {"geometry_not_array.toml", absl::StatusCode::kInvalidArgument, 16,
     "'geometry': expected an array of tables [[geometry]], found a table"},
    {"bad_name.toml", absl::StatusCode::kInvalidArgument, 5,
     "'name' must match [A-Za-z0-9_-]+, found \"my shot!\""},
    {"bad_filter.toml", absl::StatusCode::kInvalidArgument, 20,
     "unknown pixel filter \"mitchell\" (expected one of: box, gaussian, blackman-harris)"},
    {"zero_spp.toml", absl::StatusCode::kInvalidArgument, 20,
     "'spp' must be in [1, 1048576], found 0"},
    {"zero_filter_width.toml", absl::StatusCode::kInvalidArgument, 20,
     "'filter_width' must be in (0, 32], found 0"},
    {"small_tile.toml", absl::StatusCode::kInvalidArgument, 20,
     "'tile_size' must be in [4, 1024], found 2"},
    {"empty_integrator.toml", absl::StatusCode::kInvalidArgument, 20,
     "'integrator': unknown integrator \"\" (expected one of: path, pbgi)"},
    {"unknown_integrator.toml", absl::StatusCode::kInvalidArgument, 20,
     "'integrator': unknown integrator \"bidir\" (expected one of: path, pbgi)"},
    {"integrator_param_range.toml", absl::StatusCode::kInvalidArgument, 21,
     "'cut_block' must be in [8, 1024], found 3"},
    {"integrator_param_choice.toml", absl::StatusCode::kInvalidArgument, 21,
     "'gather': unknown value \"both\" (expected one of: bidirectional, per-pixel)"},
    {"integrator_param_conflict.toml", absl::StatusCode::kInvalidArgument, 21,
     "'light_solid_angle' 0.5 exceeds 'light_bound' 0.1"},
    {"integrator_param_type.toml", absl::StatusCode::kInvalidArgument, 21,
     "'bake_points': expected an integer"},
    {"zero_views.toml", absl::StatusCode::kInvalidArgument, 15,
     "'views'[0] must be in [1, 1024], found 0"},
    {"views_mosaic_too_big.toml", absl::StatusCode::kInvalidArgument, 15,
     "'views' 4 x 2 of 4096 x 4096 pixels make a mosaic of 134217728 pixels; at most 67108864"},
    {"geometry_scale.toml", absl::StatusCode::kInvalidArgument, 18, "'scale' must be > 0, found 0"},
    {"geometry_key_unknown.toml", absl::StatusCode::kInvalidArgument, 21,
     "[[geometry.key]] #1: unknown key 'rotate' (expected one of: frame, translate, rotate_deg, "
     "scale)"},
};

class ShotFileMalformedTest : public ::testing::TestWithParam<Malformed> {};

TEST_P(ShotFileMalformedTest, IsRejectedWithFileLineColumnAndReason) {
  const Malformed& m = GetParam();
  const std::string path = shotPath(m.file);
  const absl::StatusOr<ShotDesc> shot = loadShotFile(path);
  ASSERT_FALSE(shot.ok()) << m.file << " was accepted";
  const std::string message(shot.status().message());
  EXPECT_EQ(shot.status().code(), m.code) << message;
  // "FILE:LINE:COLUMN: " with a positive column.
  const std::string prefix = fmt::format("{}:{}:", path, m.line);
  ASSERT_EQ(message.rfind(prefix, 0), 0u)
      << "expected the message to start with " << prefix << "\n  got: " << message;
  size_t i = prefix.size();
  while (i < message.size() && std::isdigit(static_cast<unsigned char>(message[i]))) ++i;
  EXPECT_GT(i, prefix.size()) << "no column in: " << message;
  EXPECT_EQ(message.substr(i, 2), ": ") << message;
  EXPECT_NE(std::stoi(message.substr(prefix.size(), i - prefix.size())), 0) << message;
  EXPECT_NE(message.find(m.phrase), std::string::npos)
      << "expected the message to contain: " << m.phrase << "\n  got: " << message;
}

INSTANTIATE_TEST_SUITE_P(ShotFiles, ShotFileMalformedTest, ::testing::ValuesIn(kMalformed),
                         [](const ::testing::TestParamInfo<Malformed>& info) {
                           return fs::path(info.param.file).stem().string();
                         });

// A malformed file added to tests/data/shots without a row above would never be tested.
TEST(ShotFileMalformed, EveryMalformedFileIsInTheTable) {
  std::set<std::string> listed;
  for (const Malformed& m : kMalformed) listed.insert(m.file);
  for (const auto& entry : fs::directory_iterator(shotsDir())) {
    const std::string name = entry.path().filename().string();
    const bool valid = name.size() > 10 && name.ends_with(".shot.toml");
    if (entry.path().extension() == ".toml" && !valid) {
      EXPECT_TRUE(listed.contains(name)) << name << " has no row in kMalformed";
    }
  }
  EXPECT_GE(listed.size(), 16u);
}

TEST(ShotFileMalformed, MessagesSayWhatWasExpectedInFull) {
  const std::string path = shotPath("unknown_key_camera.toml");
  EXPECT_EQ(loadShotFile(path).status().message(),
            path +
                ":14:1: [camera]: unknown key 'fov' (expected one of: position, look_at, up, "
                "fov_y_deg, aperture_radius, focus_distance, views, view_spacing, key)");
  const std::string fov = shotPath("negative_fov.toml");
  EXPECT_EQ(loadShotFile(fov).status().message(),
            fov + ":14:13: [camera]: 'fov_y_deg' must be in (0, 180), found -10.0");
}

TEST(ShotFileMalformed, MissingFileNamesTheShotLineAndResolvedPath) {
  const std::string path = shotPath("missing_geometry_file.toml");
  const absl::Status status = loadShotFile(path).status();
  EXPECT_EQ(status.code(), absl::StatusCode::kNotFound);
  EXPECT_EQ(
      status.message(),
      fmt::format("{}:17:8: [[geometry]] #1: 'file': file \"missing.obj\" not found (resolved "
                  "to {})",
                  path, resolved(shotsDir() / "missing.obj")));
}

// ---- loading: the shot file itself ----

TEST(ShotFile, MissingShotFileIsNotFound) {
  const std::string path = shotPath("no_such_shot.toml");
  const absl::StatusOr<ShotDesc> shot = loadShotFile(path);
  ASSERT_FALSE(shot.ok());
  EXPECT_EQ(shot.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(shot.status().message().find(path), std::string::npos) << shot.status();
}

TEST(ShotFile, FolderIsNotAShotFile) {
  const absl::StatusOr<ShotDesc> shot = loadShotFile(shotsDir().string());
  ASSERT_FALSE(shot.ok());
  EXPECT_EQ(shot.status().code(), absl::StatusCode::kInvalidArgument) << shot.status();
}

TEST(ShotFile, HugeFileIsRejectedBeforeParsing) {
  const fs::path dir = testing::makeTempDir("shot-huge");
  const fs::path path = dir / "huge.toml";
  {
    std::ofstream out(path, std::ios::binary);
    const std::string line(1023, '#');
    for (int i = 0; i < 17 * 1024; ++i) out << line << '\n';
  }
  const absl::StatusOr<ShotDesc> shot = loadShotFile(path.string());
  ASSERT_FALSE(shot.ok());
  EXPECT_EQ(shot.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(shot.status().message().find("a shot file is at most 16777216 bytes"),
            std::string::npos)
      << shot.status();
  fs::remove_all(dir);
}

TEST(ShotFile, SyntaxErrorReportsLineAndColumn) {
  const std::string text = "version = 1\n[shot]\nname = \"x\"\nframes = [1, 2\n";
  const absl::StatusOr<ShotDesc> shot = parseShot(text, "mem/syntax.toml");
  ASSERT_FALSE(shot.ok());
  EXPECT_EQ(shot.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(shot.status().message().rfind("mem/syntax.toml:", 0), 0u) << shot.status();
  EXPECT_NE(shot.status().message().find("TOML syntax error"), std::string::npos) << shot.status();
}

TEST(ShotFile, DuplicateKeyIsASyntaxErrorAtTheSecondOne) {
  const std::string text = "version = 1\nversion = 1\n";
  const absl::StatusOr<ShotDesc> shot = parseShot(text, "dup.toml");
  ASSERT_FALSE(shot.ok());
  EXPECT_EQ(shot.status().message().rfind("dup.toml:2:", 0), 0u) << shot.status();
}

// ---- valid files ----

TEST(ShotFile, MinimalShotTakesEveryDefault) {
  const absl::StatusOr<ShotDesc> shot = loadShotFile(shotPath("minimal.shot.toml"));
  ASSERT_TRUE(shot.ok()) << shot.status();
  EXPECT_EQ(shot->path, shotPath("minimal.shot.toml"));
  EXPECT_EQ(shot->dir, resolved(shotsDir()));
  EXPECT_EQ(shot->version, 1);
  EXPECT_EQ(shot->name, "minimal");
  EXPECT_EQ(shot->firstFrame, 7);
  EXPECT_EQ(shot->lastFrame, 7);
  EXPECT_EQ(shot->width, 32);
  EXPECT_EQ(shot->height, 16);
  EXPECT_EQ(shot->output, resolved(shotsDir() / "minimal.exr"));
  // Integers stand for floats.
  expectVec(shot->camera.base.position, 0.0f, 1.0f, -5.0f);
  EXPECT_FLOAT_EQ(shot->camera.base.fovYDeg, 45.0f);
  EXPECT_FLOAT_EQ(shot->camera.base.apertureRadius, 0.0f);
  EXPECT_FLOAT_EQ(shot->camera.base.focusDistance, 0.0f);
  EXPECT_EQ(shot->camera.views, Vec2i(1, 1));
  EXPECT_FLOAT_EQ(shot->camera.viewSpacing, 0.0f);
  EXPECT_TRUE(shot->camera.keys.empty());
  EXPECT_EQ(shot->camera.where.line, 10);
  ASSERT_EQ(shot->geometry.size(), 1u);
  EXPECT_EQ(shot->geometry[0].file, resolved(shotsDir() / "tri.obj"));
  expectVec(shot->geometry[0].base.translate, 0.0f, 0.0f, 0.0f);
  expectVec(shot->geometry[0].base.rotateDeg, 0.0f, 0.0f, 0.0f);
  EXPECT_FLOAT_EQ(shot->geometry[0].base.scale, 1.0f);
  EXPECT_TRUE(shot->materials.empty());
  EXPECT_TRUE(shot->lights.empty());
  const RenderSettings& r = shot->render;
  EXPECT_EQ(r.integrator, "path");
  EXPECT_EQ(r.spp, 4);
  EXPECT_EQ(r.seed, 0u);
  EXPECT_EQ(r.maxDepth, 64);
  EXPECT_EQ(r.filter, FilterType::kBox);
  EXPECT_FLOAT_EQ(r.filterWidth, 1.0f);
  EXPECT_EQ(r.tileSize, 32);
  EXPECT_EQ(r.rouletteDepth, 3);
}

TEST(ShotFile, FullShotParsesEveryPart) {
  const absl::StatusOr<ShotDesc> shot = loadShotFile(shotPath("full.shot.toml"));
  ASSERT_TRUE(shot.ok()) << shot.status();
  EXPECT_EQ(shot->name, "full_test-shot");
  EXPECT_EQ(shot->firstFrame, 1);
  EXPECT_EQ(shot->lastFrame, 5);
  EXPECT_EQ(shot->width, 320);
  EXPECT_EQ(shot->height, 240);
  EXPECT_EQ(shot->output, resolved(shotsDir() / "renders" / "full.####.exr"));

  const CameraDesc& cam = shot->camera;
  expectVec(cam.base.position, 0.0f, 1.0f, -5.0f);
  expectVec(cam.base.lookAt, 0.0f, 1.0f, 0.0f);
  expectVec(cam.base.up, 0.0f, 1.0f, 0.0f);
  EXPECT_FLOAT_EQ(cam.base.fovYDeg, 40.0f);
  EXPECT_FLOAT_EQ(cam.base.apertureRadius, 0.05f);
  EXPECT_FLOAT_EQ(cam.base.focusDistance, 5.0f);
  EXPECT_EQ(cam.views, Vec2i(2, 1));
  EXPECT_FLOAT_EQ(cam.viewSpacing, 0.065f);
  ASSERT_EQ(cam.keys.size(), 2u);
  EXPECT_EQ(cam.keys[0].frame, 3);
  ASSERT_TRUE(cam.keys[0].position.has_value());
  expectVec(*cam.keys[0].position, 2.0f, 1.0f, -5.0f);
  EXPECT_EQ(cam.keys[0].fovYDeg, 30.0f);
  EXPECT_FALSE(cam.keys[0].lookAt.has_value());
  EXPECT_FALSE(cam.keys[0].up.has_value());
  EXPECT_EQ(cam.keys[0].where.line, 21);
  EXPECT_EQ(cam.keys[1].frame, 5);
  EXPECT_EQ(cam.keys[1].apertureRadius, 0.0f);
  EXPECT_FALSE(cam.keys[1].position.has_value());

  // The keys drive the camera over the frames.
  const CameraParams at2 = cameraAt(cam, shot->firstFrame, 2);
  expectVec(at2.position, 1.0f, 1.0f, -5.0f);
  EXPECT_FLOAT_EQ(at2.fovYDeg, 35.0f);
  const CameraParams at5 = cameraAt(cam, shot->firstFrame, 5);
  expectVec(at5.position, 2.0f, 1.0f, -5.0f);
  expectVec(at5.lookAt, 0.0f, 2.0f, 0.0f);
  EXPECT_FLOAT_EQ(at5.apertureRadius, 0.0f);

  ASSERT_EQ(shot->geometry.size(), 2u);
  EXPECT_EQ(shot->geometry[0].file, resolved(shotsDir() / "tri.obj"));
  EXPECT_EQ(shot->geometry[1].file, resolved(shotsDir() / "tri.obj"));
  EXPECT_EQ(shot->geometry[1].where.line, 34);
  expectVec(shot->geometry[1].base.translate, 1.0f, 0.0f, 0.0f);
  expectVec(shot->geometry[1].base.rotateDeg, 0.0f, 45.0f, 0.0f);
  EXPECT_FLOAT_EQ(shot->geometry[1].base.scale, 2.0f);
  ASSERT_EQ(shot->geometry[1].keys.size(), 1u);
  EXPECT_EQ(shot->geometry[1].keys[0].frame, 5);
  EXPECT_EQ(shot->geometry[1].keys[0].scale, 4.0f);
  const TransformParams t3 = transformAt(shot->geometry[1], shot->firstFrame, 3);
  expectVec(t3.rotateDeg, 0.0f, 67.5f, 0.0f);
  EXPECT_FLOAT_EQ(t3.scale, 3.0f);
  expectVec(t3.translate, 1.0f, 0.0f, 0.0f);

  ASSERT_EQ(shot->materials.size(), 7u);
  const MaterialDesc& plain = shot->materials[0];
  EXPECT_EQ(plain.name, "plain");
  EXPECT_EQ(plain.type, MaterialType::kDiffuse);
  ASSERT_TRUE(plain.albedo.has_value());
  expectVec(*plain.albedo, 0.73f, 0.73f, 0.73f);
  EXPECT_FALSE(plain.albedoTexture.has_value());
  EXPECT_EQ(plain.where.line, 45);
  const MaterialDesc& checker = shot->materials[1];
  EXPECT_FALSE(checker.albedo.has_value());
  EXPECT_EQ(checker.albedoTexture, resolved(shotsDir() / "checker.png"));
  const MaterialDesc& gold = shot->materials[2];
  EXPECT_EQ(gold.type, MaterialType::kConductor);
  EXPECT_FLOAT_EQ(gold.roughness, 0.2f);
  EXPECT_EQ(gold.distribution, MicrofacetDistribution::kBeckmann);
  EXPECT_FALSE(gold.specular.has_value());
  ASSERT_TRUE(gold.eta.has_value() && gold.k.has_value());
  expectVec(*gold.eta, 0.143f, 0.374f, 1.442f);
  expectVec(*gold.k, 3.983f, 2.385f, 1.603f);
  expectVec(gold.tint, 1.0f, 0.9f, 0.8f);
  const MaterialDesc& chrome = shot->materials[3];
  EXPECT_EQ(chrome.type, MaterialType::kConductor);
  EXPECT_EQ(chrome.distribution, MicrofacetDistribution::kGgx);
  EXPECT_FLOAT_EQ(chrome.roughness, 0.0f);
  ASSERT_TRUE(chrome.specular.has_value());
  expectVec(*chrome.specular, 0.55f, 0.56f, 0.55f);
  expectVec(chrome.tint, 1.0f, 1.0f, 1.0f);
  EXPECT_FALSE(chrome.eta.has_value());
  const MaterialDesc& glass = shot->materials[4];
  EXPECT_EQ(glass.type, MaterialType::kDielectric);
  EXPECT_FLOAT_EQ(glass.ior, 1.5f);
  const MaterialDesc& frosted = shot->materials[5];
  EXPECT_FLOAT_EQ(frosted.roughness, 0.3f);
  EXPECT_FLOAT_EQ(frosted.ior, 1.33f);
  EXPECT_EQ(frosted.distribution, MicrofacetDistribution::kGgx);
  const MaterialDesc& lamp = shot->materials[6];
  EXPECT_EQ(lamp.type, MaterialType::kEmissive);
  expectVec(lamp.radiance, 10.0f, 9.0f, 8.0f);

  ASSERT_EQ(shot->lights.size(), 6u);
  const LightDesc& quad = shot->lights[0];
  EXPECT_EQ(quad.type, LightType::kQuad);
  expectVec(quad.corner, -0.5f, 3.0f, -0.5f);
  expectVec(quad.edgeU, 0.0f, 0.0f, 1.0f);
  expectVec(quad.edgeV, 1.0f, 0.0f, 0.0f);
  expectVec(quad.radiance, 17.0f, 12.0f, 4.0f);
  EXPECT_EQ(quad.where.line, 87);
  const LightDesc& sphere = shot->lights[1];
  EXPECT_EQ(sphere.type, LightType::kSphere);
  expectVec(sphere.center, 2.0f, 2.0f, 0.0f);
  EXPECT_FLOAT_EQ(sphere.radius, 0.25f);
  expectVec(sphere.radiance, 5.0f, 5.0f, 5.0f);
  const LightDesc& point = shot->lights[2];
  EXPECT_EQ(point.type, LightType::kPoint);
  expectVec(point.position, -2.0f, 2.0f, 0.0f);
  expectVec(point.intensity, 3.0f, 3.0f, 3.0f);
  const LightDesc& spot = shot->lights[3];
  EXPECT_EQ(spot.type, LightType::kSpot);
  expectVec(spot.position, 0.0f, 4.0f, 0.0f);
  expectVec(spot.direction, 0.0f, -1.0f, 0.0f);  // normalised
  EXPECT_FLOAT_EQ(spot.coneDeg, 25.0f);
  expectVec(spot.intensity, 20.0f, 20.0f, 20.0f);
  const LightDesc& sun = shot->lights[4];
  EXPECT_EQ(sun.type, LightType::kDirectional);
  expectVec(sun.direction, 0.0f, -0.6f, 0.8f);
  expectVec(sun.irradiance, 2.0f, 1.9f, 1.8f);
  const LightDesc& env = shot->lights[5];
  EXPECT_EQ(env.type, LightType::kEnvironment);
  EXPECT_EQ(env.file, resolved(shotsDir() / "sky_grey.exr"));
  EXPECT_FLOAT_EQ(env.scale, 0.5f);
  EXPECT_FLOAT_EQ(env.rotateDeg, 90.0f);

  const RenderSettings& r = shot->render;
  EXPECT_EQ(r.integrator, "pbgi");
  EXPECT_EQ(r.spp, 8);
  EXPECT_EQ(r.seed, 42u);
  EXPECT_EQ(r.maxDepth, 5);
  EXPECT_EQ(r.filter, FilterType::kBlackmanHarris);
  EXPECT_FLOAT_EQ(r.filterWidth, 3.0f);
  EXPECT_EQ(r.tileSize, 16);
  EXPECT_EQ(r.rouletteDepth, 2);
}

TEST(ShotFile, ParseShotResolvesAgainstTheGivenPathsFolder) {
  const fs::path dir = testing::makeTempDir("shot-resolve");
  fs::create_directories(dir / "meshes");
  fs::copy_file(shotsDir() / "tri.obj", dir / "meshes" / "tri.obj");
  const std::string text = R"(version = 1
[shot]
name = "t"
frames = [0, 0]
resolution = [8, 8]
output = "../elsewhere/t.exr"
[camera]
position = [0, 0, -1]
look_at = [0, 0, 0]
up = [0, 1, 0]
fov_y_deg = 30
[[geometry]]
file = "meshes/tri.obj"
[[geometry]]
file = ")" + (dir / "meshes" / "tri.obj").string() +
                           R"("
)";
  const std::string path = (dir / "shot.toml").string();
  const absl::StatusOr<ShotDesc> shot = parseShot(text, path);
  ASSERT_TRUE(shot.ok()) << shot.status();
  EXPECT_EQ(shot->path, path);
  EXPECT_EQ(shot->output, resolved(dir.parent_path() / "elsewhere" / "t.exr"));
  ASSERT_EQ(shot->geometry.size(), 2u);
  EXPECT_EQ(shot->geometry[0].file, resolved(dir / "meshes" / "tri.obj"));
  EXPECT_EQ(shot->geometry[1].file, resolved(dir / "meshes" / "tri.obj"));
  // The same text beside no mesh fails, naming the path it looked for.
  const absl::StatusOr<ShotDesc> elsewhere = parseShot(text, (dir / "meshes" / "s.toml").string());
  ASSERT_FALSE(elsewhere.ok());
  EXPECT_EQ(elsewhere.status().code(), absl::StatusCode::kNotFound);
  EXPECT_NE(elsewhere.status().message().find(resolved(dir / "meshes" / "meshes" / "tri.obj")),
            std::string::npos)
      << elsewhere.status();
  fs::remove_all(dir);
}

// A degenerate camera half-way between two good keys is caught at the frame it happens.
TEST(ShotFile, InterpolatedDegenerateCameraIsRejected) {
  const std::string text = R"(version = 1
[shot]
name = "t"
frames = [1, 3]
resolution = [8, 8]
output = "t.####.exr"
[camera]
position = [-1, 0, 0]
look_at = [1, 0, 0]
up = [0, 1, 0]
fov_y_deg = 30
[[camera.key]]
frame = 3
position = [1, 0, 0]
look_at = [-1, 0, 0]
[[geometry]]
file = "tri.obj"
)";
  const absl::StatusOr<ShotDesc> shot = parseShot(text, shotPath("interp.toml"));
  ASSERT_FALSE(shot.ok());
  EXPECT_EQ(shot.status().message(),
            shotPath("interp.toml") +
                ":12:1: [[camera.key]] #1: the camera at frame 2 is degenerate: position and "
                "look_at coincide at (0, 0, 0)");
}

// The shipped sample scene must always load.
TEST(ShotFile, ShippedCornellSceneLoads) {
  const fs::path dir = testing::sourceDir() / "config" / "scenes" / "cornell";
  const absl::StatusOr<ShotDesc> shot = loadShotFile((dir / "cornell.shot.toml").string());
  ASSERT_TRUE(shot.ok()) << shot.status();
  EXPECT_EQ(shot->name, "cornell");
  EXPECT_EQ(shot->firstFrame, 1);
  EXPECT_EQ(shot->lastFrame, 3);
  EXPECT_EQ(shot->width, 256);
  EXPECT_EQ(shot->height, 256);
  EXPECT_EQ(shot->output, resolved(dir / "out" / "cornell.####.exr"));
  EXPECT_EQ(outputPathForFrame(shot->output, 2, true), resolved(dir / "out" / "cornell.0002.exr"));
  expectVec(shot->camera.base.position, 278.0f, 273.0f, -800.0f);
  expectVec(shot->camera.base.lookAt, 278.0f, 273.0f, 0.0f);
  EXPECT_FLOAT_EQ(shot->camera.base.fovYDeg, 37.0f);
  expectVec(cameraAt(shot->camera, shot->firstFrame, 2).position, 304.0f, 273.0f, -790.0f);
  expectVec(cameraAt(shot->camera, shot->firstFrame, 3).position, 330.0f, 273.0f, -780.0f);
  ASSERT_EQ(shot->geometry.size(), 1u);
  EXPECT_EQ(shot->geometry[0].file, resolved(dir / "cornell_box.obj"));
  ASSERT_EQ(shot->materials.size(), 3u);
  EXPECT_EQ(shot->materials[1].name, "red");
  expectVec(*shot->materials[1].albedo, 0.63f, 0.065f, 0.05f);
  ASSERT_EQ(shot->lights.size(), 1u);
  EXPECT_EQ(shot->lights[0].type, LightType::kQuad);
  // The light shines down into the box.
  const Vec3f n = cross(shot->lights[0].edgeU, shot->lights[0].edgeV);
  expectVec(n, 0.0f, -13650.0f, 0.0f);
  // The sample is the product: PBGI through the bidirectional cut.
  EXPECT_EQ(shot->render.integrator, "pbgi");
  EXPECT_EQ(shot->render.params.choiceOr("gather", ""), "bidirectional");
  EXPECT_EQ(shot->render.params.intOr("bake_points", 0), 250000);
  EXPECT_EQ(shot->render.spp, 16);
  EXPECT_EQ(shot->render.seed, 0u);
}

TEST(ShotFile, SharedTestScenesLoad) {
  PBGI_REQUIRE_SHARED_SCENES(scenes);
  for (const char* name : {"cornell-box/cornell.shot.toml", "sponza/sponza.shot.toml"}) {
    const absl::StatusOr<ShotDesc> shot = loadShotFile((scenes / name).string());
    EXPECT_TRUE(shot.ok()) << name << ": " << shot.status();
  }
}

// ---- keyframe evaluation (core/scene/shot.h) ----

CameraDesc movingCamera() {
  CameraDesc camera;
  camera.base.position = Vec3f(0.0f, 0.0f, 0.0f);
  camera.base.fovYDeg = 40.0f;
  CameraKey a;
  a.frame = 5;
  a.position = Vec3f(4.0f, 0.0f, 0.0f);
  CameraKey b;
  b.frame = 9;
  b.position = Vec3f(4.0f, 8.0f, 0.0f);
  b.fovYDeg = 20.0f;
  camera.keys = {b, a};  // order in the file does not matter
  return camera;
}

TEST(ShotKeyframes, CameraHoldsBeforeTheFirstKey) {
  const CameraDesc camera = movingCamera();
  expectVec(cameraAt(camera, 1, 0).position, 0.0f, 0.0f, 0.0f);
  expectVec(cameraAt(camera, 1, 1).position, 0.0f, 0.0f, 0.0f);
  EXPECT_FLOAT_EQ(cameraAt(camera, 1, -3).fovYDeg, 40.0f);
}

TEST(ShotKeyframes, CameraInterpolatesLinearlyBetweenKeys) {
  const CameraDesc camera = movingCamera();
  expectVec(cameraAt(camera, 1, 3).position, 2.0f, 0.0f, 0.0f);
  expectVec(cameraAt(camera, 1, 5).position, 4.0f, 0.0f, 0.0f);
  expectVec(cameraAt(camera, 1, 6).position, 4.0f, 2.0f, 0.0f);
  // fov has keys only at the base (frame 1) and frame 9: frame 5 sits half-way.
  EXPECT_FLOAT_EQ(cameraAt(camera, 1, 5).fovYDeg, 30.0f);
  EXPECT_FLOAT_EQ(cameraAt(camera, 1, 7).fovYDeg, 25.0f);
  // Values no key sets stay at the base.
  expectVec(cameraAt(camera, 1, 6).lookAt, 0.0f, 0.0f, 1.0f);
}

TEST(ShotKeyframes, CameraHoldsAfterTheLastKey) {
  const CameraDesc camera = movingCamera();
  expectVec(cameraAt(camera, 1, 9).position, 4.0f, 8.0f, 0.0f);
  expectVec(cameraAt(camera, 1, 100).position, 4.0f, 8.0f, 0.0f);
  EXPECT_FLOAT_EQ(cameraAt(camera, 1, 100).fovYDeg, 20.0f);
}

TEST(ShotKeyframes, BaseActsAsAKeyAtTheFirstFrame) {
  const CameraDesc camera = movingCamera();
  // With the shot starting at frame 3 the base sits at 3, so frame 4 is half-way to frame 5.
  expectVec(cameraAt(camera, 3, 4).position, 2.0f, 0.0f, 0.0f);
  expectVec(cameraAt(camera, 3, 2).position, 0.0f, 0.0f, 0.0f);
  // A key at the first frame overrides the base.
  CameraDesc overridden = camera;
  CameraKey first;
  first.frame = 1;
  first.position = Vec3f(-4.0f, 0.0f, 0.0f);
  overridden.keys.push_back(first);
  expectVec(cameraAt(overridden, 1, 1).position, -4.0f, 0.0f, 0.0f);
  expectVec(cameraAt(overridden, 1, 3).position, 0.0f, 0.0f, 0.0f);
}

TEST(ShotKeyframes, TransformFollowsTheSameRules) {
  GeometryDesc geometry;
  geometry.base.translate = Vec3f(1.0f, 2.0f, 3.0f);
  geometry.base.scale = 1.0f;
  TransformKey key;
  key.frame = 11;
  key.scale = 3.0f;
  key.rotateDeg = Vec3f(0.0f, 90.0f, 0.0f);
  geometry.keys.push_back(key);
  EXPECT_FLOAT_EQ(transformAt(geometry, 1, 0).scale, 1.0f);
  EXPECT_FLOAT_EQ(transformAt(geometry, 1, 6).scale, 2.0f);
  expectVec(transformAt(geometry, 1, 6).rotateDeg, 0.0f, 45.0f, 0.0f);
  expectVec(transformAt(geometry, 1, 6).translate, 1.0f, 2.0f, 3.0f);
  EXPECT_FLOAT_EQ(transformAt(geometry, 1, 11).scale, 3.0f);
  EXPECT_FLOAT_EQ(transformAt(geometry, 1, 50).scale, 3.0f);
}

// ---- output paths ----

TEST(ShotOutputPath, HashRunsBecomeTheZeroPaddedFrame) {
  EXPECT_EQ(outputPathForFrame("/r/shot.####.exr", 7, true), "/r/shot.0007.exr");
  EXPECT_EQ(outputPathForFrame("/r/shot.####.exr", 12345, true), "/r/shot.12345.exr");
  EXPECT_EQ(outputPathForFrame("/r/s.#.exr", 42, true), "/r/s.42.exr");
  EXPECT_EQ(outputPathForFrame("a##b###.exr", 5, true), "a05b005.exr");
  EXPECT_EQ(outputPathForFrame("/r/shot.####.exr", 3, false), "/r/shot.0003.exr");
}

TEST(ShotOutputPath, PatternWithoutHashesGetsAFrameNumberOnlyWhenNeeded) {
  EXPECT_EQ(outputPathForFrame("/r/shot.exr", 3, true), "/r/shot.0003.exr");
  EXPECT_EQ(outputPathForFrame("/r/shot.exr", 3, false), "/r/shot.exr");
  EXPECT_EQ(outputPathForFrame("/r.v2/shot", 3, true), "/r.v2/shot.0003");
}

}  // namespace
}  // namespace pbgi
