#include "core/render/renderer.h"

#include <algorithm>
#include <atomic>
#include <mutex>

#include <tbb/blocked_range.h>
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

std::vector<TileRect> makeTiles(int width, int height, int tileSize) {
  PBGI_CHECK_GT(tileSize, 0);
  const int nx = (width + tileSize - 1) / tileSize;
  const int ny = (height + tileSize - 1) / tileSize;
  std::vector<std::pair<uint32_t, TileRect>> keyed;
  keyed.reserve(static_cast<size_t>(nx) * ny);
  for (int ty = 0; ty < ny; ++ty) {
    for (int tx = 0; tx < nx; ++tx) {
      TileRect r{tx * tileSize, ty * tileSize, std::min(width, (tx + 1) * tileSize),
                 std::min(height, (ty + 1) * tileSize)};
      keyed.emplace_back(morton2(tx, ty), r);
    }
  }
  std::sort(keyed.begin(), keyed.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<TileRect> tiles;
  tiles.reserve(keyed.size());
  for (auto& [key, rect] : keyed) tiles.push_back(rect);
  return tiles;
}

RenderCounters renderTile(const Integrator& integrator, const Camera& camera,
                          const RenderSettings& settings, int frame, const TileRect& tile,
                          Image& image) {
  PBGI_CHECK_EQ(image.channelCount(), static_cast<int>(kChannelCount));
  const FilterSampler filter(settings.filter, settings.filterWidth);
  RenderCounters counters;
  const int spp = std::max(1, settings.spp);
  for (int y = tile.y0; y < tile.y1; ++y) {
    for (int x = tile.x0; x < tile.x1; ++x) {
      const uint64_t pixel = static_cast<uint64_t>(y) * image.width() + x;
      Rgb sum(0.0f), direct(0.0f), indirect(0.0f), albedo(0.0f);
      Vec3f normal(0.0f);
      double depth = 0.0;
      int valid = 0, hits = 0;
      for (int s = 0; s < spp; ++s) {
        Rng rng = Rng::forKeys(settings.seed, frame, pixel, s);
        const Vec2f uFilter(rng.uniform(), rng.uniform());
        const Vec2f uLens(rng.uniform(), rng.uniform());
        const Vec2f offset = filter.sample(uFilter);
        const Ray ray = camera.generateRay(static_cast<float>(x) + 0.5f + offset.x,
                                           static_cast<float>(y) + 0.5f + offset.y, uLens);
        const PathSample ps = integrator.li(ray, rng);
        ++counters.cameraSamples;
        const Rgb L = ps.radiance();
        if (!isFinite(L) || !isFinite(ps.direct) || !isFinite(ps.indirect) ||
            !isFinite(ps.albedo) || !isFinite(ps.normal) || !std::isfinite(ps.depth)) {
          ++counters.discardedSamples;
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
      if (hits == 0) ++counters.pixelsWithoutHit;
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
  }
  return counters;
}

Image renderFrame(const Integrator& integrator, const Camera& camera,
                  const RenderSettings& settings, int frame, const FrameRenderOptions& options,
                  RenderCounters* countersOut) {
  Image image(camera.imageWidth(), camera.imageHeight(), frameChannels());
  const int tileSize = options.tileSize > 0 ? options.tileSize : settings.tileSize;
  const std::vector<TileRect> tiles = makeTiles(image.width(), image.height(), tileSize);
  std::vector<RenderCounters> perTile(tiles.size());
  std::atomic<int> done{0};
  const int threads = options.threads > 0 ? options.threads : tbb::this_task_arena::max_concurrency();
  tbb::task_arena arena(threads);
  arena.execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, tiles.size(), 1),
        [&](const tbb::blocked_range<size_t>& range) {
          for (size_t i = range.begin(); i != range.end(); ++i) {
            perTile[i] = renderTile(integrator, camera, settings, frame, tiles[i], image);
            const int n = ++done;
            if (options.progress) options.progress(n, static_cast<int>(tiles.size()));
          }
        },
        tbb::simple_partitioner());
  });
  if (countersOut) {
    RenderCounters total;
    for (const auto& c : perTile) total.add(c);
    *countersOut = total;
  }
  return image;
}

}  // namespace pbgi
