// Throughput of the baker's first stages: surfel sampling (streamed, one thread), direct
// shading of surfels (16 light samples each, all threads), and codebook training for the
// quantized tree. Reports numbers; never fails on time.
// Run: build/bin/surfel_bench [--benchmark_filter=...]

#include <benchmark/benchmark.h>

#include <filesystem>
#include <map>

#include "core/bake/surfel_sampler.h"
#include "core/bake/surfel_shading.h"
#include "core/pbgi/quantize.h"
#include "core/pbgi/sh.h"
#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"
#include "formats/scene/frame_scene.h"
#include "formats/shot/shot_file.h"
#include "tests/support/test_paths.h"
#include "tests/support/sh_lobes.h"

namespace pbgi {
namespace {

// Loads each shot's first frame once for all benchmarks; nullptr when the file is absent.
const Scene* loadScene(const std::string& name) {
  static std::map<std::string, std::unique_ptr<FrameScene>> cache;
  if (auto it = cache.find(name); it != cache.end())
    return it->second ? it->second->scene.get() : nullptr;
  std::filesystem::path path;
  if (name == "cornell") {
    path = testing::sourceDir() / "config/scenes/cornell/cornell.shot.toml";
  } else if (auto shared = testing::sharedScenesDir()) {
    path = *shared / "sponza/sponza.shot.toml";
  }
  std::unique_ptr<FrameScene> loaded;
  if (!path.empty() && std::filesystem::exists(path)) {
    auto shot = loadShotFile(path.string());
    if (shot.ok()) {
      auto frame = loadFrameScene(*shot, shot->firstFrame);
      if (frame.ok()) loaded = std::make_unique<FrameScene>(std::move(*frame));
    }
  }
  const Scene* scene = loaded ? loaded->scene.get() : nullptr;
  cache[name] = std::move(loaded);
  return scene;
}

void sampling(benchmark::State& state, const std::string& name) {
  const Scene* scene = loadScene(name);
  if (!scene) return state.SkipWithError(("scene unavailable: " + name).c_str());
  SurfelSamplingOptions o;
  o.targetCount = static_cast<uint64_t>(state.range(0));
  int64_t surfels = 0;
  for (auto _ : state) {
    double sum = 0.0;
    SurfelSamplingStats stats;
    const absl::Status s = sampleSurfels(
        *scene, o,
        [&sum](const Surfel& surfel) {
          sum += surfel.position.x;
          return absl::OkStatus();
        },
        &stats);
    if (!s.ok()) return state.SkipWithError(std::string(s.message()).c_str());
    benchmark::DoNotOptimize(sum);
    surfels += static_cast<int64_t>(stats.surfels);
  }
  state.counters["surfels/s"] =
      benchmark::Counter(static_cast<double>(surfels), benchmark::Counter::kIsRate);
}

void shading(benchmark::State& state, const std::string& name) {
  const Scene* scene = loadScene(name);
  if (!scene) return state.SkipWithError(("scene unavailable: " + name).c_str());
  SurfelSamplingOptions o;
  o.targetCount = static_cast<uint64_t>(state.range(0));
  std::vector<Surfel> surfels;
  const absl::Status s = sampleSurfels(
      *scene, o,
      [&surfels](const Surfel& surfel) {
        surfels.push_back(surfel);
        return absl::OkStatus();
      },
      nullptr);
  if (!s.ok()) return state.SkipWithError(std::string(s.message()).c_str());
  int64_t shaded = 0;
  for (auto _ : state) {
    shadeSurfelsDirect(*scene, surfels, 0, SurfelShadingOptions{});
    shaded += static_cast<int64_t>(surfels.size());
  }
  state.counters["surfels/s"] =
      benchmark::Counter(static_cast<double>(shaded), benchmark::Counter::kIsRate);
}

// state.range(1) != 0: each vector scaled to unit length first, the shape-only codebook a
// tree would pair with a per-node scale (nodes' powers span orders of magnitude).
void codebookTraining(benchmark::State& state) {
  std::vector<float> data = testing::lambertianLobeVectors(static_cast<size_t>(state.range(0)));
  if (state.range(1) != 0) {
    for (size_t i = 0; i < data.size(); i += Sh9Rgb::kFloats) {
      double norm2 = 0.0;
      for (int j = 0; j < Sh9Rgb::kFloats; ++j) norm2 += double(data[i + j]) * data[i + j];
      const float scale = norm2 > 0.0 ? static_cast<float>(1.0 / std::sqrt(norm2)) : 0.0f;
      for (int j = 0; j < Sh9Rgb::kFloats; ++j) data[i + j] *= scale;
    }
  }
  KMeansOptions o;  // the paper's setting: 100 centres, 10 iterations, a 10 % sample
  Codebook book;
  for (auto _ : state) {
    book = trainCodebook(data, Sh9Rgb::kFloats, o);
    benchmark::DoNotOptimize(book.entries.data());
  }
  const QuantizationError err = measureError(book, data);
  state.counters["entries"] = book.size();
  state.counters["relative_rms"] = err.relativeRms;
  state.counters["max_relative"] = err.maxRelative;
}

BENCHMARK_CAPTURE(sampling, cornell, std::string("cornell"))
    ->Arg(1000000)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(sampling, sponza, std::string("sponza"))
    ->Arg(1000000)
    ->Unit(benchmark::kMillisecond);
BENCHMARK_CAPTURE(shading, cornell, std::string("cornell"))
    ->Arg(100000)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK_CAPTURE(shading, sponza, std::string("sponza"))
    ->Arg(100000)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();
BENCHMARK(codebookTraining)
    ->Args({1000000, 0})
    ->Args({1000000, 1})
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace pbgi

BENCHMARK_MAIN();
