#pragma once
// Light sources. Area lights (quad, sphere, emissive triangles) are also surfaces of the
// scene: the camera sees them, they cast shadows, and they reflect nothing. Point, spot and
// directional lights are invisible deltas; the environment surrounds the scene.

#include <memory>
#include <optional>
#include <vector>

#include "core/math/vec.h"
#include "core/sampling/sampling.h"
#include "core/scene/shot.h"
#include "core/scene/texture.h"

namespace pbgi {

struct LightSample {
  Rgb radiance{0.0f};     // arriving at the receiver along -wi (irradiance for deltas)
  Vec3f wi{0.0f};         // unit direction from the receiver towards the light
  float distance = 0.0f;  // to the sampled point; infinity for infinite lights
  float pdf = 0.0f;       // solid angle density at the receiver; 1 for delta lights
  bool delta = false;
  // The sampled point (finite distances), and the unit normal of the light's surface there;
  // zero for a light without a surface (point and spot). What a shadow ray aims at.
  Vec3f point{0.0f};
  Vec3f normal{0.0f};
};

class Light {
 public:
  virtual ~Light() = default;

  // Samples incident light at receiver p; nullopt when nothing can arrive.
  virtual std::optional<LightSample> sample(const Vec3f& p, const Vec2f& u) const = 0;
  // Solid-angle density at p of sampling the direction wi that reaches the light's surface
  // at point `hit` with unit normal `n` (area lights), or escapes (infinite lights).
  virtual float pdf(const Vec3f& p, const Vec3f& wi, const Vec3f& hit, const Vec3f& n) const {
    return 0.0f;
  }
  // Radiance leaving the light's surface at a point with normal n towards direction w.
  virtual Rgb emitted(const Vec3f& n, const Vec3f& w) const { return Rgb(0.0f); }
  // Radiance arriving along a ray with direction d that leaves the scene.
  virtual Rgb escaped(const Vec3f& d) const { return Rgb(0.0f); }

  // Called once the scene's bounds are known (infinite lights need them).
  virtual void preprocess(const Bounds3f& sceneBounds) {}
  // Emitted power, for choosing lights in proportion to it.
  virtual float power() const = 0;
  virtual bool isDelta() const { return false; }
  virtual bool isInfinite() const { return false; }
};

// An environment: light from every direction at infinity that is not a delta (directional
// lights are). PBGI's records take its light once each (core/render/sky_irradiance.h).
inline bool isSkyLight(const Light& light) { return light.isInfinite() && !light.isDelta(); }

// Emitters, each also a surface where it has one.
std::unique_ptr<Light> makeQuadLight(const Vec3f& corner, const Vec3f& edgeU, const Vec3f& edgeV,
                                     const Rgb& radiance);
std::unique_ptr<Light> makeSphereLight(const Vec3f& center, float radius, const Rgb& radiance);
// An emissive triangle; it emits on both sides.
std::unique_ptr<Light> makeTriangleLight(const Vec3f& p0, const Vec3f& p1, const Vec3f& p2,
                                         const Rgb& radiance);
std::unique_ptr<Light> makePointLight(const Vec3f& position, const Rgb& intensity);
// A spot with a hard edge at coneDeg from its axis (the half-angle of the cone).
std::unique_ptr<Light> makeSpotLight(const Vec3f& position, const Vec3f& direction,
                                     float coneDeg, const Rgb& intensity);
std::unique_ptr<Light> makeDirectionalLight(const Vec3f& direction, const Rgb& irradiance);
// A lat-long radiance map, importance-sampled in proportion to luminance times sin(theta).
std::unique_ptr<Light> makeEnvironmentLight(std::shared_ptr<const LatLongImage> image,
                                            float scale, float rotateDeg);
// Uniform radiance from every direction (tests: the white furnace).
std::unique_ptr<Light> makeUniformEnvironmentLight(const Rgb& radiance);

// Direction <-> lat-long coordinates (u across, v down, both in [0, 1)) per the shot spec.
Vec3f latLongToDirection(const Vec2f& uv);
Vec2f directionToLatLong(const Vec3f& d);

}  // namespace pbgi
