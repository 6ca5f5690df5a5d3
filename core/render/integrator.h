#pragma once
// An integrator turns a camera ray into a radiance sample. The tile renderer drives one.

#include <memory>
#include <string>

#include "core/render/path_tracer.h"

namespace pbgi {

class Integrator {
 public:
  virtual ~Integrator() = default;
  virtual std::string name() const = 0;
  // Must be deterministic in (ray, rng state) and safe to call from many threads.
  virtual PathSample li(const Ray& ray, Rng& rng) const = 0;
};

class PathIntegrator final : public Integrator {
 public:
  PathIntegrator(const Scene& scene, PathTracerSettings settings)
      : scene_(scene), settings_(settings) {}
  std::string name() const override { return "path"; }
  PathSample li(const Ray& ray, Rng& rng) const override {
    return tracePath(scene_, ray, rng, settings_);
  }

 private:
  const Scene& scene_;
  PathTracerSettings settings_;
};

}  // namespace pbgi
