#pragma once
// Textures as the renderer sees them. Concrete image textures live in formats/ (OIIO's
// TextureSystem); core only evaluates them.

#include <memory>

#include "core/math/vec.h"

namespace pbgi {

class Texture {
 public:
  virtual ~Texture() = default;
  // Linear RGB at texture coordinates uv (OBJ convention: v = 0 at the bottom row).
  // Must be safe to call from many threads at once.
  virtual Rgb evaluate(const Vec2f& uv) const = 0;
};

// An equirectangular (lat-long) radiance map, +y up, as the spec describes: row 0 looks
// along +y, the centre column along +x, three quarters across along +z.
struct LatLongImage {
  int width = 0;
  int height = 0;
  std::vector<Rgb> texels;  // row-major, row 0 on top
};

}  // namespace pbgi
