#include "core/scene/camera.h"

#include <algorithm>

#include "core/sampling/sampling.h"
#include "core/util/check.h"

namespace pbgi {

Camera::Camera(const CameraParams& p, int width, int height, Vec2i views, float viewSpacing)
    : width_(width), height_(height), views_(views), viewSpacing_(viewSpacing) {
  PBGI_CHECK_GT(width, 0);
  PBGI_CHECK_GT(height, 0);
  PBGI_CHECK_GE(views.x, 1);
  PBGI_CHECK_GE(views.y, 1);
  origin_ = p.position;
  forward_ = normalize(p.lookAt - p.position);
  // Right-handed: with forward +z and up +y, the image's right is -x (the Cornell box's red
  // wall, at large x, appears on the left as in its published photographs).
  right_ = normalize(cross(forward_, p.up));
  up_ = cross(right_, forward_);
  tanHalfFovY_ = std::tan(radians(p.fovYDeg) * 0.5f);
  aspect_ = static_cast<float>(width) / static_cast<float>(height);
  apertureRadius_ = p.apertureRadius;
  focusDistance_ = p.focusDistance > 0.0f ? p.focusDistance : 1.0f;
  PBGI_CHECK(isFinite(forward_) && isFinite(right_));
}

Ray Camera::generateRay(float x, float y, const Vec2f& lensSample) const {
  const int col = std::clamp(static_cast<int>(x) / width_, 0, views_.x - 1);
  const int row = std::clamp(static_cast<int>(y) / height_, 0, views_.y - 1);
  const float lx = x - static_cast<float>(col * width_);
  const float ly = y - static_cast<float>(row * height_);
  // Views sit on a grid centred on the camera, in the plane of right and up.
  const float offX = (static_cast<float>(col) - 0.5f * static_cast<float>(views_.x - 1)) * viewSpacing_;
  const float offY = (0.5f * static_cast<float>(views_.y - 1) - static_cast<float>(row)) * viewSpacing_;
  const Vec3f viewOrigin = origin_ + right_ * offX + up_ * offY;

  const float sx = (2.0f * lx / static_cast<float>(width_) - 1.0f) * tanHalfFovY_ * aspect_;
  const float sy = (1.0f - 2.0f * ly / static_cast<float>(height_)) * tanHalfFovY_;
  Vec3f dir = normalize(forward_ + right_ * sx + up_ * sy);
  Ray ray{viewOrigin, dir};
  if (apertureRadius_ > 0.0f) {
    const Vec3f focus = viewOrigin + dir * (focusDistance_ / dot(dir, forward_));
    const Vec2f d = sampleUniformDiskConcentric(lensSample) * apertureRadius_;
    ray.origin = viewOrigin + right_ * d.x + up_ * d.y;
    ray.dir = normalize(focus - ray.origin);
  }
  return ray;
}

}  // namespace pbgi
