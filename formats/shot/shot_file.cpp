#include "formats/shot/shot_file.h"

#include <absl/status/status.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <toml++/toml.h>

#include <algorithm>
#include <cctype>
#include <cerrno>
#include <climits>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <string>
#include <string_view>
#include <system_error>
#include <utility>
#include <vector>

#include "core/math/vec.h"
#include "core/render/integrators.h"
#include "core/util/source_location.h"
#include "formats/shot/strict_toml.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
using strict_toml::kInf;
using strict_toml::kNonNegative;
using strict_toml::kPositive;
using strict_toml::kUnitInterval;
using strict_toml::Range;
using strict_toml::Section;
using strict_toml::Source;
using strict_toml::Variants;

constexpr int64_t kSupportedVersion = 1;
constexpr int kMaxResolution = kMaxShotResolution;
constexpr int64_t kMaxPixels = kMaxShotPixels;
// Hand-written and generated shots are kilobytes; anything this big is not a shot file.
constexpr std::uintmax_t kMaxShotFileBytes = std::uintmax_t{16} << 20;
// Degeneracy checks run on every frame of ranges up to this long, on the keys beyond it.
constexpr int64_t kMaxFramesToCheck = 10000;

constexpr Range kFovRange{0.0, 180.0, true, true};
constexpr Range kConeRange{0.0, 90.0, true, false};
constexpr Range kIorRange{1.0, kInf, true, false};
constexpr Range kFrameRange{0.0, INT_MAX, false, false};
constexpr Range kResolutionRange{1.0, kMaxResolution, false, false};
constexpr Range kViewsRange{1.0, 1024.0, false, false};
constexpr Range kSppRange{1.0, 1 << 20, false, false};
constexpr Range kDepthRange{1.0, 65536.0, false, false};
constexpr Range kFilterWidthRange{0.0, 32.0, true, false};
constexpr Range kTileSizeRange{4.0, 1024.0, false, false};

// Rejects two keys at the same frame, which would silently drop one of them.
absl::Status checkUniqueFrame(std::map<int, int>& seen, int frame, const Section& key) {
  auto [it, inserted] = seen.emplace(frame, key.where().line);
  if (!inserted) {
    return key.error(*key.find("frame"),
                     fmt::format("frame {} already has a key at line {}", frame, it->second));
  }
  return absl::OkStatus();
}

// --- [shot] ------------------------------------------------------------------------------

absl::Status parseShotTable(const Section& s, ShotDesc& shot) {
  PBGI_RETURN_IF_ERROR(s.allowOnly({"name", "frames", "resolution", "output"}));

  PBGI_ASSIGN_OR_RETURN(shot.name, s.need<std::string>("name"));
  const bool nameOk =
      !shot.name.empty() && std::all_of(shot.name.begin(), shot.name.end(), [](char c) {
        return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
      });
  if (!nameOk) {
    return s.error(*s.find("name"),
                   fmt::format("'name' must match [A-Za-z0-9_-]+, found \"{}\"", shot.name));
  }

  PBGI_ASSIGN_OR_RETURN(const Vec2i frames, s.need<Vec2i>("frames", kFrameRange));
  if (frames.x > frames.y) {
    return s.error(*s.find("frames"),
                   fmt::format("'frames' must be [first, last] with first <= last, found [{}, {}]",
                               frames.x, frames.y));
  }
  shot.firstFrame = frames.x;
  shot.lastFrame = frames.y;

  PBGI_ASSIGN_OR_RETURN(const Vec2i res, s.need<Vec2i>("resolution", kResolutionRange));
  const int64_t pixels = int64_t{res.x} * res.y;
  if (pixels > kMaxPixels) {
    return s.error(*s.find("resolution"),
                   fmt::format("'resolution' {} x {} is {} pixels; at most {} (2^26) are allowed",
                               res.x, res.y, pixels, kMaxPixels));
  }
  shot.width = res.x;
  shot.height = res.y;

  PBGI_ASSIGN_OR_RETURN(const std::string output, s.need<std::string>("output"));
  if (output.empty() || output.back() == '/') {
    return s.error(
        *s.find("output"),
        fmt::format("'output': expected a file pattern such as \"{}.####.exr\", found \"{}\"",
                    shot.name, output));
  }
  shot.output = s.source().resolve(output);
  return absl::OkStatus();
}

// --- [camera] ----------------------------------------------------------------------------

// Why a camera cannot form an image, and which key to blame; nullopt when it can.
struct CameraProblem {
  std::string what;
  std::string_view key;
};

std::optional<CameraProblem> cameraProblem(const CameraParams& c) {
  const Vec3f dir = c.lookAt - c.position;
  const float scale = std::max({1.0f, maxAbsComponent(vmax(c.position, -c.position)),
                                maxAbsComponent(vmax(c.lookAt, -c.lookAt))});
  if (length(dir) <= 1e-6f * scale) {
    return CameraProblem{fmt::format("position and look_at coincide at {}", c.position), "look_at"};
  }
  if (length(c.up) == 0.0f) return CameraProblem{"up is the zero vector", "up"};
  if (length(cross(normalize(dir), normalize(c.up))) < 1e-5f) {
    return CameraProblem{
        fmt::format("up {} is parallel to the view direction {}", c.up, normalize(dir)), "up"};
  }
  if (c.apertureRadius > 0.0f && !(c.focusDistance > 0.0f)) {
    return CameraProblem{fmt::format("aperture_radius {} > 0 needs focus_distance > 0, found {}",
                                     c.apertureRadius, c.focusDistance),
                         "aperture_radius"};
  }
  return std::nullopt;
}

const std::vector<std::string_view> kCameraKeyValues = {
    "position", "look_at", "up", "fov_y_deg", "aperture_radius", "focus_distance"};

absl::StatusOr<CameraKey> parseCameraKey(const Section& s) {
  std::vector<std::string_view> allowed = {"frame"};
  allowed.insert(allowed.end(), kCameraKeyValues.begin(), kCameraKeyValues.end());
  PBGI_RETURN_IF_ERROR(s.allowOnly(allowed));
  CameraKey key;
  key.where = s.where();
  PBGI_ASSIGN_OR_RETURN(key.frame, s.need<int>("frame", kFrameRange));
  PBGI_ASSIGN_OR_RETURN(key.position, s.get<Vec3f>("position"));
  PBGI_ASSIGN_OR_RETURN(key.lookAt, s.get<Vec3f>("look_at"));
  PBGI_ASSIGN_OR_RETURN(key.up, s.get<Vec3f>("up"));
  PBGI_ASSIGN_OR_RETURN(key.fovYDeg, s.get<float>("fov_y_deg", kFovRange));
  PBGI_ASSIGN_OR_RETURN(key.apertureRadius, s.get<float>("aperture_radius", kNonNegative));
  PBGI_ASSIGN_OR_RETURN(key.focusDistance, s.get<float>("focus_distance", kPositive));
  if (s.table().size() == 1) {
    return s.errorHere(fmt::format("key at frame {} sets nothing (expected at least one of: {})",
                                   key.frame, fmt::join(kCameraKeyValues, ", ")));
  }
  return key;
}

// The camera must be usable on every frame it renders, including interpolated ones: a key
// can make up parallel to the view direction half-way between two good keys.
absl::Status checkCameraOverTime(const Section& s, const CameraDesc& camera, int firstFrame,
                                 int lastFrame, const std::vector<Section>& keySections) {
  std::vector<int> frames;
  for (const CameraKey& key : camera.keys) frames.push_back(key.frame);
  if (int64_t{lastFrame} - firstFrame < kMaxFramesToCheck) {
    for (int64_t f = firstFrame; f <= lastFrame; ++f) frames.push_back(static_cast<int>(f));
  }
  std::sort(frames.begin(), frames.end());
  frames.erase(std::unique(frames.begin(), frames.end()), frames.end());
  for (int frame : frames) {
    const auto problem = cameraProblem(cameraAt(camera, firstFrame, frame));
    if (!problem) continue;
    // Blame the key that sets this frame, else the next key, whose values pull it there.
    const Section* blame = nullptr;
    int blameFrame = INT_MAX;
    for (size_t i = 0; i < camera.keys.size(); ++i) {
      const int kf = camera.keys[i].frame;
      if (kf >= frame && kf < blameFrame) {
        blame = &keySections[i];
        blameFrame = kf;
      }
    }
    const Section& at = blame != nullptr ? *blame : s;
    return at.errorHere(
        fmt::format("the camera at frame {} is degenerate: {}", frame, problem->what));
  }
  return absl::OkStatus();
}

absl::Status parseCamera(const Section& s, ShotDesc& shot) {
  PBGI_RETURN_IF_ERROR(
      s.allowOnly({"position", "look_at", "up", "fov_y_deg", "aperture_radius", "focus_distance",
                   "views", "view_spacing", "key"}));
  CameraDesc& camera = shot.camera;
  CameraParams& base = camera.base;
  camera.where = s.where();
  PBGI_ASSIGN_OR_RETURN(base.position, s.need<Vec3f>("position"));
  PBGI_ASSIGN_OR_RETURN(base.lookAt, s.need<Vec3f>("look_at"));
  PBGI_ASSIGN_OR_RETURN(base.up, s.need<Vec3f>("up"));
  PBGI_ASSIGN_OR_RETURN(base.fovYDeg, s.need<float>("fov_y_deg", kFovRange));
  PBGI_ASSIGN_OR_RETURN(base.apertureRadius,
                             s.getOr<float>("aperture_radius", 0.0f, kNonNegative));
  PBGI_ASSIGN_OR_RETURN(const std::optional<float> focus,
                             s.get<float>("focus_distance", kPositive));
  base.focusDistance = focus.value_or(0.0f);
  PBGI_ASSIGN_OR_RETURN(camera.views, s.getOr<Vec2i>("views", Vec2i(1, 1), kViewsRange));
  PBGI_ASSIGN_OR_RETURN(camera.viewSpacing,
                             s.getOr<float>("view_spacing", 0.0f, kNonNegative));
  // A camera array renders one mosaic of all its views, so the pixel cap applies to the whole.
  const int64_t mosaic = int64_t{camera.views.x} * camera.views.y * shot.width * shot.height;
  if (mosaic > kMaxPixels) {
    return s.error(
        *s.find("views"),
        fmt::format("'views' {} x {} of {} x {} pixels make a mosaic of {} pixels; at "
                    "most {} (2^26) are allowed",
                    camera.views.x, camera.views.y, shot.width, shot.height, mosaic, kMaxPixels));
  }

  if (auto problem = cameraProblem(base)) {
    const toml::node* blame = s.find(problem->key);
    // A given focus_distance is > 0, so an aperture problem here means it is missing.
    return s.error(*blame, problem->key == "aperture_radius"
                               ? std::string("'aperture_radius' > 0 turns on depth of field and "
                                             "needs 'focus_distance' (> 0), which is missing")
                               : problem->what);
  }

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> keys,
                             tableArray(s, "key", "[[camera.key]]"));
  std::map<int, int> seen;
  for (const Section& k : keys) {
    PBGI_ASSIGN_OR_RETURN(CameraKey key, parseCameraKey(k));
    PBGI_RETURN_IF_ERROR(checkUniqueFrame(seen, key.frame, k));
    camera.keys.push_back(std::move(key));
  }
  return checkCameraOverTime(s, camera, shot.firstFrame, shot.lastFrame, keys);
}

// --- [[geometry]] ------------------------------------------------------------------------

absl::StatusOr<TransformKey> parseTransformKey(const Section& s) {
  PBGI_RETURN_IF_ERROR(s.allowOnly({"frame", "translate", "rotate_deg", "scale"}));
  TransformKey key;
  key.where = s.where();
  PBGI_ASSIGN_OR_RETURN(key.frame, s.need<int>("frame", kFrameRange));
  PBGI_ASSIGN_OR_RETURN(key.translate, s.get<Vec3f>("translate"));
  PBGI_ASSIGN_OR_RETURN(key.rotateDeg, s.get<Vec3f>("rotate_deg"));
  PBGI_ASSIGN_OR_RETURN(key.scale, s.get<float>("scale", kPositive));
  if (s.table().size() == 1) {
    return s.errorHere(fmt::format(
        "key at frame {} sets nothing (expected at least one of: translate, rotate_deg, scale)",
        key.frame));
  }
  return key;
}

absl::StatusOr<GeometryDesc> parseGeometry(const Section& s) {
  PBGI_RETURN_IF_ERROR(s.allowOnly({"file", "translate", "rotate_deg", "scale", "key"}));
  GeometryDesc geometry;
  geometry.where = s.where();
  if (s.find("file") == nullptr) return s.missing("file");
  // The format is checked before the file so that a typo in the extension says so.
  const toml::node& fileNode = *s.find("file");
  if (const auto* given = fileNode.as_string()) {
    std::string ext = fs::path(given->get()).extension().string();
    std::transform(ext.begin(), ext.end(), ext.begin(),
                   [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
    if (ext != ".obj" && ext != ".gltf" && ext != ".glb") {
      return s.error(fileNode, fmt::format("'file': expected a Wavefront OBJ (.obj) or glTF 2.0 "
                                           "(.gltf, .glb) file, found \"{}\"",
                                           given->get()));
    }
  }
  PBGI_ASSIGN_OR_RETURN(const std::optional<std::string> file, s.existingFile("file"));
  geometry.file = *file;
  PBGI_ASSIGN_OR_RETURN(geometry.base.translate, s.getOr<Vec3f>("translate", Vec3f(0.0f)));
  PBGI_ASSIGN_OR_RETURN(geometry.base.rotateDeg, s.getOr<Vec3f>("rotate_deg", Vec3f(0.0f)));
  PBGI_ASSIGN_OR_RETURN(geometry.base.scale, s.getOr<float>("scale", 1.0f, kPositive));

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> keys,
                             tableArray(s, "key", "[[geometry.key]]"));
  std::map<int, int> seen;
  for (const Section& k : keys) {
    PBGI_ASSIGN_OR_RETURN(TransformKey key, parseTransformKey(k));
    PBGI_RETURN_IF_ERROR(checkUniqueFrame(seen, key.frame, k));
    geometry.keys.push_back(std::move(key));
  }
  return geometry;
}

// --- emission, of materials and lights ----------------------------------------------------

// Light past kMaxEmission (core/scene/shot.h says why), with the key that gave it.
absl::Status tooBright(const Section& s, std::string_view key, const std::string& value) {
  return s.error(*s.find(key),
                 fmt::format("'{}' {}: expected at most {:g} per component, past which PBGI's "
                             "sums of light overflow float",
                             key, value, kMaxEmission));
}

// Radiance, intensity or irradiance: components from 0 to kMaxEmission.
absl::StatusOr<Vec3f> needEmission(const Section& s, std::string_view key) {
  PBGI_ASSIGN_OR_RETURN(const Vec3f v, s.need<Vec3f>(key, kNonNegative));
  if (maxComponent(v) > kMaxEmission) {
    return tooBright(s, key, fmt::format("{}", v));
  }
  return v;
}

// --- [[material]] ------------------------------------------------------------------------

// The keys each type allows, in the order of MaterialType.
const Variants& materialKeys() {
  static const Variants kKeys = {
      {"diffuse", {"name", "type", "albedo", "albedo_texture"}},
      {"conductor", {"name", "type", "roughness", "distribution", "specular", "eta", "k", "tint"}},
      {"dielectric", {"name", "type", "roughness", "distribution", "ior"}},
      {"emissive", {"name", "type", "radiance"}},
  };
  return kKeys;
}

absl::StatusOr<MaterialDesc> parseMaterial(const Section& s) {
  MaterialDesc m;
  m.where = s.where();
  PBGI_ASSIGN_OR_RETURN(const std::optional<MaterialType> type,
                             s.choice<MaterialType>("type", "material type",
                                                    {{"diffuse", MaterialType::kDiffuse},
                                                     {"conductor", MaterialType::kConductor},
                                                     {"dielectric", MaterialType::kDielectric},
                                                     {"emissive", MaterialType::kEmissive}}));
  if (!type) return s.missing("type");
  m.type = *type;
  const auto& [typeName, allowed] = materialKeys()[static_cast<size_t>(m.type)];
  PBGI_RETURN_IF_ERROR(
      s.allowOnly(allowed, strict_toml::otherVariantHint(materialKeys(), typeName, "material")));

  PBGI_ASSIGN_OR_RETURN(m.name, s.need<std::string>("name"));
  if (m.name.empty()) {
    return s.error(*s.find("name"), "'name': expected a material name, found \"\"");
  }

  const std::vector<std::pair<std::string_view, MicrofacetDistribution>> distributions = {
      {"ggx", MicrofacetDistribution::kGgx}, {"beckmann", MicrofacetDistribution::kBeckmann}};
  switch (m.type) {
    case MaterialType::kDiffuse: {
      PBGI_ASSIGN_OR_RETURN(m.albedo, s.get<Vec3f>("albedo", kUnitInterval));
      PBGI_ASSIGN_OR_RETURN(m.albedoTexture, s.existingFile("albedo_texture"));
      if (m.albedo && m.albedoTexture) {
        return s.error(*s.find("albedo_texture"),
                       "a diffuse material takes 'albedo' or 'albedo_texture', not both");
      }
      if (!m.albedo && !m.albedoTexture) {
        return s.errorHere(
            "a diffuse material needs 'albedo' = [r, g, b] or 'albedo_texture' = \"path\"");
      }
      break;
    }
    case MaterialType::kConductor: {
      PBGI_ASSIGN_OR_RETURN(m.roughness, s.getOr<float>("roughness", 0.0f, kNonNegative));
      PBGI_ASSIGN_OR_RETURN(
          auto d, s.choice<MicrofacetDistribution>("distribution", "distribution", distributions));
      m.distribution = d.value_or(MicrofacetDistribution::kGgx);
      PBGI_ASSIGN_OR_RETURN(m.specular, s.get<Vec3f>("specular", kUnitInterval));
      PBGI_ASSIGN_OR_RETURN(m.eta, s.get<Vec3f>("eta", kPositive));
      PBGI_ASSIGN_OR_RETURN(m.k, s.get<Vec3f>("k", kNonNegative));
      PBGI_ASSIGN_OR_RETURN(m.tint, s.getOr<Vec3f>("tint", Rgb(1.0f), kUnitInterval));
      if (m.specular && (m.eta || m.k)) {
        return s.error(*s.find(m.eta ? "eta" : "k"),
                       "a conductor's Fresnel is either 'specular' or 'eta' and 'k', not both");
      }
      if (m.eta.has_value() != m.k.has_value()) {
        return s.error(*s.find(m.eta ? "eta" : "k"),
                       fmt::format("'{}' needs '{}': a complex index of refraction is eta + i k",
                                   m.eta ? "eta" : "k", m.eta ? "k" : "eta"));
      }
      if (!m.specular && !m.eta) {
        return s.errorHere("a conductor needs 'specular' = [r, g, b] or both 'eta' and 'k'");
      }
      break;
    }
    case MaterialType::kDielectric: {
      PBGI_ASSIGN_OR_RETURN(m.roughness, s.getOr<float>("roughness", 0.0f, kNonNegative));
      PBGI_ASSIGN_OR_RETURN(
          auto d, s.choice<MicrofacetDistribution>("distribution", "distribution", distributions));
      m.distribution = d.value_or(MicrofacetDistribution::kGgx);
      PBGI_ASSIGN_OR_RETURN(m.ior, s.getOr<float>("ior", 1.5f, kIorRange));
      break;
    }
    case MaterialType::kEmissive: {
      PBGI_ASSIGN_OR_RETURN(m.radiance, needEmission(s, "radiance"));
      break;
    }
  }
  return m;
}

// --- [[light]] ---------------------------------------------------------------------------

// The keys each type allows, in the order of LightType.
const Variants& lightKeys() {
  static const Variants kKeys = {
      {"quad", {"type", "corner", "edge_u", "edge_v", "radiance"}},
      {"sphere", {"type", "center", "radius", "radiance"}},
      {"point", {"type", "position", "intensity"}},
      {"spot", {"type", "position", "direction", "cone_deg", "intensity"}},
      {"directional", {"type", "direction", "irradiance"}},
      {"environment", {"type", "file", "scale", "rotate_deg"}},
  };
  return kKeys;
}

absl::StatusOr<Vec3f> needDirection(const Section& s, std::string_view key) {
  PBGI_ASSIGN_OR_RETURN(const Vec3f d, s.need<Vec3f>(key));
  if (length(d) == 0.0f) {
    return s.error(*s.find(key), fmt::format("'{}' must be a non-zero vector, found {}", key, d));
  }
  return normalize(d);
}

absl::StatusOr<LightDesc> parseLight(const Section& s) {
  LightDesc l;
  l.where = s.where();
  PBGI_ASSIGN_OR_RETURN(const std::optional<LightType> type,
                             s.choice<LightType>("type", "light type",
                                                 {{"quad", LightType::kQuad},
                                                  {"sphere", LightType::kSphere},
                                                  {"point", LightType::kPoint},
                                                  {"spot", LightType::kSpot},
                                                  {"directional", LightType::kDirectional},
                                                  {"environment", LightType::kEnvironment}}));
  if (!type) return s.missing("type");
  l.type = *type;
  const auto& [typeName, allowed] = lightKeys()[static_cast<size_t>(l.type)];
  PBGI_RETURN_IF_ERROR(
      s.allowOnly(allowed, strict_toml::otherVariantHint(lightKeys(), typeName, "light")));

  switch (l.type) {
    case LightType::kQuad: {
      PBGI_ASSIGN_OR_RETURN(l.corner, s.need<Vec3f>("corner"));
      PBGI_ASSIGN_OR_RETURN(l.edgeU, s.need<Vec3f>("edge_u"));
      PBGI_ASSIGN_OR_RETURN(l.edgeV, s.need<Vec3f>("edge_v"));
      const float area = length(cross(l.edgeU, l.edgeV));
      if (!(area > 1e-6f * length(l.edgeU) * length(l.edgeV)) || area == 0.0f) {
        return s.error(
            *s.find("edge_v"),
            fmt::format("edge_u {} and edge_v {} are parallel or zero: the quad has no area",
                        l.edgeU, l.edgeV));
      }
      PBGI_ASSIGN_OR_RETURN(l.radiance, needEmission(s, "radiance"));
      break;
    }
    case LightType::kSphere: {
      PBGI_ASSIGN_OR_RETURN(l.center, s.need<Vec3f>("center"));
      PBGI_ASSIGN_OR_RETURN(l.radius, s.need<float>("radius", kPositive));
      PBGI_ASSIGN_OR_RETURN(l.radiance, needEmission(s, "radiance"));
      break;
    }
    case LightType::kPoint: {
      PBGI_ASSIGN_OR_RETURN(l.position, s.need<Vec3f>("position"));
      PBGI_ASSIGN_OR_RETURN(l.intensity, needEmission(s, "intensity"));
      break;
    }
    case LightType::kSpot: {
      PBGI_ASSIGN_OR_RETURN(l.position, s.need<Vec3f>("position"));
      PBGI_ASSIGN_OR_RETURN(l.direction, needDirection(s, "direction"));
      PBGI_ASSIGN_OR_RETURN(l.coneDeg, s.need<float>("cone_deg", kConeRange));
      PBGI_ASSIGN_OR_RETURN(l.intensity, needEmission(s, "intensity"));
      break;
    }
    case LightType::kDirectional: {
      PBGI_ASSIGN_OR_RETURN(l.direction, needDirection(s, "direction"));
      PBGI_ASSIGN_OR_RETURN(l.irradiance, needEmission(s, "irradiance"));
      break;
    }
    case LightType::kEnvironment: {
      if (s.find("file") == nullptr) return s.missing("file");
      PBGI_ASSIGN_OR_RETURN(const std::optional<std::string> file, s.existingFile("file"));
      l.file = *file;
      PBGI_ASSIGN_OR_RETURN(l.scale, s.getOr<float>("scale", 1.0f, kNonNegative));
      if (l.scale > kMaxEmission) return tooBright(s, "scale", fmt::format("{}", l.scale));
      PBGI_ASSIGN_OR_RETURN(l.rotateDeg, s.getOr<float>("rotate_deg", 0.0f));
      break;
    }
  }
  return l;
}

// --- [render] ----------------------------------------------------------------------------

// The keys every integrator shares; the rest of [render] are integrator parameters, declared
// by each integrator in the registry (core/render/integrators.h).
const std::vector<std::string_view> kCommonRenderKeys = {
    "integrator", "spp", "seed", "max_depth", "filter", "filter_width", "tile_size",
    "roulette_depth"};

// An integrator parameter, read as its declaration says.
absl::Status parseParam(const Section& s, const ParamSpec& spec, IntegratorParams& params) {
  const toml::node& node = *s.find(spec.key);
  ParamValue value{.where = s.source().at(node.source())};
  const Range range{spec.lo, spec.hi, spec.loOpen, false};
  switch (spec.type) {
    case ParamType::kInt: {
      PBGI_ASSIGN_OR_RETURN(value.value, s.need<int64_t>(spec.key, range));
      break;
    }
    case ParamType::kFloat: {
      PBGI_ASSIGN_OR_RETURN(const float v, s.need<float>(spec.key, range));
      value.value = static_cast<double>(v);
      break;
    }
    case ParamType::kChoice: {
      std::vector<std::pair<std::string_view, std::string>> options;
      for (std::string_view c : spec.choices) options.push_back({c, std::string(c)});
      PBGI_ASSIGN_OR_RETURN(const std::optional<std::string> v,
                            s.choice<std::string>(spec.key, "value", options));
      value.value = *v;
      break;
    }
  }
  return params.set(spec, std::move(value));
}

absl::Status parseRender(const Section& s, RenderSettings& r, std::vector<std::string>* warnings) {
  std::vector<std::string_view> allowed = kCommonRenderKeys;
  for (std::string_view key : allParamKeys()) allowed.push_back(key);
  PBGI_RETURN_IF_ERROR(s.allowOnly(allowed));
  PBGI_ASSIGN_OR_RETURN(r.integrator, s.getOr<std::string>("integrator", r.integrator));
  if (const toml::node* n = s.find("integrator")) {
    r.integratorWhere = s.source().at(n->source());
    if (absl::Status st = findIntegrator(r.integrator).status(); !st.ok()) {
      return s.error(*n, fmt::format("'integrator': unknown integrator \"{}\" (expected one of: {})",
                                     r.integrator, fmt::join(integratorNames(), ", ")));
    }
  }
  PBGI_ASSIGN_OR_RETURN(r.spp, s.getOr<int>("spp", r.spp, kSppRange));
  PBGI_ASSIGN_OR_RETURN(const int64_t seed,
                             s.getOr<int64_t>("seed", static_cast<int64_t>(r.seed), kNonNegative));
  r.seed = static_cast<uint64_t>(seed);
  PBGI_ASSIGN_OR_RETURN(r.maxDepth, s.getOr<int>("max_depth", r.maxDepth, kDepthRange));
  PBGI_ASSIGN_OR_RETURN(
      const std::optional<FilterType> filter,
      s.choice<FilterType>("filter", "pixel filter",
                           {{"box", FilterType::kBox},
                            {"gaussian", FilterType::kGaussian},
                            {"blackman-harris", FilterType::kBlackmanHarris}}));
  r.filter = filter.value_or(r.filter);
  PBGI_ASSIGN_OR_RETURN(r.filterWidth,
                             s.getOr<float>("filter_width", r.filterWidth, kFilterWidthRange));
  PBGI_ASSIGN_OR_RETURN(r.tileSize, s.getOr<int>("tile_size", r.tileSize, kTileSizeRange));
  PBGI_ASSIGN_OR_RETURN(r.rouletteDepth,
                             s.getOr<int>("roulette_depth", r.rouletteDepth, kDepthRange));
  for (std::string_view key : allParamKeys()) {
    if (s.find(key) == nullptr) continue;
    PBGI_RETURN_IF_ERROR(parseParam(s, *findParam(key), r.params));
  }
  // The integrator's own checks across its parameters (their messages name file and line).
  return validateRenderSettings(r, warnings);
}

// --- the whole file ----------------------------------------------------------------------

absl::StatusOr<ShotDesc> parseDocument(const Source& source, const toml::table& root) {
  ShotDesc shot;
  shot.path = source.file();
  shot.dir = source.dir().string();
  const Section top(source, root, "top level");

  // The version decides what every other key means, so it is checked before any of them: a
  // newer file fails with "update pbgi", not with a list of keys this build does not know.
  if (top.find("version") == nullptr) {
    return top.errorHere(fmt::format("missing required key 'version' (this build reads version {})",
                                     kSupportedVersion));
  }
  PBGI_ASSIGN_OR_RETURN(const int64_t version, top.need<int64_t>("version"));
  if (version > kSupportedVersion) {
    return top.error(
        *top.find("version"),
        fmt::format("'version' {} is newer than this build of pbgi reads ({}); update pbgi",
                    version, kSupportedVersion));
  }
  if (version != kSupportedVersion) {
    return top.error(*top.find("version"),
                     fmt::format("'version' must be {}, found {}", kSupportedVersion, version));
  }
  shot.version = static_cast<int>(version);
  PBGI_RETURN_IF_ERROR(
      top.allowOnly({"version", "shot", "camera", "geometry", "material", "light", "render"}));

  PBGI_ASSIGN_OR_RETURN(const std::optional<Section> shotTable,
                             subTable(top, "shot", "[shot]"));
  if (!shotTable) return top.errorHere("missing required table [shot]");
  PBGI_RETURN_IF_ERROR(parseShotTable(*shotTable, shot));

  PBGI_ASSIGN_OR_RETURN(const std::optional<Section> camera,
                             subTable(top, "camera", "[camera]"));
  if (!camera) return top.errorHere("missing required table [camera]");
  PBGI_RETURN_IF_ERROR(parseCamera(*camera, shot));

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> geometry,
                             tableArray(top, "geometry", "[[geometry]]"));
  if (geometry.empty()) {
    return top.errorHere("missing required [[geometry]]: a shot needs at least one geometry file");
  }
  for (const Section& g : geometry) {
    PBGI_ASSIGN_OR_RETURN(GeometryDesc desc, parseGeometry(g));
    shot.geometry.push_back(std::move(desc));
  }

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> materials,
                             tableArray(top, "material", "[[material]]"));
  std::map<std::string, int> materialLines;
  for (const Section& m : materials) {
    PBGI_ASSIGN_OR_RETURN(MaterialDesc desc, parseMaterial(m));
    auto [it, inserted] = materialLines.emplace(desc.name, desc.where.line);
    if (!inserted) {
      return m.error(*m.find("name"), fmt::format("material \"{}\" is already defined at line {}",
                                                  desc.name, it->second));
    }
    shot.materials.push_back(std::move(desc));
  }

  PBGI_ASSIGN_OR_RETURN(const std::vector<Section> lights,
                             tableArray(top, "light", "[[light]]"));
  int environmentLine = 0;
  for (const Section& l : lights) {
    PBGI_ASSIGN_OR_RETURN(LightDesc desc, parseLight(l));
    // Two environment maps would both claim every escaping ray; nothing sums them.
    if (desc.type == LightType::kEnvironment) {
      if (environmentLine > 0) {
        return l.errorHere(fmt::format(
            "a shot has at most one environment light; another is at line {}", environmentLine));
      }
      environmentLine = desc.where.line;
    }
    shot.lights.push_back(std::move(desc));
  }

  PBGI_ASSIGN_OR_RETURN(const std::optional<Section> render,
                             subTable(top, "render", "[render]"));
  if (render) PBGI_RETURN_IF_ERROR(parseRender(*render, shot.render, &shot.warnings));
  return shot;
}

absl::Status syntaxError(const std::string& path, const toml::parse_error& e) {
  const SourceLocation loc{path, static_cast<int>(e.source().begin.line),
                           static_cast<int>(e.source().begin.column)};
  return absl::InvalidArgumentError(
      fmt::format("{}: TOML syntax error: {}", loc.toString(), e.description()));
}

}  // namespace

absl::StatusOr<ShotDesc> parseShot(std::string_view text, const std::string& path) {
  toml::table root;
#if TOML_EXCEPTIONS
  try {
    root = toml::parse(text, std::string_view(path));
  } catch (const toml::parse_error& e) {
    return syntaxError(path, e);
  }
#else
  toml::parse_result result = toml::parse(text, std::string_view(path));
  if (!result) return syntaxError(path, result.error());
  root = std::move(result).table();
#endif
  const Source source(path);
  absl::StatusOr<ShotDesc> shot = parseDocument(source, root);
  if (shot.ok()) shot->source = std::string(text);
  return shot;
}

absl::StatusOr<ShotDesc> loadShotFile(const std::string& path) {
  std::error_code ec;
  const fs::file_status st = fs::status(path, ec);
  if (!fs::exists(st)) return absl::NotFoundError(fmt::format("{}: shot file not found", path));
  if (!fs::is_regular_file(st)) {
    return absl::InvalidArgumentError(fmt::format("{}: not a regular file", path));
  }
  const std::uintmax_t size = fs::file_size(path, ec);
  if (!ec && size > kMaxShotFileBytes) {
    return absl::InvalidArgumentError(
        fmt::format("{}: shot file is {} bytes; a shot file is at most {} bytes", path, size,
                    kMaxShotFileBytes));
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::PermissionDeniedError(
        fmt::format("{}: cannot open shot file: {}", path, std::strerror(errno)));
  }
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) {
    return absl::DataLossError(
        fmt::format("{}: cannot read shot file: {}", path, std::strerror(errno)));
  }
  return parseShot(text.str(), path);
}

}  // namespace pbgi
