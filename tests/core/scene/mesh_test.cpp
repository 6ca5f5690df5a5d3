#include "core/scene/mesh.h"

#include <cmath>
#include <limits>

#include <gtest/gtest.h>

namespace pbgi {
namespace {

constexpr float kNan = std::numeric_limits<float>::quiet_NaN();
constexpr float kInf = std::numeric_limits<float>::infinity();

// A unit square in z = 0 as two triangles, materials 10 and 11.
MeshData square() {
  MeshData mesh;
  mesh.name = "square";
  mesh.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  mesh.indices = {0, 1, 2, 0, 2, 3};
  mesh.materials = {10, 11};
  return mesh;
}

// Appends triangle (a, b, c) with its own material id.
void addTriangle(MeshData& mesh, const Vec3f& a, const Vec3f& b, const Vec3f& c,
                 uint32_t material) {
  const auto base = static_cast<uint32_t>(mesh.positions.size());
  mesh.positions.insert(mesh.positions.end(), {a, b, c});
  mesh.indices.insert(mesh.indices.end(), {base, base + 1, base + 2});
  mesh.materials.push_back(material);
}

TEST(CleanMesh, LeavesAGoodMeshAlone) {
  MeshData mesh = square();
  mesh.normals = {{0, 0, 1}, {0, 0, 1}, {0, 0, 1}, {0, 0, 1}};
  mesh.uvs = {{0, 0}, {1, 0}, {1, 1}, {0, 1}};
  const MeshData before = mesh;
  const MeshCleanReport report = cleanMesh(mesh);
  EXPECT_EQ(report.total(), 0u);
  EXPECT_EQ(report.toString(), "");
  EXPECT_EQ(mesh.indices, before.indices);
  EXPECT_EQ(mesh.materials, before.materials);
  EXPECT_EQ(mesh.normals, before.normals);
  EXPECT_EQ(mesh.uvs, before.uvs);
}

TEST(CleanMesh, DropsNonFiniteTrianglesAndKeepsMaterialsInStep) {
  MeshData mesh = square();
  addTriangle(mesh, {0, 0, 0}, {kNan, 0, 0}, {0, 1, 0}, 20);
  addTriangle(mesh, {5, 5, 5}, {6, 5, 5}, {5, 6, 5}, 21);  // good, after a bad one
  addTriangle(mesh, {0, 0, 0}, {1, kInf, 0}, {0, 1, 0}, 22);
  addTriangle(mesh, {0, 0, -kInf}, {1, 0, 0}, {0, 1, 0}, 23);
  // Finite, but the edge vectors' cross product overflows float.
  addTriangle(mesh, {0, 0, 0}, {3e20f, 0, 0}, {0, 3e20f, 0}, 24);

  const MeshCleanReport report = cleanMesh(mesh);
  EXPECT_EQ(report.nonFiniteTriangles, 4u);
  EXPECT_EQ(report.degenerateTriangles, 0u);
  EXPECT_EQ(report.droppedTriangles(), 4u);
  ASSERT_EQ(mesh.triangleCount(), 3u);
  EXPECT_EQ(mesh.materials, (std::vector<uint32_t>{10, 11, 21}));
  EXPECT_EQ(mesh.positions[mesh.indices[6]], Vec3f(5, 5, 5));
  EXPECT_EQ(report.toString(), "dropped 4 triangles with NaN/Inf vertices");
}

TEST(CleanMesh, DropsDegenerateTrianglesAtAnyScale) {
  MeshData mesh;
  addTriangle(mesh, {0, 0, 0}, {1, 0, 0}, {0, 0, 0}, 0);            // repeated vertex
  addTriangle(mesh, {0, 0, 0}, {1, 1, 1}, {2, 2, 2}, 1);            // exactly collinear
  addTriangle(mesh, {1, 2, 3}, {1, 2, 3}, {1, 2, 3}, 2);            // a point
  addTriangle(mesh, {0, 0, 0}, {1, 0, 0}, {0.5f, 1e-13f, 0}, 3);    // area 5e-14 of 1
  addTriangle(mesh, {0, 0, 0}, {1, 0, 0}, {0.5f, 1e-3f, 0}, 4);     // a sliver, but real
  addTriangle(mesh, {0, 0, 0}, {1e-15f, 0, 0}, {0, 1e-15f, 0}, 5);  // tiny, but real
  addTriangle(mesh, {0, 0, 0}, {1e15f, 0, 0}, {0, 1e15f, 0}, 6);    // huge, but real
  const MeshCleanReport report = cleanMesh(mesh);
  EXPECT_EQ(report.degenerateTriangles, 4u);
  EXPECT_EQ(report.nonFiniteTriangles, 0u);
  EXPECT_EQ(mesh.materials, (std::vector<uint32_t>{4, 5, 6}));
  EXPECT_EQ(report.toString(), "dropped 4 degenerate (zero-area) triangles");
}

TEST(CleanMesh, DropsTrianglesWithOutOfRangeIndices) {
  MeshData mesh = square();
  mesh.indices.insert(mesh.indices.end(), {0, 1, 4});
  mesh.materials.push_back(12);
  const MeshCleanReport report = cleanMesh(mesh);
  EXPECT_EQ(report.badIndices, 1u);
  EXPECT_EQ(mesh.triangleCount(), 2u);
  EXPECT_EQ(mesh.materials, (std::vector<uint32_t>{10, 11}));
  EXPECT_EQ(report.toString(), "dropped 1 triangle with out-of-range vertex indices");
}

TEST(CleanMesh, ZeroesBadNormalsAndNormalizesTheRest) {
  MeshData mesh = square();
  mesh.positions.push_back({9, 9, 9});  // used by no triangle
  mesh.normals = {{0, 0, 1}, {kNan, 0, 1}, {0, 0, 0}, {0, 0, 3}, {kInf, 0, 0}};
  const MeshCleanReport report = cleanMesh(mesh);
  EXPECT_EQ(report.badNormals, 2u) << "the unused vertex's normal is repaired but not counted";
  EXPECT_EQ(mesh.normals[0], Vec3f(0, 0, 1));
  EXPECT_EQ(mesh.normals[1], Vec3f(0, 0, 0));
  EXPECT_EQ(mesh.normals[2], Vec3f(0, 0, 0));
  EXPECT_FLOAT_EQ(mesh.normals[3].z, 1.0f);
  EXPECT_EQ(mesh.normals[4], Vec3f(0, 0, 0));
  EXPECT_EQ(mesh.triangleCount(), 2u) << "bad normals do not drop triangles";
  EXPECT_EQ(report.toString(), "2 vertex normals missing, zero or non-finite (face normal used)");
}

TEST(CleanMesh, ZeroesNonFiniteUvs) {
  MeshData mesh = square();
  mesh.uvs = {{0, 0}, {kNan, 0.5f}, {1, kInf}, {0.25f, 0.75f}};
  const MeshCleanReport report = cleanMesh(mesh);
  EXPECT_EQ(report.badUvs, 2u);
  EXPECT_EQ(mesh.uvs[1], Vec2f(0, 0));
  EXPECT_EQ(mesh.uvs[2], Vec2f(0, 0));
  EXPECT_EQ(mesh.uvs[3], Vec2f(0.25f, 0.75f));
}

TEST(CleanMesh, IsIdempotent) {
  MeshData mesh = square();
  addTriangle(mesh, {0, 0, 0}, {kNan, 0, 0}, {0, 1, 0}, 20);
  addTriangle(mesh, {0, 0, 0}, {1, 1, 1}, {2, 2, 2}, 21);
  mesh.normals.assign(mesh.positions.size(), Vec3f(0, 0, 2));
  mesh.normals[1] = Vec3f(kNan);
  mesh.uvs.assign(mesh.positions.size(), Vec2f(kInf));
  const MeshCleanReport first = cleanMesh(mesh);
  EXPECT_EQ(first.nonFiniteTriangles, 1u);
  EXPECT_EQ(first.degenerateTriangles, 1u);
  EXPECT_EQ(first.badNormals, 1u);
  EXPECT_EQ(first.badUvs, 4u);
  EXPECT_EQ(first.toString(),
            "dropped 1 triangle with NaN/Inf vertices, 1 degenerate (zero-area) triangle; 1 "
            "vertex normal missing, zero or non-finite (face normal used); 4 non-finite uvs "
            "set to 0");
  const MeshData cleaned = mesh;
  const MeshCleanReport second = cleanMesh(mesh);
  EXPECT_EQ(second.droppedTriangles(), 0u);
  EXPECT_EQ(second.badUvs, 0u);
  // A zero normal is the "use the face normal" marker, and a file can hold it too: it is
  // counted each time.
  EXPECT_EQ(second.badNormals, 1u);
  EXPECT_EQ(mesh.indices, cleaned.indices);
  EXPECT_EQ(mesh.normals, cleaned.normals);
}

TEST(CleanMeshDeathTest, MaterialsMustMatchTriangles) {
  MeshData mesh = square();
  mesh.materials.pop_back();
  EXPECT_DEATH(cleanMesh(mesh), "materials");
}

}  // namespace
}  // namespace pbgi
