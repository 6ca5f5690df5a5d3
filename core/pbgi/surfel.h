#pragma once
// A surfel: a small oriented disk standing for a piece of surface, the unit of point-based
// global illumination. The baker samples them from the scene's triangles and lights them;
// the tree aggregates them; the renderer gathers from them.

#include <cstdint>
#include <vector>

#include "core/math/vec.h"

namespace pbgi {

// What a surfel's surface does with light, so that work a scene does not need is skipped
// (no glossy or transmissive surfels: no directional radiance is baked or gathered).
enum class MaterialClass : uint8_t { kDiffuse = 0, kGlossy = 1, kTransmissive = 2, kEmissive = 3 };

struct Surfel {
  Vec3f position{0.0f};
  Vec3f normal{0.0f, 0.0f, 1.0f};  // unit; the triangle's front (winding) side
  float radius = 0.0f;             // area = pi * radius^2
  Rgb albedo{0.0f};                // diffuse reflectance (texture looked up)
  Rgb radiance{0.0f};              // outgoing radiance, diffuse: emitted + reflected
  MaterialClass materialClass = MaterialClass::kDiffuse;
  uint32_t triangle = 0;           // global triangle id (Scene::globalTriangleId)
  Vec2f barycentric{0.0f};         // (b1, b2) on that triangle

  float area() const { return kPi * radius * radius; }
};

}  // namespace pbgi
