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

absl::StatusOr<FrameScene> loadFrameScene(const ShotDesc& shot, int frame) {
  std::vector<std::string> warnings;
  SceneBuilder builder;

  // Materials by name: the shot's override the files'.
  std::map<std::string, uint32_t> materialIndex;
  std::map<std::string, std::shared_ptr<const Texture>> textures;
  auto texture = [&](const std::string& path) -> absl::StatusOr<std::shared_ptr<const Texture>> {
    if (auto it = textures.find(path); it != textures.end()) return it->second;
    auto t = loadImageTexture(path);
    if (!t.ok()) return t.status();
    textures[path] = *t;
    return *t;
  };
  auto addMaterial = [&](const MaterialDesc& d) -> absl::StatusOr<uint32_t> {
    Material m = toMaterial(d);
    if (d.albedoTexture) {
      auto t = texture(*d.albedoTexture);
      if (!t.ok()) {
        if (d.where.line > 0) return withContext(t.status(), d.where.toString());
        warnings.push_back(fmt::format("material '{}': {}; using its constant albedo", d.name,
                                       t.status().message()));
      } else {
        m.albedoTexture = *t;
      }
    }
    return builder.addMaterial(std::move(m));
  };
  std::set<std::string> shotMaterials;
  for (const MaterialDesc& d : shot.materials) {
    auto index = addMaterial(d);
    if (!index.ok()) return index.status();
    materialIndex[d.name] = *index;
    shotMaterials.insert(d.name);
  }

  TriangleSet triangles;  // of every geometry file, transformed: coincident copies go
  size_t coincident = 0;
  for (const GeometryDesc& g : shot.geometry) {
    auto loaded = loadGeometry(g.file);
    if (!loaded.ok()) {
      return withContext(loaded.status(), g.where.toString());
    }
    for (std::string& w : loaded->warnings) warnings.push_back(std::move(w));
    // Map the file's material indices to the scene's. What the loader could not map of a
    // material warns only where the shot does not define that material itself.
    std::vector<uint32_t> remap(loaded->materials.size());
    bool usesFileMaterials = false;
    for (size_t i = 0; i < loaded->materials.size(); ++i) {
      const MaterialDesc& fileMaterial = loaded->materials[i];
      const bool shotDefines = shotMaterials.contains(fileMaterial.name);
      usesFileMaterials = usesFileMaterials || !shotDefines;
      if (!shotDefines) {
        for (std::string& w : loaded->materialWarnings[i]) warnings.push_back(std::move(w));
      }
      if (auto it = materialIndex.find(fileMaterial.name); it != materialIndex.end()) {
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
      materialIndex[fileMaterial.name] = *index;
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
      coincident += triangles.dropCoincident(mesh);
      builder.addMesh(std::move(mesh));
    }
    if (kept == 0) {
      return withContext(
          absl::InvalidArgumentError(fmt::format(
              "geometry file '{}': no usable triangles under the transform at frame {} ({}): {}",
              g.file, frame, transformText(at), fmt::join(transformDrops, "; "))),
          g.where.toString());
    }
    if (!transformDrops.empty()) {
      warnings.push_back(fmt::format("{}: under the transform at frame {} ({}): {}", g.file, frame,
                                     transformText(at), fmt::join(transformDrops, "; ")));
    }
    if (usesFileMaterials) {
      for (std::string& w : loaded->libraryWarnings) warnings.push_back(std::move(w));
    }
  }

  if (coincident > 0) {
    warnings.push_back(fmt::format(
        "dropped {} triangle{} that coincide{} with another (the same three vertices): a "
        "surface modelled twice in one place renders once",
        coincident, coincident == 1 ? "" : "s", coincident == 1 ? "s" : ""));
  }

  for (const LightDesc& l : shot.lights) {
    if (l.type == LightType::kEnvironment) {
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
      builder.addLight(l, std::make_shared<const LatLongImage>(std::move(*image)));
    } else {
      builder.addLight(l);
    }
  }

  auto scene = builder.build();
  if (!scene.ok()) return scene.status();
  const CameraParams params = cameraAt(shot.camera, shot.firstFrame, frame);
  FrameScene out{std::move(*scene),
                 Camera(params, shot.width, shot.height, shot.camera.views, shot.camera.viewSpacing),
                 std::move(warnings)};
  return out;
}

}  // namespace pbgi
