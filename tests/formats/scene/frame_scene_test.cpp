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

// The materials of a shipped shot's first frame that `is` holds for (-1 when it does not load,
// which fails the test).
template <typename Predicate>
int countMaterials(const std::string& shotUnderConfigScenes, Predicate is) {
  const fs::path path = testing::sourceDir() / "config" / "scenes" / shotUnderConfigScenes;
  auto shot = loadShotFile(path.string());
  EXPECT_TRUE(shot.ok()) << path << ": " << shot.status();
  if (!shot.ok()) return -1;
  auto scene = loadFrameScene(*shot, shot->firstFrame);
  EXPECT_TRUE(scene.ok()) << path << ": " << scene.status();
  if (!scene.ok()) return -1;
  int count = 0;
  for (const Material& m : scene->scene->materials()) count += is(m) ? 1 : 0;
  return count;
}

// The shipped glossy and caustic scenes have the materials they are for.
TEST(FrameScene, TheGlossyAndCausticScenesHaveTheirMaterials) {
  EXPECT_EQ(countMaterials("glossy-plates/plates.shot.toml",
                           [](const Material& m) {
                             return m.type == MaterialType::kConductor && m.roughness > 0.0f;
                           }),
            4);
  EXPECT_EQ(countMaterials("glass-caustic/caustic.shot.toml",
                           [](const Material& m) { return m.type == MaterialType::kDielectric; }),
            1);
}

}  // namespace
}  // namespace pbgi
