#pragma once
// Path-traced references for the benchmarks, rendered once and cached by the shot's bytes, its
// size, the frame, the spp and the version: what run-time-against-error curves are measured
// against.
#include <cstdio>
#include <algorithm>
#include <filesystem>
#include <map>
#include <optional>
#include <string>

#include <absl/status/statusor.h>
#include <fmt/format.h>
#ifndef XXH_INLINE_ALL
#define XXH_INLINE_ALL  // benchmarks do not link libxxhash themselves
#endif
#include <xxhash.h>

#include "core/render/image.h"
#include "core/scene/shot.h"
#include "formats/image/image_io.h"
#include "formats/shot/shot_file.h"
#include "services/render/frame_render.h"
#include "tests/support/params.h"

namespace pbgi::testing {

inline double stageSeconds(const std::vector<StageTime>& stages, const std::string& name) {
  for (const StageTime& s : stages) {
    if (s.stage == name) return s.seconds;
  }
  return 0.0;
}

// The path tracer's image of `shot` (at its size) at `spp`, from `cacheDir` when rendered
// before, else rendered (on `threads`, 0: all) and kept there.
inline absl::StatusOr<Image> cachedPathReference(const ShotDesc& shot, int frame, int spp,
                                                 const std::filesystem::path& cacheDir,
                                                 int threads,
                                                 const std::vector<TileRect>& regions = {}) {
  std::string regionKey;
  for (const TileRect& r : regions) regionKey += fmt::format(" {},{},{},{}", r.x0, r.y0, r.x1, r.y1);
  const std::string key = fmt::format("{}|frame={}|spp={}|size={}x{}|regions={}|version={}",
                                      shot.source, frame, spp, shot.width, shot.height, regionKey,
                                      PBGI_VERSION);
  const std::string path =
      (cacheDir / fmt::format("{}.{:04d}.{}x{}.path{}.{:016x}.exr", shot.name, frame, shot.width,
                              shot.height, spp, XXH3_64bits(key.data(), key.size())))
          .string();
  if (std::filesystem::exists(path)) {
    std::printf("reference %s (cached)\n", path.c_str());
    return readImage(path);
  }
  std::printf("reference: path tracing %dx%d at %d spp (cached afterwards as %s)\n", shot.width,
              shot.height, spp, path.c_str());
  std::fflush(stdout);
  std::error_code ec;
  std::filesystem::create_directories(cacheDir, ec);
  FrameRenderRequest request;
  request.frame = frame;
  request.overrides.integrator = "path";
  request.overrides.spp = spp;
  request.threads = threads;
  request.regions = regions;
  request.outPath = path;
  request.preview = false;
  auto report = renderShotFrame(shot, request);
  if (!report.ok()) return report.status();
  std::printf("  %.1f s\n", stageSeconds(report->stages, "render"));
  return readImage(path);
}

// The image box-filtered down by an integer factor (each output pixel the mean of a
// factor x factor block), channels and metadata kept.
inline Image downsample(const Image& image, int factor) {
  if (factor <= 1) return image;
  Image out(image.width() / factor, image.height() / factor, image.channels());
  const float inv = 1.0f / static_cast<float>(factor * factor);
  for (int y = 0; y < out.height(); ++y) {
    for (int x = 0; x < out.width(); ++x) {
      for (int c = 0; c < image.channelCount(); ++c) {
        float sum = 0.0f;
        for (int dy = 0; dy < factor; ++dy) {
          for (int dx = 0; dx < factor; ++dx) sum += image.at(x * factor + dx, y * factor + dy, c);
        }
        out.at(x, y, c) = sum * inv;
      }
    }
  }
  return out;
}

// One PBGI render with a page cache of `fraction` of the tree's decoded bytes (0: unlimited), its
// image read back and compared bit for bit with the first (unlimited) run's, kept in `unlimited`.
struct CacheRun {
  TreeReadReport tree;
  size_t cacheBytes = 0;
  double renderSeconds = 0.0;
  bool identical = true;  // to the unlimited run's pixels
};
inline absl::StatusOr<CacheRun> renderWithCache(const ShotDesc& shot, FrameRenderRequest request,
                                                uint64_t treeBytes, double fraction,
                                                std::optional<Image>* unlimited) {
  request.cacheBytes =
      fraction > 0.0 ? std::max<size_t>(1, static_cast<size_t>(double(treeBytes) * fraction))
                     : size_t{1} << 40;
  auto report = renderShotFrame(shot, request);
  if (!report.ok()) return report.status();
  auto image = readImage(request.outPath);
  if (!image.ok()) return image.status();
  CacheRun run{.tree = *report->tree,
               .cacheBytes = request.cacheBytes,
               .renderSeconds = stageSeconds(report->stages, "render")};
  if (!*unlimited) {
    *unlimited = std::move(*image);
  } else {
    run.identical = image->pixels() == (*unlimited)->pixels();
  }
  return run;
}

// The shot's tree for its first frame, baked (or found, when baked before) under `bakeDir` by
// a tiny render: the benchmarks' bake, timed apart from their renders.
struct BakedTree {
  std::string path;
  double seconds = 0.0;  // the bake's, or the tree stage's when the tree was found
  bool baked = false;
};
inline absl::StatusOr<BakedTree> bakeTree(ShotDesc shot, const std::filesystem::path& bakeDir,
                                          const std::filesystem::path& outDir, int threads) {
  shot.width = 8;
  shot.height = 8;
  FrameRenderRequest r;
  r.frame = shot.firstFrame;
  r.overrides.spp = 1;
  r.threads = threads;
  r.preview = false;
  r.bakeDir = bakeDir.string();
  r.outPath = (outDir / (std::filesystem::path(shot.path).stem().string() + ".bake.exr")).string();
  auto report = renderShotFrame(shot, r);
  if (!report.ok()) return report.status();
  const bool baked = report->tree->baked;
  return BakedTree{.path = report->tree->treePath,
                   .seconds = stageSeconds(report->stages, baked ? "bake" : "tree"),
                   .baked = baked};
}

// A dev scene's shot (`shared`/<name>, the Cornell box or Sponza) as the PBGI benchmarks
// render it: integrator pbgi, `bakePoints` surfels when above 0, then each "KEY=VALUE" of
// `sets` (a user's --set). InvalidArgument names an unknown scene or a bad setting.
inline absl::StatusOr<ShotDesc> devPbgiShot(const std::filesystem::path& shared,
                                            const std::string& name, uint64_t bakePoints,
                                            const std::vector<std::string>& sets) {
  static const std::map<std::string, std::string> files = {
      {"cornell-box", "cornell.shot.toml"}, {"sponza", "sponza.shot.toml"}};
  const auto file = files.find(name);
  if (file == files.end()) {
    return absl::InvalidArgumentError(
        fmt::format("unknown scene {} (cornell-box, sponza)", name));
  }
  absl::StatusOr<ShotDesc> shot = loadShotFile((shared / name / file->second).string());
  if (!shot.ok()) return shot.status();
  shot->render.integrator = "pbgi";
  if (bakePoints > 0) setParam(shot->render.params, "bake_points", std::to_string(bakePoints));
  for (const std::string& line : sets) {
    const size_t eq = line.find('=');
    if (eq == std::string::npos) {
      return absl::InvalidArgumentError(fmt::format("--set {}: expected KEY=VALUE", line));
    }
    if (absl::Status s = setParamText(shot->render.params, line.substr(0, eq),
                                      line.substr(eq + 1), {"--set"});
        !s.ok()) {
      return s;
    }
  }
  return shot;
}

}  // namespace pbgi::testing
