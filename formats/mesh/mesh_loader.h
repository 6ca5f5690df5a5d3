#pragma once
// Geometry files through Assimp: Wavefront OBJ (+MTL) and glTF 2.0 (.gltf / .glb).

#include <string>
#include <vector>

#include <absl/status/statusor.h>

#include "core/scene/mesh.h"
#include "core/scene/shot.h"

namespace pbgi {

struct LoadedGeometry {
  std::vector<MeshData> meshes;  // MeshData::materials index into `materials`
  // The file's materials mapped to our types (OBJ: Kd/map_Kd to diffuse albedo, Ke to
  // emissive radiance; glTF metallic-roughness to conductor/diffuse). Texture paths resolved.
  std::vector<MaterialDesc> materials;
  std::vector<std::string> warnings;  // about the file's geometry (cleaned meshes, dropped lines)
  // Per entry of `materials`: what the loader could not map (not in any MTL file, ignored
  // features). Moot when the shot defines a material of that name: loadFrameScene drops them.
  std::vector<std::vector<std::string>> materialWarnings;
  // Material libraries the file names but that are not there: moot when the shot defines
  // every material the file uses.
  std::vector<std::string> libraryWarnings;

  // All of the above, as the file alone would warn.
  std::vector<std::string> everyWarning() const {
    std::vector<std::string> all = warnings;
    for (const auto& m : materialWarnings) all.insert(all.end(), m.begin(), m.end());
    all.insert(all.end(), libraryWarnings.begin(), libraryWarnings.end());
    return all;
  }
};

absl::StatusOr<LoadedGeometry> loadGeometry(const std::string& path);

// The files loading `path` reads besides it, as the loader finds them: an OBJ's material
// libraries and the diffuse textures (map_Kd) they name. None listed for glTF (its external
// buffers and images). Reads the OBJ's text to find its mtllib statements.
std::vector<std::string> referencedFiles(const std::string& path);

}  // namespace pbgi
