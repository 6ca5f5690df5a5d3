#pragma once
// Small scenes built in code for the renderer's tests.

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>

#include "core/scene/scene.h"

namespace pbgi::testing {

// A closed sphere (geodesic, 1280 triangles) of the given radius around the origin, every
// triangle with material `material`, normals pointing outwards.
inline MeshData makeSphereMesh(float radius, uint32_t material, int subdivisions = 3) {
  MeshData mesh;
  mesh.name = "sphere";
  const float t = (1.0f + std::sqrt(5.0f)) / 2.0f;
  std::vector<Vec3f> v = {{-1, t, 0}, {1, t, 0}, {-1, -t, 0}, {1, -t, 0}, {0, -1, t}, {0, 1, t},
                          {0, -1, -t}, {0, 1, -t}, {t, 0, -1}, {t, 0, 1}, {-t, 0, -1}, {-t, 0, 1}};
  std::vector<uint32_t> f = {0, 11, 5, 0, 5, 1, 0, 1, 7, 0, 7, 10, 0, 10, 11, 1, 5, 9, 5, 11, 4,
                             11, 10, 2, 10, 7, 6, 7, 1, 8, 3, 9, 4, 3, 4, 2, 3, 2, 6, 3, 6, 8,
                             3, 8, 9, 4, 9, 5, 2, 4, 11, 6, 2, 10, 8, 6, 7, 9, 8, 1};
  for (auto& p : v) p = normalize(p);
  for (int s = 0; s < subdivisions; ++s) {
    std::vector<uint32_t> next;
    std::map<std::pair<uint32_t, uint32_t>, uint32_t> mid;
    auto midpoint = [&](uint32_t a, uint32_t b) {
      auto key = std::minmax(a, b);
      if (auto it = mid.find(key); it != mid.end()) return it->second;
      v.push_back(normalize(v[a] + v[b]));
      return mid[key] = static_cast<uint32_t>(v.size() - 1);
    };
    for (size_t i = 0; i < f.size(); i += 3) {
      const uint32_t a = f[i], b = f[i + 1], c = f[i + 2];
      const uint32_t ab = midpoint(a, b), bc = midpoint(b, c), ca = midpoint(c, a);
      next.insert(next.end(), {a, ab, ca, b, bc, ab, c, ca, bc, ab, bc, ca});
    }
    f = std::move(next);
  }
  mesh.normals = v;
  for (auto& p : v) p *= radius;
  mesh.positions = std::move(v);
  mesh.indices = std::move(f);
  mesh.materials.assign(mesh.indices.size() / 3, material);
  return mesh;
}

inline MeshData makeQuadMesh(const Vec3f& corner, const Vec3f& u, const Vec3f& v, uint32_t material) {
  MeshData mesh;
  mesh.name = "quad";
  mesh.positions = {corner, corner + u, corner + u + v, corner + v};
  mesh.indices = {0, 1, 2, 0, 2, 3};
  mesh.materials = {material, material};
  return mesh;
}

// An open box in the spirit of the Cornell box (unit-ish, 1 x 1 x 1), white floor, ceiling
// and back wall, red left and green right walls, lit by a quad light under the ceiling.
inline std::unique_ptr<Scene> makeBoxScene() {
  SceneBuilder b;
  Material white, red, green;
  white.albedo = Rgb(0.73f);
  red.albedo = Rgb(0.63f, 0.065f, 0.05f);
  green.albedo = Rgb(0.14f, 0.45f, 0.091f);
  const uint32_t w = b.addMaterial(white), r = b.addMaterial(red), g = b.addMaterial(green);
  b.addMesh(makeQuadMesh({0, 0, 0}, {0, 0, 1}, {1, 0, 0}, w));  // floor
  b.addMesh(makeQuadMesh({0, 1, 0}, {1, 0, 0}, {0, 0, 1}, w));  // ceiling
  b.addMesh(makeQuadMesh({0, 0, 1}, {0, 1, 0}, {1, 0, 0}, w));  // back
  b.addMesh(makeQuadMesh({1, 0, 0}, {0, 0, 1}, {0, 1, 0}, r));  // left (x = 1)
  b.addMesh(makeQuadMesh({0, 0, 0}, {0, 1, 0}, {0, 0, 1}, g));  // right (x = 0)
  MeshData block = makeSphereMesh(0.2f, w, 2);
  for (auto& p : block.positions) p += Vec3f(0.5f, 0.2f, 0.6f);
  b.addMesh(std::move(block));
  LightDesc light;
  light.type = LightType::kQuad;
  light.corner = {0.6f, 0.999f, 0.4f};
  light.edgeU = {0.0f, 0.0f, 0.2f};
  light.edgeV = {-0.2f, 0.0f, 0.0f};
  light.radiance = Rgb(17.0f, 12.0f, 4.0f);
  b.addLight(light);
  auto scene = b.build();
  return scene.ok() ? std::move(*scene) : nullptr;
}

// A closed unit box from (x0, 0, 0) to (x0 + 1, 1, 1).
inline void addClosedBox(SceneBuilder& b, float x0, uint32_t material) {
  const float x1 = x0 + 1.0f;
  b.addMesh(makeQuadMesh({x0, 0, 0}, {0, 0, 1}, {1, 0, 0}, material));  // floor
  b.addMesh(makeQuadMesh({x0, 1, 0}, {1, 0, 0}, {0, 0, 1}, material));  // ceiling
  b.addMesh(makeQuadMesh({x0, 0, 1}, {0, 1, 0}, {1, 0, 0}, material));  // back
  b.addMesh(makeQuadMesh({x0, 0, 0}, {1, 0, 0}, {0, 1, 0}, material));  // front
  b.addMesh(makeQuadMesh({x0, 0, 0}, {0, 1, 0}, {0, 0, 1}, material));  // x0 wall
  b.addMesh(makeQuadMesh({x1, 0, 0}, {0, 0, 1}, {0, 1, 0}, material));  // x1 wall
}

// Two closed white rooms either side of a wall 1 cm thick (x from 1 to 1.01), a quad light
// under the ceiling of the one at x > 1.01; the other is dark.
inline std::unique_ptr<Scene> makeTwoRoomsScene() {
  SceneBuilder b;
  Material white;
  white.albedo = Rgb(0.8f);
  const uint32_t w = b.addMaterial(white);
  addClosedBox(b, 0.0f, w);   // dark
  addClosedBox(b, 1.01f, w);  // lit
  LightDesc light;
  light.type = LightType::kQuad;
  light.corner = {1.61f, 0.999f, 0.4f};
  light.edgeU = {0.0f, 0.0f, 0.2f};
  light.edgeV = {-0.2f, 0.0f, 0.0f};
  light.radiance = Rgb(20.0f);
  b.addLight(light);
  auto scene = b.build();
  return scene.ok() ? std::move(*scene) : nullptr;
}

}  // namespace pbgi::testing
