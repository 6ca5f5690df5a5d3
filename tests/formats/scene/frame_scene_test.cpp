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

// What the loader could not map of a file's material (here: no MTL file defines 'ghost', and
// the file's library is missing) warns only where the shot does not define that material.
TEST(FrameScene, AMaterialTheShotDefinesDoesNotWarnAboutTheFilesVersion) {
  const std::string mesh = (testing::sourceDir() / "tests/data/meshes/no_mtl.obj").string();
  const std::string head = "version = 1\n[shot]\nname = \"ghost\"\nframes = [1, 1]\n"
                           "resolution = [8, 8]\noutput = \"out/g.exr\"\n[camera]\n"
                           "position = [0, 0, 5]\nlook_at = [0, 0, 0]\nup = [0, 1, 0]\nfov_y_deg = 40.0\n"
                           "[[light]]\ntype = \"sphere\"\ncenter = [0, 2, 2]\nradius = 0.1\n"
                           "radiance = [1, 1, 1]\n[[geometry]]\nfile = \"" + mesh + "\"\n";
  const std::string ghost = "[[material]]\nname = \"ghost\"\ntype = \"diffuse\"\n"
                            "albedo = [0.5, 0.5, 0.5]\n";
  for (const bool defined : {false, true}) {
    auto shot = parseShot(head + (defined ? ghost : ""), "ghost.shot.toml");
    ASSERT_TRUE(shot.ok()) << shot.status();
    auto scene = loadFrameScene(*shot, 1);
    ASSERT_TRUE(scene.ok()) << scene.status();
    std::string all;
    for (const std::string& w : scene->warnings) all += "\n  " + w;
    if (defined) {
      EXPECT_TRUE(scene->warnings.empty()) << all;
    } else {
      EXPECT_NE(all.find("material 'ghost': not defined in any MTL file"), std::string::npos)
          << all;
      EXPECT_NE(all.find("material library 'not_here.mtl' not found"), std::string::npos) << all;
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
