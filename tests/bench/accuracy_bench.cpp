// Run time against error (architecture invariant 6): for one shot, a high-spp path-traced
// reference (cached by the shot's bytes, frame, spp and version), then the path tracer at a
// sweep of spp and the PBGI integrator at a sweep of quality presets and spp, each measured
// as render seconds against RMSE and relMSE. Writes:
//   OUT/<shot>.csv            one row per run
//   OUT/<shot>.plot.png       relMSE against render seconds, log-log, a series per integrator
//   OUT/<shot>.<run>.exr      each run's image, and OUT/<shot>.<run>.error.exr |image - ref|
//   OUT/<shot>.<run>.bias.png where the run's indirect light is too bright (red) or too dark
//                             (blue), averaged over 8x8 blocks (the mean ratio is printed)
// and prints, for the path tracer at 256 and 1024 spp (when swept), the render time each PBGI
// gather and preset needs to reach the same relMSE (log-log interpolated along its spp sweep)
// and the equal-error speed-up, without and with the bake's time; and, for each PBGI run, the
// render time the path tracer needs to reach its relMSE (log-log interpolated along the path
// tracer's sweep) and that speed-up. The PBGI sweep covers both
// gathers (--gathers bidirectional,per-pixel) at every preset.
//
// Then the page cache: each gather's default preset rendered from the same tree (on a frame
// scaled down to 96 pixels wide, 4 spp) with a cache of 5 % and 20 % of the tree's decoded
// pages and without a limit, reporting hit rates, pages read over pages in the file, and
// whether the images are bit-identical (they must be).
//
// With --suite FOLDER (config/scenes) instead of --shot: every scene of the folder at its own
// size, samples, preset and bake, one row each in one table (and OUT/suite.csv): PBGI's channel
// means over the reference's, its relMSE, low-frequency relMSE and seam step ratio, the
// reference's own relMSE (estimated from the path tracer's sweep, --pt-spp), and the path
// tracer's render time at PBGI's relMSE against PBGI's. A production-size frame (over
// kSuiteFullFramePixels) is measured on its central crop of about kSuiteCropPixels, of the
// frame's shape, unless --crop names one: its bake covers the whole frame.
//
// Render seconds are the render stage alone (the scene load, the bake and the EXR write are
// reported apart). Reports numbers; never fails on time.
//
// Run: build/bin/accuracy_bench --shot ../shared/scenes/cornell-box/cornell.shot.toml
//      build/bin/accuracy_bench --suite config/scenes --pt-spp 16,64,256 [--reference-spp N]
//        [--out DIR] [--cache DIR] [--frame N] [--reference-spp 4096] [--pt-spp 4,16,...]
//        [--pbgi-spp 1,4,...] [--gathers bidirectional,per-pixel] [--qualities draft,default,high]
//        [--threads N] [--no-cache-runs] [--bake-points N] [--bake-bounces K] [--set KEY=VALUE]
//        [--resolution W,H] [--crop X0,Y0,X1,Y1]
//
// --crop renders every run, the reference's too, on those pixels alone (a production
// frame's central crop: its error measured where a full frame's would be, at a fraction of
// the reference's cost); the bake still covers the whole frame, and is timed on its own.

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "formats/image/compare.h"
#include "formats/image/image_io.h"
#include "formats/image/ocio_config.h"
#include "formats/image/plot.h"
#include "formats/pbgi/tree_file.h"
#include "formats/shot/shot_file.h"
#include "core/render/integrators.h"
#include "services/render/frame_render.h"
#include "tests/support/params.h"
#include "tests/support/reference_image.h"
#include "tests/support/tree_files.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

struct Args {
  std::string shot;
  std::string suite;  // a folder of scenes, each a folder with its shot file
  std::string out = "accuracy";
  std::string cache;
  std::optional<int> frame;
  int referenceSpp = 4096;
  std::vector<int> ptSpp = {4, 16, 64, 256, 1024};
  std::vector<int> pbgiSpp = {1, 4, 16, 64, 256};
  std::vector<std::string> gathers = {"bidirectional", "per-pixel"};
  std::vector<std::string> qualities = {"draft", "default", "high"};
  int threads = 0;
  uint64_t bakePoints = 0;  // 0: the shot's bake_points
  int bakeBounces = -1;     // -1: the shot's bake_bounces
  bool cacheRuns = true;
  std::vector<std::string> set;  // integrator parameters for every PBGI run, KEY=VALUE
  std::vector<int> resolution;   // W,H in place of the shot's
  std::vector<int> crop;         // X0,Y0,X1,Y1: every run renders (and is measured on) this
};

struct Run {
  std::string integrator;
  std::string gather;   // PBGI only
  std::string quality;  // PBGI only
  int spp = 0;
  double renderSeconds = 0.0;
  double bakeSeconds = 0.0;  // the PBGI tree's bake (the first PBGI run pays it)
  ImageMetrics rgb;
  ImageMetrics direct;
  ImageMetrics indirect;
  RenderCounters counters;
  std::string settings;  // the integrator's description
  std::string series() const {
    return gather.empty() ? integrator : fmt::format("{} {} {}", integrator, gather, quality);
  }
  std::string name() const {
    return gather.empty() ? fmt::format("{}.spp{}", integrator, spp)
                          : fmt::format("{}-{}-{}.spp{}", integrator, gather, quality, spp);
  }
};

using testing::stageSeconds;

// The three channels `prefix`.R/G/B of an image as a plain RGB image.
Image layer(const Image& image, const std::string& prefix) {
  Image out(image.width(), image.height(), {"R", "G", "B"});
  const int c0 = image.channelIndex(prefix + ".R");
  for (int y = 0; y < image.height(); ++y) {
    for (int x = 0; x < image.width(); ++x) {
      for (int c = 0; c < 3; ++c) out.at(x, y, c) = c0 >= 0 ? image.at(x, y, c0 + c) : 0.0f;
    }
  }
  return out;
}

// Where a run is biased: the signed difference of indirect light from the reference's,
// averaged over blocks of kBiasBlock^2 pixels (which averages the noise away and leaves the
// bias), relative to the reference's total light in the block. Red is too bright, blue too
// dark; full colour at kBiasScale. The mean indirect ratio is returned.
constexpr int kBiasBlock = 8;
constexpr float kBiasScale = 0.25f;

double writeBiasMap(const Image& indirect, const Image& refIndirect, const Image& ref,
                    const std::string& path) {
  auto lum = [](const Image& im, int x, int y) {
    return double(luminance(Rgb(im.at(x, y, 0), im.at(x, y, 1), im.at(x, y, 2))));
  };
  Image map(ref.width(), ref.height(), {"R", "G", "B"});
  double sumImage = 0.0, sumRef = 0.0;
  for (int by = 0; by < ref.height(); by += kBiasBlock) {
    for (int bx = 0; bx < ref.width(); bx += kBiasBlock) {
      const int x1 = std::min(bx + kBiasBlock, ref.width());
      const int y1 = std::min(by + kBiasBlock, ref.height());
      double blockImage = 0.0, blockRef = 0.0, total = 0.0;
      for (int y = by; y < y1; ++y) {
        for (int x = bx; x < x1; ++x) {
          blockImage += lum(indirect, x, y);
          blockRef += lum(refIndirect, x, y);
          total += lum(ref, x, y);
        }
      }
      sumImage += blockImage;
      sumRef += blockRef;
      const float v =
          total > 0.0 ? static_cast<float>((blockImage - blockRef) / total) / kBiasScale : 0.0f;
      const Rgb colour = v > 0.0f ? Rgb(std::min(v, 1.0f), 0.0f, 0.0f)
                                  : Rgb(0.0f, 0.0f, std::min(-v, 1.0f));
      for (int y = by; y < y1; ++y) {
        for (int x = bx; x < x1; ++x) {
          for (int c = 0; c < 3; ++c) map.at(x, y, c) = colour[c];
        }
      }
    }
  }
  if (auto s = writePreviewPng(map, path, defaultOcioConfigPath()); !s.ok()) {
    std::fprintf(stderr, "%s\n", std::string(s.message()).c_str());
  }
  return sumRef > 0.0 ? sumImage / sumRef : 0.0;
}

// The regions every run renders: the crop, or none (the whole frame).
std::vector<TileRect> cropRegions(const Args& args) {
  if (args.crop.size() != 4) return {};
  return {{args.crop[0], args.crop[1], args.crop[2], args.crop[3]}};
}

absl::StatusOr<Image> reference(const ShotDesc& shot, int frame, const Args& args) {
  const fs::path dir = args.cache.empty() ? fs::path(args.out) / "reference" : fs::path(args.cache);
  return testing::cachedPathReference(shot, frame, args.referenceSpp, dir, args.threads,
                                      cropRegions(args));
}

absl::StatusOr<Run> measure(const ShotDesc& shot, FrameRenderRequest request, const Image& ref,
                            const std::string& outDir, Run run,
                            std::optional<TreeReadReport>* tree = nullptr) {
  request.overrides.spp = run.spp;
  request.overrides.integrator = run.integrator;
  if (!run.gather.empty()) {
    testing::setParam(request.overrides.params, "gather", run.gather);
    testing::setParam(request.overrides.params, "quality", run.quality);
  }
  request.preview = false;
  request.outPath = (fs::path(outDir) / fmt::format("{}.{}.exr", shot.name, run.name())).string();
  auto report = renderShotFrame(shot, request);
  if (!report.ok()) return report.status();
  run.renderSeconds = stageSeconds(report->stages, "render");
  run.bakeSeconds = stageSeconds(report->stages, "bake");
  run.counters = report->counters;
  run.settings = report->tree ? report->tree->integratorDescription : run.integrator;
  if (tree) *tree = report->tree;
  // What was written, read back: the numbers are about the file a user gets.
  auto image = readImage(request.outPath);
  if (!image.ok()) return image.status();
  Image diff;
  auto rgb = compareImages(*image, ref, &diff);
  if (!rgb.ok()) return rgb.status();
  run.rgb = *rgb;
  const Image imageIndirect = layer(*image, "indirect");
  const Image refIndirect = layer(ref, "indirect");
  auto direct = compareImages(layer(*image, "direct"), layer(ref, "direct"));
  auto indirect = compareImages(imageIndirect, refIndirect);
  if (!direct.ok()) return direct.status();
  if (!indirect.ok()) return indirect.status();
  run.direct = *direct;
  run.indirect = *indirect;
  const std::string errorPath =
      (fs::path(outDir) / fmt::format("{}.{}.error.exr", shot.name, run.name())).string();
  if (auto s = writeExr(diff, errorPath); !s.ok()) return s;
  const double indirectRatio = writeBiasMap(
      imageIndirect, refIndirect, ref,
      (fs::path(outDir) / fmt::format("{}.{}.bias.png", shot.name, run.name())).string());
  const double meanRatio =
      (rgb->channels[0].meanImage + rgb->channels[1].meanImage + rgb->channels[2].meanImage) /
      (rgb->channels[0].meanReference + rgb->channels[1].meanReference +
       rgb->channels[2].meanReference);
  std::printf("%-22s %8.3f s  relMSE %.3e (direct %.3e, indirect %.3e)  RMSE %.4f  mean %.4f"
              " (indirect %.4f)%s\n",
              run.name().c_str(), run.renderSeconds, rgb->relMse, direct->relMse,
              indirect->relMse, rgb->rmse, meanRatio, indirectRatio,
              run.bakeSeconds > 0 ? fmt::format("  (bake {:.1f} s)", run.bakeSeconds).c_str() : "");
  std::fflush(stdout);
  return run;
}

// The render seconds at which a series (ascending time) first reaches `error`, interpolated in
// log-log between the two runs around it; nullopt when it never does.
std::optional<double> timeToReach(const std::vector<Run>& series, double error) {
  for (size_t i = 0; i < series.size(); ++i) {
    if (series[i].rgb.relMse > error) continue;
    if (i == 0) return series[0].renderSeconds;
    const Run& a = series[i - 1];
    const Run& b = series[i];
    const double t = (std::log(error) - std::log(a.rgb.relMse)) /
                     (std::log(b.rgb.relMse) - std::log(a.rgb.relMse));
    return std::exp(std::log(a.renderSeconds) +
                    t * (std::log(b.renderSeconds) - std::log(a.renderSeconds)));
  }
  return std::nullopt;
}

void printSpeedups(const std::vector<Run>& path, const std::vector<std::vector<Run>>& pbgi,
                   double bakeSeconds) {
  // Each PBGI run at its own error: the time the path tracer's sweep needs to reach it.
  std::printf("equal error with each PBGI run (the path tracer's time interpolated along its "
              "sweep):\n");
  for (const auto& series : pbgi) {
    for (const Run& r : series) {
      const auto t = timeToReach(path, r.rgb.relMse);
      if (!t) {
        std::printf("  %-36s relMSE %.3e: the path tracer's sweep does not reach it\n",
                    r.name().c_str(), r.rgb.relMse);
        continue;
      }
      std::printf("  %-36s relMSE %.3e in %.2f s; the path tracer %.2f s: speed-up %.2fx "
                  "(%.2fx counting the %.1f s bake)\n",
                  r.name().c_str(), r.rgb.relMse, r.renderSeconds, *t, *t / r.renderSeconds,
                  *t / (r.renderSeconds + bakeSeconds), bakeSeconds);
    }
  }
  for (const int spp : {256, 1024}) {
    auto it = std::find_if(path.begin(), path.end(), [&](const Run& r) { return r.spp == spp; });
    if (it == path.end()) continue;
    std::printf("equal error with path %d spp (relMSE %.3e, %.2f s):\n", spp, it->rgb.relMse,
                it->renderSeconds);
    for (const auto& series : pbgi) {
      if (series.empty()) continue;
      const auto t = timeToReach(series, it->rgb.relMse);
      double floor = series.front().rgb.relMse;
      for (const Run& r : series) floor = std::min(floor, r.rgb.relMse);
      if (!t) {
        std::printf("  %-28s not reached (lowest relMSE %.3e)\n", series[0].series().c_str(),
                    floor);
      } else {
        std::printf("  %-28s %.2f s: speed-up %.2fx (%.2fx counting the %.1f s bake)\n",
                    series[0].series().c_str(), *t, it->renderSeconds / *t,
                    it->renderSeconds / (*t + bakeSeconds), bakeSeconds);
      }
    }
  }
}

// The frame the cache runs render: the shot's, scaled down to at most kCacheRunWidth pixels
// wide, at kCacheRunSpp. A cache much smaller than the pages a gather touches decodes pages on
// nearly every miss (minutes per full frame); the hit rates are those of the same traversal
// order (Morton tiles, Morton pixels), over fewer pixels.
constexpr int kCacheRunWidth = 96;
constexpr int kCacheRunSpp = 4;

int cacheRuns(ShotDesc shot, FrameRenderRequest request, const std::string& gather,
              const std::string& treePath, const std::string& outDir, std::FILE* csv) {
  auto total = testing::decodedTreeBytes(treePath);
  if (!total.ok()) return std::fprintf(stderr, "%s\n", total.status().ToString().c_str()), 1;
  if (shot.width > kCacheRunWidth) {
    shot.height = std::max(1, shot.height * kCacheRunWidth / shot.width);
    shot.width = kCacheRunWidth;
  }
  std::printf("page cache (%s gather, default preset, %dx%d pixels, %d spp, tree %s: %.1f MiB "
              "decoded)\n",
              gather.c_str(), shot.width, shot.height, kCacheRunSpp, treePath.c_str(),
              *total / 1048576.0);
  request.treePath = treePath;
  request.regions.clear();  // the whole (scaled) frame
  request.overrides.integrator = "pbgi";
  testing::setParam(request.overrides.params, "gather", gather);
  testing::setParam(request.overrides.params, "quality", "default");
  request.overrides.spp = kCacheRunSpp;
  request.preview = false;
  std::optional<Image> unlimited;
  for (const double fraction : {0.0, 0.20, 0.05}) {
    const std::string label = fraction > 0.0 ? fmt::format("{:.0f}%", fraction * 100) : "unlimited";
    request.outPath = (fs::path(outDir) / fmt::format("{}.{}.cache-{}.exr", shot.name, gather,
                                                      fraction > 0.0 ? int(fraction * 100) : 100))
                          .string();
    auto run = testing::renderWithCache(shot, request, *total, fraction, &unlimited);
    if (!run.ok()) return std::fprintf(stderr, "%s\n", run.status().ToString().c_str()), 1;
    const bool identical = run->identical;
    request.cacheBytes = run->cacheBytes;
    const TreeReadReport& t = run->tree;
    std::printf("  cache %-9s %7.1f MiB: hit rate %.4f (%llu hits, %llu misses, %llu evictions), "
                "pages read %llu of %llu (%.1f %%), render %.2f s, %s\n",
                label.c_str(), request.cacheBytes / 1048576.0, t.cache.hitRate(),
                static_cast<unsigned long long>(t.cache.hits),
                static_cast<unsigned long long>(t.cache.misses),
                static_cast<unsigned long long>(t.cache.evictions),
                static_cast<unsigned long long>(t.pagesRead),
                static_cast<unsigned long long>(t.pagesInFile),
                100.0 * double(t.pagesRead) / double(std::max<uint64_t>(1, t.pagesInFile)),
                run->renderSeconds,
                identical ? "bit-identical to unlimited" : "DIFFERS from unlimited");
    std::fprintf(csv, "cache,%s,%s,%zu,%.6f,%llu,%llu,%llu,%llu,%d\n", gather.c_str(), label.c_str(),
                 request.cacheBytes, t.cache.hitRate(), static_cast<unsigned long long>(t.cache.hits),
                 static_cast<unsigned long long>(t.cache.misses),
                 static_cast<unsigned long long>(t.pagesRead),
                 static_cast<unsigned long long>(t.pagesInFile), identical ? 1 : 0);
    if (!identical) return 1;
  }
  return 0;
}

// The request every run of a shot's frame starts from.
FrameRenderRequest baseRequest(const Args& args, int frame) {
  FrameRenderRequest base;
  base.frame = frame;
  base.threads = args.threads;
  base.bakeDir = (fs::path(args.out) / "bake").string();
  base.regions = cropRegions(args);
  return base;
}

// A shot's frame measured against its reference: the reference, the request every run starts
// from, and the path tracer at each of --pt-spp.
struct Measured {
  Image reference;
  FrameRenderRequest base;
  std::vector<Run> path;
};
absl::StatusOr<Measured> referenceAndPathSweep(const Args& args, const ShotDesc& shot, int frame) {
  Measured m;
  auto ref = reference(shot, frame, args);
  if (!ref.ok()) return ref.status();
  m.reference = *std::move(ref);
  m.base = baseRequest(args, frame);
  for (const int spp : args.ptSpp) {
    auto run = measure(shot, m.base, m.reference, args.out, Run{.integrator = "path", .spp = spp});
    if (!run.ok()) return run.status();
    m.path.push_back(*run);
  }
  return m;
}

// The shot as the flags change it (bake points and bounces, --set, --resolution); an exit code
// (2) after printing why, or 0.
int adjustShot(const Args& args, ShotDesc& shot) {
  if (args.bakePoints > 0) {
    testing::setParam(shot.render.params, "bake_points", std::to_string(args.bakePoints));
  }
  if (args.bakeBounces >= 0) {
    testing::setParam(shot.render.params, "bake_bounces", std::to_string(args.bakeBounces));
  }
  for (const std::string& line : args.set) {
    const size_t eq = line.find('=');
    if (eq == std::string::npos) return std::fprintf(stderr, "--set %s: expected KEY=VALUE\n", line.c_str()), 2;
    testing::setParam(shot.render.params, line.substr(0, eq), line.substr(eq + 1));
  }
  if (!args.resolution.empty()) {
    if (args.resolution.size() != 2 || args.resolution[0] < 1 || args.resolution[1] < 1) {
      return std::fprintf(stderr, "--resolution: expected W,H\n"), 2;
    }
    shot.width = args.resolution[0];
    shot.height = args.resolution[1];
  }
  return 0;
}

int runBench(const Args& args) {
  auto shot = loadShotFile(args.shot);
  if (!shot.ok()) return std::fprintf(stderr, "%s\n", shot.status().ToString().c_str()), 1;
  if (const int rc = adjustShot(args, *shot); rc != 0) return rc;
  if (!args.crop.empty() && args.crop.size() != 4) {
    return std::fprintf(stderr, "--crop: expected X0,Y0,X1,Y1\n"), 2;
  }
  std::printf("%dx%d%s\n", shot->width, shot->height,
              args.crop.empty() ? ""
                                : fmt::format(", measured on the crop [{}, {}) x [{}, {})",
                                              args.crop[0], args.crop[2], args.crop[1],
                                              args.crop[3]).c_str());
  std::printf("bake: %s", shot->render.params.toString().c_str());
  const int frame = args.frame.value_or(shot->firstFrame);
  std::error_code ec;
  fs::create_directories(args.out, ec);
  auto measured = referenceAndPathSweep(args, *shot, frame);
  if (!measured.ok()) return std::fprintf(stderr, "%s\n", measured.status().ToString().c_str()), 1;
  const Image* ref = &measured->reference;
  const FrameRenderRequest& base = measured->base;
  const std::vector<Run>& path = measured->path;
  std::vector<std::vector<Run>> pbgi;
  double bakeSeconds = 0.0;
  std::string treePath;
  for (const std::string& gather : args.gathers) {
    for (const std::string& quality : args.qualities) {
      std::vector<Run>& series = pbgi.emplace_back();
      for (const int spp : args.pbgiSpp) {
        std::optional<TreeReadReport> tree;
        auto run = measure(
            *shot, base, *ref, args.out,
            Run{.integrator = "pbgi", .gather = gather, .quality = quality, .spp = spp}, &tree);
        if (!run.ok()) return std::fprintf(stderr, "%s\n", run.status().ToString().c_str()), 1;
        bakeSeconds = std::max(bakeSeconds, run->bakeSeconds);
        if (tree) treePath = tree->treePath;
        series.push_back(*run);
      }
    }
  }

  if (!treePath.empty()) {
    // The tree's size, and what of it is glossy light (wavelets) against the rest.
    auto tree = TreeFile::open(treePath);
    if (tree.ok()) {
      std::error_code ec;
      const uint64_t fileBytes = fs::file_size(treePath, ec);
      uint64_t payload = 0;
      for (const PageEntry& e : (*tree)->container().directory()) payload += e.uncompressedSize;
      uint64_t waveletBytes = 0;
      std::string waveletError = "-", worst = "-";
      for (const auto& [k, v] : (*tree)->treeInfo()) {
        if (k == "wavelet_bytes") waveletBytes = std::stoull(v);
        if (k == "wavelet_error") waveletError = v;
        if (k == "wavelet_max_relative_error") worst = v;
      }
      std::printf("tree %s: %llu bytes, pages %llu bytes uncompressed, of which wavelets %llu "
                  "(%.2fx the pages without them; coded within %s, worst measured %s)\n",
                  treePath.c_str(), static_cast<unsigned long long>(fileBytes),
                  static_cast<unsigned long long>(payload),
                  static_cast<unsigned long long>(waveletBytes),
                  payload > waveletBytes ? double(waveletBytes) / double(payload - waveletBytes)
                                         : 0.0,
                  waveletError.c_str(), worst.c_str());
    }
  }

  const std::string csvPath = (fs::path(args.out) / (shot->name + ".csv")).string();
  std::FILE* csv = std::fopen(csvPath.c_str(), "w");
  if (!csv) return std::fprintf(stderr, "cannot write %s\n", csvPath.c_str()), 1;
  std::fprintf(csv, "integrator,gather,quality,settings,spp,seconds,bake_seconds,rmse,relmse,"
                    "relmse_direct,relmse_indirect\n");
  std::vector<PlotSeries> plot;
  plot.push_back({.name = "path", .color = Rgb(0.1f, 0.1f, 0.1f)});
  const Rgb colors[] = {Rgb(0.2f, 0.5f, 0.9f), Rgb(0.9f, 0.4f, 0.1f), Rgb(0.2f, 0.7f, 0.3f),
                        Rgb(0.7f, 0.2f, 0.7f), Rgb(0.1f, 0.7f, 0.7f), Rgb(0.8f, 0.7f, 0.1f)};
  for (size_t i = 0; i < pbgi.size(); ++i) {
    plot.push_back({.name = pbgi[i].empty() ? "" : pbgi[i][0].series(), .color = colors[i % 6]});
  }
  auto row = [&](const Run& r) {
    std::fprintf(csv, "%s,%s,%s,\"%s\",%d,%.4f,%.4f,%.6g,%.6g,%.6g,%.6g\n", r.integrator.c_str(),
                 r.gather.c_str(), r.quality.c_str(), r.settings.c_str(), r.spp, r.renderSeconds,
                 r.bakeSeconds, r.rgb.rmse, r.rgb.relMse, r.direct.relMse, r.indirect.relMse);
  };
  for (const Run& r : path) {
    row(r);
    plot[0].points.push_back({r.renderSeconds, r.rgb.relMse});
  }
  for (size_t i = 0; i < pbgi.size(); ++i) {
    for (const Run& r : pbgi[i]) {
      row(r);
      plot[i + 1].points.push_back({r.renderSeconds, r.rgb.relMse});
    }
  }
  std::printf("wrote %s\n", csvPath.c_str());
  const std::string plotPath = (fs::path(args.out) / (shot->name + ".plot.png")).string();
  std::string warning;
  if (auto s = writeLogLogPlot(plot,
                               {.title = fmt::format("{} frame {}: relMSE against render time "
                                                     "(reference: path {} spp)",
                                                     shot->name, frame, args.referenceSpp),
                                .xLabel = "render seconds",
                                .yLabel = "relMSE"},
                               plotPath, &warning);
      !s.ok()) {
    std::fprintf(stderr, "%s\n", s.ToString().c_str());
  } else {
    std::printf("wrote %s%s%s\n", plotPath.c_str(), warning.empty() ? "" : ": ", warning.c_str());
  }
  printSpeedups(path, pbgi, bakeSeconds);
  int rc = 0;
  for (const std::string& gather : args.gathers) {
    if (rc == 0 && args.cacheRuns && !treePath.empty()) {
      rc = cacheRuns(*shot, base, gather, treePath, args.out, csv);
    }
  }
  std::fclose(csv);
  return rc;
}

// One scene of the suite: PBGI at the shot's own settings against the reference and the path
// tracer's sweep.
struct SuiteRow {
  std::string name;
  int width = 0, height = 0, spp = 0;
  std::vector<int> crop;  // X0,Y0,X1,Y1 where measured on a crop
  Run pbgi;
  double referenceRelMse = 0.0;  // the reference's own, estimated from the path tracer's sweep
  double ptSeconds = 0.0;        // the path tracer's time to PBGI's relMSE
  bool extrapolated = false;     // past the sweep, at the path tracer's 1/spp rate
};

// Frames larger than this are measured on a central crop of about kSuiteCropPixels: a 4096-spp
// reference of a whole 1920x1080 frame takes hours on a workstation.
constexpr int64_t kSuiteFullFramePixels = 512 * 512;
constexpr int64_t kSuiteCropPixels = 400 * 225;

// The crop a suite scene is measured on: --crop where given, else the central crop of a frame
// over kSuiteFullFramePixels, else none (the whole frame).
std::vector<int> suiteCrop(const Args& args, int width, int height) {
  if (!args.crop.empty()) return args.crop;
  const int64_t pixels = int64_t(width) * height;
  if (pixels <= kSuiteFullFramePixels) return {};
  const double scale = std::sqrt(double(kSuiteCropPixels) / double(pixels));
  const int w = std::max(1, int(std::lround(width * scale)));
  const int h = std::max(1, int(std::lround(height * scale)));
  const int x0 = (width - w) / 2, y0 = (height - h) / 2;
  return {x0, y0, x0 + w, y0 + h};
}

// The scenes of `folder` (each subfolder's *.shot.toml), in name order.
std::vector<fs::path> suiteShots(const fs::path& folder) {
  std::vector<fs::path> shots;
  std::error_code ec;
  for (const fs::directory_entry& d : fs::directory_iterator(folder, ec)) {
    if (!d.is_directory()) continue;
    for (const fs::directory_entry& f : fs::directory_iterator(d.path(), ec)) {
      const std::string name = f.path().filename().string();
      if (name.size() > 10 && name.ends_with(".shot.toml")) shots.push_back(f.path());
    }
  }
  std::sort(shots.begin(), shots.end());
  return shots;
}

// The suite: every scene at its own size, samples, preset and bake, one row each: PBGI's channel
// means against the reference's, its relMSE, low-frequency relMSE and seam step ratio, the
// reference's own relMSE (c / N, c fitted to the path tracer's sweep as relMSE(n) = c (1/n +
// 1/N)), PBGI's render and bake seconds, and the path tracer's render seconds to reach PBGI's
// relMSE (interpolated along its sweep, or extrapolated past it at its 1/spp rate: marked ~).
int runSuite(const Args& args) {
  const std::vector<fs::path> shots = suiteShots(args.suite);
  if (shots.empty()) return std::fprintf(stderr, "%s: no scene folders with a .shot.toml\n", args.suite.c_str()), 1;
  std::error_code ec;
  fs::create_directories(args.out, ec);
  std::vector<SuiteRow> rows;
  for (const fs::path& file : shots) {
    auto shot = loadShotFile(file.string());
    if (!shot.ok()) return std::fprintf(stderr, "%s\n", shot.status().ToString().c_str()), 1;
    if (const int rc = adjustShot(args, *shot); rc != 0) return rc;
    Args sceneArgs = args;
    sceneArgs.crop = suiteCrop(args, shot->width, shot->height);
    std::printf("== %s (%dx%d%s)\n", shot->name.c_str(), shot->width, shot->height,
                sceneArgs.crop.empty() ? "" : fmt::format(", measured on its crop {}",
                                                          fmt::join(sceneArgs.crop, ",")).c_str());
    const int frame = args.frame.value_or(shot->firstFrame);
    auto measured = referenceAndPathSweep(sceneArgs, *shot, frame);
    if (!measured.ok()) return std::fprintf(stderr, "%s\n", measured.status().ToString().c_str()), 1;
    const std::vector<Run>& path = measured->path;
    auto pbgi = measure(*shot, measured->base, measured->reference, args.out,
                        Run{.integrator = "pbgi", .spp = shot->render.spp});
    if (!pbgi.ok()) return std::fprintf(stderr, "%s\n", pbgi.status().ToString().c_str()), 1;
    SuiteRow row{.name = shot->name, .width = shot->width, .height = shot->height,
                 .spp = shot->render.spp, .crop = sceneArgs.crop, .pbgi = *pbgi};
    if (!path.empty()) {
      const Run& last = path.back();
      const double n = last.spp, big = args.referenceSpp;
      const double c = last.rgb.relMse / (1.0 / n + 1.0 / big);
      row.referenceRelMse = c / big;
      if (std::optional<double> t = timeToReach(path, pbgi->rgb.relMse)) {
        row.ptSeconds = *t;
      } else {
        row.ptSeconds = last.renderSeconds * (c / std::max(pbgi->rgb.relMse, 1e-30)) / n;
        row.extrapolated = true;
      }
    }
    rows.push_back(row);
  }
  const std::string csvPath = (fs::path(args.out) / "suite.csv").string();
  std::FILE* csv = std::fopen(csvPath.c_str(), "w");
  if (!csv) return std::fprintf(stderr, "cannot write %s\n", csvPath.c_str()), 1;
  std::fprintf(csv, "scene,width,height,spp,mean_r,mean_g,mean_b,relmse,lowfreq_relmse,"
                    "seam_step_ratio,reference_relmse,pbgi_seconds,bake_seconds,"
                    "path_seconds_equal_error,extrapolated,crop\n");
  const std::string mdPath = (fs::path(args.out) / "suite.md").string();
  std::FILE* md = std::fopen(mdPath.c_str(), "w");
  if (!md) return std::fclose(csv), std::fprintf(stderr, "cannot write %s\n", mdPath.c_str()), 1;
  std::fprintf(md,
               "# PBGI against the path tracer on the scene suite\n\n"
               "Written by `accuracy_bench --suite` (tests/bench/accuracy_bench.cpp): each shot at "
               "its own size, samples, preset and bake (a frame over %lld pixels measured on its "
               "central crop, its bake the whole frame's), against a %d-spp path trace; the path "
               "tracer's render time at PBGI's relMSE from its sweep (%s spp), extrapolated past "
               "it where marked ~. Means: PBGI's over the reference's, per channel. Low-frequency "
               "relMSE and seams: `pbgi compare`. Ref relMSE: the reference's own noise.\n\n"
               "| scene | size | spp | means R G B | relMSE | low-freq relMSE | seams | ref relMSE "
               "| PBGI render | bake | path tracer at equal error | speed-up |\n"
               "|---|---|---|---|---|---|---|---|---|---|---|---|\n",
               static_cast<long long>(kSuiteFullFramePixels), args.referenceSpp,
               fmt::format("{}", fmt::join(args.ptSpp, ", ")).c_str());
  std::printf("\nthe suite against path-traced references at %d spp (means: PBGI over the "
              "reference; PT: the path tracer's render time at PBGI's relMSE, ~ past its sweep)\n",
              args.referenceSpp);
  std::printf("%-16s %22s %4s  %-20s %9s %9s %6s %9s %8s %8s %9s %8s\n", "scene", "size", "spp",
              "means R G B", "relMSE", "low-freq", "seams", "ref rel", "PBGI s", "bake s",
              "PT s", "speed-up");
  for (const SuiteRow& r : rows) {
    double mean[3];
    for (int c = 0; c < 3; ++c) {
      const ChannelMetrics& m = r.pbgi.rgb.channels[c];
      mean[c] = m.meanReference != 0.0 ? m.meanImage / m.meanReference : 0.0;
    }
    const std::string size =
        r.crop.size() == 4 ? fmt::format("{}x{} crop {}x{}", r.width, r.height, r.crop[2] - r.crop[0],
                                         r.crop[3] - r.crop[1])
                           : fmt::format("{}x{}", r.width, r.height);
    std::printf("%-16s %22s %4d  %.3f %.3f %.3f  %9.2e %9.2e %6.2f %9.2e %8.2f %8.2f %s%8.1f %7.1fx\n",
                r.name.c_str(), size.c_str(), r.spp, mean[0], mean[1], mean[2], r.pbgi.rgb.relMse,
                r.pbgi.rgb.lowFrequencyRelMse, r.pbgi.rgb.seamStepRatio, r.referenceRelMse,
                r.pbgi.renderSeconds, r.pbgi.bakeSeconds, r.extrapolated ? "~" : " ", r.ptSeconds,
                r.ptSeconds / std::max(r.pbgi.renderSeconds, 1e-9));
    std::fprintf(md,
                 "| %s | %s | %d | %.3f %.3f %.3f | %.2e | %.1e | %.2f | %.1e | %.1f s | %.1f s "
                 "| %s%.1f s | %.1fx |\n",
                 r.name.c_str(), size.c_str(), r.spp, mean[0], mean[1], mean[2],
                 r.pbgi.rgb.relMse, r.pbgi.rgb.lowFrequencyRelMse, r.pbgi.rgb.seamStepRatio,
                 r.referenceRelMse, r.pbgi.renderSeconds, r.pbgi.bakeSeconds,
                 r.extrapolated ? "~" : "", r.ptSeconds,
                 r.ptSeconds / std::max(r.pbgi.renderSeconds, 1e-9));
    std::fprintf(csv, "%s,%d,%d,%d,%.5f,%.5f,%.5f,%.6g,%.6g,%.4f,%.6g,%.4f,%.4f,%.4f,%d,%s\n",
                 r.name.c_str(), r.width, r.height, r.spp, mean[0], mean[1], mean[2],
                 r.pbgi.rgb.relMse, r.pbgi.rgb.lowFrequencyRelMse, r.pbgi.rgb.seamStepRatio,
                 r.referenceRelMse, r.pbgi.renderSeconds, r.pbgi.bakeSeconds, r.ptSeconds,
                 r.extrapolated ? 1 : 0, fmt::format("{}", fmt::join(r.crop, " ")).c_str());
  }
  std::fclose(csv);
  std::fclose(md);
  std::printf("wrote %s and %s\n", csvPath.c_str(), mdPath.c_str());
  return 0;
}

}  // namespace
}  // namespace pbgi

int main(int argc, char** argv) {
  pbgi::Args args;
  CLI::App app("Run time against error: the path tracer and PBGI against a path-traced reference");
  app.add_option("--shot", args.shot, "Shot file");
  app.add_option("--suite", args.suite,
                 "A folder of scenes (each a folder with its .shot.toml, as config/scenes): PBGI "
                 "at each shot's own settings, one table");
  app.add_option("--out", args.out, "Output folder (default: ./accuracy)");
  app.add_option("--cache", args.cache, "Reference cache folder (default: OUT/reference)");
  app.add_option("--frame", args.frame, "Frame (default: the shot's first)");
  app.add_option("--reference-spp", args.referenceSpp, "Reference samples per pixel");
  app.add_option("--pt-spp", args.ptSpp, "Path tracer spp sweep")->delimiter(',');
  app.add_option("--pbgi-spp", args.pbgiSpp, "PBGI spp sweep")->delimiter(',');
  app.add_option("--gathers", args.gathers, "PBGI gathers: bidirectional, per-pixel")->delimiter(',');
  app.add_option("--qualities", args.qualities, "PBGI presets")->delimiter(',');
  app.add_option("--threads", args.threads, "Render threads (default: all cores)");
  app.add_option("--bake-points", args.bakePoints, "Surfels of the PBGI bake (default: the shot's)");
  app.add_option("--bake-bounces", args.bakeBounces, "Bounces of the PBGI bake (default: the shot's)");
  bool noCache = false;
  app.add_flag("--no-cache-runs", noCache, "Skip the page cache runs");
  app.add_option("--set", args.set, "An integrator parameter for every PBGI run, KEY=VALUE");
  app.add_option("--resolution", args.resolution, "W,H in place of the shot's resolution")
      ->delimiter(',');
  app.add_option("--crop", args.crop,
                 "X0,Y0,X1,Y1: render and measure only these pixels of the frame (half-open, "
                 "origin top left; the bake still covers the whole frame)")
      ->delimiter(',');
  CLI11_PARSE(app, argc, argv);
  args.cacheRuns = !noCache;
  if (args.shot.empty() == args.suite.empty()) {
    std::fprintf(stderr, "accuracy_bench: give --shot or --suite\n");
    return 2;
  }
  return args.suite.empty() ? pbgi::runBench(args) : pbgi::runSuite(args);
}
