#pragma once
// The environment's light at PBGI's records, once per record and shared by every camera sample
// that reads the record (Christensen 2008 takes it through the point-based gather's unoccluded
// directions; here, through the directions' own visibility, so that it does not depend on the
// cloud's holes). The sphere of directions is cut into the cells of a cube map, kSkyFaceCells a
// side of each face. Each cell's radiance, the environment's mean over the cell, is integrated
// once per scene. A record's irradiance is the sum, over the cells, of the cell's radiance
// times the cosine-weighted solid angle towards one direction jittered inside the cell, where a
// ray in that direction escapes: stratified sampling with one ray a cell. Where the sky is in
// full view or hidden the estimate is exact up to the cells' mean; its noise is at the edges of
// what hides the sky. So a cell among whose neighbours some rays escaped and some were blocked
// (an edge) is sampled again, kSkyEdgeRays^2 rays stratified over it, in place of its first
// ray (its own first ray does not decide, so neither choice biases it). The
// estimate is the same for every sample that reads the record.
//
// Which lights: environments (infinite and not a delta). Directional lights stay one shadow
// ray per camera sample, as do the lights with a surface.

#include <cstdint>
#include <vector>

#include "core/math/vec.h"
#include "core/scene/scene.h"

namespace pbgi {

inline constexpr int kSkyFaceCells = 8;       // cells a side of each cube face
inline constexpr int kSkyCellSubsamples = 8;  // lookups a side of a cell for its mean radiance
inline constexpr int kSkyEdgeRays = 3;        // rays a side of an edge cell
inline constexpr int kSkyCells = 6 * kSkyFaceCells * kSkyFaceCells;

// Whether the scene has an environment light (isSkyLight).
bool hasSkyLight(const Scene& scene);

class SkyIrradiance {
 public:
  explicit SkyIrradiance(const Scene& scene);
  // No environment light: every record's sky is black, and nothing is traced.
  bool empty() const { return cells_.empty(); }
  // Irradiance at p on the side of unit shading normal n (geometric normal ng on the same side)
  // from the scene's environment lights; the jitter keyed by `key`. Adds the rays it traces.
  Rgb at(const Vec3f& p, const Vec3f& n, const Vec3f& ng, uint64_t key, uint64_t* rays) const;

 private:
  struct Cell {
    int face = 0;
    float s0 = 0.0f, t0 = 0.0f;  // the cell's lower corner on its face, in [-1, 1]
    Rgb radiance{0.0f};          // the environment's mean over the cell
    uint32_t firstNeighbour = 0, endNeighbour = 0;  // a range of neighbours_
  };
  // What a ray through point (s, t) of cell c finds: nothing (below the horizon, no ray),
  // the scene (blocked), or the sky, with the irradiance it stands for.
  enum class Seen : uint8_t { kNothing, kScene, kSky };
  struct Through {
    Seen seen = Seen::kNothing;
    Rgb irradiance{0.0f};
  };
  Through through(const Cell& c, float s, float t, const Vec3f& p, const Vec3f& n,
                  const Vec3f& ng, uint64_t* rays) const;
  const Scene& scene_;
  std::vector<Cell> cells_;          // cells with any light
  std::vector<uint32_t> neighbours_;  // of each cell, the cells that touch it (indices)
};

// A key for a record's jitter from where it lies: the same record, whatever tile or thread
// takes it, draws the same directions.
uint64_t skyKey(const Vec3f& p);

}  // namespace pbgi
