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
//   --light bounce: the bake's own first bounce (BounceGatherer) at surfels in runs along the
//     Morton curve, both sides, against rays; sides shut in by geometry (every ray meets dark
//     geometry: the insides of walls) apart, as they should gather nothing.
// Rays (--rays per receiver, cosine-weighted) measure the exact answer: the ratio is the
// surfels' discretization and the cut's together. With --brute, the sum over every surfel at
// every receiver (bruteForceIrradiance) splits the two: the cut against it is its clustering
// error alone; and the brute force against rays is printed by the receivers' distance to the
// nearest other geometry, where the discretization loses light (near contacts).
// Reports one line per quality preset and one each for the bake's first and later bounces'
// cuts; never fails on a number.
//
// Run: build/bin/transfer_bench --shot ../shared/scenes/sponza/sponza.shot.toml
//        [--points 100000] [--receivers 1000] [--rays 1024] [--light unit|direct|bounce]
//        [--brute]
#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <string>
#include <vector>

#include <fmt/format.h>

#include "core/bake/surfel_bounce.h"
#include "core/bake/surfel_sampler.h"
#include "core/bake/surfel_shading.h"
#include "core/pbgi/bidirectional_cut.h"
#include "core/pbgi/morton.h"
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
  std::string light = "unit";  // unit, direct, bounce
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
      if (v != "unit" && v != "direct" && v != "bounce") return false;
      args->light = v;
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

// What each receiver gathers by rays (cosine-weighted: pi times the mean radiance they meet),
// from one set of rays: of unit radiance on every surface (`covered`), and of the direct light
// the surfaces they meet reflect (`reflected`: diffuse, both sides, the surfel baker's
// estimator at the hit with as many light samples); and the nearest hit.
struct RayGather {
  double covered = 0.0;
  double reflected = 0.0;
  float nearest = std::numeric_limits<float>::infinity();
};
std::vector<RayGather> raysGather(const Scene& scene, std::span<const CutReceiver> receivers,
                                  int rays, bool withLight) {
  std::vector<RayGather> out(receivers.size());
  const SurfelShadingOptions shading;
  Rng rng(9);
  for (size_t i = 0; i < receivers.size(); ++i) {
    const Frame f(receivers[i].n);
    RayGather& g = out[i];
    for (int k = 0; k < rays; ++k) {
      const Vec3f d = f.toWorld(sampleCosineHemisphere({rng.uniform(), rng.uniform()}));
      SurfaceHit hit;
      if (!scene.intersect(scene.spawnRay(receivers[i].p, receivers[i].ng, d), &hit)) continue;
      g.nearest = std::min(g.nearest, hit.t);
      if (hit.material == kNoMaterial) continue;
      g.covered += 1.0;
      if (!withLight || scene.material(hit.material).type != MaterialType::kDiffuse) continue;
      Rgb e(0.0f);
      for (int l = 0; l < shading.lightSamples; ++l) {
        const TwoSidedIrradiance two = sampleIrradianceBothSides(scene, hit.p, hit.ng, rng);
        e += dot(hit.ng, d) < 0.0f ? two.front : two.back;
      }
      g.reflected += luminance(scene.albedoAt(hit) * e) / (kPi * shading.lightSamples);
    }
    g.covered *= kPi / rays;
    g.reflected *= kPi / rays;
  }
  return out;
}

double sumLuminance(std::span<const Rgb> v) {
  double sum = 0.0;
  for (const Rgb& e : v) sum += luminance(e);
  return sum;
}

// Brute force against rays, the receivers binned by the distance from them to the nearest
// geometry the rays met, in surfel radii: where the surfels' discretization loses light.
template <typename Skip>
void printByNearest(std::span<const RayGather> rays, std::span<const Rgb> brute, float radius,
                    bool unitLight, Skip skip) {
  double bc[6] = {}, br[6] = {}, all = 0.0;
  int bn[6] = {};
  for (size_t i = 0; i < rays.size(); ++i) {
    if (skip(i)) continue;
    const float nearest = rays[i].nearest / radius;
    const int b = nearest < 0.5f ? 0 : nearest < 1.0f ? 1 : nearest < 2.0f ? 2
                : nearest < 4.0f ? 3 : nearest < 16.0f ? 4 : 5;
    const double want = unitLight ? rays[i].covered : rays[i].reflected;
    bc[b] += luminance(brute[i]), br[b] += want, ++bn[b];
    all += want;
  }
  const char* names[6] = {"<0.5r", "<1r", "<2r", "<4r", "<16r", "far"};
  for (int b = 0; b < 6; ++b) {
    std::printf("    nearest geometry %-5s: %5d receivers, %.4f of the light, brute / rays %.4f\n",
                names[b], bn[b], br[b] / all, br[b] > 0 ? bc[b] / br[b] : 0.0);
  }
}

// The bake's own first bounce (BounceGatherer: surfel receivers, a cut per side) at random
// diffuse surfels, against rays from the same points: the irradiance on both sides, from the
// direct light the surfaces the rays meet reflect.
int runBounce(const Args& args, const Scene& scene, const std::vector<Surfel>& surfels,
              TreePageSource& tree) {
  // Runs of surfels consecutive along the Morton curve, as a bake's groups are.
  std::vector<std::pair<uint64_t, uint32_t>> order(surfels.size());
  Bounds3f bounds;
  for (const Surfel& s : surfels) bounds.extend(s.position);
  for (uint32_t i = 0; i < surfels.size(); ++i) order[i] = {mortonKey(surfels[i].position, bounds), i};
  std::sort(order.begin(), order.end());
  const size_t run = std::min<size_t>(256, surfels.size());
  std::vector<Surfel> picked;
  Rng rng(5);
  for (int tries = 0; static_cast<int>(picked.size()) < args.receivers && tries < 1000; ++tries) {
    const size_t first = static_cast<size_t>(rng.uniform() * (surfels.size() - run));
    for (size_t k = first; k < first + run; ++k) {
      if (reflectsLight(surfels[order[k].second])) picked.push_back(surfels[order[k].second]);
    }
  }
  if (picked.empty()) return std::fprintf(stderr, "no surfel of the scene reflects light\n"), 1;
  std::vector<CutReceiver> sides;
  for (const Surfel& s : picked) {
    sides.push_back({s.position, s.normal, s.normal});
    sides.push_back({s.position, -s.normal, -s.normal});
  }
  const std::vector<RayGather> rays = raysGather(scene, sides, args.rays, true);
  double exact = 0.0;
  for (const RayGather& g : rays) exact += g.reflected;
  auto isShut = [&](size_t i) { return rays[i].covered > 0.999 * kPi && rays[i].reflected == 0.0; };
  if (args.brute) {
    std::vector<Rgb> brute(sides.size());
    if (absl::Status st = bruteForceIrradiance(tree, scene, sides, *cutPreset("default"), brute);
        !st.ok()) {
      return std::fprintf(stderr, "%s\n", st.ToString().c_str()), 1;
    }
    double open = 0, openRef = 0, shut = 0;
    for (size_t i = 0; i < sides.size(); ++i) {
      (isShut(i) ? shut : open) += luminance(brute[i]);
      if (!isShut(i)) openRef += rays[i].reflected;
    }
    std::printf("  brute force: open sides / rays %.4f; shut-in sides gather %.4f of the total\n",
                open / openRef, shut / exact);
    printByNearest(rays, brute, surfels.front().radius, false, isShut);
  }
  for (const char* preset : {"draft", "default", "high"}) {
    BounceGatherer bouncer(*cutPreset(preset), /*receiverSpacing=*/1);
    std::vector<SurfelIrradiance> e(picked.size());
    const size_t groupSize = run;
    std::vector<uint64_t> keys((picked.size() + groupSize - 1) / groupSize);
    for (size_t g = 0; g < keys.size(); ++g) keys[g] = hashKeys(uint64_t{7}, g);
    CutStats stats;
    if (absl::Status st = bouncer.gather(tree, scene, picked, groupSize, keys, 1, e, &stats);
        !st.ok()) {
      return std::fprintf(stderr, "%s\n", st.ToString().c_str()), 1;
    }
    double sum = 0.0;
    for (const SurfelIrradiance& x : e) sum += luminance(x.front) + luminance(x.back);
    // Split: sides that see the sky or open space, and sides shut in (rays meet geometry
    // within every direction and nothing lit).
    double openCut = 0, openRef = 0, shutCut = 0;
    int shut = 0;
    for (size_t i = 0; i < sides.size(); ++i) {
      const double c = luminance(i % 2 == 0 ? e[i / 2].front : e[i / 2].back);
      if (isShut(i)) {
        shutCut += c, ++shut;
      } else {
        openCut += c, openRef += rays[i].reflected;
      }
    }
    std::printf("  %-8s open sides: cut / rays %.4f; %d shut-in sides (rays meet only dark "
                "geometry) gather %.4f of the total\n", preset, openCut / openRef, shut,
                shutCut / exact);
    std::printf("  %-8s bounce gather / rays %.4f  (%s)\n", preset, sum / exact,
                stats.toString().c_str());
  }
  return 0;
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
  const bool unitLight = args.light == "unit";
  if (unitLight) {
    for (Surfel& s : *surfels) s.radiance = s.backRadiance = Rgb(1.0f);
  } else {
    shadeSurfelsDirect(scene, *surfels, 0, {});
  }
  std::vector<Surfel> lights = *surfels;
  for (Surfel& s : lights) facingBrighterSide(s);
  auto tree = testing::memoryTree(lights);
  if (!tree.ok()) return std::fprintf(stderr, "%s\n", tree.status().ToString().c_str()), 1;
  if (args.light == "bounce") {
    std::printf("%s: %zu surfels of radius %.4g, the bake's first bounce at %d surfels\n",
                args.shot.c_str(), surfels->size(), surfels->front().radius, args.receivers);
    return runBounce(args, scene, *surfels, **tree);
  }
  const std::vector<CutReceiver> receivers = imageReceivers(scene, frame->camera, args.receivers);
  if (receivers.empty()) return std::fprintf(stderr, "the camera sees no surface\n"), 1;
  std::printf("%s: %zu surfels of radius %.4g, %zu receivers, %s light\n", args.shot.c_str(),
              surfels->size(), surfels->front().radius, receivers.size(),
              args.light.c_str());

  double exact = 0.0;
  const char* against = "rays";
  const std::vector<RayGather> rays = raysGather(scene, receivers, args.rays, !unitLight);
  for (const RayGather& g : rays) exact += unitLight ? g.covered : g.reflected;
  std::vector<Rgb> brute(receivers.size());
  if (args.brute) {
    auto options = cutPreset("default");
    if (absl::Status s = bruteForceIrradiance(**tree, scene, receivers, *options, brute); !s.ok()) {
      return std::fprintf(stderr, "%s\n", s.ToString().c_str()), 1;
    }
    const double sum = sumLuminance(brute);
    std::printf("  brute force / rays %.4f\n", sum / exact);
    printByNearest(rays, brute, surfels->front().radius, unitLight,
                   [](size_t) { return false; });
    exact = sum;
    against = "brute force";
  }
  // The presets, and the bake's first and later bounces' cuts (bounceCutOptions: the draft
  // preset's thresholds, its descents by normal cones for the first; times
  // kLaterBounceCoarsening for the later; with the draft's near field, as the brute force has
  // one).
  for (const char* preset : {"draft", "default", "high", "first", "later"}) {
    std::vector<Rgb> out(receivers.size());
    const CutOptions options =
        std::strcmp(preset, "first") == 0   ? bounceCutOptions(*cutPreset("draft"), 1)
        : std::strcmp(preset, "later") == 0 ? bounceCutOptions(*cutPreset("draft"), 2)
                                            : *cutPreset(preset);
    BidirectionalCut cut(options);
    CutStats stats;
    if (absl::Status s = cut.irradiance(**tree, scene, receivers, 5, out, &stats); !s.ok()) {
      return std::fprintf(stderr, "%s\n", s.ToString().c_str()), 1;
    }
    // With --brute: each receiver's error against it, RMS, over the mean receiver's light.
    std::string rms;
    if (args.brute) {
      double sq = 0.0;
      for (size_t r = 0; r < out.size(); ++r) {
        sq += sqr(static_cast<double>(luminance(out[r])) - luminance(brute[r]));
      }
      rms = fmt::format(", RMS {:.4f}", std::sqrt(sq / static_cast<double>(out.size())) /
                                            (exact / static_cast<double>(out.size())));
    }
    std::printf("  %-8s cut / %s %.4f%s  (%s)\n", preset, against, sumLuminance(out) / exact,
                rms.c_str(), stats.toString().c_str());
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
                 "[--light unit|direct|bounce] [--brute]\n");
    return 2;
  }
  return pbgi::run(args);
}
