#pragma once
// Gathers shared between nearby receivers: the samples of one pixel (the PBGI integrator) and
// neighbouring surfels along the Morton curve (a bake's bounces). Indirect light varies
// slowly, so a receiver takes the result of an earlier gather when it lies within that
// gather's reach, within its plane reach of the gather's tangent plane, faces the same way,
// has the same key, and (when the gather kept a view direction) looks the same way.
#include <cmath>
#include <cstdint>
#include <limits>
#include <span>
#include <vector>

#include "core/math/vec.h"

namespace pbgi {

struct SharedGather {
  Vec3f p{0.0f};
  Vec3f n{0.0f, 0.0f, 1.0f};
  float reach = 0.0f;                                         // how far from p a receiver may lie
  float planeReach = std::numeric_limits<float>::infinity();  // and off the tangent plane
  uint32_t key = 0;                                           // receivers share only within one key
  Vec3f wo{0.0f};                                             // zero: any view direction
  Rgb value{0.0f};
  uint32_t slot = 0;  // the caller's: where the value will be when it is gathered later
};

class GatherReuse {
 public:
  // Normals must agree to `normalCos`, kept view directions to `viewCos`; at most `capacity`
  // gathers are kept.
  GatherReuse(float normalCos, float viewCos, size_t capacity)
      : normalCos_(normalCos), viewCos_(viewCos), capacity_(capacity) {
    kept_.reserve(capacity);
  }

  void clear() { kept_.clear(); }

  // The first kept gather a receiver at p facing n (unit), seen along wo, may take; null for none.
  const SharedGather* find(const Vec3f& p, const Vec3f& n, const Vec3f& wo, uint32_t key) const {
    return find(kept_, p, n, wo, key);
  }
  // The same among `gathers` (kept by another GatherReuse of the same thresholds).
  const SharedGather* find(std::span<const SharedGather> gathers, const Vec3f& p, const Vec3f& n,
                           const Vec3f& wo, uint32_t key) const {
    for (const SharedGather& g : gathers) {
      if (g.key != key || dot(g.n, n) < normalCos_) continue;
      const Vec3f d = p - g.p;
      if (std::abs(dot(d, g.n)) > g.planeReach || length(d) > g.reach) continue;
      if (g.wo.length2() > 0.0f && dot(g.wo, wo) < viewCos_) continue;
      return &g;
    }
    return nullptr;
  }
  std::span<const SharedGather> kept() const { return kept_; }

  // Keeps `g` for later receivers while there is room.
  void add(const SharedGather& g) {
    if (kept_.size() < capacity_) kept_.push_back(g);
  }

 private:
  float normalCos_;
  float viewCos_;
  size_t capacity_;
  std::vector<SharedGather> kept_;
};

}  // namespace pbgi
