#include "formats/mesh/mesh_loader.h"

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <set>
#include <string>
#include <tuple>
#include <utility>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
using ::pbgi::testing::makeTempDir;
using ::pbgi::testing::testDataDir;

std::string meshPath(const std::string& name) { return (testDataDir() / "meshes" / name).string(); }

const MaterialDesc* findMaterial(const LoadedGeometry& g, const std::string& name) {
  for (const MaterialDesc& m : g.materials) {
    if (m.name == name) return &m;
  }
  return nullptr;
}

const MeshData* findMesh(const LoadedGeometry& g, const std::string& name) {
  for (const MeshData& m : g.meshes) {
    if (m.name == name) return &m;
  }
  return nullptr;
}

// The warnings that mention `needle`.
std::vector<std::string> warningsWith(const LoadedGeometry& g, const std::string& needle) {
  std::vector<std::string> out;
  for (const std::string& w : g.everyWarning()) {
    if (w.find(needle) != std::string::npos) out.push_back(w);
  }
  return out;
}

std::string allWarnings(const LoadedGeometry& g) {
  std::string s;
  for (const std::string& w : g.everyWarning()) s += "\n  " + w;
  return s;
}

size_t triangleCount(const LoadedGeometry& g) {
  size_t n = 0;
  for (const MeshData& m : g.meshes) n += m.triangleCount();
  return n;
}

void expectRgb(const std::optional<Rgb>& got, const Rgb& want) {
  ASSERT_TRUE(got.has_value());
  EXPECT_FLOAT_EQ(got->x, want.x);
  EXPECT_FLOAT_EQ(got->y, want.y);
  EXPECT_FLOAT_EQ(got->z, want.z);
}

TEST(LoadGeometry, MapsObjMaterials) {
  const auto g = loadGeometry(meshPath("materials.obj"));
  ASSERT_TRUE(g.ok()) << g.status();
  EXPECT_EQ(g->meshes.size(), 5u);
  EXPECT_EQ(triangleCount(*g), 10u);  // five quads
  // Only the materials that triangles use: "unused" and Assimp's default are left out.
  ASSERT_EQ(g->materials.size(), 5u);
  EXPECT_EQ(findMaterial(*g, "unused"), nullptr);

  const MaterialDesc* red = findMaterial(*g, "red");
  ASSERT_NE(red, nullptr);
  EXPECT_EQ(red->type, MaterialType::kDiffuse);
  expectRgb(red->albedo, {0.5f, 0.25f, 0.125f});
  EXPECT_FALSE(red->albedoTexture.has_value());

  const MaterialDesc* lamp = findMaterial(*g, "lamp");
  ASSERT_NE(lamp, nullptr);
  EXPECT_EQ(lamp->type, MaterialType::kEmissive);
  EXPECT_EQ(lamp->radiance, Rgb(10, 8, 6));

  // map_Kd ..\textures\Checker.PNG: backslashes, relative to the OBJ's folder, and the
  // file name's case is forgiven.
  const MaterialDesc* textured = findMaterial(*g, "textured");
  ASSERT_NE(textured, nullptr);
  EXPECT_EQ(textured->type, MaterialType::kDiffuse);
  ASSERT_TRUE(textured->albedoTexture.has_value());
  EXPECT_TRUE(fs::equivalent(*textured->albedoTexture, testDataDir() / "textures" / "checker.png"))
      << *textured->albedoTexture;
  expectRgb(textured->albedo, {0.2f, 0.2f, 0.2f});

  // A missing texture falls back to Kd, with a warning that names material and file.
  const MaterialDesc* missing = findMaterial(*g, "missing_texture");
  ASSERT_NE(missing, nullptr);
  EXPECT_FALSE(missing->albedoTexture.has_value());
  expectRgb(missing->albedo, {0.3f, 0.6f, 0.9f});
  const auto missingWarnings = warningsWith(*g, "'missing_texture'");
  ASSERT_EQ(missingWarnings.size(), 1u) << allWarnings(*g);
  EXPECT_NE(missingWarnings[0].find("does_not_exist.png"), std::string::npos) << missingWarnings[0];
  EXPECT_NE(missingWarnings[0].find("materials.obj"), std::string::npos) << missingWarnings[0];

  // Glossy and transparent parts cannot be mapped: one warning names them and the material.
  const MaterialDesc* shiny = findMaterial(*g, "shiny");
  ASSERT_NE(shiny, nullptr);
  EXPECT_EQ(shiny->type, MaterialType::kDiffuse);
  expectRgb(shiny->albedo, {0.5f, 0.5f, 0.5f});
  const auto shinyWarnings = warningsWith(*g, "'shiny'");
  ASSERT_EQ(shinyWarnings.size(), 1u) << allWarnings(*g);
  EXPECT_NE(shinyWarnings[0].find("Ks 0.25 0.25 0.25"), std::string::npos) << shinyWarnings[0];
  EXPECT_NE(shinyWarnings[0].find("Ns 100"), std::string::npos) << shinyWarnings[0];
  EXPECT_NE(shinyWarnings[0].find("d 0.5"), std::string::npos) << shinyWarnings[0];

  EXPECT_EQ(g->everyWarning().size(), 2u) << allWarnings(*g);

  // Each mesh points at its own material; uvs come through with v = 0 at the bottom.
  const MeshData* quad = findMesh(*g, "textured_quad");
  ASSERT_NE(quad, nullptr);
  ASSERT_EQ(quad->materials.size(), 2u);
  EXPECT_EQ(g->materials[quad->materials[0]].name, "textured");
  EXPECT_EQ(quad->materials[1], quad->materials[0]);
  ASSERT_EQ(quad->uvs.size(), quad->positions.size());
  for (size_t v = 0; v < quad->positions.size(); ++v) {
    EXPECT_EQ(quad->uvs[v], Vec2f(quad->positions[v].x, quad->positions[v].y));
  }
  EXPECT_TRUE(quad->normals.empty()) << "no normals are made up for a file without them";
}

TEST(LoadGeometry, DropsNonFiniteAndDegenerateTrianglesWithAWarning) {
  const auto g = loadGeometry(meshPath("nan.obj"));
  ASSERT_TRUE(g.ok()) << g.status();
  ASSERT_EQ(g->meshes.size(), 1u);
  const MeshData& mesh = g->meshes[0];
  EXPECT_EQ(mesh.triangleCount(), 4u);
  EXPECT_EQ(mesh.materials.size(), 4u);
  for (uint32_t i : mesh.indices) {
    ASSERT_LT(i, mesh.positions.size());
    EXPECT_TRUE(isFinite(mesh.positions[i])) << mesh.positions[i];
  }
  const auto w = warningsWith(*g, "mesh 'hostile'");
  ASSERT_EQ(w.size(), 1u) << allWarnings(*g);
  EXPECT_NE(w[0].find("dropped 3 triangles with NaN/Inf vertices, 3 degenerate (zero-area) "
                      "triangles"),
            std::string::npos)
      << w[0];
  EXPECT_NE(w[0].find("nan.obj"), std::string::npos) << w[0];
}

TEST(LoadGeometry, KeepsVertexNormals) {
  const auto g = loadGeometry(meshPath("normals.obj"));
  ASSERT_TRUE(g.ok()) << g.status();
  ASSERT_EQ(g->meshes.size(), 1u);
  const MeshData& mesh = g->meshes[0];
  ASSERT_EQ(mesh.triangleCount(), 2u);
  ASSERT_EQ(mesh.normals.size(), mesh.positions.size());
  // The file's normal per position (the second one normalized).
  auto expected = [](const Vec3f& p) {
    if (p == Vec3f(0, 0, 0)) return Vec3f(0, 0, 1);
    if (p == Vec3f(1, 0, 0)) return Vec3f(0, 0, 1);
    if (p == Vec3f(0, 1, 0)) return Vec3f(0.6f, 0, 0.8f);
    return Vec3f(0, 0.6f, 0.8f);
  };
  for (size_t v = 0; v < mesh.positions.size(); ++v) {
    const Vec3f want = expected(mesh.positions[v]);
    EXPECT_NEAR((mesh.normals[v] - want).length(), 0.0f, 1e-6f)
        << "vertex " << mesh.positions[v] << ": " << mesh.normals[v] << " vs " << want;
  }
  EXPECT_TRUE(g->everyWarning().empty()) << allWarnings(*g);
}

TEST(LoadGeometry, AppliesGltfNodeTransformsAndMapsMetallicRoughness) {
  const auto g = loadGeometry(meshPath("transformed.gltf"));
  ASSERT_TRUE(g.ok()) << g.status();
  EXPECT_TRUE(g->everyWarning().empty()) << allWarnings(*g);

  // gold_node: scale 2, then translate (10, 20, 30).
  const MeshData* gold = findMesh(*g, "gold_mesh");
  ASSERT_NE(gold, nullptr);
  ASSERT_EQ(gold->triangleCount(), 1u);
  std::set<std::tuple<float, float, float>> goldPositions;
  for (uint32_t i : gold->indices) {
    const Vec3f& p = gold->positions[i];
    goldPositions.insert({p.x, p.y, p.z});
  }
  EXPECT_EQ(goldPositions,
            (std::set<std::tuple<float, float, float>>{{10, 20, 30}, {12, 20, 30}, {10, 22, 30}}));
  const MaterialDesc& goldMat = g->materials[gold->materials[0]];
  EXPECT_EQ(goldMat.name, "gold");
  EXPECT_EQ(goldMat.type, MaterialType::kConductor);
  expectRgb(goldMat.specular, {1.0f, 0.75f, 0.25f});
  EXPECT_FLOAT_EQ(goldMat.roughness, 0.25f);  // roughnessFactor 0.5 squared
  EXPECT_EQ(goldMat.distribution, MicrofacetDistribution::kGgx);

  // painted_node sits under a parent turned 90 degrees about +z: x -> y, y -> -x, and the
  // normal (0, 0, 1) stays.
  size_t painted = 0;
  for (const MeshData& mesh : g->meshes) {
    if (&mesh == gold) continue;
    ++painted;
    ASSERT_EQ(mesh.triangleCount(), 1u);
    ASSERT_EQ(mesh.normals.size(), mesh.positions.size());
    ASSERT_EQ(mesh.uvs.size(), mesh.positions.size());
    for (uint32_t i : mesh.indices) {
      const Vec3f& p = mesh.positions[i];
      const bool origin = (p - Vec3f(0, 0, 0)).length() < 1e-6f;
      const bool fromX = (p - Vec3f(0, 1, 0)).length() < 1e-6f;
      const bool fromY = (p - Vec3f(-1, 0, 0)).length() < 1e-6f;
      EXPECT_TRUE(origin || fromX || fromY) << p;
      EXPECT_NEAR((mesh.normals[i] - Vec3f(0, 0, 1)).length(), 0.0f, 1e-6f) << mesh.normals[i];
      // glTF's uv (0, 0) is the image's top left, which is v = 1 in our convention.
      const Vec2f wantUv = origin ? Vec2f(0, 1) : fromX ? Vec2f(1, 1) : Vec2f(0, 0);
      EXPECT_EQ(mesh.uvs[i], wantUv) << p;
    }
  }
  EXPECT_EQ(painted, 2u);

  const MaterialDesc* paint = findMaterial(*g, "paint");
  ASSERT_NE(paint, nullptr);
  EXPECT_EQ(paint->type, MaterialType::kDiffuse);
  expectRgb(paint->albedo, {1, 1, 1});
  ASSERT_TRUE(paint->albedoTexture.has_value());
  EXPECT_TRUE(fs::equivalent(*paint->albedoTexture, testDataDir() / "textures" / "checker.png"));

  const MaterialDesc* glow = findMaterial(*g, "glow");
  ASSERT_NE(glow, nullptr);
  EXPECT_EQ(glow->type, MaterialType::kEmissive);
  EXPECT_EQ(glow->radiance, Rgb(1.0f, 0.5f, 0.25f));
}

TEST(LoadGeometry, EmbeddedTexturesWarnAndFallBackToTheFactor) {
  // A data: URI in .gltf, a buffer view in .glb: both are embedded textures to Assimp.
  for (const auto& [file, material] :
       {std::pair{"embedded.gltf", "packed"}, std::pair{"embedded.glb", "packed_glb"}}) {
    SCOPED_TRACE(file);
    const auto g = loadGeometry(meshPath(file));
    ASSERT_TRUE(g.ok()) << g.status();
    EXPECT_EQ(triangleCount(*g), 1u);
    const MaterialDesc* packed = findMaterial(*g, material);
    ASSERT_NE(packed, nullptr);
    EXPECT_EQ(packed->type, MaterialType::kDiffuse);
    EXPECT_FALSE(packed->albedoTexture.has_value());
    expectRgb(packed->albedo, {0.5f, 0.5f, 0.5f});
    const auto w = warningsWith(*g, fmt::format("material '{}'", material));
    ASSERT_EQ(w.size(), 1u) << allWarnings(*g);
    EXPECT_NE(w[0].find("embedded"), std::string::npos) << w[0];
    EXPECT_EQ(g->everyWarning().size(), 1u) << allWarnings(*g);
  }
}

TEST(LoadGeometry, GltfPartsThatCannotBeMappedAreOneWarningNamingTheMaterial) {
  const auto g = loadGeometry(meshPath("unmappable.gltf"));
  ASSERT_TRUE(g.ok()) << g.status();
  const MaterialDesc* glass = findMaterial(*g, "glass");
  ASSERT_NE(glass, nullptr);
  EXPECT_EQ(glass->type, MaterialType::kDiffuse);  // metallicFactor 0.3 < 0.5
  expectRgb(glass->albedo, {0.9f, 0.9f, 0.9f});
  ASSERT_EQ(g->everyWarning().size(), 1u) << allWarnings(*g);
  const std::string w = g->everyWarning()[0];
  EXPECT_NE(w.find("material 'glass'"), std::string::npos) << w;
  for (const char* part :
       {"KHR_materials_transmission", "normalTexture", "alphaMode BLEND", "metallicFactor 0.3"}) {
    EXPECT_NE(w.find(part), std::string::npos) << part << " in: " << w;
  }
}

TEST(LoadGeometry, WarnsAboutMaterialsNoLibraryDefines) {
  const auto g = loadGeometry(meshPath("no_mtl.obj"));
  ASSERT_TRUE(g.ok()) << g.status();
  ASSERT_EQ(g->materials.size(), 1u);
  EXPECT_EQ(g->materials[0].name, "ghost");
  EXPECT_EQ(g->materials[0].type, MaterialType::kDiffuse);
  expectRgb(g->materials[0].albedo, {0.6f, 0.6f, 0.6f});
  const auto w = warningsWith(*g, "'ghost'");
  ASSERT_EQ(w.size(), 1u) << allWarnings(*g);
  EXPECT_NE(w[0].find("not defined in any MTL file"), std::string::npos) << w[0];
}

TEST(LoadGeometry, MissingFileIsNotFound) {
  const std::string path = meshPath("no_such_mesh.obj");
  const auto g = loadGeometry(path);
  ASSERT_FALSE(g.ok());
  EXPECT_EQ(g.status().code(), absl::StatusCode::kNotFound) << g.status();
  EXPECT_NE(g.status().message().find(path), std::string::npos) << g.status();
}

TEST(LoadGeometry, GarbageIsInvalidArgument) {
  const fs::path dir = makeTempDir("mesh-loader");
  for (uint32_t seed : {1u, 2u, 3u, 4u}) {
    const std::string path = (dir / fmt::format("garbage{}.obj", seed)).string();
    {
      std::ofstream out(path, std::ios::binary);
      uint32_t state = seed;
      for (int i = 0; i < 8192; ++i) {
        state = state * 1664525u + 1013904223u;
        out.put(static_cast<char>(state >> 24));
      }
    }
    const auto g = loadGeometry(path);
    ASSERT_FALSE(g.ok()) << path;
    EXPECT_EQ(g.status().code(), absl::StatusCode::kInvalidArgument) << g.status();
    EXPECT_NE(g.status().message().find(path), std::string::npos) << g.status();
  }
  // A glTF that is not JSON: Assimp's own message comes through.
  const std::string gltf = (dir / "broken.gltf").string();
  std::ofstream(gltf) << "{ \"asset\": { \"version\": \"2.0\" }, \"meshes\": [ {";
  const auto g = loadGeometry(gltf);
  ASSERT_FALSE(g.ok());
  EXPECT_EQ(g.status().code(), absl::StatusCode::kInvalidArgument) << g.status();
  EXPECT_NE(g.status().message().find("Assimp"), std::string::npos) << g.status();
  fs::remove_all(dir);
}

TEST(LoadGeometry, FileWithoutTrianglesIsInvalidArgument) {
  const auto g = loadGeometry(meshPath("lines_only.obj"));
  ASSERT_FALSE(g.ok());
  EXPECT_EQ(g.status().code(), absl::StatusCode::kInvalidArgument) << g.status();
  EXPECT_NE(g.status().message().find("no usable triangles"), std::string::npos) << g.status();
  EXPECT_NE(g.status().message().find("dropped 1 point and 2 line segments"), std::string::npos)
      << g.status();
}

TEST(LoadGeometry, RejectsOtherFormats) {
  const fs::path dir = makeTempDir("mesh-loader");
  const std::string path = (dir / "model.ply").string();
  std::ofstream(path) << "ply\nformat ascii 1.0\nend_header\n";
  const auto g = loadGeometry(path);
  ASSERT_FALSE(g.ok());
  EXPECT_EQ(g.status().code(), absl::StatusCode::kInvalidArgument) << g.status();
  EXPECT_NE(g.status().message().find(".ply"), std::string::npos) << g.status();
  fs::remove_all(dir);
}

TEST(LoadGeometry, SponzaLoadsWithItsTextures) {
  PBGI_REQUIRE_SHARED_SCENES(scenes);
  const fs::path obj = scenes / "sponza" / "sponza.obj";
  if (!fs::exists(obj)) GTEST_SKIP() << obj << " is absent";
  const auto g = loadGeometry(obj.string());
  ASSERT_TRUE(g.ok()) << g.status();
  // 66,445 triangles in the file (SOURCES.md), none of them degenerate.
  EXPECT_EQ(triangleCount(*g), 66445u) << allWarnings(*g);
  EXPECT_EQ(g->materials.size(), 19u);
  size_t textured = 0;
  for (const MaterialDesc& m : g->materials) {
    EXPECT_EQ(m.type, MaterialType::kDiffuse) << m.name;
    if (!m.albedoTexture) continue;
    ++textured;
    EXPECT_TRUE(fs::is_regular_file(*m.albedoTexture)) << m.name << ": " << *m.albedoTexture;
  }
  // Every map_Kd of sponza.mtl resolves; only sp_00_svod and sp_01_stub_baza_ have none.
  EXPECT_EQ(textured, 17u) << allWarnings(*g);
  EXPECT_TRUE(warningsWith(*g, "material").empty()) << allWarnings(*g);
  // Shading normals come from the file.
  size_t withNormals = 0;
  for (const MeshData& m : g->meshes) withNormals += m.normals.empty() ? 0 : 1;
  EXPECT_GT(withNormals, 0u);
}

}  // namespace
}  // namespace pbgi
