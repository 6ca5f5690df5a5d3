#include "formats/scene/frame_scene.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <vector>

#include "formats/shot/shot_file.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

// Every scene the project ships loads as its README says: the shot parses, every frame's
// geometry, materials and lights build, and nothing is left for a warning (the shot sets every
// material its geometry names).
TEST(FrameScene, EveryShippedSceneLoadsWithoutWarnings) {
  std::vector<fs::path> shots;
  for (const auto& dir : fs::directory_iterator(testing::sourceDir() / "config" / "scenes")) {
    for (const auto& file : fs::directory_iterator(dir.path())) {
      if (file.path().string().ends_with(".shot.toml")) shots.push_back(file.path());
    }
  }
  ASSERT_GE(shots.size(), 3u);  // the Cornell box, the glossy plates, the glass caustic
  for (const fs::path& path : shots) {
    auto shot = loadShotFile(path.string());
    ASSERT_TRUE(shot.ok()) << path << ": " << shot.status();
    for (int frame = shot->firstFrame; frame <= shot->lastFrame; ++frame) {
      auto scene = loadFrameScene(*shot, frame);
      ASSERT_TRUE(scene.ok()) << path << " frame " << frame << ": " << scene.status();
      EXPECT_GT(scene->scene->stats().triangles, 0u) << path;
      EXPECT_GT(scene->scene->stats().lights, 0u) << path;
      for (const std::string& w : scene->warnings) ADD_FAILURE() << path << ": " << w;
    }
  }
}

// The shipped glossy and caustic scenes have the materials they are for.
TEST(FrameScene, TheGlossyAndCausticScenesHaveTheirMaterials) {
  const fs::path scenes = testing::sourceDir() / "config" / "scenes";
  auto plates = loadShotFile((scenes / "glossy-plates" / "plates.shot.toml").string());
  ASSERT_TRUE(plates.ok()) << plates.status();
  auto platesScene = loadFrameScene(*plates, plates->firstFrame);
  ASSERT_TRUE(platesScene.ok()) << platesScene.status();
  int conductors = 0;
  for (const Material& m : platesScene->scene->materials()) {
    conductors += m.type == MaterialType::kConductor && m.roughness > 0.0f;
  }
  EXPECT_EQ(conductors, 4);
  auto caustic = loadShotFile((scenes / "glass-caustic" / "caustic.shot.toml").string());
  ASSERT_TRUE(caustic.ok()) << caustic.status();
  auto causticScene = loadFrameScene(*caustic, caustic->firstFrame);
  ASSERT_TRUE(causticScene.ok()) << causticScene.status();
  int dielectrics = 0;
  for (const Material& m : causticScene->scene->materials()) {
    dielectrics += m.type == MaterialType::kDielectric;
  }
  EXPECT_EQ(dielectrics, 1);
}

}  // namespace
}  // namespace pbgi
