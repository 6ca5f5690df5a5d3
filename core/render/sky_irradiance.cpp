#include "core/render/sky_irradiance.h"

#include <array>
#include <cmath>

#include "core/sampling/rng.h"

namespace pbgi {

namespace {

constexpr float kCellWidth = 2.0f / static_cast<float>(kSkyFaceCells);

// The direction through point (s, t) of cube face `face` (+x, -x, +y, -y, +z, -z), unnormalized.
Vec3f faceDirection(int face, float s, float t) {
  switch (face) {
    case 0: return {1.0f, t, -s};
    case 1: return {-1.0f, t, s};
    case 2: return {s, 1.0f, -t};
    case 3: return {s, -1.0f, t};
    case 4: return {s, t, 1.0f};
    default: return {-s, t, -1.0f};
  }
}

// Solid angle per unit face area at (s, t): 1 / (1 + s^2 + t^2)^(3/2).
float faceJacobian(float s, float t) {
  const float r2 = 1.0f + s * s + t * t;
  return 1.0f / (r2 * std::sqrt(r2));
}

}  // namespace

namespace {

std::vector<const Light*> skyLights(const Scene& scene) {
  std::vector<const Light*> sky;
  for (const int index : scene.infiniteLights()) {
    if (isSkyLight(*scene.lights()[index])) sky.push_back(scene.lights()[index].get());
  }
  return sky;
}

}  // namespace

bool hasSkyLight(const Scene& scene) { return !skyLights(scene).empty(); }

SkyIrradiance::SkyIrradiance(const Scene& scene) : scene_(scene) {
  const std::vector<const Light*> sky = skyLights(scene);
  if (sky.empty()) return;
  constexpr float kStep = kCellWidth / static_cast<float>(kSkyCellSubsamples);
  for (int face = 0; face < 6; ++face) {
    for (int j = 0; j < kSkyFaceCells; ++j) {
      for (int i = 0; i < kSkyFaceCells; ++i) {
        Cell c{.face = face,
               .s0 = -1.0f + static_cast<float>(i) * kCellWidth,
               .t0 = -1.0f + static_cast<float>(j) * kCellWidth};
        // The mean over the cell's solid angle: lookups weighted by the solid angle each spans.
        Rgb sum(0.0f);
        float weights = 0.0f;
        for (int b = 0; b < kSkyCellSubsamples; ++b) {
          for (int a = 0; a < kSkyCellSubsamples; ++a) {
            const float s = c.s0 + (static_cast<float>(a) + 0.5f) * kStep;
            const float t = c.t0 + (static_cast<float>(b) + 0.5f) * kStep;
            const Vec3f d = normalize(faceDirection(face, s, t));
            const float w = faceJacobian(s, t);
            for (const Light* light : sky) sum += light->escaped(d) * w;
            weights += w;
          }
        }
        c.radiance = sum / weights;
        if (!isBlack(c.radiance)) cells_.push_back(c);
      }
    }
  }
  // Neighbours: cells whose centres lie within 1.5 cell widths' angle of each other's, across
  // the faces' borders too (a cell's width subtends 2 / kSkyFaceCells radians at most).
  const auto centre = [](const Cell& c) {
    return normalize(faceDirection(c.face, c.s0 + 0.5f * kCellWidth, c.t0 + 0.5f * kCellWidth));
  };
  const float cosNear = std::cos(1.5f * kCellWidth);
  for (Cell& c : cells_) {
    c.firstNeighbour = static_cast<uint32_t>(neighbours_.size());
    const Vec3f a = centre(c);
    for (uint32_t k = 0; k < cells_.size(); ++k) {
      if (&cells_[k] != &c && dot(a, centre(cells_[k])) >= cosNear) neighbours_.push_back(k);
    }
    c.endNeighbour = static_cast<uint32_t>(neighbours_.size());
  }
}

SkyIrradiance::Through SkyIrradiance::through(const Cell& c, float s, float t, const Vec3f& p,
                                              const Vec3f& n, const Vec3f& ng,
                                              uint64_t* rays) const {
  const Vec3f d = normalize(faceDirection(c.face, s, t));
  const float cosTheta = dot(d, n);
  if (cosTheta <= 0.0f || dot(d, ng) <= 0.0f) return {};
  ++*rays;
  if (scene_.occluded(scene_.spawnRay(p, ng, d))) return {.seen = Seen::kScene};
  // The cell's solid angle over its face area, times the density of (s, t) at d.
  return {.seen = Seen::kSky, .irradiance = c.radiance * (cosTheta * faceJacobian(s, t))};
}

Rgb SkyIrradiance::at(const Vec3f& p, const Vec3f& n, const Vec3f& ng, uint64_t key,
                      uint64_t* rays) const {
  // First a ray a cell (two numbers a cell whatever happens, so that each cell's direction
  // depends on the key alone), each cell's result kept with whether its ray escaped.
  Rng rng = Rng::forKeys(key);
  std::array<Through, kSkyCells> first;  // on the stack: a record's sky is on the render's path
  for (size_t k = 0; k < cells_.size(); ++k) {
    const Cell& c = cells_[k];
    const float s = c.s0 + rng.uniform() * kCellWidth;
    const float t = c.t0 + rng.uniform() * kCellWidth;
    first[k] = through(c, s, t, p, n, ng, rays);
  }
  // Then the edges again, stratified.
  constexpr float kSub = kCellWidth / static_cast<float>(kSkyEdgeRays);
  Rgb e(0.0f);
  for (size_t k = 0; k < cells_.size(); ++k) {
    const Cell& c = cells_[k];
    // An edge: its neighbours' rays both escaped and were blocked. The cell's own ray does
    // not take part, so that its estimate stays unbiased whichever way the test goes; rays
    // that went below the horizon decide nothing (the horizon is no edge).
    bool escaped = false, blocked = false;
    for (uint32_t j = c.firstNeighbour; j < c.endNeighbour; ++j) {
      escaped = escaped || first[neighbours_[j]].seen == Seen::kSky;
      blocked = blocked || first[neighbours_[j]].seen == Seen::kScene;
    }
    if (!(escaped && blocked)) {
      e += first[k].irradiance * (kCellWidth * kCellWidth);
      continue;
    }
    for (int b = 0; b < kSkyEdgeRays; ++b) {
      for (int a = 0; a < kSkyEdgeRays; ++a) {
        const float s = c.s0 + (static_cast<float>(a) + rng.uniform()) * kSub;
        const float t = c.t0 + (static_cast<float>(b) + rng.uniform()) * kSub;
        e += through(c, s, t, p, n, ng, rays).irradiance * (kSub * kSub);
      }
    }
  }
  return e;
}

uint64_t skyKey(const Vec3f& p) { return hashPoint(p); }

}  // namespace pbgi
