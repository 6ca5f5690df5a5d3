#include "core/scene/scene.h"

#include <gtest/gtest.h>

#include "tests/core/render/test_scenes.h"

namespace pbgi {
namespace {

// Quads across the z axis at the given depths, each 2 x 2 around the axis, of `material`.
void addPanes(SceneBuilder& b, std::initializer_list<float> depths, uint32_t material) {
  for (const float z : depths) {
    b.addMesh(testing::makeQuadMesh({-1.0f, -1.0f, z}, {2.0f, 0.0f, 0.0f}, {0.0f, 2.0f, 0.0f},
                                    material));
  }
}

// The segment along the z axis from z = 0 to z = `to`.
Ray alongZ(float to) { return Ray{Vec3f(0.0f), Vec3f(0.0f, 0.0f, 1.0f), 0.0f, to}; }

Material glass() {
  Material m;
  m.type = MaterialType::kDielectric;
  m.ior = 1.5f;
  return m;
}

TEST(SceneTest, OpaqueOcclusionLooksThroughGlass) {
  SceneBuilder b;
  const uint32_t g = b.addMaterial(glass());
  const uint32_t wall = b.addMaterial(Material{});
  addPanes(b, {1.0f, 1.1f}, g);  // a glass slab
  addPanes(b, {3.0f}, wall);     // a wall behind it
  auto scene = b.build();
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_TRUE((*scene)->occluded(alongZ(2.0f)));
  EXPECT_FALSE((*scene)->occludedByOpaque(alongZ(2.0f)));  // through the slab
  EXPECT_TRUE((*scene)->occludedByOpaque(alongZ(4.0f)));   // through the slab to the wall
  EXPECT_FALSE((*scene)->occludedByOpaque(alongZ(0.5f)));  // short of everything
}

TEST(SceneTest, OpaqueOcclusionIsOcclusionWithoutGlass) {
  SceneBuilder b;
  const uint32_t wall = b.addMaterial(Material{});
  addPanes(b, {1.0f}, wall);
  auto scene = b.build();
  ASSERT_TRUE(scene.ok()) << scene.status();
  for (const float to : {0.5f, 2.0f}) {
    EXPECT_EQ((*scene)->occludedByOpaque(alongZ(to)), (*scene)->occluded(alongZ(to))) << to;
  }
}

// Any number of glass surfaces in a row is passed: each is filtered out of the one query.
TEST(SceneTest, ManyPanesOfGlassArePassed) {
  SceneBuilder b;
  const uint32_t g = b.addMaterial(glass());
  const uint32_t wall = b.addMaterial(Material{});
  for (int i = 0; i < 20; ++i) addPanes(b, {1.0f + 0.1f * static_cast<float>(i)}, g);
  addPanes(b, {4.0f}, wall);
  auto scene = b.build();
  ASSERT_TRUE(scene.ok()) << scene.status();
  EXPECT_FALSE((*scene)->occludedByOpaque(alongZ(3.5f)));
  EXPECT_TRUE((*scene)->occludedByOpaque(alongZ(4.5f)));
  EXPECT_TRUE((*scene)->occluded(alongZ(3.5f)));
}

// One mesh holding a glass triangle and an opaque one: only the glass is passed.
TEST(SceneTest, GlassIsPassedTriangleByTriangle) {
  SceneBuilder b;
  const uint32_t g = b.addMaterial(glass());
  const uint32_t wall = b.addMaterial(Material{});
  MeshData pane = testing::makeQuadMesh({-1.0f, -1.0f, 1.0f}, {2.0f, 0.0f, 0.0f},
                                        {0.0f, 2.0f, 0.0f}, g);
  pane.materials = {g, wall};  // the second triangle (corners 0, 2, 3) opaque
  b.addMesh(std::move(pane));
  auto scene = b.build();
  ASSERT_TRUE(scene.ok()) << scene.status();
  // Through the first triangle (below the diagonal y = x) and through the second.
  const auto segment = [](float x, float y) {
    return Ray{Vec3f(x, y, 0.0f), Vec3f(0.0f, 0.0f, 1.0f), 0.0f, 2.0f};
  };
  EXPECT_FALSE((*scene)->occludedByOpaque(segment(0.5f, -0.5f)));
  EXPECT_TRUE((*scene)->occludedByOpaque(segment(-0.5f, 0.5f)));
}

}  // namespace
}  // namespace pbgi
