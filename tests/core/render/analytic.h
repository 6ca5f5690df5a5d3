#pragma once
// Closed forms of direct irradiance, in double precision, for the analytic suites (the path
// tracer's and the surfel baker's): what a light of uniform radiance delivers to a point of a
// surface, with no sampling in it.

#include <cmath>
#include <cstdio>
#include <functional>
#include <memory>
#include <numbers>
#include <string>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "core/math/vec.h"
#include "core/scene/scene.h"
#include "tests/core/render/test_scenes.h"

namespace pbgi::analytic {

// The float vector's functions beside the double ones below.
using pbgi::cross;
using pbgi::dot;
using pbgi::length;
using pbgi::normalize;

struct Vec3d {
  double x = 0.0, y = 0.0, z = 0.0;
  Vec3d() = default;
  Vec3d(double x_, double y_, double z_) : x(x_), y(y_), z(z_) {}
  explicit Vec3d(const Vec3f& v) : x(v.x), y(v.y), z(v.z) {}
  Vec3d operator+(const Vec3d& o) const { return {x + o.x, y + o.y, z + o.z}; }
  Vec3d operator-(const Vec3d& o) const { return {x - o.x, y - o.y, z - o.z}; }
  Vec3d operator*(double s) const { return {x * s, y * s, z * s}; }
};
inline double dot(const Vec3d& a, const Vec3d& b) { return a.x * b.x + a.y * b.y + a.z * b.z; }
inline Vec3d cross(const Vec3d& a, const Vec3d& b) {
  return {a.y * b.z - a.z * b.y, a.z * b.x - a.x * b.z, a.x * b.y - a.y * b.x};
}
inline double length(const Vec3d& a) { return std::sqrt(dot(a, a)); }
inline Vec3d normalize(const Vec3d& a) { return a * (1.0 / length(a)); }

// The part of a planar polygon on the side of the plane through p with normal n that n points
// to (Sutherland-Hodgman against one plane).
inline std::vector<Vec3d> clipAbovePlane(const std::vector<Vec3d>& poly, const Vec3d& p,
                                         const Vec3d& n) {
  std::vector<Vec3d> out;
  for (size_t i = 0; i < poly.size(); ++i) {
    const Vec3d& a = poly[i];
    const Vec3d& b = poly[(i + 1) % poly.size()];
    const double da = dot(a - p, n), db = dot(b - p, n);
    if (da >= 0.0) out.push_back(a);
    if ((da >= 0.0) != (db >= 0.0)) out.push_back(a + (b - a) * (da / (da - db)));
  }
  return out;
}

// Irradiance at p (unit normal n) from a planar polygon of uniform radiance L seen from p,
// occluded by nothing: Lambert's formula, E = L/2 sum_i theta_i (n . gamma_i), over the part
// of the polygon above p's tangent plane. Either winding.
inline double polygonIrradiance(const Vec3d& p, const Vec3d& n, const std::vector<Vec3d>& polygon,
                                double L) {
  const std::vector<Vec3d> poly = clipAbovePlane(polygon, p, n);
  if (poly.size() < 3) return 0.0;
  double sum = 0.0;
  for (size_t i = 0; i < poly.size(); ++i) {
    const Vec3d a = normalize(poly[i] - p);
    const Vec3d b = normalize(poly[(i + 1) % poly.size()] - p);
    const Vec3d c = cross(a, b);
    const double s = length(c);
    if (s == 0.0) continue;
    sum += std::atan2(s, dot(a, b)) * dot(n, c * (1.0 / s));
  }
  return 0.5 * L * std::abs(sum);
}

// The same for a one-sided emitter that shines along `emitNormal`: nothing behind it.
inline double oneSidedPolygonIrradiance(const Vec3d& p, const Vec3d& n,
                                        const std::vector<Vec3d>& polygon, const Vec3d& emitNormal,
                                        double L) {
  if (dot(p - polygon[0], emitNormal) <= 0.0) return 0.0;
  return polygonIrradiance(p, n, polygon, L);
}

// Irradiance at p (unit normal n) from a sphere of uniform radiance L that lies wholly above
// p's tangent plane: pi L sin^2(alpha) cos(theta) (alpha the half-angle it subtends, theta its
// centre's angle from n). Negative when part of it is below the plane (callers keep clear).
inline double sphereIrradiance(const Vec3d& p, const Vec3d& n, const Vec3d& center, double radius,
                               double L) {
  const Vec3d d = center - p;
  const double dist = length(d);
  const double sinAlpha = radius / dist;
  const double cosTheta = dot(normalize(d), n);
  if (cosTheta < sinAlpha) return -1.0;  // would need the horizon-clipped form
  return std::numbers::pi * L * sinAlpha * sinAlpha * cosTheta;
}

// Radiance inside a closed diffuse enclosure of albedo a whose walls emit Le, for paths of
// at most maxDepth bounces after the camera vertex: Le (1 + a + ... + a^maxDepth).
inline double furnaceRadiance(double a, double Le, int maxDepth) {
  return Le * (1.0 - std::pow(a, maxDepth + 1)) / (1.0 - a);
}

inline std::vector<Vec3d> quadCorners(const Vec3f& corner, const Vec3f& u, const Vec3f& v) {
  const Vec3d c(corner), du(u), dv(v);
  return {c, c + du, c + du + dv, c + dv};
}

// ---- The cases: a scene, points on its diffuse receivers, and their exact irradiance ----

struct Receiver {
  Vec3f p;       // on a receiving surface
  Vec3f n;       // the unit normal of the side the light reaches
  double exact;  // irradiance there
  std::string label;
};

struct AnalyticCase {
  std::string name;
  std::unique_ptr<Scene> scene;
  std::vector<Receiver> receivers;
  // Stated per case: the largest relative standard deviation of one sample of an estimator
  // (the path tracer's direct light, or one surfel light sample), measured over the points
  // with margin. A point's bound on the relative error of the mean of n samples is then
  // 4 sigma / sqrt(n) (the suites check the measured deviation against it too).
  double sigmaPathTracer = 0.0;
  double sigmaSurfel = 0.0;
};

inline constexpr float kReceiverAlbedo = 0.5f;

inline uint32_t addReceiverMaterial(SceneBuilder& b) {
  Material m;
  m.albedo = Rgb(kReceiverAlbedo);
  return b.addMaterial(m);
}

// A square of side `size` centred at c in the plane spanned by unit vectors a and b; its
// winding faces a x b, or the other way when `flip`.
inline MeshData squareMesh(const Vec3f& c, const Vec3f& a, const Vec3f& b, float size, bool flip,
                           uint32_t material) {
  const Vec3f corner = c - (a + b) * (0.5f * size);
  return flip ? testing::makeQuadMesh(corner, b * size, a * size, material)
              : testing::makeQuadMesh(corner, a * size, b * size, material);
}

// A small square of receiver surface at a receiver, facing the way it does, for receivers in
// empty space (the path tracer shades surfaces; the receiver's camera ray meets this one).
inline void addPatch(SceneBuilder& b, const Receiver& r, float size, uint32_t material) {
  const Frame frame(r.n);
  b.addMesh(squareMesh(r.p, frame.s, frame.t, size, false, material));
}

inline std::unique_ptr<Scene> buildOrNull(SceneBuilder& b) {
  auto scene = b.build();
  if (!scene.ok()) return nullptr;
  return std::move(*scene);
}

// The scene of the grazing-angle report: a 0.55 x 0.55 quad emitter of radiance 10 facing
// down at a height over a square floor, receivers on the floor from 0 to 85 degrees off the
// emitter's axis (as far as the floor reaches), along x and along the diagonal.
struct QuadOverFloor {
  float scale = 1.0f;  // every length times this
  float height = 2.0f;
  float turnDeg = 0.0f;       // the emitter turned about its normal
  float floorSide = 0.0f;     // 0: wide enough for 85 degrees
  bool flipFloor = false;     // the floor wound downwards
  bool emissiveMesh = false;  // two emissive triangles (MTL Ke) instead of a [[light]] quad
  bool facePlusX = false;     // the whole set-up turned so that the floor faces +x
};

// The report's own variants: its 40 x 40 floor under the quad light at height 2, an emissive
// mesh at height 4 (the same angles), the set-up turned to face +x, the light turned 45
// degrees about its normal. Lit to the floor's edge (84 and 78 degrees off the axis).
inline std::vector<QuadOverFloor> reportedQuadOverFloorScenes() {
  return {{.floorSide = 40.0f},
          {.height = 4.0f, .floorSide = 40.0f, .emissiveMesh = true},
          {.floorSide = 40.0f, .facePlusX = true},
          {.turnDeg = 45.0f, .floorSide = 40.0f, .emissiveMesh = true, .facePlusX = true}};
}

inline AnalyticCase quadOverFloorCase(const QuadOverFloor& q) {
  // The set-up is built facing +y, then turned by -90 degrees about z where it faces +x.
  auto turn = [&](const Vec3f& v) { return q.facePlusX ? Vec3f(v.y, -v.x, v.z) : v; };
  SceneBuilder b;
  const uint32_t floorMaterial = addReceiverMaterial(b);
  const float side = q.floorSide > 0.0f
                         ? q.floorSide
                         : std::max(60.0f, 2.5f * q.height * std::tan(radians(85.0f)));
  b.addMesh(squareMesh(Vec3f(0.0f), turn(Vec3f(0, 0, 1)), turn(Vec3f(1, 0, 0)), side * q.scale,
                       q.flipFloor, floorMaterial));
  const float c = std::cos(radians(q.turnDeg)), s = std::sin(radians(q.turnDeg));
  // u x v = -y: the emitter shines down.
  const Vec3f u = turn(Vec3f(c, 0.0f, -s) * (0.55f * q.scale));
  const Vec3f v = turn(Vec3f(s, 0.0f, c) * (0.55f * q.scale));
  const Vec3f corner = turn(Vec3f(0.0f, q.height * q.scale, 0.0f)) - (u + v) * 0.5f;
  if (q.emissiveMesh) {
    Material emissive;
    emissive.type = MaterialType::kEmissive;
    emissive.radiance = Rgb(10.0f);
    b.addMesh(testing::makeQuadMesh(corner, u, v, b.addMaterial(emissive)));
  } else {
    LightDesc light;
    light.type = LightType::kQuad;
    light.corner = corner;
    light.edgeU = u;
    light.edgeV = v;
    light.radiance = Rgb(10.0f);
    b.addLight(light);
  }
  AnalyticCase out;
  out.name = fmt::format("{} over floor {:.0f}, height {}, turned {} deg{}{}, scale {}",
                         q.emissiveMesh ? "emissive quad mesh" : "quad light", side, q.height,
                         q.turnDeg, q.flipFloor ? ", floor wound down" : "",
                         q.facePlusX ? ", facing +x" : "", q.scale);
  out.scene = buildOrNull(b);
  const auto poly = quadCorners(corner, u, v);
  const Vec3f n = turn(Vec3f(0.0f, 1.0f, 0.0f));
  for (int deg = 0; deg <= 85; deg += 5) {
    const float r = q.height * std::tan(radians(static_cast<float>(deg)));
    for (const Vec3f& dir : {Vec3f(1, 0, 0), normalize(Vec3f(1, 0, 1))}) {
      if (maxAbsComponent(dir * r) > 0.48f * side) continue;
      const Vec3f p = turn(dir * (r * q.scale));
      out.receivers.push_back({p, n, polygonIrradiance(Vec3d(p), Vec3d(n), poly, 10.0),
                               fmt::format("{} deg along ({}, {})", deg, dir.x, dir.z)});
    }
  }
  out.sigmaPathTracer = 0.25;
  out.sigmaSurfel = 0.25;
  return out;
}

// A 1 x 1 quad light in the plane y = 2 facing down, spanning x in [0, 1], and a wall, the
// plane x = 0 facing +x, perpendicular to it through its edge: points of the wall below the
// light see it from 0 to nearly 90 degrees off either surface's normal.
inline AnalyticCase quadAndWallCase(float scale) {
  SceneBuilder b;
  const uint32_t wallMaterial = addReceiverMaterial(b);
  b.addMesh(squareMesh(Vec3f(0.0f, 0.0f, 0.0f) * scale, Vec3f(0, 1, 0), Vec3f(0, 0, 1),
                       8.0f * scale, false, wallMaterial));  // x = 0, facing +x
  LightDesc light;
  light.type = LightType::kQuad;
  light.corner = Vec3f(0.0f, 2.0f, -0.5f) * scale;
  light.edgeU = Vec3f(1.0f, 0.0f, 0.0f) * scale;
  light.edgeV = Vec3f(0.0f, 0.0f, 1.0f) * scale;  // u x v = -y
  light.radiance = Rgb(10.0f);
  b.addLight(light);
  AnalyticCase out;
  out.name = fmt::format("quad and perpendicular wall, scale {}", scale);
  out.scene = buildOrNull(b);
  const auto poly = quadCorners(light.corner, light.edgeU, light.edgeV);
  const Vec3f n(1.0f, 0.0f, 0.0f);
  for (const float depth : {0.05f, 0.2f, 0.5f, 1.0f, 1.5f, 2.0f, 3.0f}) {
    for (const float z : {0.0f, 0.4f, 1.0f}) {
      const Vec3f p = Vec3f(0.0f, 2.0f - depth, z) * scale;
      out.receivers.push_back({p, n, polygonIrradiance(Vec3d(p), Vec3d(n), poly, 10.0),
                               fmt::format("{} below the light, z {}", depth, z)});
    }
  }
  out.sigmaPathTracer = 1.5;
  out.sigmaSurfel = 7.0;
  return out;
}

// A sphere light of radius 1 and radiance 4 at the origin; receivers at distances from 1.02 to
// 100 radii, facing the centre or turned away from it as far as keeps the whole sphere above
// their horizon.
inline AnalyticCase sphereLightCase(float scale) {
  SceneBuilder b;
  const uint32_t receiver = addReceiverMaterial(b);
  LightDesc light;
  light.type = LightType::kSphere;
  light.center = Vec3f(0.0f);
  light.radius = 1.0f * scale;
  light.radiance = Rgb(4.0f);
  b.addLight(light);
  AnalyticCase out;
  out.name = fmt::format("sphere light, scale {}", scale);
  for (const float d : {1.02f, 1.2f, 1.5f, 2.0f, 5.0f, 20.0f, 100.0f}) {
    const float alpha = std::asin(1.0f / d);
    for (const float tilt : {0.0f, 0.5f, 0.95f}) {
      // Turned by tilt times the most that keeps the sphere above the horizon.
      const float theta = tilt * (0.5f * kPi - alpha);
      // Each receiver in a direction of its own, so that no receiver's patch shades another.
      const float azimuth = 2.0f * kPi * static_cast<float>(out.receivers.size()) / 21.0f;
      const Vec3f p =
          normalize(Vec3f(std::cos(azimuth), 0.4f * std::sin(3.0f * azimuth), std::sin(azimuth))) *
          (d * scale);
      const Vec3f toCenter = normalize(-p);
      const Vec3f side = normalize(cross(toCenter, Vec3f(0, 0, 1)));
      const Vec3f n = normalize(toCenter * std::cos(theta) + side * std::sin(theta));
      const double exact =
          sphereIrradiance(Vec3d(p), Vec3d(n), Vec3d(light.center), light.radius, 4.0);
      out.receivers.push_back({p, n, exact, fmt::format("{} radii, tilt {}", d, tilt)});
      addPatch(b, out.receivers.back(), 1e-3f * scale * d, receiver);
    }
  }
  out.scene = buildOrNull(b);
  out.sigmaPathTracer = 0.6;
  out.sigmaSurfel = 0.6;
  return out;
}

// An emissive triangle (MTL Ke; radiance 6) in the plane y = 0: it emits on both sides, so
// receivers facing it from either side get the same closed form. Far to its side, a quad
// light facing +x: one-sided, it lights nothing behind it. Each receiver's closed form sums
// both lights (the quad's front sees the triangle too, faintly; its back sees neither).
inline AnalyticCase triangleLightCase(float scale) {
  SceneBuilder b;
  const uint32_t receiver = addReceiverMaterial(b);
  Material emissive;
  emissive.type = MaterialType::kEmissive;
  emissive.albedo = Rgb(0.0f);
  emissive.radiance = Rgb(6.0f);
  const uint32_t e = b.addMaterial(emissive);
  MeshData emitter;
  emitter.name = "emitter";
  emitter.positions = {Vec3f(-0.5f, 0.0f, -0.4f) * scale, Vec3f(0.6f, 0.0f, -0.3f) * scale,
                       Vec3f(0.0f, 0.0f, 0.7f) * scale};  // winding faces -y
  emitter.indices = {0, 1, 2};
  emitter.materials = {e};
  const std::vector<Vec3d> triangle = {Vec3d(emitter.positions[0]), Vec3d(emitter.positions[1]),
                                       Vec3d(emitter.positions[2])};
  LightDesc quad;
  quad.type = LightType::kQuad;
  quad.corner = Vec3f(10.0f, -0.5f, -0.5f) * scale;
  quad.edgeU = Vec3f(0.0f, 1.0f, 0.0f) * scale;
  quad.edgeV = Vec3f(0.0f, 0.0f, 1.0f) * scale;  // u x v = +x
  quad.radiance = Rgb(6.0f);
  b.addLight(quad);
  const auto quadPoly = quadCorners(quad.corner, quad.edgeU, quad.edgeV);
  auto exact = [&](const Vec3f& p, const Vec3f& n) {
    return polygonIrradiance(Vec3d(p), Vec3d(n), triangle, 6.0) +
           oneSidedPolygonIrradiance(Vec3d(p), Vec3d(n), quadPoly, Vec3d(1, 0, 0), 6.0);
  };
  AnalyticCase out;
  out.name =
      fmt::format("triangle light (two-sided) and a quad's back (one-sided), scale {}", scale);
  for (const float side : {-1.0f, 1.0f}) {
    for (const float h : {0.1f, 0.5f, 2.0f}) {
      for (const float x : {0.0f, 1.0f, 3.0f}) {
        const Vec3f p = Vec3f(x, side * h, 0.1f) * scale;
        const Vec3f n(0.0f, -side, 0.0f);
        out.receivers.push_back(
            {p, n, exact(p, n),
             fmt::format("triangle, {} side, height {}, x {}", side < 0 ? "front" : "back", h, x)});
      }
      // Facing the quad light from its front, and from behind (nothing arrives there).
      const Vec3f q = Vec3f(10.0f + side * h, 0.1f, 0.0f) * scale;
      const Vec3f n(-side, 0.0f, 0.0f);
      out.receivers.push_back(
          {q, n, exact(q, n),
           fmt::format("quad light, {}, distance {}", side > 0 ? "front" : "behind", h)});
    }
  }
  // Receivers' patches first: a surfel's triangle 0 is a receiver's.
  for (const Receiver& r : out.receivers) addPatch(b, r, 1e-3f * scale, receiver);
  b.addMesh(std::move(emitter));
  out.scene = buildOrNull(b);
  out.sigmaPathTracer = 2.2;
  out.sigmaSurfel = 6.0;
  return out;
}

// A directional light of irradiance 3 (normal to its direction) on an open floor, `deg` off
// the floor's normal: E = 3 cos.
inline AnalyticCase directionalCase(float scale, float deg) {
  SceneBuilder b;
  const uint32_t m = addReceiverMaterial(b);
  b.addMesh(squareMesh(Vec3f(0.0f), Vec3f(0, 0, 1), Vec3f(1, 0, 0), 10.0f * scale, false, m));
  LightDesc light;
  light.type = LightType::kDirectional;
  const float theta = radians(deg), phi = radians(20.0f);
  light.direction =
      Vec3f(std::sin(theta) * std::cos(phi), -std::cos(theta), std::sin(theta) * std::sin(phi));
  light.irradiance = Rgb(3.0f);
  b.addLight(light);
  AnalyticCase out;
  out.name = fmt::format("directional light {} deg off the normal, scale {}", deg, scale);
  out.scene = buildOrNull(b);
  const Vec3f n(0.0f, 1.0f, 0.0f);
  const double cosTheta = std::abs(dot(Vec3d(normalize(light.direction)), Vec3d(n)));
  for (const float x : {-4.0f, 0.0f, 3.0f}) {
    const Vec3f p = Vec3f(x, 0.0f, 0.5f * x) * scale;
    out.receivers.push_back({p, n, 3.0 * cosTheta, fmt::format("x {}", x)});
  }
  out.sigmaPathTracer = 0.001;
  out.sigmaSurfel = 0.001;
  return out;
}

inline std::shared_ptr<const LatLongImage> constantLatLong(const Rgb& radiance) {
  auto image = std::make_shared<LatLongImage>();
  image->width = 16;
  image->height = 8;
  image->texels.assign(16 * 8, radiance);
  return image;
}

// A constant environment of radiance 2 (a lat-long map, as a shot has it) over an open floor:
// E = pi L anywhere on it, facing up; and a closed box of side 2 with one square opening of
// side 1 in its top: a point of the inside floor sees the sky through the opening alone,
// E = L times the opening's form factor (Lambert's formula over the opening).
inline AnalyticCase environmentCase(float scale, bool box) {
  SceneBuilder b;
  const uint32_t m = addReceiverMaterial(b);
  AnalyticCase out;
  const float L = 2.0f;
  if (!box) {
    out.name = fmt::format("constant environment over a plane, scale {}", scale);
    b.addMesh(squareMesh(Vec3f(0.0f), Vec3f(0, 0, 1), Vec3f(1, 0, 0), 10.0f * scale, false, m));
  } else {
    out.name = fmt::format("constant environment into a box through one opening, scale {}", scale);
    const float s = 2.0f * scale, h = 1.0f * scale;
    // Floor, four walls, and the top as four strips round a 1 x 1 hole (all facing in).
    b.addMesh(squareMesh(Vec3f(0.0f), Vec3f(0, 0, 1), Vec3f(1, 0, 0), s, false, m));
    b.addMesh(squareMesh(Vec3f(h, h, 0), Vec3f(0, 1, 0), Vec3f(0, 0, 1), s, true, m));
    b.addMesh(squareMesh(Vec3f(-h, h, 0), Vec3f(0, 1, 0), Vec3f(0, 0, 1), s, false, m));
    b.addMesh(squareMesh(Vec3f(0, h, h), Vec3f(1, 0, 0), Vec3f(0, 1, 0), s, false, m));
    b.addMesh(squareMesh(Vec3f(0, h, -h), Vec3f(1, 0, 0), Vec3f(0, 1, 0), s, true, m));
    const float y = 2.0f * h, q = 0.5f * scale;
    auto strip = [&](Vec3f c0, Vec3f c1) {
      b.addMesh(testing::makeQuadMesh(c0, Vec3f(c1.x - c0.x, 0, 0), Vec3f(0, 0, c1.z - c0.z), m));
    };
    strip(Vec3f(-h, y, -h), Vec3f(h, y, -q));
    strip(Vec3f(-h, y, q), Vec3f(h, y, h));
    strip(Vec3f(-h, y, -q), Vec3f(-q, y, q));
    strip(Vec3f(q, y, -q), Vec3f(h, y, q));
  }
  b.addLight(LightDesc{.type = LightType::kEnvironment}, constantLatLong(Rgb(L)));
  out.scene = buildOrNull(b);
  const Vec3f n(0.0f, 1.0f, 0.0f);
  const float y = 2.0f * scale, q = 0.5f * scale;
  const std::vector<Vec3d> opening = {Vec3d(-q, y, -q), Vec3d(q, y, -q), Vec3d(q, y, q),
                                      Vec3d(-q, y, q)};
  for (const float x : {0.0f, 0.5f, 0.9f}) {
    for (const float z : {0.0f, 0.7f}) {
      if (x == 0.0f && z == 0.7f) continue;
      const Vec3f p = Vec3f(x, 0.0f, z) * scale;
      const double exact =
          box ? polygonIrradiance(Vec3d(p), Vec3d(n), opening, L) : std::numbers::pi * L;
      out.receivers.push_back({p, n, exact, fmt::format("x {}, z {}", x, z)});
    }
  }
  out.sigmaPathTracer = box ? 5.5 : 0.4;
  out.sigmaSurfel = box ? 11.0 : 1.6;
  return out;
}

// ---- The suite: every estimator runs the same groups of cases ----

inline constexpr float kScales[] = {1.0f, 1e-4f, 1e4f};

// A test's worth of cases (the test's name) and the relative bound each point must keep.
struct CaseGroup {
  std::string name;
  double bound = 0.0;
  std::function<std::vector<AnalyticCase>()> cases;
};

// Cases over the three units.
inline std::vector<AnalyticCase> inEveryUnit(const std::function<AnalyticCase(float)>& make) {
  std::vector<AnalyticCase> out;
  for (const float scale : kScales) out.push_back(make(scale));
  return out;
}

inline std::vector<CaseGroup> caseGroups() {
  return {
      {"QuadLightOverAParallelFloorAtEveryAngleTo85Degrees", 0.02,
       [] {
         std::vector<AnalyticCase> out;
         for (const float scale : kScales)
           for (const float height : {2.0f, 4.0f})
             for (const float turn : {0.0f, 45.0f})
               out.push_back(quadOverFloorCase({.scale = scale,
                                                .height = height,
                                                .turnDeg = turn,
                                                .flipFloor = height == 4.0f}));
         return out;
       }},
      {"TheReportedFloorIsLitPast60DegreesOffTheLightsAxis", 0.02,
       [] {
         std::vector<AnalyticCase> out;
         for (const QuadOverFloor& q : reportedQuadOverFloorScenes())
           out.push_back(quadOverFloorCase(q));
         return out;
       }},
      {"QuadLightOverAPerpendicularWall", 0.03, [] { return inEveryUnit(quadAndWallCase); }},
      {"SphereLightFromNearToFar", 0.02, [] { return inEveryUnit(sphereLightCase); }},
      {"TriangleLightLightsBothSidesAndAQuadLightOnlyItsFront", 0.03,
       [] { return inEveryUnit(triangleLightCase); }},
      {"DirectionalLightToGrazingIncidence", 1e-4,
       [] {
         std::vector<AnalyticCase> out;
         for (const float scale : kScales)
           for (const float deg : {0.0f, 45.0f, 80.0f, 85.0f, 89.0f})
             out.push_back(directionalCase(scale, deg));
         return out;
       }},
      {"ConstantEnvironmentOverAPlane", 0.01,
       [] { return inEveryUnit([](float scale) { return environmentCase(scale, false); }); }},
      {"ConstantEnvironmentThroughABoxOpening", 0.03,
       [] { return inEveryUnit([](float scale) { return environmentCase(scale, true); }); }},
  };
}

// How gtest names a group in its output (instead of the struct's bytes).
inline void PrintTo(const CaseGroup& group, std::ostream* os) { *os << group.name; }

// The random key of a group's first case (FNV-1a of its name), the same on every platform.
inline uint64_t groupKey(const CaseGroup& group) {
  uint64_t h = 0xcbf29ce484222325ull;
  for (const char c : group.name) h = (h ^ static_cast<uint8_t>(c)) * 0x100000001b3ull;
  return h;
}

inline std::string caseGroupName(const ::testing::TestParamInfo<CaseGroup>& info) {
  return info.param.name;
}

// ---- Checking an estimator against a case ----

struct Estimate {
  double mean = 0.0;
  double relStd = 0.0;  // of one sample, relative to the closed form (absolute where it is 0)
};

// The mean of n samples and one sample's deviation relative to `exact`, from their sum and
// sum of squares.
inline Estimate estimateOf(double sum, double sum2, int n, double exact) {
  Estimate out;
  out.mean = sum / n;
  const double deviation = std::sqrt(std::max(0.0, sum2 / n - out.mean * out.mean));
  out.relStd = exact > 0.0 ? deviation / exact : deviation;
  return out;
}

// Samples per point for a stated sigma to reach a relative bound (4 sigma / sqrt n).
inline int samplesFor(double sigma, double bound) {
  return static_cast<int>(std::ceil(std::pow(4.0 * sigma / bound, 2.0)));
}

// Every receiver's mean within `bound` of its closed form (exactly 0 where nothing can arrive)
// and its sample deviation within the stated `sigma`; prints the worst of both.
inline void expectWithinBounds(const AnalyticCase& c, const std::vector<Estimate>& estimates,
                               int samples, double bound, double sigma, const char* estimator) {
  double worstError = 0.0, worstSigma = 0.0;
  for (size_t i = 0; i < c.receivers.size(); ++i) {
    const Receiver& r = c.receivers[i];
    const Estimate& e = estimates[i];
    if (r.exact == 0.0) {
      EXPECT_EQ(e.mean, 0.0) << c.name << ", " << r.label << ": lit where nothing can arrive";
      continue;
    }
    const double relError = std::abs(e.mean / r.exact - 1.0);
    worstError = std::max(worstError, relError);
    worstSigma = std::max(worstSigma, e.relStd);
    EXPECT_LE(relError, bound) << c.name << ", " << r.label << ": " << estimator << " " << e.mean
                               << ", closed form " << r.exact << " (" << samples << " samples)";
    EXPECT_LE(e.relStd, sigma) << c.name << ", " << r.label
                               << ": a sample's relative deviation past the stated one";
  }
  std::printf(
      "%s, %s: %zu points x %d samples, worst relative error %.2e (bound %.2e), worst "
      "sample deviation %.3f (stated %.3f)\n",
      estimator, c.name.c_str(), c.receivers.size(), samples, worstError, bound, worstSigma, sigma);
}

}  // namespace pbgi::analytic
