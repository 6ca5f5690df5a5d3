#include "services/bake/frame_bake.h"

#include <malloc.h>

#include <atomic>
#include <filesystem>
#include <functional>
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
// How bounces gather, for the bake hash: raised whenever a change makes the bounces' light
// differ, so that no bake made before it is reused (the commit log says what each changed).
constexpr int kBounceRevision = 20;
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
  const TreeSettings needs = tree->treeSettings(shot.render);
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

// Cancelled once the request's cancel flag is set (checked between chunks of every stage).
absl::Status bakeCancelled(const FrameBakeRequest& request) {
  if (request.cancel && request.cancel->load(std::memory_order_relaxed)) {
    return absl::CancelledError("the bake was cancelled");
  }
  return absl::OkStatus();
}

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
      request.bounces > 0 ? fmt::format("{} chunk {} tail {} spacing {} revision {}",
                                        request.bounceCut.toString(), kBounceChunkSurfels,
                                        request.bounceTail, request.bounceSpacing, kBounceRevision)
                          : "",
      treeEncodingName(request.tree.encoding), request.tree.build.leafSize, request.tree.pageSize,
      request.tree.powerCentres, request.tree.areaCentres, request.tree.exactNodes,
      request.waveletResolution, request.tree.wavelets.relativeError,
      request.tree.wavelets.maxNodes, kTreePayloadVersion, request.pbgiVersion);
  // Only when set, so that bakes made before the setting keep their hash.
  if (request.glossyPairThreshold > 0.0f) {
    text += fmt::format("|glossy_pairs={}", request.glossyPairThreshold);
  }
  return XXH3_64bits(text.data(), text.size());
}

namespace {

// How many groups of kBounceChunkSurfels surfels sweep the tree together. Each sweep loads the
// pages its cuts need once, so more groups load fewer pages, but a group's cuts hold what waits
// on pages below the sweep, and the batch holds the groups' surfels (kBatchBytesPerSurfel each:
// the spill's record, the surfel, three irradiances). What waits grows with the group's
// receivers: about 32 MiB when every surfel gathers, about a sixteenth of that with a record per
// 16 surfels (measured in the README's "Baking"). The cuts' waiting work and the
// batch each get a quarter of the budget (the page cache has another); at least a group per
// thread.
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
    if (request.glossyPairThreshold > 0.0f) {
      options.tree.wavelets.leaves = [r = &*reflector, report](std::span<WaveletLeafJob> jobs) {
        r->bakeLeaves(jobs, &report->glossyPairs);
      };
    }
  }
  if (toPath != nullptr) {
    auto created = TreeFileWriter::create(*toPath, options);
    if (!created.ok()) return created.status();
    writer = *std::move(created);
    bounce.added = [w = writer.get()](const SortedSurfel& s) { return w->add(s); };
  }
  bounce.from = &cache;
  bounce.cancel = request.cancel;
  bounce.receiverSpacing = bounceReceiverSpacing(request.bounceSpacing, bounce.bounce);
  bounce.shutSides = &report->bounceShutSides;
  bounce.groupsTogether = groupsSweepingTogether(request.memoryBudget, bounce.receiverSpacing);
  bounce.batchSurfels = std::max(kBounceBatchSurfels, bounce.groupsTogether * kBounceChunkSurfels);
  if (request.progress) {
    bounce.progress = [&](uint64_t done, uint64_t total) {
      request.progress(fmt::format("bounce {} of {}", bounce.bounce, request.bounces), done, total);
    };
  }
  auto reflected = runBounce(bounce, &report->bounceCut);
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

namespace {

// InvalidArgument naming the field for a request no bake can serve.
absl::Status validateBakeRequest(const FrameBakeRequest& request) {
  if (request.bounces < 0 || request.bounces > kMaxBakeBounces) {
    return absl::InvalidArgumentError(
        fmt::format("bounces {}: expected 0 to {}", request.bounces, kMaxBakeBounces));
  }
  PBGI_RETURN_IF_ERROR(request.bounceCut.validate());
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
  if (!(request.glossyPairThreshold >= 0.0f && request.glossyPairThreshold <= 4.0f * kPi)) {
    return absl::InvalidArgumentError(fmt::format(
        "glossy pairs {}: expected a solid angle from 0 to 4 pi sr", request.glossyPairThreshold));
  }
  return absl::OkStatus();
}

// The sort's options: half the budget. InvalidArgument when the budget cannot hold a run.
absl::StatusOr<ExternalSortOptions> bakeSortOptions(const FrameBakeRequest& request) {
  ExternalSortOptions options;
  options.memoryBudgetBytes = request.memoryBudget / 2;
  options.tempDir = request.tempDir;
  options.threads = request.threads;
  if (auto s = ExternalSurfelSorter::validateOptions(options); !s.ok()) {
    return absl::InvalidArgumentError(fmt::format(
        "memory budget {} MiB is too small: {}", request.memoryBudget >> 20, s.message()));
  }
  return options;
}

// Glossy and refractive light the SH cannot hold goes into the direct-light tree and the final
// one as wavelets; a scene without such materials bakes none.
struct GlossyBakers {
  GlossyBakers(const Scene& scene, const ShotDesc& shot, const FrameBakeRequest& request)
      : options(glossyOptions(shot, request)),
        direct(scene, directTreeOptions(options, request)),
        reflector(scene, reflectOnly(options)) {}
  bool any() const { return direct.anyWavelets(); }

  GlossyBakeOptions options;  // the final tree's: direct light, reflection and specular chains
  // The direct-light tree of a bake with bounces leaves the specular chains (caustics) to the
  // final tree: they cost most and only light what bounces after them.
  GlossyLeafBaker direct;
  GlossyLeafBaker reflector;  // a bounce's: the light glossy surfels reflect of the last tree

 private:
  static GlossyBakeOptions glossyOptions(const ShotDesc& shot, const FrameBakeRequest& request) {
    GlossyBakeOptions o;
    o.resolution = request.waveletResolution;
    o.pairReceiverSolidAngle = request.glossyPairThreshold;
    o.seed = shot.render.seed;
    o.frame = request.frame;
    return o;
  }
  static GlossyBakeOptions directTreeOptions(GlossyBakeOptions o, const FrameBakeRequest& r) {
    o.specularChains = r.bounces == 0;
    return o;
  }
  static GlossyBakeOptions reflectOnly(GlossyBakeOptions o) {
    o.directLight = false;
    return o;
  }
};

// Whether to write the OpenVDB point cloud: always, never, or (auto) when OpenVDB's copy fits
// a quarter of the budget, warning when it does not.
bool keepPointCloud(const FrameBakeRequest& request, uint64_t surfels,
                    std::vector<std::string>* warnings) {
  if (request.pointCloud != PointCloudMode::kAuto) {
    return request.pointCloud == PointCloudMode::kAlways;
  }
  const uint64_t bytes = surfels * kPointCloudBytesPerPoint;
  if (bytes <= request.memoryBudget / 4) return true;
  warnings->push_back(fmt::format(
      "point cloud not written: OpenVDB would hold {} surfels (about {} MiB) in memory, over a "
      "quarter of the {} MiB budget (--point-cloud always writes it anyway)",
      surfels, bytes >> 20, request.memoryBudget >> 20));
  return false;
}

// Stage "sample+shade": samples `plan.surfels` surfels, shades their direct light a chunk at a
// time and adds them to `sorter` by Morton key. Returns the shaded surfels when `keepCloud` (for
// the point cloud), else none.
absl::StatusOr<std::vector<Surfel>> sampleAndShade(const Scene& scene, const ShotDesc& shot,
                                                   const FrameBakeRequest& request,
                                                   const SurfelSamplingOptions& sampling,
                                                   uint64_t planned, bool keepCloud,
                                                   ExternalSurfelSorter& sorter,
                                                   FrameBakeReport* report) {
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
    report->shading.surfels += s.surfels;
    report->shading.emissive += s.emissive;
    report->shading.discardedSamples += s.discardedSamples;
    report->shading.nonFiniteSurfels += s.nonFiniteSurfels;
    if (keepCloud) cloud.insert(cloud.end(), chunk.begin(), chunk.end());
    for (Surfel& surfel : chunk) {
      // The tree carries the light that gathers are for: reflected light. Emitters are lights
      // that renderers and bounces sample directly, so an emissive surfel sends nothing from
      // the tree (it still occludes); the point cloud keeps its emission.
      if (surfel.materialClass == MaterialClass::kEmissive) {
        surfel.radiance = surfel.backRadiance = Rgb(0.0f);
      }
      PBGI_RETURN_IF_ERROR(sorter.add(mortonKey(surfel.position, cube), surfel));
    }
    shadedSoFar += chunk.size();
    chunk.clear();
    if (request.progress) request.progress("sample and shade surfels", shadedSoFar, planned);
    return bakeCancelled(request);
  };
  absl::Status sampled = sampleSurfels(
      scene, sampling,
      [&](const Surfel& s) -> absl::Status {
        chunk.push_back(s);
        return chunk.size() == kChunkSurfels ? flush() : absl::OkStatus();
      },
      &report->sampling);
  if (sampled.ok() && !chunk.empty()) sampled = flush();
  if (!sampled.ok()) return sampled;
  return cloud;
}

// What the tree's header says of the bake.
std::vector<std::pair<std::string, std::string>> bakeInfo(const ShotDesc& shot,
                                                          const FrameBakeRequest& request,
                                                          const SurfelSamplingStats& sampling) {
  return {
      {"shot", shot.path},
      {"frame", std::to_string(request.frame)},
      {"seed", std::to_string(shot.render.seed)},
      {"points", std::to_string(sampling.surfels)},
      {"surfel_radius", fmt::format("{:g}", sampling.radius)},
      {"light_samples", std::to_string(request.lightSamples)},
      {"bounces", std::to_string(request.bounces)},
      {"bounce_spacing", std::to_string(request.bounceSpacing)},
      {"pbgi_version", request.pbgiVersion},
  };
}

struct DirectTree {
  TreeWriteResult tree;
  Rgb reflectedPower{0.0f};  // what the reflecting surfels send of the direct light
};

// Stage "merge+build": merges the sorter's runs into the direct light's tree at `path` (the
// sorter merges lazily, as the build pulls surfels) and, when `sorted` is given, spills the
// sorted surfels there for the bounces.
absl::StatusOr<DirectTree> buildDirectTree(ExternalSurfelSorter& sorter, const std::string& path,
                                           const TreeFileWriteOptions& options,
                                           const FrameBakeRequest& request, uint64_t surfels,
                                           SpillFile* sorted) {
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<TreeFileWriter> writer,
                        TreeFileWriter::create(path, options));
  SortedSurfel next;
  uint8_t record[kSurfelRecordBytes];
  uint64_t built = 0;
  double power[3] = {0.0, 0.0, 0.0};
  constexpr const char* kStage = "merge the sorted runs and build the tree";
  while (true) {
    PBGI_ASSIGN_OR_RETURN(const bool more, sorter.next(&next));
    if (!more) break;
    PBGI_RETURN_IF_ERROR(writer->add(next));
    if (sorted != nullptr) {
      encodeSurfelRecord(next, record);
      PBGI_RETURN_IF_ERROR(sorted->write(record));
      if (reflectsLight(next.surfel)) {
        const Rgb both = next.surfel.radiance + next.surfel.backRadiance;
        for (int c = 0; c < 3; ++c) power[c] += next.surfel.area() * both[c];
      }
    }
    if ((++built & 0xffff) == 0) {
      if (request.progress) request.progress(kStage, built, surfels);
      PBGI_RETURN_IF_ERROR(bakeCancelled(request));
    }
  }
  if (request.progress) request.progress(kStage, built, surfels);
  PBGI_ASSIGN_OR_RETURN(const TreeWriteResult tree, writer->finish());
  return DirectTree{
      .tree = tree,
      .reflectedPower = Rgb(static_cast<float>(power[0]), static_cast<float>(power[1]),
                            static_cast<float>(power[2]))};
}

// What the bounces leave for the final tree: the last bounces' irradiance per surfel (so far),
// which the tail is estimated from.
struct BouncedLight {
  static constexpr size_t kKept = kTailBounces;
  std::vector<SpillFile> irradiance;  // the last bounce's last
  SpillFile* beforeLast() {
    return irradiance.size() >= 2 ? &irradiance[irradiance.size() - 2] : nullptr;
  }
  std::vector<SpillFile*> kept() {
    std::vector<SpillFile*> out;
    for (SpillFile& f : irradiance) out.push_back(&f);
    return out;
  }
};

// Stages "bounce k": bounce k gathers from tree k - 1 (the light bounce k - 1 added; the direct
// light's for k = 1) and writes tree k of the light it adds, except the last, which only
// gathers (core/bake/multi_bounce.h). `treePath(k)` names tree k; each is removed once read.
absl::StatusOr<BouncedLight> bounceLight(const Scene& scene, const ShotDesc& shot,
                                         const FrameBakeRequest& request, SpillFile& sorted,
                                         const std::function<std::string(int)>& treePath,
                                         const TreeFileWriteOptions& treeOptions,
                                         const GlossyBakers& glossy, StageClock& clock,
                                         FrameBakeReport* report) {
  BouncedLight light;
  for (int bounce = 1; bounce <= request.bounces; ++bounce) {
    PBGI_ASSIGN_OR_RETURN(SpillFile spill,
                          SpillFile::create(request.tempDir, "pbgi-bake-irradiance"));
    if (light.irradiance.size() == BouncedLight::kKept) {
      light.irradiance.erase(light.irradiance.begin());
    }
    light.irradiance.push_back(std::move(spill));
    const bool last = bounce == request.bounces;
    const std::string to = treePath(bounce);
    Rgb power(0.0f);
    auto lit = bakeBounce(treePath(bounce - 1), last ? nullptr : &to,
                          {.sorted = &sorted,
                           .previous = light.beforeLast(),
                           .next = &light.irradiance.back(),
                           .scene = &scene,
                           .cut = bounceCutOptions(request.bounceCut, bounce),
                           .seed = shot.render.seed,
                           .frame = request.frame,
                           .bounce = bounce,
                           .surfels = report->sampling.surfels},
                          treeOptions, glossy.any() ? &glossy.reflector : nullptr, request, report,
                          &power);
    std::error_code removeError;
    std::filesystem::remove(treePath(bounce - 1), removeError);
    if (!lit.ok()) return lit.status();
    report->bouncePower.push_back(power);
    if (!last) report->tree = *lit;
    clock.lap(fmt::format("bounce {}", bounce));
  }
  return light;
}

// Writes the final tree at `path`: the direct light and every bounce's, with the estimated tail
// (`tail`; zero for none), through `options` (which may add glossy leaves' wavelets).
absl::StatusOr<TreeWriteResult> writeFinalTree(const std::string& path,
                                               const TreeFileWriteOptions& options,
                                               SpillFile& sorted, BouncedLight& light,
                                               const Rgb& tail, uint64_t surfels) {
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<TreeFileWriter> writer,
                        TreeFileWriter::create(path, options));
  PBGI_RETURN_IF_ERROR(finalLight(sorted, light.kept(), tail, surfels,
                                  [w = writer.get()](const SortedSurfel& s) { return w->add(s); }));
  return writer->finish();
}

// Stage "glossy indirect": glossy surfels reflect the indirect light too, that of the final tree
// at `path` (every bounce's light, diffuse surfels' and what glossy ones reflected of each
// bounce), gathered at each glossy leaf; the final tree is written again with it, their direct
// light and mirrors' and glass's specular chains. `stem` names the temporary copy.
absl::StatusOr<TreeWriteResult> addGlossyIndirect(
    const Scene& scene, const std::string& path, const std::string& stem,
    TreeFileWriteOptions options, const GlossyBakers& glossy, const FrameBakeRequest& request,
    SpillFile& sorted, BouncedLight& light, const Rgb& tail, uint64_t surfels,
    PairGatherStats* pairs) {
  const std::string lit = stem + ".glossy.tmp.pbgi";
  std::error_code renameError;
  std::filesystem::rename(path, lit, renameError);
  if (renameError) {
    return absl::InternalError(
        fmt::format("cannot rename {} to {}: {}", path, lit, renameError.message()));
  }
  absl::StatusOr<TreeWriteResult> written = [&]() -> absl::StatusOr<TreeWriteResult> {
    PBGI_ASSIGN_OR_RETURN(std::unique_ptr<TreeFile> from, TreeFile::open(lit));
    PageCache cache(
        *from, {.budgetBytes = request.memoryBudget / 4, .policy = PageCachePolicy::kLeastRecent});
    GlossyLeafBaker indirect(scene, glossy.options);
    indirect.setIncoming(&cache);
    options.tree.wavelets.leaf = [&indirect](std::span<Surfel> s, uint64_t key) {
      return indirect(s, key);
    };
    if (request.glossyPairThreshold > 0.0f) {
      options.tree.wavelets.leaves = [&indirect, pairs](std::span<WaveletLeafJob> jobs) {
        indirect.bakeLeaves(jobs, pairs);
      };
    }
    return writeFinalTree(path, options, sorted, light, tail, surfels);
  }();
  std::error_code removeError;
  std::filesystem::remove(lit, removeError);
  return written;
}

// Stage "point cloud": the shaded surfels as an OpenVDB point cloud at `path`.
absl::Status writePointCloud(const std::string& path, const std::vector<Surfel>& cloud,
                             const ShotDesc& shot, const FrameBakeRequest& request) {
  SurfelVdbOptions vdb;
  vdb.metadata.shot = shot.name;
  vdb.metadata.frame = request.frame;
  vdb.metadata.seed = shot.render.seed;
  vdb.metadata.pbgiVersion = request.pbgiVersion;
  return writeSurfelVdb(path, cloud, vdb);
}

// The bake's stages in order, in the calling thread's arena: load, sample+shade, sort,
// merge+build, each bounce, the final tree (and its glossy indirect light), the point cloud.
absl::StatusOr<FrameBakeReport> runBake(const ShotDesc& shot, const FrameBakeRequest& request,
                                        const Scene* loadedScene,
                                        const ExternalSortOptions& sortOptions,
                                        const TreeFileWriteOptions& baseTreeOptions) {
  FrameBakeReport report;
  StageClock clock(&report.stages);
  std::optional<FrameScene> loaded;
  if (loadedScene == nullptr) {
    PBGI_ASSIGN_OR_RETURN(FrameScene frameScene, loadFrameScene(shot, request.frame));
    report.warnings = frameScene.warnings;
    loaded = std::move(frameScene);
    loadedScene = loaded->scene.get();
    // The importer's and the BVH build's temporaries are freed by now but glibc keeps much of
    // them mapped, and how much depends on heap layout; give them back so that what stays
    // resident is the scene itself, the same from run to run.
    ::malloc_trim(0);
  }
  const Scene& scene = *loadedScene;
  clock.lap("load");
  const GlossyBakers glossy(scene, shot, request);
  if (glossy.any()) {
    TreeWriteOptions withWavelets = baseTreeOptions.tree;
    withWavelets.wavelets.leaf = [](std::span<Surfel>, uint64_t) { return WaveletRadiance(); };
    PBGI_RETURN_IF_ERROR(TreeWriter::validateOptions(withWavelets));
  }
  SurfelSamplingOptions sampling;
  sampling.targetCount = request.points > 0 ? request.points : kDefaultBakePoints;
  sampling.seed = shot.render.seed;
  sampling.frame = request.frame;
  SurfelSamplingStats plan;
  PBGI_RETURN_IF_ERROR(planSurfels(scene, sampling, &plan));

  const std::string stem = framePathStem(shot, request).string();
  report.treePath = stem + ".pbgi";
  const std::filesystem::path folder = std::filesystem::path(report.treePath).parent_path();
  std::error_code ec;
  std::filesystem::create_directories(folder, ec);
  if (ec) {
    return absl::PermissionDeniedError(
        fmt::format("cannot create {}: {}", folder.string(), ec.message()));
  }
  const bool keepCloud = keepPointCloud(request, plan.surfels, &report.warnings);

  ExternalSurfelSorter sorter(sortOptions);
  PBGI_ASSIGN_OR_RETURN(
      const std::vector<Surfel> cloud,
      sampleAndShade(scene, shot, request, sampling, plan.surfels, keepCloud, sorter, &report));
  clock.lap("sample+shade");
  PBGI_RETURN_IF_ERROR(sorter.finish());
  clock.lap("sort");

  TreeFileWriteOptions treeOptions = baseTreeOptions;
  treeOptions.sceneBounds = scene.bounds();
  treeOptions.sceneHash = bakeHash(shot, request);
  treeOptions.bakeInfo = bakeInfo(shot, request, report.sampling);
  TreeFileWriteOptions glossyTreeOptions = treeOptions;
  if (glossy.any()) {
    glossyTreeOptions.tree.wavelets.leaf = [&glossy](std::span<Surfel> s, uint64_t key) {
      return glossy.direct(s, key);
    };
  }
  // Without bounces the sorted stream goes straight into the output tree. With K bounces it
  // goes to tree 0 and to a spill (direct light only), and the bounces make the output from
  // them.
  std::optional<SpillFile> sorted;
  if (request.bounces > 0) {
    PBGI_ASSIGN_OR_RETURN(SpillFile spill, SpillFile::create(request.tempDir, "pbgi-bake-sorted"));
    sorted.emplace(std::move(spill));
  }
  const auto treePath = [&](int bounce) {
    return bounce == request.bounces ? report.treePath
                                     : fmt::format("{}.bounce{}.tmp.pbgi", stem, bounce);
  };
  PBGI_ASSIGN_OR_RETURN(const DirectTree direct,
                        buildDirectTree(sorter, treePath(0), glossyTreeOptions, request,
                                        report.sampling.surfels, sorted ? &*sorted : nullptr));
  report.sort = sorter.stats();
  report.tree = direct.tree;
  clock.lap("merge+build");

  report.bouncePower.push_back(direct.reflectedPower);
  if (request.bounces > 0) {
    PBGI_ASSIGN_OR_RETURN(BouncedLight light, bounceLight(scene, shot, request, *sorted, treePath,
                                                          treeOptions, glossy, clock, &report));
    std::vector<std::array<double, 3>> power;
    for (const Rgb& p : report.bouncePower) power.push_back({p.x, p.y, p.z});
    report.tail = request.bounceTail ? tailFactor(power, largestBounceRatio(scene)) : Rgb(0.0f);
    const uint64_t surfels = report.sampling.surfels;
    // Written first without wavelets when glossy surfels then gather from it.
    PBGI_ASSIGN_OR_RETURN(
        report.tree, writeFinalTree(report.treePath, glossy.any() ? treeOptions : glossyTreeOptions,
                                    *sorted, light, report.tail, surfels));
    clock.lap("final tree");
    if (glossy.any()) {
      PBGI_ASSIGN_OR_RETURN(
          report.tree,
          addGlossyIndirect(scene, report.treePath, stem, treeOptions, glossy, request, *sorted,
                            light, report.tail, surfels, &report.glossyPairs));
      clock.lap("glossy indirect");
    }
  }
  report.treeFileBytes = std::filesystem::file_size(report.treePath, ec);

  if (keepCloud) {
    report.pointCloudPath = stem + ".vdb";
    PBGI_RETURN_IF_ERROR(writePointCloud(report.pointCloudPath, cloud, shot, request));
    clock.lap("point cloud");
  }
  report.wallSeconds = clock.totalSeconds();
  return report;
}

}  // namespace

absl::StatusOr<FrameBakeReport> bakeShotFrame(const ShotDesc& shot, const FrameBakeRequest& request,
                                              const Scene* loadedScene) {
  PBGI_RETURN_IF_ERROR(checkShotFrame(shot, request.frame));
  PBGI_RETURN_IF_ERROR(validateBakeRequest(request));
  PBGI_ASSIGN_OR_RETURN(const ExternalSortOptions sortOptions, bakeSortOptions(request));
  TreeFileWriteOptions treeOptions;
  treeOptions.tree = request.tree;
  treeOptions.tree.seed = shot.render.seed;
  treeOptions.tree.tempDir = request.tempDir;
  PBGI_RETURN_IF_ERROR(TreeWriter::validateOptions(treeOptions.tree));
  const auto bake = [&] { return runBake(shot, request, loadedScene, sortOptions, treeOptions); };
  if (request.threads <= 0) return bake();
  tbb::task_arena arena(request.threads);
  return arena.execute(bake);
}

}  // namespace pbgi
