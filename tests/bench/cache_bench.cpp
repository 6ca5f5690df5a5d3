// The page cache at small budgets: for each dev scene of ../shared/scenes,
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
// Then, for the first gather, the unlimited run again as a farm worker with no shared files
// renders it: the tree through the page service of a real coordinator on loopback, a page a
// call, into a fresh disk cache and then with that cache warm: seconds against the local
// tree, pages and bytes over the network against the file, pages the traversals touched.
//
// Writes OUT/cache.csv (a row per run; a remote row's "misses" are its pages over the network).
// Reports numbers; never fails on time.
//
// Run: build/bin/cache_bench [--out DIR] [--scenes cornell-box,sponza] [--gathers
//        bidirectional,per-pixel] [--budgets 100,20,10,5,2,1] [--size 256] [--per-pixel-size 64]
//        [--spp 1] [--bake-points N | --tree FILE.pbgi] [--threads N] [--set KEY=VALUE]...
//        [--no-remote]

#include <cstdio>
#include <filesystem>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "core/util/status.h"
#include "formats/pbgi/remote_page_file.h"
#include "formats/shot/shot_file.h"
#include "services/coordinator/coordinator.h"
#include "services/farm/farm_client.h"
#include "services/farm/farm_wire.h"
#include "services/farm/job_rules.h"
#include "services/render/frame_render.h"
#include "tests/support/farm_fixtures.h"
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
  bool remote = true;
};

// A tile rendered as by a worker with no shared files: the tree through the page service (a
// real coordinator on loopback, a page a call) and a fresh disk cache, then again with that
// disk cache warm (a later tile of the frame), against the same render from the local file.
absl::Status remoteTile(const std::string& name, const ShotDesc& frame,
                        const FrameRenderRequest& local, const std::string& treePath,
                        uint64_t treeBytes, double localSeconds, std::optional<Image>* localImage,
                        const fs::path& out, std::FILE* csv) {
  namespace farm = pbgi::farm;
  const fs::path dir = out / ("page-service-" + name);
  std::error_code ec;
  fs::remove_all(dir, ec);
  farm::CoordinatorOptions o;
  o.stateDir = (dir / "state").string();
  o.outputRoot = dir.string();
  o.token = "cache-bench";
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<farm::Coordinator> coordinator,
                        farm::Coordinator::start(o));
  farm::FarmClient client(coordinator->address(), o.token);
  farm::v1::SubmitJobRequest submit;
  submit.set_shot_path(frame.path);
  submit.set_shot_text(testing::slurpFile(frame.path));
  RenderOverrides pbgi;
  pbgi.integrator = "pbgi";
  *submit.mutable_render() = farm::toWire(pbgi);
  submit.set_output_dir((dir / "frames").string());
  submit.add_frames(frame.firstFrame);
  PBGI_ASSIGN_OR_RETURN(const farm::v1::SubmitJobResponse job, client.submitJob(submit));
  // The frame's bake, where the job's bake task would have written it.
  PBGI_ASSIGN_OR_RETURN(const ShotDesc jobShot,
                        farm::jobShot(submit.shot_text(), frame.path, pbgi));
  PBGI_ASSIGN_OR_RETURN(const std::string jobTree,
                        farm::jobTreePath(jobShot, farm::jobWorkDir(o.stateDir, job.job()),
                                          frame.firstFrame));
  fs::create_directories(fs::path(jobTree).parent_path());
  fs::copy_file(treePath, jobTree, fs::copy_options::overwrite_existing);
  PBGI_ASSIGN_OR_RETURN(std::shared_ptr<PageDiskCache> disk,
                        PageDiskCache::open((dir / "worker-cache").string(), uint64_t{4} << 30));
  for (const char* state : {"cold", "warm"}) {
    auto stats = std::make_shared<RemoteFetchStats>();
    auto fetcher = std::make_shared<farm::FarmPageFetcher>(client, job.job(), frame.firstFrame);
    FrameRenderRequest r = local;
    r.treePath.clear();
    r.outPath = (dir / fmt::format("remote-{}.exr", state)).string();
    r.openTree = [&]() -> absl::StatusOr<std::unique_ptr<TreeFile>> {
      PBGI_ASSIGN_OR_RETURN(PageFileHead head, fetcher->head());
      return TreeFile::open(openRemotePageFile(std::move(head), fetcher, disk, stats));
    };
    PBGI_ASSIGN_OR_RETURN(const testing::CacheRun run,
                          testing::renderWithCache(frame, r, treeBytes, 0.0, localImage));
    const uint64_t fileBytes = fs::file_size(treePath);
    std::printf("%-12s remote tile (%s disk cache): render %7.2f s (%.2fx the local tree)  pages "
                "over the network %llu of %llu (%.2f of %.2f MiB, head %.1f KiB), from disk %llu, "
                "touched by the traversals %llu  %s\n",
                name.c_str(), state, run.renderSeconds, run.renderSeconds / localSeconds,
                static_cast<unsigned long long>(stats->pagesFetched.load()),
                static_cast<unsigned long long>(run.tree.pagesInFile),
                (stats->bytesFetched + stats->headBytes) / 1048576.0, fileBytes / 1048576.0,
                stats->headBytes / 1024.0,
                static_cast<unsigned long long>(stats->diskHits.load()),
                static_cast<unsigned long long>(run.tree.pagesRead),
                run.identical ? "bit-identical" : "DIFFERS from the local tree");
    std::fflush(stdout);
    std::fprintf(csv, "%s,remote-%s,%d,%d,0,100,%zu,%.3f,%.3f,%.5f,%llu,%llu,%llu,%llu,%d\n",
                 name.c_str(), state, frame.width, frame.height, run.cacheBytes, run.renderSeconds,
                 run.renderSeconds / localSeconds, run.tree.cache.hitRate(),
                 static_cast<unsigned long long>(run.tree.cache.hits),
                 static_cast<unsigned long long>(stats->pagesFetched.load()),
                 static_cast<unsigned long long>(run.tree.pagesRead),
                 static_cast<unsigned long long>(run.tree.pagesInFile), run.identical ? 1 : 0);
    if (!run.identical) return absl::InternalError("the remote tree's pixels differ");
  }
  return absl::OkStatus();
}

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
        r.overrides.integrator = "pbgi";
        r.overrides.spp = args.spp;
        r.threads = args.threads;
        r.treePath = baked->path;
        r.preview = false;
        r.overrides.params = frame.render.params;
        testing::setParam(r.overrides.params, "gather", gather);
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
        if (fraction == 0.0 && args.remote && gather == args.gathers.front()) {
          if (absl::Status s = remoteTile(name, frame, r, baked->path, *total, unlimitedSeconds,
                                          &unlimited, out, csv);
              !s.ok()) {
            std::fprintf(stderr, "remote tile: %s\n", s.ToString().c_str());
            return std::fclose(csv), 1;
          }
        }
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
  app.add_flag("!--no-remote", args.remote,
               "Skip the remote tile (the tree through the page service on loopback)");
  CLI11_PARSE(app, argc, argv);
  if (args.budgets.empty() || args.budgets.front() < 100) {
    std::fprintf(stderr, "--budgets: the first must be 100 (the unlimited run the others match)\n");
    return 2;
  }
  return pbgi::runBench(args);
}
