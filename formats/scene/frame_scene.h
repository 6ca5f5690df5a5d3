#pragma once
// Builds the renderable scene of one frame of a shot: geometry files loaded and transformed
// by their keyframes, materials merged (the shot's [[material]] overrides the file's by name),
// textures and environment maps decoded, camera evaluated at the frame.

#include <memory>
#include <string>
#include <vector>

#include <absl/status/statusor.h>

#include "core/scene/camera.h"
#include "core/scene/scene.h"
#include "core/scene/shot.h"

namespace pbgi {

struct FrameScene {
  std::unique_ptr<Scene> scene;
  Camera camera;
  std::vector<std::string> warnings;
};

// Loads what the frame needs. Geometry, textures and environment maps are read once per
// call; render many frames of one shot through a ShotCache to reuse them. Triangles that a
// geometry's transform makes unusable (its area underflows, its edges overflow) are dropped
// and counted in a warning; a geometry left with none is refused, naming its file.
absl::StatusOr<FrameScene> loadFrameScene(const ShotDesc& shot, int frame);

}  // namespace pbgi
