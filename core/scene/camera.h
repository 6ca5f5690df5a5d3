#pragma once
// The shot camera: a pinhole or thin lens, optionally an array of views (stereo, light field).
// A camera array renders into one mosaic image: view (column c, row r) covers the pixels
// [c*width, (c+1)*width) x [r*height, (r+1)*height), row 0 of views on top.

#include "core/math/vec.h"
#include "core/scene/shot.h"

namespace pbgi {

struct Ray {
  Vec3f origin;
  Vec3f dir;  // unit length
  float tMin = 0.0f;
  float tMax = std::numeric_limits<float>::infinity();
};

class Camera {
 public:
  // width, height: pixels of one view.
  Camera(const CameraParams& params, int width, int height, Vec2i views = {1, 1},
         float viewSpacing = 0.0f);

  int viewWidth() const { return width_; }
  int viewHeight() const { return height_; }
  // Size of the whole (mosaic) image.
  int imageWidth() const { return width_ * views_.x; }
  int imageHeight() const { return height_ * views_.y; }
  // Columns and rows of the camera array ({1, 1} for a single view).
  Vec2i views() const { return views_; }

  // A primary ray through the mosaic image position (x, y) in pixels (y down), with a lens
  // sample in [0,1)^2 used only when the aperture is open.
  Ray generateRay(float x, float y, const Vec2f& lensSample) const;

 private:
  Vec3f origin_, forward_, right_, up_;
  float tanHalfFovY_ = 1.0f;
  float aspect_ = 1.0f;
  float apertureRadius_ = 0.0f;
  float focusDistance_ = 1.0f;
  int width_ = 1, height_ = 1;
  Vec2i views_{1, 1};
  float viewSpacing_ = 0.0f;
};

}  // namespace pbgi
