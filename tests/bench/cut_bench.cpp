// The bidirectional cut against the per-pixel gather, on the dev scenes
// of ../shared/scenes: for each scene, one bake (reported apart), then both gathers at square
// resolutions (512, 1024, 2048 by default) and samples per pixel (1, 4), and a light field (a
// 4 x 4 camera array) against a single view of the same size. For each run: render seconds,
// shading points (camera samples whose first hit gathers), evaluations of the cut (light
// clusters and leaves against receivers), shadow rays, seconds per shading point, relMSE against
// a path-traced reference and the page cache's hit rate. The reference is rendered once at
// --reference-size (cached by the shot's bytes, size, spp and version) and each run is
// box-filtered down to it before comparing: a 2048^2 path-traced reference would take hours,
// and both gathers are compared the same way.
//
// --crop N renders frames larger than N only in their central N x N pixels (both gathers
// alike, compared with the reference under the crop), so that 2048^2 x 4 spp runs of the
// per-pixel gather take minutes, not hours; the density of shading points is the frame's.
//
// Then the page cache: one farm tile (256^2 of the 1024^2 frame) of the cut with a cache of
// 5 % of the tree's decoded pages, its hit rate and its pixels against an unlimited cache.
// A 4 x 4 light field and the cache runs are the cut's only (see below).
//
// Writes OUT/cut.csv (a row per run) and OUT/<scene>.cut.png (seconds against shading points,
// log-log, a series per gather) and prints the ratios the issue asks for. Reports numbers;
// never fails on time.
//
// Run: build/bin/cut_bench [--out DIR] [--cache DIR] [--scenes cornell-box,sponza]
//        [--sizes 512,1024,2048] [--spp 1,4] [--light-field-size 256] [--reference-size 256]
//        [--reference-spp 1024] [--crop N] [--bake-points N] [--threads N] [--set KEY=VALUE]...

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "core/render/pbgi_receiver.h"
#include "formats/image/compare.h"
#include "formats/image/image_io.h"
#include "formats/image/plot.h"
#include "formats/shot/shot_file.h"
#include "services/render/frame_assembly.h"
#include "services/render/frame_render.h"
#include "tests/support/params.h"
#include "tests/support/reference_image.h"
#include "tests/support/test_paths.h"
#include "tests/support/tree_files.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;
using testing::stageSeconds;

struct Args {
  std::string out = "cut";
  std::string cache;
  std::vector<std::string> scenes = {"cornell-box", "sponza"};
  std::vector<int> sizes = {512, 1024, 2048};
  std::vector<int> spp = {1, 4};
  int lightFieldSize = 256;
  int referenceSize = 256;
  int referenceSpp = 1024;
  int crop = 0;  // > 0: frames larger than this render only their central crop x crop pixels
  uint64_t bakePoints = 0;  // 0: the shot's
  int threads = 0;
  std::vector<std::string> set;
};

struct Run {
  std::string scene;
  std::string gather;
  std::string label;  // "512x512 4spp", "light field 4x4 of 256"
  int width = 0, height = 0, spp = 0, views = 1;
  double seconds = 0.0;
  uint64_t shadingPoints = 0;
  uint64_t evaluations = 0;
  uint64_t shadowRays = 0;
  double hitRate = 0.0;
  double relMse = -1.0;  // against the reference; -1 when not compared
};

struct Scene {
  std::string name;
  ShotDesc shot;
  std::string tree;
  double bakeSeconds = 0.0;
  Image reference;
};

absl::StatusOr<Run> renderRun(const Scene& scene, const Args& args, const std::string& gather,
                              int size, int spp, int views, const fs::path& out) {
  ShotDesc shot = scene.shot;
  shot.width = size;
  shot.height = size;
  shot.camera.views = {views, views};
  if (views > 1) shot.camera.viewSpacing = 0.002f * length(shot.camera.base.position -
                                                            shot.camera.base.lookAt);
  FrameRenderRequest r;
  r.frame = shot.firstFrame;
  r.overrides.integrator = "pbgi";
  r.overrides.spp = spp;
  r.threads = args.threads;
  r.treePath = scene.tree;
  r.preview = false;
  r.outPath = (out / fmt::format("{}.{}.{}x{}.{}spp.v{}.exr", scene.name, gather, size, size, spp,
                                 views))
                  .string();
  r.overrides.params = shot.render.params;
  testing::setParam(r.overrides.params, "gather", gather);
  // The central crop, on the grid of the cut's blocks (64) and of the reference's pixels.
  const bool cropped = views == 1 && args.crop > 0 && size > args.crop;
  TileRect crop{0, 0, size, size};
  if (cropped) {
    const int x0 = (size - args.crop) / 2 / 64 * 64;
    crop = {x0, x0, x0 + args.crop, x0 + args.crop};
    r.regions = {crop};
  }
  auto report = renderShotFrame(shot, r);
  if (!report.ok()) return report.status();
  Run run;
  run.scene = scene.name;
  run.gather = gather;
  run.width = size * views;
  run.height = size * views;
  run.spp = spp;
  run.views = views;
  run.label = views > 1 ? fmt::format("light field {}x{} of {}", views, views, size)
                        : fmt::format("{}x{} {}spp", size, size, spp);
  if (cropped) run.label += fmt::format(" (central {}x{})", args.crop, args.crop);
  run.seconds = stageSeconds(report->stages, "render");
  const RenderCounters& c = report->counters;
  run.shadingPoints = c.cameraSamples - c[kBlackReceivers] - c[kPathTracedReceivers];
  // Gathers are the per-pixel gather's evaluations; the cut's diffuse receivers are counted
  // there too, and only its glossy gathers are evaluations of their own.
  run.evaluations = c[kCutClusterPairs] + c[kCutLeafPairs] +
                    (c[kCuts] > 0 ? c[kGlossyGathers] : c[kGathers]);
  run.shadowRays = c[kCutShadowRays];
  run.hitRate = report->tree->cache.hitRate();
  const int factor = size / args.referenceSize;
  if (views == 1 && !scene.reference.pixels().empty() && size % args.referenceSize == 0 &&
      crop.x0 % factor == 0 && crop.width() % factor == 0) {
    auto image = readImage(r.outPath);
    if (!image.ok()) return image.status();
    // The reference's pixels under the crop.
    Image ref(crop.width() / factor, crop.height() / factor, scene.reference.channels());
    for (int y = 0; y < ref.height(); ++y)
      for (int x = 0; x < ref.width(); ++x)
        for (int c = 0; c < ref.channelCount(); ++c)
          ref.at(x, y, c) = scene.reference.at(crop.x0 / factor + x, crop.y0 / factor + y, c);
    auto m = compareImages(testing::downsample(*image, factor), ref);
    if (!m.ok()) return m.status();
    run.relMse = m->relMse;
  }
  std::printf("%-12s %-14s %-24s %9.2f s  %10llu shading points  %6.2f us/point  %12llu "
              "evaluations  %12llu rays  hit rate %.4f  relMSE %s\n",
              run.scene.c_str(), gather.c_str(), run.label.c_str(), run.seconds,
              static_cast<unsigned long long>(run.shadingPoints),
              1e6 * run.seconds / std::max<double>(1.0, double(run.shadingPoints)),
              static_cast<unsigned long long>(run.evaluations),
              static_cast<unsigned long long>(run.shadowRays), run.hitRate,
              run.relMse >= 0.0 ? fmt::format("{:.3e}", run.relMse).c_str() : "-");
  std::fflush(stdout);
  return run;
}

// One 256^2 farm tile of the 1024^2 frame with a cache of 5 % of the tree: hit rate, and
// whether its pixels are those of an unlimited cache.
int tileCacheRuns(const Scene& scene, const Args& args, const fs::path& out, std::FILE* csv) {
  auto total = testing::decodedTreeBytes(scene.tree);
  if (!total.ok()) return std::fprintf(stderr, "%s\n", total.status().ToString().c_str()), 1;
  ShotDesc shot = scene.shot;
  shot.width = 1024;
  shot.height = 1024;
  const FarmTile tile = farmTiles(shot, 256)[5];  // away from the frame's corner
  // The cut only: both gathers at small caches are cache_bench's.
  {
    const std::string gather = "bidirectional";
    std::optional<Image> unlimited;
    for (const double fraction : {0.0, 0.05}) {
      FrameRenderRequest r;
      r.frame = shot.firstFrame;
      r.overrides.integrator = "pbgi";
      r.overrides.spp = 1;
      r.threads = args.threads;
      r.treePath = scene.tree;
      r.preview = false;
      r.regions = tile;
      r.overrides.params = shot.render.params;
      testing::setParam(r.overrides.params, "gather", gather);
      r.outPath = (out / fmt::format("{}.{}.tile.cache{}.exr", scene.name, gather,
                                     int(fraction * 100)))
                      .string();
      auto run = testing::renderWithCache(shot, r, *total, fraction, &unlimited);
      if (!run.ok()) return std::fprintf(stderr, "%s\n", run.status().ToString().c_str()), 1;
      const bool identical = run->identical;
      r.cacheBytes = run->cacheBytes;
      const TreeReadReport& t = run->tree;
      std::printf("%-12s %-14s tile %s, cache %s (%.1f of %.1f MiB): hit rate %.4f (%llu hits, "
                  "%llu misses), pages read %llu of %llu, render %.2f s, %s\n",
                  scene.name.c_str(), gather.c_str(), regionText(tile[0]).c_str(),
                  fraction > 0.0 ? "5 %" : "unlimited", r.cacheBytes / 1048576.0,
                  *total / 1048576.0, t.cache.hitRate(),
                  static_cast<unsigned long long>(t.cache.hits),
                  static_cast<unsigned long long>(t.cache.misses),
                  static_cast<unsigned long long>(t.pagesRead),
                  static_cast<unsigned long long>(t.pagesInFile), run->renderSeconds,
                  identical ? "bit-identical to unlimited" : "DIFFERS from unlimited");
      std::fprintf(csv, "%s,%s,tile cache %s,,,,,%.4f,,,,%.6f,\n", scene.name.c_str(),
                   gather.c_str(), fraction > 0.0 ? "5%" : "unlimited", run->renderSeconds,
                   t.cache.hitRate());
      if (!identical) return 1;
    }
  }
  return 0;
}

const Run* find(const std::vector<Run>& runs, const std::string& scene, const std::string& gather,
                int size, int spp, int views = 1) {
  for (const Run& r : runs) {
    if (r.scene == scene && r.gather == gather && r.width == size * views && r.spp == spp &&
        r.views == views) {
      return &r;
    }
  }
  return nullptr;
}

int runBench(const Args& args) {
  const auto shared = testing::sharedScenesDir();
  if (!shared) {
    std::fprintf(stderr, "cut_bench: ../shared/scenes is absent (set PBGI_SHARED_SCENES)\n");
    return 1;
  }
  const fs::path out(args.out);
  std::error_code ec;
  fs::create_directories(out, ec);
  const fs::path cache = args.cache.empty() ? out / "reference" : fs::path(args.cache);
  const std::string csvPath = (out / "cut.csv").string();
  std::FILE* csv = std::fopen(csvPath.c_str(), "w");
  if (!csv) return std::fprintf(stderr, "cannot write %s\n", csvPath.c_str()), 1;
  std::fprintf(csv, "scene,gather,run,width,height,spp,views,seconds,shading_points,evaluations,"
                    "shadow_rays,hit_rate,relmse\n");
  std::vector<Run> runs;
  int rc = 0;
  for (const std::string& name : args.scenes) {
    auto shot = testing::devPbgiShot(*shared, name, args.bakePoints, args.set);
    if (!shot.ok()) return std::fprintf(stderr, "%s\n", shot.status().ToString().c_str()), 2;
    Scene scene;
    scene.name = name;
    scene.shot = *shot;
    // The reference, square like the runs.
    ShotDesc refShot = scene.shot;
    refShot.width = args.referenceSize;
    refShot.height = args.referenceSize;
    auto ref = testing::cachedPathReference(refShot, refShot.firstFrame, args.referenceSpp, cache,
                                            args.threads);
    if (!ref.ok()) return std::fprintf(stderr, "%s\n", ref.status().ToString().c_str()), 1;
    scene.reference = *std::move(ref);
    // The bake, once (a tiny render that bakes).
    {
      auto baked = testing::bakeTree(scene.shot, out / "bake", out, args.threads);
      if (!baked.ok()) return std::fprintf(stderr, "%s\n", baked.status().ToString().c_str()), 1;
      scene.tree = baked->path;
      scene.bakeSeconds = baked->seconds;
      std::printf("%s: tree %s (%s %.1f s)\n", name.c_str(), scene.tree.c_str(),
                  baked->baked ? "baked in" : "reused, baked before", scene.bakeSeconds);
    }
    for (const int size : args.sizes) {
      for (const int spp : args.spp) {
        for (const std::string gather : {"bidirectional", "per-pixel"}) {
          auto run = renderRun(scene, args, gather, size, spp, 1, out);
          if (!run.ok()) return std::fprintf(stderr, "%s\n", run.status().ToString().c_str()), 1;
          runs.push_back(*run);
        }
      }
    }
    // A 4 x 4 light field against one view of the same size, both at 1 spp. The cut only: the
    // per-pixel gather shares nothing across views by construction (16 views cost 16 times
    // one), and a light field of it takes as long as the rest of the benchmark.
    {
      const std::string gather = "bidirectional";
      for (const int views : {1, 4}) {
        if (views == 1 && find(runs, name, gather, args.lightFieldSize, 1)) continue;
        auto run = renderRun(scene, args, gather, args.lightFieldSize, 1, views, out);
        if (!run.ok()) return std::fprintf(stderr, "%s\n", run.status().ToString().c_str()), 1;
        runs.push_back(*run);
      }
    }
    // Seconds against shading points, a series per gather.
    std::vector<PlotSeries> plot = {{.name = "bidirectional", .color = Rgb(0.9f, 0.4f, 0.1f)},
                                    {.name = "per-pixel", .color = Rgb(0.2f, 0.5f, 0.9f)}};
    for (const Run& r : runs) {
      if (r.scene != name || r.views > 1) continue;
      plot[r.gather == "bidirectional" ? 0 : 1].points.push_back(
          {double(r.shadingPoints), r.seconds});
    }
    std::string warning;
    const std::string plotPath = (out / (name + ".cut.png")).string();
    if (auto s = writeLogLogPlot(plot,
                                 {.title = name + ": render seconds against shading points",
                                  .xLabel = "shading points",
                                  .yLabel = "seconds"},
                                 plotPath, &warning);
        !s.ok()) {
      std::fprintf(stderr, "%s\n", s.ToString().c_str());
    } else {
      std::printf("wrote %s%s%s\n", plotPath.c_str(), warning.empty() ? "" : ": ",
                  warning.c_str());
    }
    if (rc == 0) rc = tileCacheRuns(scene, args, out, csv);
    // The ratios.
    std::printf("%s ratios:\n", name.c_str());
    for (const int size : args.sizes) {
      for (const int spp : args.spp) {
        const Run* b = find(runs, name, "bidirectional", size, spp);
        const Run* p = find(runs, name, "per-pixel", size, spp);
        if (!b || !p) continue;
        std::printf("  %dx%d %d spp: bidirectional %.2fx faster than per-pixel, relMSE %.3e against "
                    "%.3e; seconds per shading point %.3g us against %.3g us\n",
                    size, size, spp, p->seconds / b->seconds, b->relMse, p->relMse,
                    1e6 * b->seconds / double(b->shadingPoints),
                    1e6 * p->seconds / double(p->shadingPoints));
      }
    }
    for (const std::string gather : {"bidirectional", "per-pixel"}) {
      const Run* one = find(runs, name, gather, args.lightFieldSize, 1);
      const Run* field = find(runs, name, gather, args.lightFieldSize, 1, 4);
      if (one && field) {
        std::printf("  %s: a 4x4 light field of %d costs %.2fx one view (16 views)\n",
                    gather.c_str(), args.lightFieldSize, field->seconds / one->seconds);
      }
    }
  }
  for (const Run& r : runs) {
    std::fprintf(csv, "%s,%s,%s,%d,%d,%d,%d,%.4f,%llu,%llu,%llu,%.6f,%.6g\n", r.scene.c_str(),
                 r.gather.c_str(), r.label.c_str(), r.width, r.height, r.spp, r.views, r.seconds,
                 static_cast<unsigned long long>(r.shadingPoints),
                 static_cast<unsigned long long>(r.evaluations),
                 static_cast<unsigned long long>(r.shadowRays), r.hitRate, r.relMse);
  }
  std::fclose(csv);
  std::printf("wrote %s\n", csvPath.c_str());
  return rc;
}

}  // namespace
}  // namespace pbgi

int main(int argc, char** argv) {
  pbgi::Args args;
  CLI::App app("The bidirectional cut against the per-pixel gather on the dev scenes");
  app.add_option("--out", args.out, "Output folder (default: ./cut)");
  app.add_option("--cache", args.cache, "Reference cache folder (default: OUT/reference)");
  app.add_option("--scenes", args.scenes, "Scenes: cornell-box, sponza")->delimiter(',');
  app.add_option("--sizes", args.sizes, "Square resolutions")->delimiter(',');
  app.add_option("--spp", args.spp, "Samples per pixel")->delimiter(',');
  app.add_option("--light-field-size", args.lightFieldSize, "Pixels a side of each light-field view");
  app.add_option("--reference-size", args.referenceSize, "Pixels a side of the reference");
  app.add_option("--reference-spp", args.referenceSpp, "Reference samples per pixel");
  app.add_option("--crop", args.crop,
                 "Frames larger than this render only their central crop (both gathers alike; "
                 "relMSE against the reference under it)");
  app.add_option("--bake-points", args.bakePoints, "Surfels of the bake (default: the shot's)");
  app.add_option("--threads", args.threads, "Render threads (default: all cores)");
  app.add_option("--set", args.set, "An integrator parameter for every run, KEY=VALUE");
  CLI11_PARSE(app, argc, argv);
  return pbgi::runBench(args);
}
