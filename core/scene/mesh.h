#pragma once
// Triangle meshes as loaded from geometry files, before they enter the Embree scene.

#include <cstdint>
#include <string>
#include <vector>

#include "core/math/vec.h"

namespace pbgi {

struct MeshData {
  std::string name;
  std::vector<Vec3f> positions;
  std::vector<Vec3f> normals;  // per vertex, or empty (face normals are used)
  std::vector<Vec2f> uvs;      // per vertex, or empty
  std::vector<uint32_t> indices;    // three per triangle
  std::vector<uint32_t> materials;  // one per triangle: index into the scene's material table

  size_t triangleCount() const { return indices.size() / 3; }
};

// What cleaning a mesh removed or repaired, for the warning the loader prints.
struct MeshCleanReport {
  size_t nonFiniteTriangles = 0;  // a vertex with NaN or Inf
  size_t degenerateTriangles = 0; // zero area
  size_t badNormals = 0;          // non-finite or zero vertex normals (face normal used)
  size_t badUvs = 0;              // non-finite texture coordinates (set to 0)
  size_t total() const { return nonFiniteTriangles + degenerateTriangles + badNormals + badUvs; }
};

// Drops triangles with non-finite vertices or zero area, and repairs bad normals and uvs, so
// that nothing downstream sees a NaN from the input.
MeshCleanReport cleanMesh(MeshData& mesh);

}  // namespace pbgi
