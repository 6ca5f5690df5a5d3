// How much light the bidirectional cut moves from surfels to the points that gather it, in a
// real scene, against exact answers: where a bake's bounces or a frame's gather lose or gain
// light, apart from everything else a render does.
//
// Receivers are where the image gathers: points the camera sees, and the points those see
// (whose bounce light the camera gathers in turn), each facing the ray that found it.
//   --light unit (default): every surfel sends radiance 1 from both sides, so a receiver
//     gathers pi times the cosine-weighted share of its hemisphere that geometry covers.
//   --light direct: the surfels lit by the shot's lights, as a bake's first bounce sees them,
//     against the direct light that the surfaces the rays meet reflect.
// Rays (--rays per receiver, cosine-weighted) measure the exact answer: the ratio is the
// surfels' discretization and the cut's together. With --brute, the sum over every surfel at
// every receiver (bruteForceIrradiance) splits the two: the cut against it is its clustering
// error alone.
// Reports one line per quality preset; never fails on a number.
//
// Run: build/bin/transfer_bench --shot ../shared/scenes/sponza/sponza.shot.toml
//        [--points 100000] [--receivers 1000] [--rays 1024] [--light unit|direct] [--brute]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "core/bake/surfel_sampler.h"
#include "core/bake/surfel_shading.h"
#include "core/pbgi/bidirectional_cut.h"
#include "core/render/path_tracer.h"
#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"
#include "formats/scene/frame_scene.h"
#include "formats/shot/shot_file.h"
#include "tests/support/memory_tree.h"

namespace pbgi {
namespace {

struct Args {
  std::string shot;
  uint64_t points = 100000;
  int receivers = 1000;
  int rays = 1024;
  bool unitLight = true;
  bool brute = false;
};

bool parse(int argc, char** argv, Args* args) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    const bool hasValue = i + 1 < argc;
    if (a == "--brute") {
      args->brute = true;
    } else if (a == "--shot" && hasValue) {
      args->shot = argv[++i];
    } else if (a == "--points" && hasValue) {
      args->points = std::strtoull(argv[++i], nullptr, 10);
    } else if (a == "--receivers" && hasValue) {
      args->receivers = std::atoi(argv[++i]);
    } else if (a == "--rays" && hasValue) {
      args->rays = std::atoi(argv[++i]);
    } else if (a == "--light" && hasValue) {
      const std::string v = argv[++i];
      if (v != "unit" && v != "direct") return false;
      args->unitLight = v == "unit";
    } else {
      return false;
    }
  }
  return !args->shot.empty() && args->points > 0 && args->receivers > 0 && args->rays > 0;
}

std::vector<CutReceiver> imageReceivers(const Scene& scene, const Camera& camera, int count) {
  std::vector<CutReceiver> receivers;
  Rng rng(3);
  int misses = 0;
  while (static_cast<int>(receivers.size()) < count && misses < 100 * count) {
    const Ray ray = camera.generateRay(rng.uniform() * camera.imageWidth(),
                                       rng.uniform() * camera.imageHeight(), {0.5f, 0.5f});
    SurfaceHit hit;
    if (!scene.intersect(ray, &hit) || hit.material == kNoMaterial) {
      ++misses;
      continue;
    }
    Vec3f n = dot(hit.ng, ray.dir) < 0.0f ? hit.ng : -hit.ng;
    receivers.push_back({hit.p, n, n});
    const Vec3f d = Frame(n).toWorld(sampleCosineHemisphere({rng.uniform(), rng.uniform()}));
    SurfaceHit seen;
    if (static_cast<int>(receivers.size()) == count ||
        !scene.intersect(scene.spawnRay(hit.p, n, d), &seen) || seen.material == kNoMaterial) {
      continue;
    }
    n = dot(seen.ng, d) < 0.0f ? seen.ng : -seen.ng;
    receivers.push_back({seen.p, n, n});
  }
  return receivers;
}

// What each receiver gathers, by rays (cosine-weighted: pi times the mean radiance they
// meet): of unit radiance on every surface, or of the direct light the surfaces reflect
// (diffuse, both sides, the surfel baker's estimator at the hit with as many light samples).
std::vector<double> raysGather(const Scene& scene, std::span<const CutReceiver> receivers,
                               int rays, bool unitLight) {
  std::vector<double> gathered(receivers.size());
  const SurfelShadingOptions shading;
  Rng rng(9);
  for (size_t i = 0; i < receivers.size(); ++i) {
    const Frame f(receivers[i].n);
    double sum = 0.0;
    for (int k = 0; k < rays; ++k) {
      const Vec3f d = f.toWorld(sampleCosineHemisphere({rng.uniform(), rng.uniform()}));
      SurfaceHit hit;
      if (!scene.intersect(scene.spawnRay(receivers[i].p, receivers[i].ng, d), &hit) ||
          hit.material == kNoMaterial) {
        continue;
      }
      if (unitLight) {
        sum += 1.0;
        continue;
      }
      const Material& m = scene.material(hit.material);
      if (m.type != MaterialType::kDiffuse) continue;
      Rgb e(0.0f);
      for (int l = 0; l < shading.lightSamples; ++l) {
        const TwoSidedIrradiance two = sampleIrradianceBothSides(scene, hit.p, hit.ng, rng);
        e += dot(hit.ng, d) < 0.0f ? two.front : two.back;
      }
      sum += luminance(scene.albedoAt(hit) * e) / (kPi * shading.lightSamples);
    }
    gathered[i] = kPi * sum / rays;
  }
  return gathered;
}

double sumLuminance(std::span<const Rgb> v) {
  double sum = 0.0;
  for (const Rgb& e : v) sum += luminance(e);
  return sum;
}

int run(const Args& args) {
  auto shot = loadShotFile(args.shot);
  if (!shot.ok()) return std::fprintf(stderr, "%s\n", shot.status().ToString().c_str()), 1;
  auto frame = loadFrameScene(*shot, shot->firstFrame);
  if (!frame.ok()) return std::fprintf(stderr, "%s\n", frame.status().ToString().c_str()), 1;
  const Scene& scene = *frame->scene;
  SurfelSamplingOptions sampling;
  sampling.targetCount = args.points;
  auto surfels = collectSurfels(scene, sampling);
  if (!surfels.ok()) return std::fprintf(stderr, "%s\n", surfels.status().ToString().c_str()), 1;
  if (args.unitLight) {
    for (Surfel& s : *surfels) s.radiance = s.backRadiance = Rgb(1.0f);
  } else {
    shadeSurfelsDirect(scene, *surfels, 0, {});
    for (Surfel& s : *surfels) facingBrighterSide(s);
  }
  auto tree = testing::memoryTree(*surfels);
  if (!tree.ok()) return std::fprintf(stderr, "%s\n", tree.status().ToString().c_str()), 1;
  const std::vector<CutReceiver> receivers = imageReceivers(scene, frame->camera, args.receivers);
  if (receivers.empty()) return std::fprintf(stderr, "the camera sees no surface\n"), 1;
  std::printf("%s: %zu surfels of radius %.4g, %zu receivers, %s light\n", args.shot.c_str(),
              surfels->size(), surfels->front().radius, receivers.size(),
              args.unitLight ? "unit" : "direct");

  double exact = 0.0;
  const char* against = "rays";
  for (double e : raysGather(scene, receivers, args.rays, args.unitLight)) exact += e;
  if (args.brute) {
    std::vector<Rgb> brute(receivers.size());
    auto options = cutPreset("default");
    if (absl::Status s = bruteForceIrradiance(**tree, scene, receivers, *options, brute); !s.ok()) {
      return std::fprintf(stderr, "%s\n", s.ToString().c_str()), 1;
    }
    const double sum = sumLuminance(brute);
    std::printf("  brute force / rays %.4f\n", sum / exact);
    exact = sum;
    against = "brute force";
  }
  for (const char* preset : {"draft", "default", "high"}) {
    std::vector<Rgb> out(receivers.size());
    BidirectionalCut cut(*cutPreset(preset));
    CutStats stats;
    if (absl::Status s = cut.irradiance(**tree, scene, receivers, 5, out, &stats); !s.ok()) {
      return std::fprintf(stderr, "%s\n", s.ToString().c_str()), 1;
    }
    std::printf("  %-8s cut / %s %.4f  (%s)\n", preset, against, sumLuminance(out) / exact,
                stats.toString().c_str());
  }
  return 0;
}

}  // namespace
}  // namespace pbgi

int main(int argc, char** argv) {
  pbgi::Args args;
  if (!pbgi::parse(argc, argv, &args)) {
    std::fprintf(stderr,
                 "usage: transfer_bench --shot SHOT [--points N] [--receivers N] [--rays N] "
                 "[--light unit|direct] [--brute]\n");
    return 2;
  }
  return pbgi::run(args);
}
