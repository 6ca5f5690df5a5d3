// Throughput of the ray tracing core and the reference path tracer, on the project's Cornell
// box and on ../shared/scenes (Cornell, Sponza) when present. Reports numbers; never fails on
// time. Run: build/bin/render_bench [--benchmark_filter=...]
//
// Rays/s: primary rays through every pixel (coherent), and shadow rays from the primary hits
// to random points on a light (incoherent-ish). Samples/s: full camera samples of the path
// tracer (all bounces, NEE, MIS) through the tile renderer on all threads.

#include <benchmark/benchmark.h>

#include <filesystem>
#include <map>

#include "core/render/renderer.h"
#include "core/sampling/rng.h"
#include "formats/scene/frame_scene.h"
#include "formats/shot/shot_file.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

struct LoadedShot {
  ShotDesc shot;
  FrameScene frame;
};

// Loads each shot once for all benchmarks; nullptr when the file is absent.
const LoadedShot* loadShot(const std::string& name) {
  static std::map<std::string, std::unique_ptr<LoadedShot>> cache;
  if (auto it = cache.find(name); it != cache.end()) return it->second.get();
  std::filesystem::path path;
  if (name == "sample-cornell") {
    path = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";
  } else if (auto shared = testing::sharedScenesDir()) {
    path = *shared / (name == "cornell" ? "cornell-box/cornell.shot.toml" : "sponza/sponza.shot.toml");
  }
  std::unique_ptr<LoadedShot> loaded;
  if (!path.empty() && std::filesystem::exists(path)) {
    auto shot = loadShotFile(path.string());
    if (shot.ok()) {
      auto frame = loadFrameScene(*shot, shot->firstFrame);
      if (frame.ok()) loaded.reset(new LoadedShot{std::move(*shot), std::move(*frame)});
    }
  }
  return (cache[name] = std::move(loaded)).get();
}

void primaryRays(benchmark::State& state, const std::string& name) {
  const LoadedShot* s = loadShot(name);
  if (!s) return state.SkipWithError(("scene unavailable: " + name).c_str());
  const Camera& camera = s->frame.camera;
  const Scene& scene = *s->frame.scene;
  int64_t rays = 0;
  for (auto _ : state) {
    for (int y = 0; y < camera.imageHeight(); ++y) {
      for (int x = 0; x < camera.imageWidth(); ++x) {
        SurfaceHit hit;
        const Ray ray = camera.generateRay(x + 0.5f, y + 0.5f, Vec2f(0.5f));
        benchmark::DoNotOptimize(scene.intersect(ray, &hit));
        ++rays;
      }
    }
  }
  state.counters["rays/s"] = benchmark::Counter(static_cast<double>(rays), benchmark::Counter::kIsRate);
}

void shadowRays(benchmark::State& state, const std::string& name) {
  const LoadedShot* s = loadShot(name);
  if (!s) return state.SkipWithError(("scene unavailable: " + name).c_str());
  const Camera& camera = s->frame.camera;
  const Scene& scene = *s->frame.scene;
  // Shadow rays from the primary hits towards light samples, prepared outside the timing.
  std::vector<Ray> rays;
  Rng rng(1);
  for (int y = 0; y < camera.imageHeight(); ++y) {
    for (int x = 0; x < camera.imageWidth(); ++x) {
      SurfaceHit hit;
      if (!scene.intersect(camera.generateRay(x + 0.5f, y + 0.5f, Vec2f(0.5f)), &hit)) continue;
      float prob = 0.0f;
      const Light* light = scene.sampleLight(rng.uniform(), &prob);
      if (!light) continue;
      auto ls = light->sample(hit.p, Vec2f(rng.uniform(), rng.uniform()));
      if (ls) rays.push_back(scene.spawnShadowRay(hit.p, hit.ng, *ls));
    }
  }
  int64_t count = 0;
  for (auto _ : state) {
    for (const Ray& r : rays) benchmark::DoNotOptimize(scene.occluded(r));
    count += static_cast<int64_t>(rays.size());
  }
  state.counters["rays/s"] = benchmark::Counter(static_cast<double>(count), benchmark::Counter::kIsRate);
}

void pathSamples(benchmark::State& state, const std::string& name) {
  const LoadedShot* s = loadShot(name);
  if (!s) return state.SkipWithError(("scene unavailable: " + name).c_str());
  RenderSettings settings = s->shot.render;
  settings.spp = 4;
  PathTracerSettings pt{settings.maxDepth, settings.rouletteDepth};
  const PathIntegrator integrator(*s->frame.scene, pt);
  FrameRenderOptions options;
  options.threads = static_cast<int>(state.range(0));
  int64_t samples = 0;
  for (auto _ : state) {
    RenderCounters counters;
    benchmark::DoNotOptimize(renderFrame(integrator, s->frame.camera, settings, 1, options, &counters));
    samples += static_cast<int64_t>(counters.cameraSamples);
  }
  state.counters["samples/s"] = benchmark::Counter(static_cast<double>(samples), benchmark::Counter::kIsRate);
}

BENCHMARK_CAPTURE(primaryRays, sample_cornell, std::string("sample-cornell"))->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(primaryRays, cornell, std::string("cornell"))->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(primaryRays, sponza, std::string("sponza"))->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(shadowRays, cornell, std::string("cornell"))->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(shadowRays, sponza, std::string("sponza"))->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(pathSamples, cornell, std::string("cornell"))->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK_CAPTURE(pathSamples, sponza, std::string("sponza"))->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
}  // namespace pbgi

BENCHMARK_MAIN();
