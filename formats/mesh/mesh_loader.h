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
  std::vector<std::string> warnings;  // e.g. a material the loader could not map, by name
};

absl::StatusOr<LoadedGeometry> loadGeometry(const std::string& path);

}  // namespace pbgi
