#include "core/scene/scene.h"

#include <algorithm>
#include <memory>

#include <embree3/rtcore.h>

#include "core/util/check.h"
#include "core/util/log.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

void embreeError(void*, RTCError code, const char* message) {
  log::error("embree error {}: {}", static_cast<int>(code), message ? message : "");
}

// Relative offset for spawned rays: Embree's robust intersections are accurate to a few
// ulps of the coordinates, so 2^-16 of the magnitude clears the surface with margin.
constexpr float kRelativeOffset = 0x1p-16f;

}  // namespace

// What an Embree geometry id stands for.
struct GeometryInfo {
  enum class Kind { kMesh, kQuadLight, kSphereLight } kind = Kind::kMesh;
  uint32_t mesh = 0;   // kMesh: index into Impl::meshes
  int light = -1;      // lights: index into lights_
  Vec3f center{0.0f};  // kSphereLight
  Vec3f normal{0.0f};  // kQuadLight
};

struct Scene::Impl {
  RTCDevice device = nullptr;
  RTCScene scene = nullptr;
  std::vector<MeshData> meshes;
  std::vector<uint64_t> triangleBase;  // per mesh: global id of its first triangle
  std::vector<std::vector<int>> triangleLights;  // per mesh: light per triangle, or empty
  std::vector<GeometryInfo> geometries;          // by Embree geometry id
  // Per mesh with dielectric triangles: 1 for each of them (the occlusion filter's user data).
  std::vector<std::unique_ptr<uint8_t[]>> dielectricTriangles;

  ~Impl() {
    if (scene) rtcReleaseScene(scene);
    if (device) rtcReleaseDevice(device);
  }
};

Scene::~Scene() = default;

const std::vector<MeshData>& Scene::meshes() const { return impl_->meshes; }
uint64_t Scene::triangleIdBase(size_t mesh) const { return impl_->triangleBase[mesh]; }

float Scene::offsetScale(const Vec3f& p) const {
  const float sceneScale = maxAbsComponent(bounds_.diagonal()) * 1e-3f;
  return kRelativeOffset * std::max({maxAbsComponent(p), sceneScale, 1e-20f});
}

Ray Scene::spawnRay(const Vec3f& p, const Vec3f& ng, const Vec3f& dir) const {
  const float eps = offsetScale(p);
  const Vec3f origin = p + ng * (dot(dir, ng) >= 0.0f ? eps : -eps);
  return Ray{origin, dir, 0.0f, std::numeric_limits<float>::infinity()};
}

Ray Scene::spawnShadowRay(const Vec3f& p, const Vec3f& ng, const LightSample& sample) const {
  if (!std::isfinite(sample.distance)) return spawnRay(p, ng, sample.wi);
  return spawnSegment(p, ng, sample.point, sample.normal);
}

Ray Scene::spawnSegment(const Vec3f& p, const Vec3f& ng, const Vec3f& q, const Vec3f& nq,
                        float stopShort) const {
  Ray ray = spawnRay(p, ng, q - p);
  Vec3f target = q;
  if (nq != Vec3f(0.0f)) {
    const float eps = offsetScale(target);
    target += nq * (dot(ray.origin - target, nq) >= 0.0f ? eps : -eps);
  }
  const Vec3f d = target - ray.origin;
  const float length = pbgi::length(d);
  if (!(length > 0.0f)) {
    ray.dir = ng;
    ray.tMax = 0.0f;
    return ray;
  }
  ray.dir = d / length;
  // A margin for Embree's rounding of t near the end, which the offset alone may not cover
  // where the surface at q is small beside the scene.
  ray.tMax = std::max(0.0f, length * (1.0f - 1e-5f) - offsetScale(target) - stopShort);
  return ray;
}

bool Scene::seeAlongSurface(const Vec3f& p, const Vec3f& np, const Vec3f& q, const Vec3f& nq,
                            float lift) const {
  const Vec3f from = p + np * (offsetScale(p) + lift);
  const Vec3f to = q + nq * (offsetScale(q) + lift);
  const Vec3f d = to - from;
  const float length = pbgi::length(d);
  if (!(length > 0.0f)) return true;
  const Ray ray{from, d / length, 0.0f, std::max(0.0f, length * (1.0f - 1e-5f) - offsetScale(to))};
  return !occluded(ray);
}

namespace {
// Embree asserts on a ray with a NaN or Inf in it (and would return garbage without the
// assertion): such a ray, from whatever arithmetic overflowed upstream, meets nothing.
bool traceable(const Ray& ray) {
  return isFinite(ray.origin) && isFinite(ray.dir) && !std::isnan(ray.tMin) &&
         !std::isnan(ray.tMax);
}
}  // namespace

bool Scene::intersect(const Ray& ray, SurfaceHit* hit) const {
  if (!traceable(ray)) return false;
  RTCIntersectContext context;
  rtcInitIntersectContext(&context);
  RTCRayHit rh;
  rh.ray.org_x = ray.origin.x;
  rh.ray.org_y = ray.origin.y;
  rh.ray.org_z = ray.origin.z;
  rh.ray.dir_x = ray.dir.x;
  rh.ray.dir_y = ray.dir.y;
  rh.ray.dir_z = ray.dir.z;
  rh.ray.tnear = ray.tMin;
  rh.ray.tfar = ray.tMax;
  rh.ray.time = 0.0f;
  rh.ray.mask = ~0u;
  rh.ray.id = 0;
  rh.ray.flags = 0;
  rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
  rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
  rtcIntersect1(impl_->scene, &context, &rh);
  if (rh.hit.geomID == RTC_INVALID_GEOMETRY_ID) return false;

  const GeometryInfo& info = impl_->geometries[rh.hit.geomID];
  hit->t = rh.ray.tfar;
  hit->geometry = rh.hit.geomID;
  hit->primitive = rh.hit.primID;
  hit->uv = Vec2f(0.0f, 0.0f);
  switch (info.kind) {
    case GeometryInfo::Kind::kSphereLight: {
      hit->p = ray.origin + ray.dir * hit->t;
      const Vec3f n = hit->p - info.center;
      hit->ng = hit->ns = length(n) > 0.0f ? normalize(n) : Vec3f(0.0f, 1.0f, 0.0f);
      hit->material = kNoMaterial;
      hit->light = info.light;
      return true;
    }
    case GeometryInfo::Kind::kQuadLight:
      hit->p = ray.origin + ray.dir * hit->t;
      hit->ng = hit->ns = info.normal;
      hit->material = kNoMaterial;
      hit->light = info.light;
      return true;
    case GeometryInfo::Kind::kMesh:
      break;
  }
  const MeshData& mesh = impl_->meshes[info.mesh];
  const uint32_t prim = rh.hit.primID;
  const uint32_t i0 = mesh.indices[3 * prim], i1 = mesh.indices[3 * prim + 1],
                 i2 = mesh.indices[3 * prim + 2];
  const float b1 = rh.hit.u, b2 = rh.hit.v, b0 = 1.0f - b1 - b2;
  const Vec3f& p0 = mesh.positions[i0];
  const Vec3f& p1 = mesh.positions[i1];
  const Vec3f& p2 = mesh.positions[i2];
  // Interpolating the vertices is more accurate than origin + t * dir far from the origin.
  hit->p = p0 * b0 + p1 * b1 + p2 * b2;
  hit->ng = normalize(cross(p1 - p0, p2 - p0));
  hit->ns = hit->ng;
  if (!mesh.normals.empty()) {
    const Vec3f n = mesh.normals[i0] * b0 + mesh.normals[i1] * b1 + mesh.normals[i2] * b2;
    const float len = length(n);
    // A zero vertex normal (repaired by cleanMesh) falls back to the face normal.
    if (len > 1e-6f && dot(mesh.normals[i0], mesh.normals[i0]) > 0.0f &&
        dot(mesh.normals[i1], mesh.normals[i1]) > 0.0f &&
        dot(mesh.normals[i2], mesh.normals[i2]) > 0.0f) {
      hit->ns = n / len;
      if (dot(hit->ns, hit->ng) < 0.0f) hit->ns = -hit->ns;
    }
  }
  if (!mesh.uvs.empty()) hit->uv = mesh.uvs[i0] * b0 + mesh.uvs[i1] * b1 + mesh.uvs[i2] * b2;
  hit->material = mesh.materials[prim];
  const auto& triLights = impl_->triangleLights[info.mesh];
  hit->light = triLights.empty() ? -1 : triLights[prim];
  return true;
}

namespace {

// An occlusion query's context: Embree hands the filter below its first member.
struct OcclusionContext {
  RTCIntersectContext base;
  bool passDielectrics = false;
};

// The occlusion filter of a mesh with dielectric triangles: their hits do not count when the
// query passes dielectrics.
void passDielectrics(const RTCFilterFunctionNArguments* args) {
  const auto* context = reinterpret_cast<const OcclusionContext*>(args->context);
  if (!context->passDielectrics) return;
  const auto* dielectric = static_cast<const uint8_t*>(args->geometryUserPtr);
  for (unsigned i = 0; i < args->N; ++i) {
    if (args->valid[i] != -1) continue;
    if (dielectric[RTCHitN_primID(args->hit, args->N, i)]) args->valid[i] = 0;
  }
}

}  // namespace

bool Scene::occluded(const Ray& ray) const { return occludedBy(ray, false); }

bool Scene::occludedByOpaque(const Ray& ray) const { return occludedBy(ray, true); }

bool Scene::occludedBy(const Ray& ray, bool passDielectrics) const {
  if (!traceable(ray)) return false;
  OcclusionContext context;
  rtcInitIntersectContext(&context.base);
  context.passDielectrics = passDielectrics;
  RTCRay r;
  r.org_x = ray.origin.x;
  r.org_y = ray.origin.y;
  r.org_z = ray.origin.z;
  r.dir_x = ray.dir.x;
  r.dir_y = ray.dir.y;
  r.dir_z = ray.dir.z;
  r.tnear = ray.tMin;
  r.tfar = ray.tMax;
  r.time = 0.0f;
  r.mask = ~0u;
  r.id = 0;
  r.flags = 0;
  rtcOccluded1(impl_->scene, &context.base, &r);
  return r.tfar < 0.0f;  // Embree sets tfar to -inf on a hit
}


const Light* Scene::sampleLight(float u, float* probability, bool withoutSky) const {
  if (lights_.empty() || (withoutSky && !anyLightButSky_)) return nullptr;
  const int i = (withoutSky ? lightDistributionWithoutSky_ : lightDistribution_)
                    .sampleDiscrete(u, probability);
  return lights_[i].get();
}

float Scene::lightProbability(int lightIndex, bool withoutSky) const {
  if (lights_.empty() || (withoutSky && !anyLightButSky_)) return 0.0f;
  return (withoutSky ? lightDistributionWithoutSky_ : lightDistribution_)
      .discreteProbability(lightIndex);
}

Rgb Scene::albedoAt(const SurfaceHit& hit) const {
  if (hit.material == kNoMaterial) return Rgb(0.0f);
  const Material& m = materials_[hit.material];
  if (m.type == MaterialType::kDiffuse && m.albedoTexture) return m.albedoTexture->evaluate(hit.uv);
  return untexturedAlbedo(m);
}

SceneBuilder::SceneBuilder() = default;
SceneBuilder::~SceneBuilder() = default;

uint32_t SceneBuilder::addMaterial(Material material) {
  materials_.push_back(std::move(material));
  return static_cast<uint32_t>(materials_.size() - 1);
}

void SceneBuilder::addMesh(MeshData mesh) { meshes_.push_back(std::move(mesh)); }

void SceneBuilder::addLight(const LightDesc& desc, std::shared_ptr<const LatLongImage> env) {
  lights_.push_back({desc, std::move(env), nullptr});
}

void SceneBuilder::addLight(std::unique_ptr<Light> light) {
  lights_.push_back({LightDesc{}, nullptr, std::move(light)});
}

namespace {

void attachGeometry(RTCScene scene, std::vector<GeometryInfo>& geometries, RTCGeometry geom,
                    GeometryInfo info) {
  rtcCommitGeometry(geom);
  const uint32_t id = rtcAttachGeometry(scene, geom);
  rtcReleaseGeometry(geom);
  if (geometries.size() <= id) geometries.resize(id + 1);
  geometries[id] = info;
}

}  // namespace

absl::Status SceneBuilder::buildMesh(Scene& scene, MeshData& mesh) {
  Scene::Impl& impl = *scene.impl_;
  const auto attach = [&](RTCGeometry geom, GeometryInfo info) {
    attachGeometry(impl.scene, impl.geometries, geom, info);
  };
  cleanMesh(mesh);
  for (uint32_t m : mesh.materials) {
    if (m >= scene.materials_.size()) {
      return absl::InvalidArgumentError(
          fmt::format("mesh '{}': material index {} out of range (have {})", mesh.name, m,
                      scene.materials_.size()));
    }
  }
  if (mesh.triangleCount() == 0) return absl::OkStatus();
  // The bounds of what renders: a vertex only dropped triangles used (one of a triangle
  // too large to represent, at 1e30) would set every ray offset and cube from the scene's
  // size.
  for (const uint32_t i : mesh.indices) scene.bounds_.extend(mesh.positions[i]);
  const uint32_t meshIndex = static_cast<uint32_t>(impl.meshes.size());
  // Emissive triangles are lights too.
  std::vector<int> triLights;
  for (size_t t = 0; t < mesh.triangleCount(); ++t) {
    const Material& mat = scene.materials_[mesh.materials[t]];
    if (isBlack(mat.radiance) || !isFinite(mat.radiance)) continue;
    if (triLights.empty()) triLights.assign(mesh.triangleCount(), -1);
    const Vec3f& p0 = mesh.positions[mesh.indices[3 * t]];
    const Vec3f& p1 = mesh.positions[mesh.indices[3 * t + 1]];
    const Vec3f& p2 = mesh.positions[mesh.indices[3 * t + 2]];
    triLights[t] = static_cast<int>(scene.lights_.size());
    scene.lights_.push_back(makeTriangleLight(p0, p1, p2, mat.radiance));
    ++scene.stats_.emissiveTriangles;
  }

  RTCGeometry geom = rtcNewGeometry(impl.device, RTC_GEOMETRY_TYPE_TRIANGLE);
  auto* vertices = static_cast<float*>(rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_VERTEX, 0,
                                                               RTC_FORMAT_FLOAT3, 3 * sizeof(float),
                                                               mesh.positions.size()));
  for (size_t i = 0; i < mesh.positions.size(); ++i) {
    const Vec3f& p = mesh.positions[i];
    vertices[3 * i] = p.x;
    vertices[3 * i + 1] = p.y;
    vertices[3 * i + 2] = p.z;
  }
  auto* indices = static_cast<uint32_t*>(
      rtcSetNewGeometryBuffer(geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3,
                              3 * sizeof(uint32_t), mesh.triangleCount()));
  std::copy(mesh.indices.begin(), mesh.indices.end(), indices);
  std::unique_ptr<uint8_t[]> dielectric;
  for (size_t t = 0; t < mesh.triangleCount(); ++t) {
    if (scene.materials_[mesh.materials[t]].type != MaterialType::kDielectric) continue;
    if (!dielectric) dielectric = std::make_unique<uint8_t[]>(mesh.triangleCount());
    dielectric[t] = 1;
  }
  if (dielectric) {
    rtcSetGeometryUserData(geom, dielectric.get());
    rtcSetGeometryOccludedFilterFunction(geom, passDielectrics);
    impl.dielectricTriangles.push_back(std::move(dielectric));
  }
  GeometryInfo info;
  info.kind = GeometryInfo::Kind::kMesh;
  info.mesh = meshIndex;
  attach(geom, info);

  impl.triangleBase.push_back(scene.stats_.triangles);
  scene.stats_.triangles += mesh.triangleCount();
  ++scene.stats_.meshes;
  impl.meshes.push_back(std::move(mesh));
  impl.triangleLights.push_back(std::move(triLights));
  return absl::OkStatus();
}

absl::Status SceneBuilder::buildLight(Scene& scene, PendingLight& pending) {
  Scene::Impl& impl = *scene.impl_;
  const auto attach = [&](RTCGeometry geom, GeometryInfo info) {
    attachGeometry(impl.scene, impl.geometries, geom, info);
  };
  if (pending.custom) {
    scene.lights_.push_back(std::move(pending.custom));
    return absl::OkStatus();
  }
  const LightDesc& d = pending.desc;
  const int lightIndex = static_cast<int>(scene.lights_.size());
  switch (d.type) {
    case LightType::kQuad: {
      scene.lights_.push_back(makeQuadLight(d.corner, d.edgeU, d.edgeV, d.radiance));
      RTCGeometry geom = rtcNewGeometry(impl.device, RTC_GEOMETRY_TYPE_TRIANGLE);
      auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
          geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), 4));
      const Vec3f corners[4] = {d.corner, d.corner + d.edgeU, d.corner + d.edgeU + d.edgeV,
                                d.corner + d.edgeV};
      for (int i = 0; i < 4; ++i) {
        v[3 * i] = corners[i].x;
        v[3 * i + 1] = corners[i].y;
        v[3 * i + 2] = corners[i].z;
        scene.bounds_.extend(corners[i]);
      }
      auto* idx = static_cast<uint32_t*>(rtcSetNewGeometryBuffer(
          geom, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(uint32_t), 2));
      const uint32_t tris[6] = {0, 1, 2, 0, 2, 3};
      std::copy(tris, tris + 6, idx);
      GeometryInfo info;
      info.kind = GeometryInfo::Kind::kQuadLight;
      info.light = lightIndex;
      info.normal = normalize(cross(d.edgeU, d.edgeV));
      attach(geom, info);
      break;
    }
    case LightType::kSphere: {
      scene.lights_.push_back(makeSphereLight(d.center, d.radius, d.radiance));
      RTCGeometry geom = rtcNewGeometry(impl.device, RTC_GEOMETRY_TYPE_SPHERE_POINT);
      auto* v = static_cast<float*>(rtcSetNewGeometryBuffer(
          geom, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT4, 4 * sizeof(float), 1));
      v[0] = d.center.x;
      v[1] = d.center.y;
      v[2] = d.center.z;
      v[3] = d.radius;
      scene.bounds_.extend(d.center - Vec3f(d.radius));
      scene.bounds_.extend(d.center + Vec3f(d.radius));
      GeometryInfo info;
      info.kind = GeometryInfo::Kind::kSphereLight;
      info.light = lightIndex;
      info.center = d.center;
      attach(geom, info);
      break;
    }
    case LightType::kPoint:
      scene.lights_.push_back(makePointLight(d.position, d.intensity));
      break;
    case LightType::kSpot:
      scene.lights_.push_back(makeSpotLight(d.position, d.direction, d.coneDeg, d.intensity));
      break;
    case LightType::kDirectional:
      scene.lights_.push_back(makeDirectionalLight(d.direction, d.irradiance));
      break;
    case LightType::kEnvironment:
      if (!pending.environment) {
        return absl::InvalidArgumentError(
            fmt::format("{}: environment light without an image", d.where.toString()));
      }
      scene.lights_.push_back(
          makeEnvironmentLight(std::move(pending.environment), d.scale, d.rotateDeg));
      break;
  }
  return absl::OkStatus();
}

void SceneBuilder::prepareLightSampling(Scene& scene) {
  if (scene.bounds_.empty()) scene.bounds_.extend(Vec3f(0.0f));
  std::vector<float> powers;
  for (size_t i = 0; i < scene.lights_.size(); ++i) {
    Light* light = scene.lights_[i].get();
    light->preprocess(scene.bounds_);
    if (light->isInfinite()) scene.infiniteLights_.push_back(static_cast<int>(i));
    const float p = light->power();
    powers.push_back(std::isfinite(p) ? std::max(p, 0.0f) : 0.0f);
  }
  if (!powers.empty()) scene.lightDistribution_ = Distribution1D(powers);
  std::vector<float> withoutSky = powers;
  for (size_t i = 0; i < withoutSky.size(); ++i) {
    if (isSkyLight(*scene.lights_[i])) withoutSky[i] = 0.0f;
    scene.anyLightButSky_ = scene.anyLightButSky_ || withoutSky[i] > 0.0f;
  }
  if (scene.anyLightButSky_) scene.lightDistributionWithoutSky_ = Distribution1D(withoutSky);
  for (const bool skyLeftOut : {false, true}) {
    std::vector<int> deltas;
    bool onlyDeltas = true;
    for (size_t i = 0; i < scene.lights_.size() && onlyDeltas; ++i) {
      if (!(scene.lightProbability(static_cast<int>(i), skyLeftOut) > 0.0f)) continue;
      onlyDeltas = scene.lights_[i]->isDelta();
      deltas.push_back(static_cast<int>(i));
    }
    if (onlyDeltas) scene.deltaLightsOnly_[skyLeftOut ? 1 : 0] = std::move(deltas);
  }
}

absl::StatusOr<std::unique_ptr<Scene>> SceneBuilder::build() {
  std::unique_ptr<Scene> scene(new Scene());
  scene->impl_ = std::make_unique<Scene::Impl>();
  Scene::Impl& impl = *scene->impl_;
  scene->materials_ = std::move(materials_);

  impl.device = rtcNewDevice("threads=0");
  if (!impl.device) {
    return absl::InternalError(fmt::format("cannot create an Embree device (error {})",
                                           static_cast<int>(rtcGetDeviceError(nullptr))));
  }
  rtcSetDeviceErrorFunction(impl.device, embreeError, nullptr);
  impl.scene = rtcNewScene(impl.device);
  rtcSetSceneFlags(impl.scene, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(impl.scene, RTC_BUILD_QUALITY_HIGH);
  for (MeshData& mesh : meshes_) PBGI_RETURN_IF_ERROR(buildMesh(*scene, mesh));
  for (PendingLight& pending : lights_) PBGI_RETURN_IF_ERROR(buildLight(*scene, pending));
  lights_.clear();

  rtcCommitScene(impl.scene);
  const RTCError err = rtcGetDeviceError(impl.device);
  if (err != RTC_ERROR_NONE) {
    return absl::InternalError(
        fmt::format("Embree scene build failed (error {})", static_cast<int>(err)));
  }
  prepareLightSampling(*scene);
  scene->stats_.lights = scene->lights_.size();
  return scene;
}

}  // namespace pbgi
