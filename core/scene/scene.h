#pragma once
// The renderable scene of one frame: triangle meshes, materials and lights in an Embree 3
// BVH (robust intersection mode), plus the light-selection distribution.

#include <array>
#include <cstdint>
#include <memory>
#include <vector>

#include <absl/status/statusor.h>

#include "core/math/vec.h"
#include "core/sampling/sampling.h"
#include "core/scene/camera.h"
#include "core/scene/light.h"
#include "core/scene/material.h"
#include "core/scene/mesh.h"

namespace pbgi {

inline constexpr uint32_t kNoMaterial = ~0u;

struct SurfaceHit {
  float t = 0.0f;
  Vec3f p{0.0f};
  Vec3f ng{0.0f, 0.0f, 1.0f};  // geometric normal: the front side by the triangle's winding
  Vec3f ns{0.0f, 0.0f, 1.0f};  // shading normal, on the same side as ng
  Vec2f uv{0.0f, 0.0f};
  uint32_t material = kNoMaterial;  // kNoMaterial on a light's own surface
  int light = -1;                   // index into Scene::lights() where the surface emits
  uint32_t geometry = 0;            // Embree geometry id
  uint32_t primitive = 0;
};

struct SceneStats {
  size_t meshes = 0;
  size_t triangles = 0;
  size_t lights = 0;
  size_t emissiveTriangles = 0;
};

class Scene {
 public:
  ~Scene();
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  bool intersect(const Ray& ray, SurfaceHit* hit) const;
  // True when anything blocks the segment [ray.tMin, ray.tMax].
  bool occluded(const Ray& ray) const;
  // True when anything but a dielectric blocks the segment: glass is passed straight through,
  // unrefracted (its hits are filtered out of the one occlusion query). Light seen through
  // glass is then gathered where the glass stands, which is what a diffuse receiver averages;
  // refraction moves it within the glass's outline.
  bool occludedByOpaque(const Ray& ray) const;

  // A ray leaving surface point p (with geometric normal ng) in direction dir, offset off
  // the surface on dir's side so that it cannot hit the surface it starts on.
  Ray spawnRay(const Vec3f& p, const Vec3f& ng, const Vec3f& dir) const;
  // A shadow ray from surface point p (geometric normal ng) towards a light sample: along
  // its direction for a light at infinity; otherwise a segment from p, offset off its
  // surface on the sample's side, to the sampled point, offset off the light's surface
  // towards p, so that it cannot meet either surface at any angle.
  Ray spawnShadowRay(const Vec3f& p, const Vec3f& ng, const LightSample& sample) const;
  // A segment from surface point p (geometric normal ng) to surface point q (normal nq; zero
  // for a point on no surface), each end offset off its surface on the side that faces the
  // other, and the direction taken between the offset ends: aiming from the offset origin at
  // q itself would shorten the way to q's plane by the offset over the cosine at q, which at
  // grazing angles outgrows any margin and lands the end on q's surface, which then blocks it.
  // tMax stops `stopShort` before the end, less a margin for Embree's rounding of t.
  Ray spawnSegment(const Vec3f& p, const Vec3f& ng, const Vec3f& q, const Vec3f& nq,
                   float stopShort = 0.0f) const;
  // Whether points p and q of one surface see each other on the side their unit normals np
  // and nq face: the segment between them, each end lifted off the surface along its normal
  // by the ray offset plus `lift` (what clears a convex surface's own bulge between them),
  // meets nothing. A wall standing on a floor parts the floor's points on its two sides.
  bool seeAlongSurface(const Vec3f& p, const Vec3f& np, const Vec3f& q, const Vec3f& nq,
                       float lift) const;

  const Material& material(uint32_t index) const { return materials_[index]; }
  const std::vector<Material>& materials() const { return materials_; }
  const std::vector<std::unique_ptr<Light>>& lights() const { return lights_; }
  // Indices (into lights()) of the lights that surround the scene.
  const std::vector<int>& infiniteLights() const { return infiniteLights_; }
  // Picks a light in proportion to its power; nullptr when the scene has none. Without the
  // sky: among the lights that are not environments (isSkyLight), for a point whose
  // environment light is taken otherwise (PBGI's records).
  const Light* sampleLight(float u, float* probability, bool withoutSky = false) const;
  float lightProbability(int lightIndex, bool withoutSky = false) const;
  // The lights sampleLight can pick (the sky left out if asked) when every one of them is a
  // delta light (point, spot, directional), whose light needs no sampling: a shadow ray each
  // gives it exactly, where more samples would repeat the same rays. Empty when an area light
  // or an environment can be picked, or none.
  const std::vector<int>& deltaLightsOnly(bool withoutSky = false) const {
    return deltaLightsOnly_[withoutSky ? 1 : 0];
  }

  // Albedo of a material at a hit (texture looked up).
  Rgb albedoAt(const SurfaceHit& hit) const;

  // The scene's triangle meshes (cleaned), in a fixed order. Global triangle ids count
  // triangles across them in that order.
  const std::vector<MeshData>& meshes() const;
  uint64_t triangleIdBase(size_t mesh) const;

  const Bounds3f& bounds() const { return bounds_; }
  const SceneStats& stats() const { return stats_; }

 private:
  friend class SceneBuilder;
  Scene() = default;
  float offsetScale(const Vec3f& p) const;
  bool occludedBy(const Ray& ray, bool passDielectrics) const;

  struct Impl;
  std::unique_ptr<Impl> impl_;
  std::vector<Material> materials_;
  std::vector<std::unique_ptr<Light>> lights_;
  std::vector<int> infiniteLights_;
  Distribution1D lightDistribution_;
  Distribution1D lightDistributionWithoutSky_;
  bool anyLightButSky_ = false;  // with power
  std::array<std::vector<int>, 2> deltaLightsOnly_;  // with the sky, without
  Bounds3f bounds_;
  SceneStats stats_;
};

class SceneBuilder {
 public:
  SceneBuilder();
  ~SceneBuilder();

  uint32_t addMaterial(Material material);
  // Triangles' material indices refer to addMaterial's return values. The mesh is cleaned
  // (cleanMesh) here if the caller has not done so.
  void addMesh(MeshData mesh);
  // A light from the shot. Quad and sphere lights become surfaces of the scene too;
  // environment lights need `environment` (the decoded lat-long image).
  void addLight(const LightDesc& desc, std::shared_ptr<const LatLongImage> environment = nullptr);
  // Any other light (no surface).
  void addLight(std::unique_ptr<Light> light);

  absl::StatusOr<std::unique_ptr<Scene>> build();

 private:
  std::vector<Material> materials_;
  std::vector<MeshData> meshes_;
  struct PendingLight {
    LightDesc desc;
    std::shared_ptr<const LatLongImage> environment;
    std::unique_ptr<Light> custom;
  };
  std::vector<PendingLight> lights_;

  // build()'s steps: each mesh's triangles (and its emissive triangles' lights), each light
  // (with the surface of a quad or sphere light), then what sampling the lights needs.
  absl::Status buildMesh(Scene& scene, MeshData& mesh);
  absl::Status buildLight(Scene& scene, PendingLight& pending);
  static void prepareLightSampling(Scene& scene);
};

}  // namespace pbgi
