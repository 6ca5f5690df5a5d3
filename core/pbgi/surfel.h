#pragma once
// A surfel: a small oriented disk standing for a piece of surface, the unit of point-based
// global illumination. The baker samples them from the scene's triangles and lights them;
// the tree aggregates them; the renderer gathers from them.

#include <cstdint>
#include <utility>
#include <vector>

#include "core/math/vec.h"

namespace pbgi {

// What a surfel's surface does with light, so that work a scene does not need is skipped
// (no glossy or transmissive surfels: no directional radiance is baked or gathered).
enum class MaterialClass : uint8_t { kDiffuse = 0, kGlossy = 1, kTransmissive = 2, kEmissive = 3 };

struct Surfel {
  Vec3f position{0.0f};
  Vec3f normal{0.0f, 0.0f, 1.0f};  // unit; the triangle's front (winding) side, or in a tree
                                   // the brighter side (facingBrighterSide)
  float radius = 0.0f;             // area = pi * radius^2
  Rgb albedo{0.0f};                // diffuse reflectance (texture looked up)
  Rgb radiance{0.0f};              // outgoing radiance of the front side (along normal), diffuse
  Rgb backRadiance{0.0f};          // of the back side (against normal): surfaces are two-sided
  MaterialClass materialClass = MaterialClass::kDiffuse;
  uint32_t triangle = 0;           // global triangle id (Scene::globalTriangleId)
  Vec2f barycentric{0.0f};         // (b1, b2) on that triangle

  float area() const { return kPi * radius * radius; }
};

// A surfel turned to face its brighter side: the normal flipped and the two radiances
// swapped when the back sends more light (by luminance) than the front. The same disk, the
// same light: what a tree stores, so that its spherical functions describe the light that
// matters most (tree.h).
inline void facingBrighterSide(Surfel& s) {
  if (luminance(s.backRadiance) > luminance(s.radiance)) {
    s.normal = -s.normal;
    std::swap(s.radiance, s.backRadiance);
  }
}

}  // namespace pbgi
