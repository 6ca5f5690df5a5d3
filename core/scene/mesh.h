#pragma once
// Triangle meshes as loaded from geometry files, before they enter the Embree scene.

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "core/math/vec.h"

namespace pbgi {

struct MeshData {
  std::string name;
  std::vector<Vec3f> positions;
  // Per vertex, or empty (face normals are used). A zero vector marks a vertex without a
  // usable normal: the renderer then uses the face normal for triangles touching it.
  std::vector<Vec3f> normals;
  std::vector<Vec2f> uvs;           // per vertex, or empty
  std::vector<uint32_t> indices;    // three per triangle
  std::vector<uint32_t> materials;  // one per triangle: index into the scene's material table

  size_t triangleCount() const { return indices.size() / 3; }
};

// What cleaning a mesh removed or repaired, for the warning the loader prints.
struct MeshCleanReport {
  size_t nonFiniteTriangles = 0;   // a vertex with NaN or Inf (or edges that overflow float)
  size_t degenerateTriangles = 0;  // zero area, or collinear within float precision
  size_t badIndices = 0;           // a vertex index past the end of `positions`
  size_t badNormals = 0;           // non-finite or zero vertex normals (face normal used)
  size_t badUvs = 0;               // non-finite texture coordinates (set to 0)
  size_t droppedTriangles() const { return nonFiniteTriangles + degenerateTriangles + badIndices; }
  size_t total() const { return droppedTriangles() + badNormals + badUvs; }
  // "dropped 2 triangles with NaN/Inf vertices, 1 degenerate (zero-area) triangle; ...";
  // empty when nothing was changed.
  std::string toString() const;
};

// Drops triangles with out-of-range indices, non-finite vertices or (near) zero area, keeping
// `materials` in step, and repairs per-vertex data so that nothing downstream sees a NaN from
// the input: non-finite or zero normals become the zero vector (the renderer then shades
// with the face normal), the others are normalized; non-finite uvs become 0. Vertices that
// no triangle uses any more are left in place. Idempotent on the data (the scene cleans again
// on build); zero normals are reported again, as a zero normal from a file would be.
// `indices` must hold whole triangles and `materials` one entry per triangle; `normals` and
// `uvs` are empty or one per vertex (programmer errors otherwise).
MeshCleanReport cleanMesh(MeshData& mesh);

// Merges vertices whose position, normal and uv are bit for bit the same, remapping `indices`;
// returns how many vertices went. (Assimp's JoinIdenticalVertices merges within an absolute
// 1e-5, which collapses whole triangles of a model built in micrometres.)
size_t joinIdenticalVertices(MeshData& mesh);

// The triangles of a scene seen so far, by their three vertex positions (in any order, bit for
// bit), for dropping coincident copies: a surface modelled twice in one place renders once
// in the path tracer but would count its area twice in a point cloud.
class TriangleSet {
 public:
  TriangleSet();
  ~TriangleSet();
  // Drops the triangles of `mesh` that one seen before (in this mesh or an earlier one)
  // coincides with, keeping `materials` in step; returns how many.
  size_t dropCoincident(MeshData& mesh);

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace pbgi
