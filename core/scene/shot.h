#pragma once
// The in-memory form of a shot file (README, "Shot files"). The TOML parser that fills it
// lives in formats/shot; everything here is plain data plus keyframe evaluation.

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include <absl/status/status.h>

#include "core/math/vec.h"
#include "core/scene/integrator_params.h"
#include "core/util/source_location.h"

namespace pbgi {

struct CameraParams {
  Vec3f position{0.0f, 0.0f, 0.0f};
  Vec3f lookAt{0.0f, 0.0f, 1.0f};
  Vec3f up{0.0f, 1.0f, 0.0f};
  float fovYDeg = 45.0f;
  float apertureRadius = 0.0f;
  float focusDistance = 0.0f;
};

// A keyframe sets any subset of the animatable values; the others come from other keys.
struct CameraKey {
  int frame = 0;
  std::optional<Vec3f> position, lookAt, up;
  std::optional<float> fovYDeg, apertureRadius, focusDistance;
  SourceLocation where;
};

struct CameraDesc {
  CameraParams base;  // the [camera] table's own values
  Vec2i views{1, 1};  // columns, rows of a camera array
  float viewSpacing = 0.0f;
  std::vector<CameraKey> keys;
  SourceLocation where;
};

struct TransformParams {
  Vec3f translate{0.0f, 0.0f, 0.0f};
  Vec3f rotateDeg{0.0f, 0.0f, 0.0f};  // XYZ Euler angles
  float scale = 1.0f;
};

struct TransformKey {
  int frame = 0;
  std::optional<Vec3f> translate, rotateDeg;
  std::optional<float> scale;
  SourceLocation where;
};

struct GeometryDesc {
  std::string file;  // absolute, or relative to the working directory (resolved by the parser)
  TransformParams base;
  std::vector<TransformKey> keys;
  SourceLocation where;
};

enum class MaterialType { kDiffuse, kConductor, kDielectric, kEmissive };
enum class MicrofacetDistribution { kGgx, kBeckmann };

struct MaterialDesc {
  std::string name;
  MaterialType type = MaterialType::kDiffuse;
  std::optional<Rgb> albedo;
  std::optional<std::string> albedoTexture;  // resolved path
  float roughness = 0.0f;
  MicrofacetDistribution distribution = MicrofacetDistribution::kGgx;
  std::optional<Rgb> specular;  // conductor, Schlick
  std::optional<Rgb> eta, k;    // conductor, complex index of refraction
  Rgb tint{1.0f, 1.0f, 1.0f};
  float ior = 1.5f;  // dielectric
  Rgb radiance{0.0f, 0.0f, 0.0f};  // emissive
  SourceLocation where;
};

enum class LightType { kQuad, kSphere, kPoint, kSpot, kDirectional, kEnvironment };

// The most light a shot may emit, per component: radiance (quad, sphere and environment
// lights, after the map's scale; emissive materials), intensity (point, spot) and irradiance
// (directional). PBGI holds a cluster's power (radiance times area) and a receiver's
// irradiance in float: at 1e20 a room of 1e6 units keeps its clusters near 1e34, under
// float's 3.4e38, where a radiance of 1e30 at that size, or of 2.5e37 at any, overflowed them
// and a render failed on non-finite irradiance. The sun is about 2e7 W/(sr m^2), 1.6e9 cd/m^2.
inline constexpr float kMaxEmission = 1e20f;

struct LightDesc {
  LightType type = LightType::kPoint;
  // quad
  Vec3f corner{0.0f}, edgeU{0.0f}, edgeV{0.0f};
  // sphere
  Vec3f center{0.0f};
  float radius = 0.0f;
  // quad, sphere
  Rgb radiance{0.0f};
  // point, spot
  Vec3f position{0.0f};
  Rgb intensity{0.0f};
  // spot, directional (the direction light travels towards)
  Vec3f direction{0.0f, -1.0f, 0.0f};
  float coneDeg = 30.0f;  // spot: half-angle of the cone
  // directional
  Rgb irradiance{0.0f};
  // environment
  std::string file;  // resolved path of a lat-long OpenEXR
  float scale = 1.0f;
  float rotateDeg = 0.0f;
  SourceLocation where;
};

enum class FilterType { kBox, kGaussian, kBlackmanHarris };

struct RenderSettings {
  std::string integrator = "path";
  SourceLocation integratorWhere;  // where the integrator was named, for its errors
  int spp = 4;
  uint64_t seed = 0;
  int maxDepth = 64;
  FilterType filter = FilterType::kBox;
  float filterWidth = 1.0f;  // full width of the filter's support, in pixels
  // Project-defined settings (README: "Render settings").
  int tileSize = 32;
  int rouletteDepth = 3;  // Russian roulette starts after this many bounces
  // The integrators' own parameters (their gathers, caches and bakes), each declared and
  // validated by its integrator (core/render/integrators.h).
  IntegratorParams params;
};

// What a command line or a farm job changes of a shot's [render] settings. Typed: values are
// parsed once, where they were written (a flag, a job's submission), and carried as values
// from there, through the farm's wire and its store, to the render.
// What a frame's image keeps: the AOV layers (frameAovs() names them) and the EXR compression.
struct OutputOptions {
  std::optional<std::vector<std::string>> aovs;  // unset: every layer; empty: none
  std::string exrCompression = "zip";            // OpenEXR's names (exrCompressions())
  bool operator==(const OutputOptions&) const = default;
};

struct RenderOverrides {
  std::string integrator;  // empty: the shot's
  SourceLocation integratorWhere;
  int spp = 0;  // 0: the shot's
  IntegratorParams params;
  int width = 0, height = 0;            // each view's pixels; 0: the shot's resolution
  std::optional<uint64_t> seed;         // unset: the shot's
  std::optional<OutputOptions> output;  // unset: the shot's (every layer, ZIP)

  bool empty() const {
    return integrator.empty() && spp == 0 && params.empty() && width == 0 && height == 0 && !seed &&
           !output;
  }
  bool operator==(const RenderOverrides& o) const {
    return integrator == o.integrator && spp == o.spp && params == o.params && width == o.width &&
           height == o.height && seed == o.seed && output == o.output;
  }
};

struct ShotDesc {
  std::string path;  // the shot file, as given
  std::string dir;   // its folder; relative paths resolve against it
  std::string source;  // the bytes parsed: what bakes and caches key on (a farm job: as submitted)
  int version = 1;
  std::string name;
  int firstFrame = 1;
  int lastFrame = 1;
  int width = 0;
  int height = 0;
  std::string output;  // resolved pattern; runs of '#' become the frame number
  CameraDesc camera;
  std::vector<GeometryDesc> geometry;
  std::vector<MaterialDesc> materials;
  std::vector<LightDesc> lights;
  RenderSettings render;
  OutputOptions outputOptions;  // a job's or a command's choice; the shot file sets none
  // Things the parser accepted but the user may not mean (a parameter of another integrator).
  std::vector<std::string> warnings;
};

// OkStatus when `frame` is one of the shot's; OutOfRange naming the shot file and its frames
// otherwise.
absl::Status checkShotFrame(const ShotDesc& shot, int frame);

// The largest image a shot may ask for: each side, and the pixels of every view together
// (8192 x 8192, 1 GiB as RGBA floats: a typo in a resolution cannot exhaust a worker).
constexpr int kMaxShotResolution = 16384;
constexpr int64_t kMaxShotPixels = int64_t{1} << 26;
// InvalidArgument, naming `where`, unless width x height views of `views` fit the limits above.
absl::Status checkImageSize(int width, int height, Vec2i views, std::string_view where);

// Keyframe evaluation. The table's own values act as a key at the shot's first frame;
// explicit keys override it. Each value interpolates linearly between the keys that set it
// and is held constant before the first and after the last.
CameraParams cameraAt(const CameraDesc& camera, int firstFrame, int frame);
TransformParams transformAt(const GeometryDesc& geometry, int firstFrame, int frame);

// The output path of one frame: each run of '#' becomes the zero-padded frame number
// (padded to the run's length). A pattern without '#' gets ".####" inserted before the
// extension when the shot has more than one frame.
std::string outputPathForFrame(const std::string& pattern, int frame, bool multiFrame);

}  // namespace pbgi
