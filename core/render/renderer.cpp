#include "core/render/renderer.h"

#include <algorithm>
#include <atomic>
#include <mutex>

#include <fmt/format.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "core/render/filter.h"
#include "core/sampling/rng.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

enum Channel : int {
  kR, kG, kB, kA,
  kAlbedoR, kAlbedoG, kAlbedoB,
  kNormalX, kNormalY, kNormalZ,
  kDepth,
  kDirectR, kDirectG, kDirectB,
  kIndirectR, kIndirectG, kIndirectB,
  kChannelCount
};

// Interleaves the bits of x and y (16 bits each).
uint32_t morton2(uint32_t x, uint32_t y) {
  auto spread = [](uint32_t v) {
    v &= 0xffff;
    v = (v | (v << 8)) & 0x00ff00ff;
    v = (v | (v << 4)) & 0x0f0f0f0f;
    v = (v | (v << 2)) & 0x33333333;
    v = (v | (v << 1)) & 0x55555555;
    return v;
  };
  return spread(x) | (spread(y) << 1);
}

void put(Image& image, int x, int y, int c, const Vec3f& v) {
  image.at(x, y, c) = v.x;
  image.at(x, y, c + 1) = v.y;
  image.at(x, y, c + 2) = v.z;
}

// The cells of an nx x ny grid, in Morton (Z) order of their positions.
std::vector<std::pair<int, int>> mortonOrder(int nx, int ny) {
  std::vector<std::pair<uint32_t, std::pair<int, int>>> keyed;
  keyed.reserve(static_cast<size_t>(nx) * ny);
  for (int y = 0; y < ny; ++y) {
    for (int x = 0; x < nx; ++x) keyed.push_back({morton2(x, y), {x, y}});
  }
  std::sort(keyed.begin(), keyed.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<std::pair<int, int>> cells;
  cells.reserve(keyed.size());
  for (const auto& [key, xy] : keyed) cells.push_back(xy);
  return cells;
}

}  // namespace

const std::vector<std::string>& frameChannels() {
  static const std::vector<std::string> channels = {
      "R", "G", "B", "A",
      "albedo.R", "albedo.G", "albedo.B",
      "normal.X", "normal.Y", "normal.Z",
      "depth.Z",
      "direct.R", "direct.G", "direct.B",
      "indirect.R", "indirect.G", "indirect.B"};
  return channels;
}

std::vector<TileRect> makeTiles(const TileRect& region, int tileSize) {
  PBGI_CHECK_GT(tileSize, 0);
  const int nx = (region.width() + tileSize - 1) / tileSize;
  const int ny = (region.height() + tileSize - 1) / tileSize;
  std::vector<TileRect> tiles;
  tiles.reserve(static_cast<size_t>(std::max(nx, 0)) * std::max(ny, 0));
  for (const auto& [tx, ty] : mortonOrder(nx, ny)) {
    tiles.push_back({region.x0 + tx * tileSize, region.y0 + ty * tileSize,
                     std::min(region.x1, region.x0 + (tx + 1) * tileSize),
                     std::min(region.y1, region.y0 + (ty + 1) * tileSize)});
  }
  return tiles;
}

std::vector<TileRect> makeTiles(int width, int height, int tileSize) {
  return makeTiles(TileRect{0, 0, width, height}, tileSize);
}

void RenderCounters::add(const RenderCounters& o) {
  cameraSamples += o.cameraSamples;
  discardedSamples += o.discardedSamples;
  pixelsWithoutHit += o.pixelsWithoutHit;
  blackReceivers += o.blackReceivers;
  gathers += o.gathers;
  gatherReuses += o.gatherReuses;
  glossyGathers += o.glossyGathers;
  pathTracedReceivers += o.pathTracedReceivers;
  gather += o.gather;
}

absl::Status PathIntegrator::shadePixel(std::span<const Ray> rays, std::span<Rng> rngs,
                                        std::span<PathSample> out, IntegratorScratch*,
                                        RenderCounters*) const {
  for (size_t s = 0; s < rays.size(); ++s) out[s] = tracePath(scene_, rays[s], rngs[s], settings_);
  return absl::OkStatus();
}

absl::Status renderTile(const Integrator& integrator, IntegratorScratch* scratch,
                        const Camera& camera, const RenderSettings& settings, int frame,
                        const TileRect& tile, Image& image, RenderCounters* counters) {
  PBGI_CHECK_EQ(image.channelCount(), static_cast<int>(kChannelCount));
  const FilterSampler filter(settings.filter, settings.filterWidth);
  const int spp = std::max(1, settings.spp);
  std::vector<Ray> rays(spp);
  std::vector<Rng> rngs;
  rngs.reserve(spp);
  std::vector<PathSample> samples(spp);
  // Pixels in Morton order: consecutive shading points lie close together, and so do the
  // tree pages their gathers read.
  for (const auto& [dx, dy] : mortonOrder(tile.width(), tile.height())) {
    const int x = tile.x0 + dx, y = tile.y0 + dy;
    const uint64_t pixel = static_cast<uint64_t>(y) * image.width() + x;
    rngs.clear();
    for (int s = 0; s < spp; ++s) {
      Rng& rng = rngs.emplace_back(Rng::forKeys(settings.seed, frame, pixel, s));
      const Vec2f uFilter(rng.uniform(), rng.uniform());
      const Vec2f uLens(rng.uniform(), rng.uniform());
      const Vec2f offset = filter.sample(uFilter);
      rays[s] = camera.generateRay(static_cast<float>(x) + 0.5f + offset.x,
                                   static_cast<float>(y) + 0.5f + offset.y, uLens);
    }
    if (absl::Status s = integrator.shadePixel(rays, rngs, samples, scratch, counters); !s.ok()) {
      return absl::Status(s.code(), fmt::format("tile [{}, {}) x [{}, {}), pixel ({}, {}): {}",
                                                tile.x0, tile.x1, tile.y0, tile.y1, x, y,
                                                std::string(s.message())));
    }
    Rgb sum(0.0f), direct(0.0f), indirect(0.0f), albedo(0.0f);
    Vec3f normal(0.0f);
    double depth = 0.0;
    int valid = 0, hits = 0;
    for (const PathSample& ps : samples) {
      ++counters->cameraSamples;
      const Rgb L = ps.radiance();
      if (!isFinite(L) || !isFinite(ps.direct) || !isFinite(ps.indirect) ||
          !isFinite(ps.albedo) || !isFinite(ps.normal) || !std::isfinite(ps.depth)) {
        ++counters->discardedSamples;
        continue;
      }
      ++valid;
      sum += L;
      direct += ps.direct;
      indirect += ps.indirect;
      albedo += ps.albedo;
      normal += ps.normal;
      if (ps.hit) {
        ++hits;
        depth += ps.depth;
      }
    }
    if (hits == 0) ++counters->pixelsWithoutHit;
    const float inv = valid > 0 ? 1.0f / static_cast<float>(valid) : 0.0f;
    put(image, x, y, kR, sum * inv);
    image.at(x, y, kA) = valid > 0 ? static_cast<float>(hits) * inv : 0.0f;
    put(image, x, y, kAlbedoR, albedo * inv);
    const float nlen = length(normal);
    put(image, x, y, kNormalX, nlen > 0.0f ? normal / nlen : Vec3f(0.0f));
    image.at(x, y, kDepth) = hits > 0 ? static_cast<float>(depth / hits) : 0.0f;
    put(image, x, y, kDirectR, direct * inv);
    put(image, x, y, kIndirectR, indirect * inv);
  }
  return absl::OkStatus();
}

absl::StatusOr<Image> renderFrame(const Integrator& integrator, const Camera& camera,
                                  const RenderSettings& settings, int frame,
                                  const FrameRenderOptions& options,
                                  RenderCounters* countersOut) {
  Image image(camera.imageWidth(), camera.imageHeight(), frameChannels());
  const int tileSize = options.tileSize > 0 ? options.tileSize : settings.tileSize;
  const std::vector<TileRect> tiles =
      makeTiles(options.region.value_or(TileRect{0, 0, image.width(), image.height()}), tileSize);
  std::vector<RenderCounters> perTile(tiles.size());
  std::vector<absl::Status> errors(tiles.size());
  std::atomic<bool> failed{false};
  std::atomic<int> done{0};
  const int threads = options.threads > 0 ? options.threads : tbb::this_task_arena::max_concurrency();
  tbb::enumerable_thread_specific<std::unique_ptr<IntegratorScratch>> scratch(
      [&] { return integrator.newScratch(); });
  tbb::task_arena arena(threads);
  arena.execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, tiles.size(), 1),
        [&](const tbb::blocked_range<size_t>& range) {
          for (size_t i = range.begin(); i != range.end(); ++i) {
            if (failed.load(std::memory_order_relaxed)) return;
            errors[i] = renderTile(integrator, scratch.local().get(), camera, settings, frame,
                                   tiles[i], image, &perTile[i]);
            if (!errors[i].ok()) failed = true;
            const int n = ++done;
            if (options.progress) options.progress(n, static_cast<int>(tiles.size()));
          }
        },
        tbb::simple_partitioner());
  });
  for (const absl::Status& e : errors) {
    if (!e.ok()) return e;
  }
  if (countersOut) {
    RenderCounters total;
    for (const auto& c : perTile) total.add(c);
    *countersOut = total;
  }
  return image;
}

}  // namespace pbgi
