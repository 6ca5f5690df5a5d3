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

#include "core/bake/multi_bounce.h"
#include "core/bake/surfel_shading.h"
#include "core/bake/surfel_bounce.h"
#include "core/pbgi/morton.h"
#include "core/pbgi/page_cache.h"
#include "core/render/integrators.h"
#include "core/util/check.h"
#include "core/util/spill_file.h"
#include "core/util/status.h"
#include "formats/mesh/mesh_loader.h"
#include "formats/pbgi/tree_file.h"
#include "formats/scene/frame_scene.h"
#include "formats/vdb/surfel_vdb.h"

namespace pbgi {

namespace {

// Surfels shaded per batch: enough to keep every core busy, small next to any budget.
constexpr size_t kChunkSurfels = 64 * 1024;
// How bounces gather, for the bake hash: 3 is the bidirectional cut with the estimated tail, 4
// each bounce gathering only the light the last one added, later bounces coarser, 5 near
// surfels' disks folded at the receiver's horizon instead of cut there, 6 near disks as exact
// polygons, walls reaching a receiver gathered, light no surfel sends dropped, 7 near disks
// spread to twice their radius, 8 glossy light as wavelets (direct, and the indirect light
// glossy surfels reflect), 9 records gathering for patches of surfels, 10 later bounces' records
// coarser, 11 shut sides not gathered after the first bounce, 12 a cluster's light weighed by
// its shadow ray's descent (what each level's children send over their parent's estimate),
// later bounces' records sparser, 13 the first bounce's descents by normal cones.
constexpr int kBounceRevision = 13;
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
  request.bounceCut = needs.bakeCut;
  request.tree.wavelets.relativeError = needs.bakeWaveletError;
  request.waveletResolution = needs.bakeWaveletResolution;
  request.pbgiVersion = std::string("pbgi ") + PBGI_VERSION;
  return request;
}

namespace {

// What the bake reads besides the shot: each geometry file and what it names (an OBJ's
// material libraries and their textures), the shot's textures and environment maps, as size
// and modification time. Editing a mesh or a texture must bake again, as editing the shot
// does; reading every byte of every file to key the cache would cost as much as a scene load.
std::string inputFilesKey(const ShotDesc& shot) {
  std::vector<std::string> files;
  for (const GeometryDesc& g : shot.geometry) {
    files.push_back(g.file);
    for (std::string& f : referencedFiles(g.file)) files.push_back(std::move(f));
  }
  for (const MaterialDesc& m : shot.materials) {
    if (m.albedoTexture) files.push_back(*m.albedoTexture);
  }
  for (const LightDesc& l : shot.lights) {
    if (!l.file.empty()) files.push_back(l.file);
  }
  std::string key;
  for (const std::string& f : files) {
    std::error_code sizeError, timeError;
    const auto size = std::filesystem::file_size(f, sizeError);
    const auto time = std::filesystem::last_write_time(f, timeError);
    key += sizeError || timeError
               ? fmt::format("|{}:absent", f)
               : fmt::format("|{}:{}:{}", f, size, time.time_since_epoch().count());
  }
  return key;
}

}  // namespace

uint64_t bakeHash(const ShotDesc& shot, const FrameBakeRequest& request) {
  // The bytes the shot was parsed from, not the file as it is now: a farm job renders the
  // text it was submitted with, whatever the file says by the time its bake runs. The files
  // it names are keyed as they are now (inputFilesKey).
  std::string text = shot.source + inputFilesKey(shot);
  const uint64_t points = request.points > 0 ? request.points : kDefaultBakePoints;
  text += fmt::format(
      "|frame={}|points={}|light_samples={}|bounces={}|bounce_cut={}|encoding={}|leaf={}"
      "|page={}|power={}|area={}|exact={}|wavelets={} {} {}|payload={}|version={}",
      request.frame, points, request.lightSamples, request.bounces,
      request.bounces > 0
          ? fmt::format("{} chunk {} tail {} spacing {} revision {}",
                        request.bounceCut.toString(), kBounceChunkSurfels, request.bounceTail,
                        request.bounceSpacing, kBounceRevision)
          : "",
      treeEncodingName(request.tree.encoding), request.tree.build.leafSize, request.tree.pageSize,
      request.tree.powerCentres, request.tree.areaCentres, request.tree.exactNodes,
      request.waveletResolution, request.tree.wavelets.relativeError,
      request.tree.wavelets.maxNodes, kTreePayloadVersion, request.pbgiVersion);
  return XXH3_64bits(text.data(), text.size());
}

namespace {

// How many groups of kBounceChunkSurfels surfels sweep the tree together. Each sweep loads the
// pages its cuts need once, so more groups load fewer pages (Sponza, 4,000,000 surfels under
// 256M, 9,477 pages a tree: 2 groups 2.75 million loads and 803 s, 64 groups 117,091 loads and
// 191 s), but a group's cuts hold what waits on pages below the sweep, and the batch the groups'
// surfels (kBatchBytesPerSurfel each: the spill's record, the surfel, three irradiances). What
// waits grows with the group's receivers: about 30 MB when every surfel gathers (heaptrack,
// Cornell 250k: 36 MB), about 2.6 MB with a record per 16 surfels (peak resident, Sponza 4M).
// The cuts' waiting work and the batch each get a quarter of the budget (the page cache has
// another); at least a group per thread.
size_t groupsSweepingTogether(uint64_t memoryBudget, int receiverSpacing) {
  constexpr uint64_t kEveryoneGathersGroupBytes = uint64_t{32} << 20;
  constexpr uint64_t kBatchBytesPerSurfel = 384;
  const uint64_t spacing = static_cast<uint64_t>(std::max(1, receiverSpacing));
  // 1.5 times the records' share (normals split a record's cell), never more than everyone's.
  const uint64_t groupBytes =
      spacing <= 1 ? kEveryoneGathersGroupBytes : kEveryoneGathersGroupBytes * 3 / (2 * spacing);
  const uint64_t byCuts = memoryBudget / 4 / groupBytes;
  const uint64_t byBatch = memoryBudget / 4 / (kBatchBytesPerSurfel * kBounceChunkSurfels);
  const auto threads = static_cast<uint64_t>(std::max(1, tbb::this_task_arena::max_concurrency()));
  return static_cast<size_t>(std::max(threads, std::min(byCuts, byBatch)));
}

// Bounce `bounce` of the bake (multi_bounce.h): gathers from the tree at `fromPath` through a
// page cache of a quarter of the budget and, when `toPath` is given, writes the tree of the
// light the bounce adds there. Adds the bounce's reflected power to `power`.
absl::StatusOr<TreeWriteResult> bakeBounce(const std::string& fromPath, const std::string* toPath,
                                           BounceRequest bounce, TreeFileWriteOptions options,
                                           const GlossyLeafBaker* glossy,
                                           const FrameBakeRequest& request,
                                           FrameBakeReport* report, Rgb* power) {
  auto from = TreeFile::open(fromPath);
  if (!from.ok()) return from.status();
  // The bounce's batches of cuts each sweep the tree's pages (see bidirectional_cut.h).
  PageCache cache(**from, {.budgetBytes = request.memoryBudget / 4,
                           .policy = PageCachePolicy::kSweeps});
  std::unique_ptr<TreeFileWriter> writer;
  // Glossy surfels add the light they reflect of the tree the bounce gathers from: the light
  // reaching diffuse surfaces by way of glossy ones then bounces on.
  std::optional<GlossyLeafBaker> reflector;
  if (toPath != nullptr && glossy != nullptr) {
    reflector.emplace(*glossy);
    reflector->setIncoming(&cache);
    options.tree.wavelets.leaf = [r = &*reflector](std::span<Surfel> s, uint64_t key) {
      return (*r)(s, key);
    };
  }
  if (toPath != nullptr) {
    auto created = TreeFileWriter::create(*toPath, options);
    if (!created.ok()) return created.status();
    writer = *std::move(created);
    bounce.added = [w = writer.get()](const SortedSurfel& s) { return w->add(s); };
  }
  bounce.from = &cache;
  bounce.receiverSpacing = bounceReceiverSpacing(request.bounceSpacing, bounce.bounce);
  bounce.shutSides = &report->bounceShutSides;
  bounce.groupsTogether = groupsSweepingTogether(request.memoryBudget, bounce.receiverSpacing);
  bounce.batchSurfels = std::max(kBounceBatchSurfels, bounce.groupsTogether * kBounceChunkSurfels);
  if (request.progress) {
    bounce.progress = [&](uint64_t done, uint64_t total) {
      request.progress(fmt::format("bounce {} of {}", bounce.bounce, request.bounces), done, total);
    };
  }
  auto reflected = bounceSurfels(bounce, &report->bounceCut);
  if (!reflected.ok()) return reflected.status();
  *power = *reflected;
  const PageCacheCounters c = cache.counters();
  report->bounceCacheHits += c.hits;
  report->bounceCacheLoads += c.misses;
  report->bounceTreePages += (*from)->container().directory().size();
  if (writer == nullptr) return TreeWriteResult{};
  return writer->finish();
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
  if (auto s = request.bounceCut.validate(); !s.ok()) return s;
  if (!(request.tree.wavelets.relativeError >= 0.0f && request.tree.wavelets.relativeError < 1.0f)) {
    return absl::InvalidArgumentError(fmt::format(
        "wavelet error {}: expected a fraction in [0, 1)", request.tree.wavelets.relativeError));
  }
  if (request.waveletResolution < 2 || request.waveletResolution > kMaxMicrobufferResolution ||
      (request.waveletResolution & (request.waveletResolution - 1)) != 0) {
    return absl::InvalidArgumentError(
        fmt::format("wavelet resolution {}: expected a power of two from 2 to {}",
                    request.waveletResolution, kMaxMicrobufferResolution));
  }
  if (request.bounceSpacing < 1 || request.bounceSpacing > kMaxBounceSpacing) {
    return absl::InvalidArgumentError(fmt::format(
        "bounce spacing {}: expected 1 to {} surfels a record", request.bounceSpacing,
        kMaxBounceSpacing));
  }
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
    // Glossy and refractive light the SH cannot hold goes into the direct-light tree and the
    // final one as wavelets (GlossyLeafBaker); a scene without such materials bakes none.
    GlossyBakeOptions glossyOptions;
    glossyOptions.resolution = request.waveletResolution;
    glossyOptions.seed = shot.render.seed;
    glossyOptions.frame = request.frame;
    // The direct-light tree of a bake with bounces leaves the specular chains (caustics) to the
    // final tree: they cost most and only light what bounces after them.
    GlossyBakeOptions firstTree = glossyOptions;
    firstTree.specularChains = request.bounces == 0;
    const GlossyLeafBaker glossyBaker(scene, firstTree);
    GlossyBakeOptions reflectOnly = glossyOptions;
    reflectOnly.directLight = false;
    const GlossyLeafBaker bounceReflector(scene, reflectOnly);
    if (glossyBaker.anyWavelets()) {
      TreeWriteOptions withWavelets = treeOptions.tree;
      withWavelets.wavelets.leaf = [](std::span<Surfel>, uint64_t) { return WaveletRadiance(); };
      if (auto s = TreeWriter::validateOptions(withWavelets); !s.ok()) return result = s, void();
    }

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
        if (surfel.materialClass == MaterialClass::kEmissive) {
          surfel.radiance = surfel.backRadiance = Rgb(0.0f);
        }
        if (auto st = sorter.add(mortonKey(surfel.position, cube), surfel); !st.ok()) return st;
      }
      shadedSoFar += chunk.size();
      chunk.clear();
      if (request.progress) request.progress("sample and shade surfels", shadedSoFar, plan.surfels);
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
        {"bounce_spacing", std::to_string(request.bounceSpacing)},
        {"pbgi_version", request.pbgiVersion},
    };
    // Without bounces the sorted stream goes straight into the output tree. With K bounces it
    // goes to tree 0 and to a spill (direct light only), and the bounces below make the
    // output from them.
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
    TreeFileWriteOptions glossyTreeOptions = treeOptions;
    if (glossyBaker.anyWavelets()) {
      glossyTreeOptions.tree.wavelets.leaf = [&glossyBaker](std::span<Surfel> s, uint64_t key) {
        return glossyBaker(s, key);
      };
    }
    auto writer = TreeFileWriter::create(bounceTreePath(0), glossyTreeOptions);
    if (!writer.ok()) return result = writer.status(), void();
    SortedSurfel next;
    uint8_t record[kSurfelRecordBytes];
    uint64_t built = 0;
    double directPower[3] = {0.0, 0.0, 0.0};  // what the reflecting surfels send of direct light
    while (true) {
      auto more = sorter.next(&next);
      if (!more.ok()) return result = more.status(), void();
      if (!*more) break;
      if (auto s = (*writer)->add(next); !s.ok()) return result = s, void();
      if (sorted) {
        encodeSurfelRecord(next, record);
        if (auto s = sorted->write(record); !s.ok()) return result = s, void();
        if (reflectsLight(next.surfel)) {
          const Rgb both = next.surfel.radiance + next.surfel.backRadiance;
          for (int c = 0; c < 3; ++c) directPower[c] += next.surfel.area() * both[c];
        }
      }
      if (request.progress && (++built & 0xffff) == 0) {
        request.progress("merge the sorted runs and build the tree", built, report.sampling.surfels);
      }
    }
    if (request.progress) {
      request.progress("merge the sorted runs and build the tree", built, report.sampling.surfels);
    }
    report.sort = sorter.stats();
    auto tree = (*writer)->finish();
    if (!tree.ok()) return result = tree.status(), void();
    report.tree = *tree;
    // The sorter merges its runs lazily, as the build pulls surfels: both are in this stage.
    clock.lap("merge+build");

    // Bounce k gathers from tree k - 1 (the light bounce k - 1 added; the direct light's for
    // k = 1) and writes tree k of the light it adds, except the last, which only gathers: the
    // final tree (direct light and every bounce's, with the estimated tail or without one) is
    // written after it (core/bake/multi_bounce.h).
    report.bouncePower.push_back(Rgb(static_cast<float>(directPower[0]),
                                     static_cast<float>(directPower[1]),
                                     static_cast<float>(directPower[2])));
    std::vector<SpillFile> irradiance;  // the last two bounces' irradiance per surfel
    for (int bounce = 1; bounce <= request.bounces; ++bounce) {
      auto spill = SpillFile::create(request.tempDir, "pbgi-bake-irradiance");
      if (!spill.ok()) return result = spill.status(), void();
      if (irradiance.size() == 2) irradiance.erase(irradiance.begin());
      irradiance.push_back(std::move(*spill));
      const bool last = bounce == request.bounces;
      const std::string to = bounceTreePath(bounce);
      Rgb power(0.0f);
      auto lit = bakeBounce(bounceTreePath(bounce - 1), last ? nullptr : &to,
                            {.sorted = &*sorted,
                             .previous = irradiance.size() == 2 ? &irradiance[0] : nullptr,
                             .next = &irradiance.back(),
                             .scene = &scene,
                             .cut = bounceCutOptions(request.bounceCut, bounce),
                             .seed = shot.render.seed,
                             .frame = request.frame,
                             .bounce = bounce,
                             .surfels = report.sampling.surfels},
                            treeOptions, glossyBaker.anyWavelets() ? &bounceReflector : nullptr,
                            request, &report, &power);
      std::error_code removeError;
      std::filesystem::remove(bounceTreePath(bounce - 1), removeError);
      if (!lit.ok()) return result = lit.status(), void();
      report.bouncePower.push_back(power);
      if (!last) report.tree = *lit;
      clock.lap(fmt::format("bounce {}", bounce));
    }
    if (request.bounces > 0) {
      const auto power = [&](int k) {
        const Rgb& p = report.bouncePower[static_cast<size_t>(k)];
        return std::array<double, 3>{p.x, p.y, p.z};
      };
      report.tail = request.bounceTail
                        ? tailFactor(power(request.bounces), power(request.bounces - 1))
                        : Rgb(0.0f);
      auto writeFinal = [&](const TreeFileWriteOptions& options) -> absl::StatusOr<TreeWriteResult> {
        PBGI_ASSIGN_OR_RETURN(std::unique_ptr<TreeFileWriter> writer,
                              TreeFileWriter::create(report.treePath, options));
        PBGI_RETURN_IF_ERROR(finalLight(
            *sorted, irradiance.back(), irradiance.size() == 2 ? &irradiance[0] : nullptr,
            report.tail, report.sampling.surfels,
            [w = writer.get()](const SortedSurfel& s) { return w->add(s); }));
        return writer->finish();
      };
      // Written first without wavelets: the light the glossy surfels then gather (below).
      auto final = writeFinal(glossyBaker.anyWavelets() ? treeOptions : glossyTreeOptions);
      if (!final.ok()) return result = final.status(), void();
      clock.lap("final tree");
      if (glossyBaker.anyWavelets()) {
        // Glossy surfels reflect the indirect light too: that of the tree just written (every
        // bounce's light, diffuse surfels' and what glossy ones reflected of each bounce),
        // gathered at each glossy leaf; the final tree is written again with it, their direct
        // light and mirrors' and glass's specular chains.
        final = [&]() -> absl::StatusOr<TreeWriteResult> {
          const std::string lit = stem + ".glossy.tmp.pbgi";
          std::error_code renameError;
          std::filesystem::rename(report.treePath, lit, renameError);
          if (renameError) {
            return absl::InternalError(fmt::format("cannot rename {} to {}: {}", report.treePath,
                                                   lit, renameError.message()));
          }
          absl::StatusOr<TreeWriteResult> written = [&]() -> absl::StatusOr<TreeWriteResult> {
            PBGI_ASSIGN_OR_RETURN(std::unique_ptr<TreeFile> from, TreeFile::open(lit));
            PageCache cache(*from, {.budgetBytes = request.memoryBudget / 4,
                                    .policy = PageCachePolicy::kLeastRecent});
            GlossyLeafBaker indirect(scene, glossyOptions);
            indirect.setIncoming(&cache);
            TreeFileWriteOptions options = treeOptions;
            options.tree.wavelets.leaf = [&indirect](std::span<Surfel> s, uint64_t key) {
              return indirect(s, key);
            };
            return writeFinal(options);
          }();
          std::error_code removeError;
          std::filesystem::remove(lit, removeError);
          return written;
        }();
        if (!final.ok()) return result = final.status(), void();
        clock.lap("glossy indirect");
      }
      report.tree = *final;
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
