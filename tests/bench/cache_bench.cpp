// The page cache at small budgets (issue 13's targets): for each dev scene of ../shared/scenes,
// one bake, then each gather renders the same frame with page caches of 100 (unlimited), 20,
// 10, 5, 2 and 1 % of the tree's decoded bytes. For each run: render seconds and their ratio to
// the unlimited run's, the cache's hit rate, hits and misses (pages loaded from the file),
// distinct pages read against the pages in the file, and whether the pixels are bit for bit
// those of the unlimited run (a difference fails the benchmark: that is a bug, not a number).
//
// The per-pixel gather renders a smaller frame by default (--per-pixel-size): each of its
// gathers cuts through the whole tree, and at 1 % of the tree a frame the cut's size takes it
// most of an hour.
//
// Writes OUT/cache.csv (a row per run). Reports numbers; never fails on time.
//
// Run: build/bin/cache_bench [--out DIR] [--scenes cornell-box,sponza] [--gathers
//        bidirectional,per-pixel] [--budgets 100,20,10,5,2,1] [--size 256] [--per-pixel-size 64]
//        [--spp 1] [--bake-points N | --tree FILE.pbgi] [--threads N] [--set KEY=VALUE]...

#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "formats/shot/shot_file.h"
#include "services/render/frame_render.h"
#include "tests/support/params.h"
#include "tests/support/reference_image.h"
#include "tests/support/test_paths.h"
#include "tests/support/tree_files.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

struct Args {
  std::string out = "cache";
  std::vector<std::string> scenes = {"cornell-box", "sponza"};
  std::vector<std::string> gathers = {"bidirectional", "per-pixel"};
  std::vector<int> budgets = {100, 20, 10, 5, 2, 1};
  int size = 256;
  int perPixelSize = 64;
  int spp = 1;
  uint64_t bakePoints = 0;  // 0: the shot's
  std::string tree;         // a tree baked before (one scene), instead of baking
  int threads = 0;
  std::vector<std::string> set;
};

int runBench(const Args& args) {
  const auto shared = testing::sharedScenesDir();
  if (!shared) {
    std::fprintf(stderr, "cache_bench: ../shared/scenes is absent (set PBGI_SHARED_SCENES)\n");
    return 1;
  }
  const fs::path out(args.out);
  std::error_code ec;
  fs::create_directories(out, ec);
  const std::string csvPath = (out / "cache.csv").string();
  std::FILE* csv = std::fopen(csvPath.c_str(), "w");
  if (!csv) return std::fprintf(stderr, "cannot write %s\n", csvPath.c_str()), 1;
  std::fprintf(csv, "scene,gather,width,height,spp,budget_percent,cache_bytes,seconds,"
                    "time_ratio,hit_rate,hits,misses,pages_read,pages_in_file,identical\n");
  for (const std::string& name : args.scenes) {
    auto loaded = testing::devPbgiShot(*shared, name, args.bakePoints, args.set);
    if (!loaded.ok()) return std::fprintf(stderr, "%s\n", loaded.status().ToString().c_str()), 2;
    const ShotDesc& shot = *loaded;
    absl::StatusOr<testing::BakedTree> baked = testing::BakedTree{.path = args.tree};
    if (args.tree.empty()) baked = testing::bakeTree(shot, out / "bake", out, args.threads);
    if (!baked.ok()) return std::fprintf(stderr, "%s\n", baked.status().ToString().c_str()), 1;
    auto total = testing::decodedTreeBytes(baked->path);
    if (!total.ok()) return std::fprintf(stderr, "%s\n", total.status().ToString().c_str()), 1;
    std::printf("%s: tree %s (%s %.1f s), %.1f MiB decoded\n", name.c_str(), baked->path.c_str(),
                baked->baked ? "baked in" : "reused, baked before", baked->seconds,
                *total / 1048576.0);
    for (const std::string& gather : args.gathers) {
      const int size = gather == "per-pixel" ? args.perPixelSize : args.size;
      ShotDesc frame = shot;
      frame.width = size;
      frame.height = size;
      std::optional<Image> unlimited;
      double unlimitedSeconds = 0.0;
      for (const int budget : args.budgets) {
        FrameRenderRequest r;
        r.frame = frame.firstFrame;
        r.integrator = "pbgi";
        r.spp = args.spp;
        r.threads = args.threads;
        r.treePath = baked->path;
        r.preview = false;
        r.params = frame.render.params;
        testing::setParam(r.params, "gather", gather);
        r.outPath = (out / fmt::format("{}.{}.{}.cache{}.exr", name, gather, size, budget)).string();
        const double fraction = budget >= 100 ? 0.0 : budget / 100.0;
        auto run = testing::renderWithCache(frame, r, *total, fraction, &unlimited);
        if (!run.ok()) return std::fprintf(stderr, "%s\n", run.status().ToString().c_str()), 1;
        if (fraction == 0.0) unlimitedSeconds = run->renderSeconds;
        const TreeReadReport& t = run->tree;
        const double ratio = unlimitedSeconds > 0.0 ? run->renderSeconds / unlimitedSeconds : 0.0;
        std::printf("%-12s %-14s %dx%d %d spp  cache %3d %% (%7.2f MiB): render %7.2f s (%.2fx "
                    "unlimited)  hit rate %.4f (%llu hits, %llu misses)  pages read %llu of %llu  "
                    "%s\n",
                    name.c_str(), gather.c_str(), size, size, args.spp, budget,
                    std::min<double>(run->cacheBytes, *total) / 1048576.0, run->renderSeconds,
                    ratio, t.cache.hitRate(), static_cast<unsigned long long>(t.cache.hits),
                    static_cast<unsigned long long>(t.cache.misses),
                    static_cast<unsigned long long>(t.pagesRead),
                    static_cast<unsigned long long>(t.pagesInFile),
                    run->identical ? "bit-identical" : "DIFFERS from the unlimited cache");
        std::fflush(stdout);
        std::fprintf(csv, "%s,%s,%d,%d,%d,%d,%zu,%.3f,%.3f,%.5f,%llu,%llu,%llu,%llu,%d\n",
                     name.c_str(), gather.c_str(), size, size, args.spp, budget, run->cacheBytes,
                     run->renderSeconds, ratio, t.cache.hitRate(),
                     static_cast<unsigned long long>(t.cache.hits),
                     static_cast<unsigned long long>(t.cache.misses),
                     static_cast<unsigned long long>(t.pagesRead),
                     static_cast<unsigned long long>(t.pagesInFile), run->identical ? 1 : 0);
        std::fflush(csv);
        if (!run->identical) return std::fclose(csv), 1;
      }
    }
  }
  std::fclose(csv);
  std::printf("wrote %s\n", csvPath.c_str());
  return 0;
}

}  // namespace
}  // namespace pbgi

int main(int argc, char** argv) {
  pbgi::Args args;
  CLI::App app{"Render time and page-cache hit rate at small cache budgets, both gathers"};
  app.add_option("--out", args.out, "Output folder (default: ./cache)");
  app.add_option("--scenes", args.scenes, "Scenes: cornell-box, sponza")->delimiter(',');
  app.add_option("--gathers", args.gathers, "Gathers: bidirectional, per-pixel")->delimiter(',');
  app.add_option("--budgets", args.budgets,
                 "Cache budgets, percent of the decoded tree (100: unlimited; run first)")->delimiter(',');
  app.add_option("--size", args.size, "Square resolution of the cut's frame");
  app.add_option("--per-pixel-size", args.perPixelSize, "Square resolution of the per-pixel frame");
  app.add_option("--spp", args.spp, "Samples per pixel");
  app.add_option("--bake-points", args.bakePoints, "Surfels of the bake (default: the shot's)");
  app.add_option("--tree", args.tree,
                 "A tree baked before (pbgi bake) instead of baking; with one scene, its own");
  app.add_option("--threads", args.threads, "Render threads (default: all cores)");
  app.add_option("--set", args.set, "An integrator parameter for every run, KEY=VALUE");
  CLI11_PARSE(app, argc, argv);
  if (args.budgets.empty() || args.budgets.front() < 100) {
    std::fprintf(stderr, "--budgets: the first must be 100 (the unlimited run the others match)\n");
    return 2;
  }
  return pbgi::runBench(args);
}
