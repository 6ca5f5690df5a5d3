#include "formats/scene/frame_scene.h"

#include <map>
#include <set>

#include <Imath/ImathMatrix.h>
#include <fmt/format.h>

#include "core/util/status.h"
#include "formats/image/image_io.h"
#include "formats/image/texture.h"
#include "formats/mesh/mesh_loader.h"

namespace pbgi {

namespace {

// Scale, then rotate about X, Y and Z in that order, then translate.
struct Transform {
  Imath::M33f rotation;
  float scale = 1.0f;
  Vec3f translate{0.0f};

  explicit Transform(const TransformParams& p) : scale(p.scale), translate(p.translate) {
    Imath::M33f rx, ry, rz;
    const float ax = radians(p.rotateDeg.x), ay = radians(p.rotateDeg.y), az = radians(p.rotateDeg.z);
    // Column-vector convention written out explicitly: Imath multiplies row vectors.
    rx = Imath::M33f(1, 0, 0, 0, std::cos(ax), -std::sin(ax), 0, std::sin(ax), std::cos(ax));
    ry = Imath::M33f(std::cos(ay), 0, std::sin(ay), 0, 1, 0, -std::sin(ay), 0, std::cos(ay));
    rz = Imath::M33f(std::cos(az), -std::sin(az), 0, std::sin(az), std::cos(az), 0, 0, 0, 1);
    rotation = rz * ry * rx;  // as matrices acting on column vectors
  }
  Vec3f rotate(const Vec3f& v) const {
    const Imath::M33f& m = rotation;
    return {m[0][0] * v.x + m[0][1] * v.y + m[0][2] * v.z,
            m[1][0] * v.x + m[1][1] * v.y + m[1][2] * v.z,
            m[2][0] * v.x + m[2][1] * v.y + m[2][2] * v.z};
  }
  Vec3f point(const Vec3f& p) const { return rotate(p * scale) + translate; }
  bool identity() const {
    return scale == 1.0f && translate == Vec3f(0.0f) && rotation == Imath::M33f();
  }
};

std::string transformText(const TransformParams& p) {
  return fmt::format("scale {}, rotate_deg {}, translate {}", p.scale, p.rotateDeg, p.translate);
}

Material toMaterial(const MaterialDesc& d) {
  Material m;
  m.name = d.name;
  m.type = d.type;
  if (d.albedo) m.albedo = *d.albedo;
  m.roughness = d.roughness;
  m.distribution = d.distribution;
  if (d.eta && d.k) {
    m.complexIor = true;
    m.eta = *d.eta;
    m.k = *d.k;
  } else if (d.specular) {
    m.specular = *d.specular;
  }
  m.tint = d.tint;
  m.ior = d.ior;
  m.radiance = d.type == MaterialType::kEmissive ? d.radiance : Rgb(0.0f);
  return m;
}

}  // namespace

namespace {

// A frame's scene as it is loaded: the materials by name (the shot's override the files'), the
// textures read once each, the triangles_ of every geometry file so far (coincident_ copies go),
// and the warnings_.
class FrameSceneLoader {
 public:
  absl::Status addShotMaterials(const ShotDesc& shot) {
    for (const MaterialDesc& d : shot.materials) {
      PBGI_ASSIGN_OR_RETURN(const uint32_t index, addMaterial(d));
      materialIndex_[d.name] = index;
      shotMaterials_.insert(d.name);
    }
    return absl::OkStatus();
  }

  // One geometry file's meshes at `frame`, transformed, their materials mapped to the scene's.
  absl::Status addGeometry(const GeometryDesc& g, const ShotDesc& shot, int frame) {
    auto loaded = loadGeometry(g.file);
    if (!loaded.ok()) {
      return withContext(loaded.status(), g.where.toString());
    }
    for (std::string& w : loaded->warnings) warnings_.push_back(std::move(w));
    // Map the file's material indices to the scene's. What the loader could not map of a
    // material warns only where the shot does not define that material itself.
    std::vector<uint32_t> remap(loaded->materials.size());
    bool usesFileMaterials = false;
    for (size_t i = 0; i < loaded->materials.size(); ++i) {
      const MaterialDesc& fileMaterial = loaded->materials[i];
      const bool shotDefines = shotMaterials_.contains(fileMaterial.name);
      usesFileMaterials = usesFileMaterials || !shotDefines;
      if (!shotDefines) {
        for (std::string& w : loaded->materialWarnings[i]) warnings_.push_back(std::move(w));
      }
      if (auto it = materialIndex_.find(fileMaterial.name); it != materialIndex_.end()) {
        remap[i] = it->second;
        continue;
      }
      if (fileMaterial.type == MaterialType::kEmissive && isFinite(fileMaterial.radiance) &&
          maxComponent(fileMaterial.radiance) > kMaxEmission) {
        return withContext(absl::InvalidArgumentError(fmt::format(
                               "geometry file '{}': material '{}' emits radiance {}: expected at "
                               "most {:g}",
                               g.file, fileMaterial.name, fileMaterial.radiance, kMaxEmission)),
                           g.where.toString());
      }
      auto index = addMaterial(fileMaterial);
      if (!index.ok()) return index.status();
      materialIndex_[fileMaterial.name] = *index;
      remap[i] = *index;
    }
    const TransformParams at = transformAt(g, shot.firstFrame, frame);
    const Transform xf(at);
    size_t kept = 0;
    std::vector<std::string> transformDrops;
    for (MeshData& mesh : loaded->meshes) {
      for (uint32_t& m : mesh.materials) m = remap.at(m);
      if (!xf.identity()) {
        for (Vec3f& p : mesh.positions) p = xf.point(p);
        for (Vec3f& n : mesh.normals) {
          const Vec3f r = xf.rotate(n);
          const float len = length(r);
          n = len > 0.0f ? r / len : Vec3f(0.0f);
        }
        // The loader kept what was usable as the file has it; scaled by 1e-30 (or 1e30, or
        // moved far off) a triangle's area can underflow or its edges overflow in float.
        const MeshCleanReport transformed = cleanMesh(mesh);
        if (transformed.droppedTriangles() > 0) {
          // Only the drops: the loader reported the repaired normals and uvs already.
          MeshCleanReport drops = transformed;
          drops.badNormals = drops.badUvs = 0;
          transformDrops.push_back(fmt::format("mesh '{}': {}", mesh.name, drops.toString()));
        }
      }
      kept += mesh.triangleCount();
      coincident_ += triangles_.dropCoincident(mesh);
      builder_.addMesh(std::move(mesh));
    }
    if (kept == 0) {
      return withContext(
          absl::InvalidArgumentError(fmt::format(
              "geometry file '{}': no usable triangles under the transform at frame {} ({}): {}",
              g.file, frame, transformText(at), fmt::join(transformDrops, "; "))),
          g.where.toString());
    }
    if (!transformDrops.empty()) {
      warnings_.push_back(fmt::format("{}: under the transform at frame {} ({}): {}", g.file, frame,
                                      transformText(at), fmt::join(transformDrops, "; ")));
    }
    if (usesFileMaterials) {
      for (std::string& w : loaded->libraryWarnings) warnings_.push_back(std::move(w));
    }
    return absl::OkStatus();
  }

  absl::Status addLights(const ShotDesc& shot) {
    for (const LightDesc& l : shot.lights) {
      if (l.type != LightType::kEnvironment) {
        builder_.addLight(l);
        continue;
      }
      auto image = readLatLong(l.file);
      if (!image.ok()) {
        return withContext(image.status(), l.where.toString());
      }
      float brightest = 0.0f;  // non-finite texels are black to the light
      for (const Rgb& c : image->texels) {
        if (isFinite(c)) brightest = std::max(brightest, maxComponent(c));
      }
      if (static_cast<double>(brightest) * l.scale > kMaxEmission) {
        return withContext(
            absl::InvalidArgumentError(fmt::format(
                "environment map '{}': texels of radiance up to {:g} times scale {:g}: expected "
                "at most {:g}",
                l.file, brightest, l.scale, kMaxEmission)),
            l.where.toString());
      }
      builder_.addLight(l, std::make_shared<const LatLongImage>(std::move(*image)));
    }
    return absl::OkStatus();
  }

  absl::StatusOr<FrameScene> finish(const ShotDesc& shot, int frame) {
    if (coincident_ > 0) {
      warnings_.push_back(fmt::format(
          "dropped {} triangle{} that coincide{} with another (the same three vertices): a "
          "surface modelled twice in one place renders once",
          coincident_, coincident_ == 1 ? "" : "s", coincident_ == 1 ? "s" : ""));
    }
    PBGI_ASSIGN_OR_RETURN(std::unique_ptr<Scene> scene, builder_.build());
    const CameraParams params = cameraAt(shot.camera, shot.firstFrame, frame);
    return FrameScene{
        std::move(scene),
        Camera(params, shot.width, shot.height, shot.camera.views, shot.camera.viewSpacing),
        std::move(warnings_)};
  }

 private:
  absl::StatusOr<std::shared_ptr<const Texture>> texture(const std::string& path) {
    if (auto it = textures_.find(path); it != textures_.end()) return it->second;
    PBGI_ASSIGN_OR_RETURN(std::shared_ptr<const Texture> t, loadImageTexture(path));
    textures_[path] = t;
    return t;
  }

  absl::StatusOr<uint32_t> addMaterial(const MaterialDesc& d) {
    Material m = toMaterial(d);
    if (d.albedoTexture) {
      auto t = texture(*d.albedoTexture);
      if (!t.ok()) {
        if (d.where.line > 0) return withContext(t.status(), d.where.toString());
        warnings_.push_back(fmt::format("material '{}': {}; using its constant albedo", d.name,
                                        t.status().message()));
      } else {
        m.albedoTexture = *t;
      }
    }
    return builder_.addMaterial(std::move(m));
  }

  SceneBuilder builder_;
  std::vector<std::string> warnings_;
  std::map<std::string, uint32_t> materialIndex_;
  std::map<std::string, std::shared_ptr<const Texture>> textures_;
  std::set<std::string> shotMaterials_;
  TriangleSet triangles_;
  size_t coincident_ = 0;
};

}  // namespace

absl::StatusOr<FrameScene> loadFrameScene(const ShotDesc& shot, int frame) {
  FrameSceneLoader loader;
  PBGI_RETURN_IF_ERROR(loader.addShotMaterials(shot));
  for (const GeometryDesc& g : shot.geometry)
    PBGI_RETURN_IF_ERROR(loader.addGeometry(g, shot, frame));
  PBGI_RETURN_IF_ERROR(loader.addLights(shot));
  return loader.finish(shot, frame);
}

}  // namespace pbgi
