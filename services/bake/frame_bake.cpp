#include "services/bake/frame_bake.h"

#include <malloc.h>

#include <atomic>
#include <filesystem>
#include <optional>

#include <fmt/format.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>
#include <xxhash.h>

#include "core/pbgi/gather.h"
#include "core/pbgi/gather_reuse.h"
#include "core/pbgi/morton.h"
#include "core/pbgi/page_cache.h"
#include "core/render/integrators.h"
#include "core/util/check.h"
#include "core/util/spill_file.h"
#include "core/util/status.h"
#include "formats/pbgi/tree_file.h"
#include "formats/scene/frame_scene.h"
#include "formats/vdb/surfel_vdb.h"

namespace pbgi {

namespace {


// Surfels shaded per batch: enough to keep every core busy, small next to any budget.
constexpr size_t kChunkSurfels = 64 * 1024;
// Bounce gathers are shared within groups of this many consecutive sorted surfels, between
// surfels at most kBounceReuseRadii of the gathering surfel's radius apart whose normals
// agree to kBounceReuseCos. Indirect light varies slowly; measured on the Cornell box at 1M
// surfels, this cuts a bounce's gathers about fourfold (see the README's Baking section).
constexpr size_t kBounceGroup = 8;
constexpr float kBounceReuseRadii = 6.0f;
constexpr float kBounceReuseCos = 0.95f;
// What OpenVDB holds per point while it builds a cloud, with our copy of the surfels.
constexpr uint64_t kPointCloudBytesPerPoint = 48 + sizeof(Surfel);

std::filesystem::path framePathStem(const ShotDesc& shot, const FrameBakeRequest& request) {
  const std::filesystem::path image(
      outputPathForFrame(shot.output, request.frame, shot.lastFrame > shot.firstFrame));
  const std::filesystem::path dir = request.outDir.empty() ? image.parent_path()
                                                           : std::filesystem::path(request.outDir);
  return dir / image.stem();
}

}  // namespace

absl::StatusOr<FrameBakeRequest> shotBakeRequest(const ShotDesc& shot, int frame) {
  // The bake of the integrator that renders from trees: the shot's own when it is one, else
  // the first in the registry that is (a bake of a path-traced shot is for comparing).
  const IntegratorInfo* tree = nullptr;
  for (const IntegratorInfo& i : integrators()) {
    if (!i.needsTree) continue;
    if (tree == nullptr || i.name == shot.render.integrator) tree = &i;
  }
  PBGI_CHECK(tree != nullptr);
  const TreeNeeds needs = tree->treeNeeds(shot.render);
  FrameBakeRequest request;
  request.frame = frame;
  request.points = needs.bakePoints;
  request.bounces = needs.bakeBounces;
  request.gather = needs.bakeGather;
  request.pbgiVersion = std::string("pbgi ") + PBGI_VERSION;
  return request;
}

uint64_t bakeHash(const ShotDesc& shot, const FrameBakeRequest& request) {
  // The bytes the shot was parsed from, not the file as it is now: a farm job renders the
  // text it was submitted with, whatever the file says by the time its bake runs.
  std::string text = shot.source;
  const uint64_t points = request.points > 0 ? request.points : kDefaultBakePoints;
  text += fmt::format(
      "|frame={}|points={}|light_samples={}|bounces={}|bounce_gather={}|encoding={}|leaf={}"
      "|page={}|power={}|area={}|exact={}|bounce_group={}|version={}",
      request.frame, points, request.lightSamples, request.bounces,
      request.bounces > 0 ? fmt::format("{} revision {}", request.gather.toString(), kGatherRevision)
                          : "",
      treeEncodingName(request.tree.encoding),
      request.tree.build.leafSize, request.tree.pageSize, request.tree.powerCentres,
      request.tree.areaCentres, request.tree.exactNodes, kBounceGroup, request.pbgiVersion);
  return XXH3_64bits(text.data(), text.size());
}

namespace {

// Lights every surfel of the sorted spill with one more bounce gathered from the tree at
// `fromPath` through a page cache, and writes the next tree to `toPath`. Surfels keep their
// direct light (and emission); only diffuse surfels reflect the gathered light, as in the
// direct pass.
absl::StatusOr<TreeWriteResult> bakeBounce(const std::string& fromPath, const std::string& toPath,
                                           SpillFile& sorted, const TreeFileWriteOptions& options,
                                           const FrameBakeRequest& request, uint64_t surfels,
                                           GatherStats* gatherStats, uint64_t* sharedGathers) {
  auto from = TreeFile::open(fromPath);
  if (!from.ok()) return from.status();
  PageCache cache(**from, {.budgetBytes = request.memoryBudget / 4});
  auto writer = TreeFileWriter::create(toPath, options);
  if (!writer.ok()) return writer.status();
  if (auto s = sorted.rewind(); !s.ok()) return s;
  tbb::enumerable_thread_specific<Gatherer> gatherers(
      [&] { return Gatherer(request.gather); });
  tbb::enumerable_thread_specific<GatherStats> stats;
  std::atomic<uint64_t> sharedCount{0};
  std::vector<SortedSurfel> batch;
  std::vector<absl::Status> errors;
  std::vector<uint8_t> bytes;
  for (uint64_t done = 0; done < surfels;) {
    const size_t n = static_cast<size_t>(std::min<uint64_t>(surfels - done, kChunkSurfels));
    bytes.resize(n * kSurfelRecordBytes);
    if (auto s = sorted.read(bytes); !s.ok()) return s;
    batch.resize(n);
    errors.assign(n, absl::OkStatus());
    for (size_t i = 0; i < n; ++i) {
      if (auto s = decodeSurfelRecord(bytes.data() + i * kSurfelRecordBytes, &batch[i]); !s.ok()) {
        return absl::DataLossError(fmt::format("{}: {}", sorted.name(), s.message()));
      }
    }
    // Groups of consecutive surfels (neighbours along the Morton curve) share gathers:
    // a surfel takes the irradiance of an earlier one of its group that lies within a few
    // radii and faces the same way, else gathers its own. Groups start at multiples of
    // kBounceGroup in the sorted order, whatever the threads.
    static_assert(kChunkSurfels % kBounceGroup == 0);
    tbb::parallel_for(size_t{0}, (n + kBounceGroup - 1) / kBounceGroup, [&](size_t g) {
      GatherReuse shared(kBounceReuseCos, 1.0f, kBounceGroup);
      GatherStats& st = stats.local();
      for (size_t i = g * kBounceGroup; i < std::min(n, (g + 1) * kBounceGroup); ++i) {
        Surfel& s = batch[i].surfel;
        if (s.materialClass != MaterialClass::kDiffuse || isBlack(s.albedo)) continue;
        Rgb e(0.0f);
        if (const SharedGather* found = shared.find(s.position, s.normal, Vec3f(0.0f), 0)) {
          e = found->value;
          sharedCount.fetch_add(1, std::memory_order_relaxed);
        } else {
          auto gathered = gatherers.local().irradiance(cache, s.position, s.normal, &st);
          if (!gathered.ok()) {
            errors[i] = gathered.status();
            return;
          }
          e = *gathered;
          shared.add({.p = s.position,
                      .n = s.normal,
                      .reach = kBounceReuseRadii * s.radius,
                      .value = e});
        }
        s.radiance += s.albedo * kInvPi * e;
      }
    });
    for (size_t i = 0; i < n; ++i) {
      if (!errors[i].ok()) return errors[i];
      if (auto s = (*writer)->add(batch[i]); !s.ok()) return s;
    }
    done += n;
    if (request.progress) request.progress("bounce", done, surfels);
  }
  for (const GatherStats& s : stats) *gatherStats += s;
  *sharedGathers += sharedCount.load();
  return (*writer)->finish();
}

}  // namespace

std::string bakeTreePath(const ShotDesc& shot, const FrameBakeRequest& request) {
  return framePathStem(shot, request).string() + ".pbgi";
}

absl::StatusOr<FrameBakeReport> bakeShotFrame(const ShotDesc& shot,
                                              const FrameBakeRequest& request,
                                              const Scene* loadedScene) {
  if (absl::Status s = checkShotFrame(shot, request.frame); !s.ok()) return s;
  if (request.bounces < 0 || request.bounces > kMaxBakeBounces) {
    return absl::InvalidArgumentError(
        fmt::format("bounces {}: expected 0 to {}", request.bounces, kMaxBakeBounces));
  }
  if (auto s = request.gather.validate(); !s.ok()) return s;
  if (request.lightSamples < 1) {
    return absl::InvalidArgumentError(
        fmt::format("light samples {}: expected at least 1", request.lightSamples));
  }
  const size_t sortBudget = request.memoryBudget / 2;
  ExternalSortOptions sortOptions;
  sortOptions.memoryBudgetBytes = sortBudget;
  sortOptions.tempDir = request.tempDir;
  sortOptions.threads = request.threads;
  if (auto s = ExternalSurfelSorter::validateOptions(sortOptions); !s.ok()) {
    return absl::InvalidArgumentError(fmt::format(
        "memory budget {} MiB is too small: {}", request.memoryBudget >> 20, s.message()));
  }
  TreeFileWriteOptions treeOptions;
  treeOptions.tree = request.tree;
  treeOptions.tree.seed = shot.render.seed;
  treeOptions.tree.tempDir = request.tempDir;
  if (auto s = TreeWriter::validateOptions(treeOptions.tree); !s.ok()) return s;

  std::optional<tbb::task_arena> arena;
  if (request.threads > 0) arena.emplace(request.threads);
  absl::StatusOr<FrameBakeReport> result;
  auto work = [&] {
    FrameBakeReport report;
    StageClock clock(&report.stages);
    std::optional<FrameScene> loaded;
    if (loadedScene == nullptr) {
      auto frameScene = loadFrameScene(shot, request.frame);
      if (!frameScene.ok()) return result = frameScene.status(), void();
      report.warnings = frameScene->warnings;
      loaded = std::move(*frameScene);
      loadedScene = loaded->scene.get();
      // The importer's and the BVH build's temporaries are freed by now but glibc keeps much
      // of them mapped, and how much depends on heap layout; give them back so that what
      // stays resident is the scene itself, the same from run to run.
      ::malloc_trim(0);
    }
    const Scene& scene = *loadedScene;
    clock.lap("load");

    SurfelSamplingOptions sampling;
    sampling.targetCount = request.points > 0 ? request.points : kDefaultBakePoints;
    sampling.seed = shot.render.seed;
    sampling.frame = request.frame;
    SurfelSamplingStats plan;
    if (auto s = planSurfels(scene, sampling, &plan); !s.ok()) return result = s, void();

    const std::string stem = framePathStem(shot, request).string();
    report.treePath = stem + ".pbgi";
    std::error_code ec;
    std::filesystem::create_directories(std::filesystem::path(report.treePath).parent_path(), ec);
    if (ec) {
      return result = absl::PermissionDeniedError(fmt::format(
                 "cannot create {}: {}",
                 std::filesystem::path(report.treePath).parent_path().string(), ec.message())),
             void();
    }
    bool keepCloud = request.pointCloud == PointCloudMode::kAlways;
    if (request.pointCloud == PointCloudMode::kAuto) {
      keepCloud = plan.surfels * kPointCloudBytesPerPoint <= request.memoryBudget / 4;
      if (!keepCloud) {
        report.warnings.push_back(fmt::format(
            "point cloud not written: OpenVDB would hold {} surfels (about {} MiB) in memory, "
            "over a quarter of the {} MiB budget (--point-cloud always writes it anyway)",
            plan.surfels, plan.surfels * kPointCloudBytesPerPoint >> 20,
            request.memoryBudget >> 20));
      }
    }

    // Sample, shade and sort, a chunk at a time.
    ExternalSurfelSorter sorter(sortOptions);
    const MortonCube cube(scene.bounds());
    std::vector<Surfel> chunk, cloud;
    chunk.reserve(kChunkSurfels);
    uint64_t shadedSoFar = 0;
    SurfelShadingOptions shading;
    shading.lightSamples = request.lightSamples;
    shading.seed = shot.render.seed;
    shading.frame = request.frame;
    auto flush = [&]() -> absl::Status {
      const SurfelShadingStats s = shadeSurfelsDirect(scene, chunk, shadedSoFar, shading);
      report.shading.surfels += s.surfels;
      report.shading.emissive += s.emissive;
      report.shading.discardedSamples += s.discardedSamples;
      report.shading.nonFiniteSurfels += s.nonFiniteSurfels;
      if (keepCloud) cloud.insert(cloud.end(), chunk.begin(), chunk.end());
      for (Surfel& surfel : chunk) {
        // The tree carries the light that gathers are for: reflected light. Emitters are
        // lights that renderers and bounces sample directly, so an emissive surfel sends
        // nothing from the tree (it still occludes); the point cloud keeps its emission.
        if (surfel.materialClass == MaterialClass::kEmissive) surfel.radiance = Rgb(0.0f);
        if (auto st = sorter.add(mortonKey(surfel.position, cube), surfel); !st.ok()) return st;
      }
      shadedSoFar += chunk.size();
      chunk.clear();
      if (request.progress) request.progress("shade", shadedSoFar, plan.surfels);
      return absl::OkStatus();
    };
    absl::Status sampled = sampleSurfels(
        scene, sampling,
        [&](const Surfel& s) -> absl::Status {
          chunk.push_back(s);
          return chunk.size() == kChunkSurfels ? flush() : absl::OkStatus();
        },
        &report.sampling);
    if (sampled.ok() && !chunk.empty()) sampled = flush();
    if (!sampled.ok()) return result = sampled, void();
    clock.lap("sample+shade");

    if (auto s = sorter.finish(); !s.ok()) return result = s, void();
    clock.lap("sort");

    treeOptions.sceneBounds = scene.bounds();
    treeOptions.sceneHash = bakeHash(shot, request);
    treeOptions.bakeInfo = {
        {"shot", shot.path},
        {"frame", std::to_string(request.frame)},
        {"seed", std::to_string(shot.render.seed)},
        {"points", std::to_string(report.sampling.surfels)},
        {"surfel_radius", fmt::format("{:g}", report.sampling.radius)},
        {"light_samples", std::to_string(request.lightSamples)},
        {"bounces", std::to_string(request.bounces)},
        {"pbgi_version", request.pbgiVersion},
    };
    // Without bounces the sorted stream goes straight into the output tree. With K bounces it
    // also goes to a spill (direct light only), tree k - 1 is gathered from for every surfel
    // to light tree k, and only the last one is the output.
    std::optional<SpillFile> sorted;
    if (request.bounces > 0) {
      auto spill = SpillFile::create(request.tempDir, "pbgi-bake-sorted");
      if (!spill.ok()) return result = spill.status(), void();
      sorted.emplace(std::move(*spill));
    }
    auto bounceTreePath = [&](int bounce) {
      return bounce == request.bounces ? report.treePath
                                       : fmt::format("{}.bounce{}.tmp.pbgi", stem, bounce);
    };
    auto writer = TreeFileWriter::create(bounceTreePath(0), treeOptions);
    if (!writer.ok()) return result = writer.status(), void();
    SortedSurfel next;
    uint8_t record[kSurfelRecordBytes];
    uint64_t built = 0;
    while (true) {
      auto more = sorter.next(&next);
      if (!more.ok()) return result = more.status(), void();
      if (!*more) break;
      if (auto s = (*writer)->add(next); !s.ok()) return result = s, void();
      if (sorted) {
        encodeSurfelRecord(next, record);
        if (auto s = sorted->write(record); !s.ok()) return result = s, void();
      }
      if (request.progress && (++built & 0xffff) == 0) {
        request.progress("build", built, report.sampling.surfels);
      }
    }
    report.sort = sorter.stats();
    auto tree = (*writer)->finish();
    if (!tree.ok()) return result = tree.status(), void();
    report.tree = *tree;
    // The sorter merges its runs lazily, as the build pulls surfels: both are in this stage.
    clock.lap("merge+build");

    for (int bounce = 1; bounce <= request.bounces; ++bounce) {
      auto lit = bakeBounce(bounceTreePath(bounce - 1), bounceTreePath(bounce), *sorted,
                            treeOptions, request, report.sampling.surfels, &report.gather,
                            &report.sharedGathers);
      std::error_code removeError;
      std::filesystem::remove(bounceTreePath(bounce - 1), removeError);
      if (!lit.ok()) return result = lit.status(), void();
      report.tree = *lit;
      clock.lap(fmt::format("bounce {}", bounce));
    }
    report.treeFileBytes = std::filesystem::file_size(report.treePath, ec);

    if (keepCloud) {
      report.pointCloudPath = stem + ".vdb";
      SurfelVdbOptions vdb;
      vdb.metadata.shot = shot.name;
      vdb.metadata.frame = request.frame;
      vdb.metadata.seed = shot.render.seed;
      vdb.metadata.pbgiVersion = request.pbgiVersion;
      if (auto s = writeSurfelVdb(report.pointCloudPath, cloud, vdb); !s.ok()) {
        return result = s, void();
      }
      clock.lap("point cloud");
    }
    report.wallSeconds = clock.totalSeconds();
    result = std::move(report);
  };
  if (arena) {
    arena->execute(work);
  } else {
    work();
  }
  return result;
}

}  // namespace pbgi
