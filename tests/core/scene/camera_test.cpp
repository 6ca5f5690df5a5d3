#include "core/scene/camera.h"

#include <gtest/gtest.h>

namespace pbgi {
namespace {

CameraParams cornellCamera() {
  CameraParams p;
  p.position = {278.0f, 273.0f, -800.0f};
  p.lookAt = {278.0f, 273.0f, 0.0f};
  p.up = {0.0f, 1.0f, 0.0f};
  p.fovYDeg = 37.0f;
  return p;
}

TEST(CameraTest, CentreRayLooksAtTargetAndRightIsMinusX) {
  const Camera camera(cornellCamera(), 100, 50);
  const Ray centre = camera.generateRay(50.0f, 25.0f, Vec2f(0.5f));
  EXPECT_NEAR(centre.dir.z, 1.0f, 1e-6f);
  // The right edge of the image looks towards -x with these axes.
  const Ray right = camera.generateRay(100.0f, 25.0f, Vec2f(0.5f));
  EXPECT_LT(right.dir.x, 0.0f);
  // The top edge is at half the vertical field of view.
  const Ray top = camera.generateRay(50.0f, 0.0f, Vec2f(0.5f));
  EXPECT_NEAR(std::atan2(top.dir.y, top.dir.z), radians(18.5f), 1e-5f);
}

TEST(CameraTest, ThinLensRaysMeetOnTheFocusPlane) {
  CameraParams p = cornellCamera();
  p.apertureRadius = 20.0f;
  p.focusDistance = 600.0f;
  const Camera camera(p, 64, 64);
  const Ray a = camera.generateRay(10.0f, 20.0f, Vec2f(0.1f, 0.9f));
  const Ray b = camera.generateRay(10.0f, 20.0f, Vec2f(0.8f, 0.3f));
  EXPECT_GT(length(a.origin - b.origin), 1.0f);
  const Vec3f fa = a.origin + a.dir * ((p.position.z + 600.0f - a.origin.z) / a.dir.z);
  const Vec3f fb = b.origin + b.dir * ((p.position.z + 600.0f - b.origin.z) / b.dir.z);
  EXPECT_LT(length(fa - fb), 1e-2f);
}

TEST(CameraTest, ArrayViewsAreOffsetAlongRightAndUp) {
  const Camera camera(cornellCamera(), 32, 32, {2, 1}, 10.0f);
  EXPECT_EQ(camera.imageWidth(), 64);
  EXPECT_EQ(camera.imageHeight(), 32);
  const Ray left = camera.generateRay(16.0f, 16.0f, Vec2f(0.5f));
  const Ray right = camera.generateRay(48.0f, 16.0f, Vec2f(0.5f));
  // Same direction, origins 10 apart along the camera's right axis (-x).
  EXPECT_NEAR(dot(left.dir, right.dir), 1.0f, 1e-6f);
  EXPECT_NEAR(right.origin.x - left.origin.x, -10.0f, 1e-3f);
}

}  // namespace
}  // namespace pbgi
