#include "core/render/renderer.h"

#include <algorithm>
#include <atomic>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <tbb/blocked_range.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include "core/render/filter.h"
#include "core/sampling/low_discrepancy.h"
#include "core/sampling/rng.h"
#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

// Keys a pixel's scramble of its samples' positions apart from its samples' own streams.
constexpr uint64_t kPixelPatternKey = 0x70697865ull;  // "pixe"

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

// Where the frame's pixels go in the image renderFrame returns: the whole frame, or only the
// regions asked for, stacked top to bottom and left-aligned (a buffer of the tile's own size).
class Raster {
 public:
  Raster(int width, int height, const std::vector<TileRect>& regions) : regions_(regions) {
    int y = 0;
    for (const TileRect& r : regions_) {
      rowOffset_.push_back(y);
      y += r.height();
    }
    const Vec2i size = regions_.empty() ? Vec2i(width, height) : stackedSize(regions_);
    image_ = Image(size.x, size.y, frameChannels());
    if (regions_.size() == 1) {
      image_.setWindow({regions_[0].x0, regions_[0].y0, width, height});
    }
  }

  bool wanted(int x, int y) const {
    return regions_.empty() || std::any_of(regions_.begin(), regions_.end(),
                                           [&](const TileRect& r) { return r.contains(x, y); });
  }
  // Calls f(ix, iy) for every place of the image that frame pixel (x, y) goes to.
  template <class F>
  void forEachPlace(int x, int y, F&& f) {
    if (regions_.empty()) return f(x, y);
    for (size_t i = 0; i < regions_.size(); ++i) {
      const TileRect& r = regions_[i];
      if (r.contains(x, y)) f(x - r.x0, y - r.y0 + rowOffset_[i]);
    }
  }
  Image& image() { return image_; }

 private:
  std::vector<TileRect> regions_;
  std::vector<int> rowOffset_;
  Image image_;
};

TileRect intersect(const TileRect& a, const TileRect& b) {
  return {std::max(a.x0, b.x0), std::max(a.y0, b.y0), std::min(a.x1, b.x1),
          std::min(a.y1, b.y1)};
}
bool emptyRect(const TileRect& r) { return r.x0 >= r.x1 || r.y0 >= r.y1; }

// A block of the fixed grid: its rect in view space (every view) and its index.
struct GridBlock {
  TileRect rect;
  Vec2i index{0, 0};
};

// One unit of work: a tile (rect in image space), or blocks (consecutive in Morton order).
struct RenderUnit {
  TileRect rect;
  bool block = false;
  std::vector<GridBlock> blocks;
};

// The units that cover `regions` (or the whole image).
std::vector<RenderUnit> makeUnits(const Integrator& integrator, const Camera& camera,
                                  const std::vector<TileRect>& regions, int tileSize) {
  const TileRect whole{0, 0, camera.imageWidth(), camera.imageHeight()};
  std::vector<TileRect> wanted;
  for (const TileRect& r : regions) {
    const TileRect clipped = intersect(r, whole);
    if (!emptyRect(clipped)) wanted.push_back(clipped);
  }
  if (regions.empty()) wanted.push_back(whole);
  std::vector<RenderUnit> units;
  const int block = integrator.blockSize();
  if (block <= 0) {
    for (const TileRect& r : wanted) {
      for (const TileRect& t : makeTiles(r, tileSize)) units.push_back({t, false, {}});
    }
    return units;
  }
  const int vw = camera.viewWidth(), vh = camera.viewHeight();
  const int nx = (vw + block - 1) / block, ny = (vh + block - 1) / block;
  std::vector<uint8_t> needed(static_cast<size_t>(nx) * ny, 0);
  for (const TileRect& r : wanted) {
    // The region's part in each view it covers, in that view's coordinates.
    for (int row = r.y0 / vh; row <= (r.y1 - 1) / vh; ++row) {
      for (int col = r.x0 / vw; col <= (r.x1 - 1) / vw; ++col) {
        const TileRect local = intersect(
            {r.x0 - col * vw, r.y0 - row * vh, r.x1 - col * vw, r.y1 - row * vh},
            {0, 0, vw, vh});
        if (emptyRect(local)) continue;
        for (int by = local.y0 / block; by <= (local.y1 - 1) / block; ++by) {
          for (int bx = local.x0 / block; bx <= (local.x1 - 1) / block; ++bx) {
            needed[static_cast<size_t>(by) * nx + bx] = 1;
          }
        }
      }
    }
  }
  const size_t perUnit = static_cast<size_t>(std::max(1, integrator.blocksPerUnit()));
  for (const Vec2i& b : mortonOrder(nx, ny)) {
    if (!needed[static_cast<size_t>(b.y) * nx + b.x]) continue;
    if (units.empty() || units.back().blocks.size() == perUnit) {
      units.push_back({{}, true, {}});
    }
    units.back().blocks.push_back({{b.x * block, b.y * block, std::min(vw, (b.x + 1) * block),
                                    std::min(vh, (b.y + 1) * block)},
                                   b});
  }
  return units;
}

std::string describe(const RenderUnit& u) {
  if (u.block) {
    std::string text;
    for (const GridBlock& b : u.blocks) {
      text += fmt::format("{}({}, {}) [{}, {}) x [{}, {})", text.empty() ? "" : ", ", b.index.x,
                          b.index.y, b.rect.x0, b.rect.x1, b.rect.y0, b.rect.y1);
    }
    return fmt::format("block{} {} of every view", u.blocks.size() > 1 ? "s" : "", text);
  }
  return fmt::format("tile [{}, {}) x [{}, {})", u.rect.x0, u.rect.x1, u.rect.y0, u.rect.y1);
}

// The buffers one thread reuses from unit to unit.
struct UnitBuffers {
  std::vector<Vec2i> pixels;
  std::vector<uint8_t> halo;  // by pixel: a block's halo, not written
  std::vector<UnitBlock> blocks;
  std::vector<Ray> rays;
  std::vector<Rng> rngs;
  std::vector<PathSample> samples;
  std::unique_ptr<IntegratorScratch> scratch;
};

absl::Status renderUnit(const Integrator& integrator, const Camera& camera,
                        const RenderSettings& settings, int frame, const RenderUnit& unit,
                        Raster& raster, UnitBuffers& buf, const std::atomic<bool>* cancel,
                        RenderCounters* counters) {
  Image& image = raster.image();
  PBGI_CHECK_EQ(image.channelCount(), static_cast<int>(kChannelCount));
  buf.pixels.clear();
  buf.blocks.clear();
  if (unit.block) {
    const Vec2i views = camera.views();
    const int halo = integrator.blockHalo();
    for (const GridBlock& b : unit.blocks) {
      const std::vector<Vec2i> order = mortonOrder(b.rect.width(), b.rect.height());
      const size_t first = buf.pixels.size();
      for (int row = 0; row < views.y; ++row) {
        for (int col = 0; col < views.x; ++col) {
          for (const Vec2i& d : order) {
            buf.pixels.push_back({col * camera.viewWidth() + b.rect.x0 + d.x,
                                  row * camera.viewHeight() + b.rect.y0 + d.y});
          }
        }
      }
      const size_t own = buf.pixels.size() - first;
      if (halo > 0) {
        // The column past the right border and the row past the bottom one (with their
        // corner), where they lie inside the view.
        const int vw = camera.viewWidth(), vh = camera.viewHeight();
        for (int row = 0; row < views.y; ++row) {
          for (int col = 0; col < views.x; ++col) {
            const auto add = [&](int x, int y) {
              const Vec2i p{col * vw + x, row * vh + y};
              if (p.x % halo != 0 || p.y % halo != 0 || x >= vw || y >= vh) return;
              buf.pixels.push_back(p);
            };
            for (int y = b.rect.y0; y < b.rect.y1; ++y) add(b.rect.x1, y);
            for (int x = b.rect.x0; x <= b.rect.x1; ++x) add(x, b.rect.y1);
          }
        }
      }
      buf.blocks.push_back({.firstPixel = first,
                            .pixelCount = own,
                            .haloCount = buf.pixels.size() - first - own,
                            .key = blockKey(settings.seed, frame, b.index.x, b.index.y)});
    }
  } else {
    const std::vector<Vec2i> order = mortonOrder(unit.rect.width(), unit.rect.height());
    for (const Vec2i& d : order) buf.pixels.push_back({unit.rect.x0 + d.x, unit.rect.y0 + d.y});
  }
  const FilterSampler filter(settings.filter, settings.filterWidth);
  const int spp = std::max(1, settings.spp);
  const size_t n = buf.pixels.size() * static_cast<size_t>(spp);
  buf.rays.resize(n);
  buf.rngs.resize(n);
  buf.samples.assign(n, PathSample{});
  for (size_t i = 0; i < buf.pixels.size(); ++i) {
    if (cancel && cancel->load(std::memory_order_relaxed)) return cancelledError();
    const Vec2i px = buf.pixels[i];
    const uint64_t pixel = static_cast<uint64_t>(px.y) * camera.imageWidth() + px.x;
    // The position in the pixel and on the lens are stratified over the pixel's samples
    // (low_discrepancy.h); the sample's own stream, which the integrator goes on drawing from,
    // still skips the four numbers it once gave them, so the paths keep their random numbers.
    const uint64_t pattern = hashKeys(settings.seed, frame, pixel, kPixelPatternKey);
    for (int s = 0; s < spp; ++s) {
      const size_t k = i * spp + s;
      Rng& rng = buf.rngs[k] = Rng::forKeys(settings.seed, frame, pixel, s);
      for (int skip = 0; skip < 4; ++skip) rng.nextU32();
      const auto index = static_cast<uint32_t>(s);
      const Vec2f uFilter = owenSobol2D(index, pattern);
      const Vec2f uLens = owenSobol2D(shuffledIndex(index, pattern), pattern + 1);
      const Vec2f offset = filter.sample(uFilter);
      buf.rays[k] = camera.generateRay(static_cast<float>(px.x) + 0.5f + offset.x,
                                       static_cast<float>(px.y) + 0.5f + offset.y, uLens);
    }
  }
  const TileSamples samples{.spp = spp,
                            .pixels = buf.pixels,
                            .rays = buf.rays,
                            .rngs = buf.rngs,
                            .blocks = buf.blocks,
                            .frameKey = frameKey(settings.seed, frame),
                            .cancel = cancel};
  if (absl::Status s = integrator.render(samples, buf.samples, buf.scratch.get(), counters);
      !s.ok()) {
    return absl::Status(s.code(), fmt::format("{}: {}", describe(unit), s.message()));
  }
  buf.halo.assign(buf.pixels.size(), 0);
  for (const UnitBlock& b : buf.blocks) {
    const size_t haloFirst = b.firstPixel + b.pixelCount;
    std::fill_n(buf.halo.begin() + static_cast<std::ptrdiff_t>(haloFirst), b.haloCount, 1);
  }
  for (size_t i = 0; i < buf.pixels.size(); ++i) {
    const int x = buf.pixels[i].x, y = buf.pixels[i].y;
    // A block renders whole, but writes only the pixels asked for, and none of its halo.
    if (buf.halo[i] || !raster.wanted(x, y)) continue;
    Rgb sum(0.0f), direct(0.0f), indirect(0.0f), albedo(0.0f);
    Vec3f normal(0.0f);
    double depth = 0.0;
    int valid = 0, hits = 0;
    for (int s = 0; s < spp; ++s) {
      const PathSample& ps = buf.samples[i * spp + s];
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
    const float nlen = length(normal);
    raster.forEachPlace(x, y, [&](int ix, int iy) {
      put(image, ix, iy, kR, sum * inv);
      image.at(ix, iy, kA) = valid > 0 ? static_cast<float>(hits) * inv : 0.0f;
      put(image, ix, iy, kAlbedoR, albedo * inv);
      put(image, ix, iy, kNormalX, nlen > 0.0f ? normal / nlen : Vec3f(0.0f));
      image.at(ix, iy, kDepth) = hits > 0 ? static_cast<float>(depth / hits) : 0.0f;
      put(image, ix, iy, kDirectR, direct * inv);
      put(image, ix, iy, kIndirectR, indirect * inv);
    });
  }
  return absl::OkStatus();
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

const std::vector<std::string>& frameAovs() {
  static const std::vector<std::string> layers = {"albedo", "normal", "depth", "direct",
                                                  "indirect"};
  return layers;
}

absl::Status checkAovs(const std::vector<std::string>& aovs) {
  for (const std::string& a : aovs) {
    if (std::find(frameAovs().begin(), frameAovs().end(), a) == frameAovs().end()) {
      return absl::InvalidArgumentError(
          fmt::format("AOV '{}': expected one of {}", a, fmt::join(frameAovs(), ", ")));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<Image> keepAovs(const Image& image, const std::vector<std::string>& aovs) {
  PBGI_RETURN_IF_ERROR(checkAovs(aovs));
  std::vector<int> kept;
  std::vector<std::string> names;
  for (int c = 0; c < image.channelCount(); ++c) {
    const std::string& name = image.channels()[static_cast<size_t>(c)];
    const size_t dot = name.find('.');
    const bool keep = dot == std::string::npos ||
                      std::find(aovs.begin(), aovs.end(), name.substr(0, dot)) != aovs.end();
    if (keep) {
      kept.push_back(c);
      names.push_back(name);
    }
  }
  Image out(image.width(), image.height(), names);
  out.setWindow(image.window());
  out.metadata() = image.metadata();
  for (int y = 0; y < image.height(); ++y) {
    for (int x = 0; x < image.width(); ++x) {
      for (size_t k = 0; k < kept.size(); ++k)
        out.at(x, y, static_cast<int>(k)) = image.at(x, y, kept[k]);
    }
  }
  return out;
}

Vec2i stackedSize(const std::vector<TileRect>& regions) {
  Vec2i size(0, 0);
  for (const TileRect& r : regions) {
    size.x = std::max(size.x, r.width());
    size.y += r.height();
  }
  return size;
}

std::vector<Vec2i> mortonOrder(int nx, int ny) {
  std::vector<std::pair<uint32_t, Vec2i>> keyed;
  keyed.reserve(static_cast<size_t>(std::max(nx, 0)) * std::max(ny, 0));
  for (int y = 0; y < ny; ++y) {
    for (int x = 0; x < nx; ++x) keyed.push_back({morton2(x, y), {x, y}});
  }
  std::sort(keyed.begin(), keyed.end(),
            [](const auto& a, const auto& b) { return a.first < b.first; });
  std::vector<Vec2i> cells;
  cells.reserve(keyed.size());
  for (const auto& [key, xy] : keyed) cells.push_back(xy);
  return cells;
}

std::vector<TileRect> makeTiles(const TileRect& region, int tileSize) {
  PBGI_CHECK_GT(tileSize, 0);
  const int nx = (region.width() + tileSize - 1) / tileSize;
  const int ny = (region.height() + tileSize - 1) / tileSize;
  std::vector<TileRect> tiles;
  for (const Vec2i& t : mortonOrder(nx, ny)) {
    tiles.push_back({region.x0 + t.x * tileSize, region.y0 + t.y * tileSize,
                     std::min(region.x1, region.x0 + (t.x + 1) * tileSize),
                     std::min(region.y1, region.y0 + (t.y + 1) * tileSize)});
  }
  return tiles;
}

std::vector<TileRect> makeTiles(int width, int height, int tileSize) {
  return makeTiles(TileRect{0, 0, width, height}, tileSize);
}

uint64_t blockKey(uint64_t seed, int frame, int bx, int by) {
  return hashKeys(seed, frame, 0x626c6f636bull /* "block" */, bx, by);
}

uint64_t frameKey(uint64_t seed, int frame) {
  return hashKeys(seed, frame, 0x6672616d65ull /* "frame" */);
}

void RenderCounters::add(const RenderCounters& o) {
  cameraSamples += o.cameraSamples;
  discardedSamples += o.discardedSamples;
  pixelsWithoutHit += o.pixelsWithoutHit;
  if (values.size() < o.values.size()) values.resize(o.values.size(), 0);
  for (size_t i = 0; i < o.values.size(); ++i) values[i] += o.values[i];
}

absl::Status PixelIntegrator::render(const TileSamples& samples, std::span<PathSample> out,
                                     IntegratorScratch* scratch, RenderCounters* counters) const {
  const size_t spp = static_cast<size_t>(samples.spp);
  for (size_t i = 0; i < samples.pixelCount(); ++i) {
    if (samples.cancelled()) return cancelledError();
    const size_t first = i * spp;
    if (absl::Status s = shadePixel(samples.rays.subspan(first, spp),
                                    samples.rngs.subspan(first, spp), out.subspan(first, spp),
                                    scratch, counters);
        !s.ok()) {
      return absl::Status(s.code(), fmt::format("pixel ({}, {}): {}", samples.pixels[i].x,
                                                samples.pixels[i].y, s.message()));
    }
  }
  return absl::OkStatus();
}

absl::Status PathIntegrator::shadePixel(std::span<const Ray> rays, std::span<Rng> rngs,
                                        std::span<PathSample> out, IntegratorScratch*,
                                        RenderCounters*) const {
  for (size_t s = 0; s < rays.size(); ++s) out[s] = tracePath(scene_, rays[s], rngs[s], settings_);
  return absl::OkStatus();
}

absl::Status cancelledError() { return absl::CancelledError("the render was cancelled"); }

absl::Status checkRegions(const std::vector<TileRect>& regions, int width, int height) {
  for (const TileRect& r : regions) {
    if (r.x0 >= r.x1 || r.y0 >= r.y1) {
      return absl::OutOfRangeError(
          fmt::format("region [{}, {}) x [{}, {}) is empty", r.x0, r.x1, r.y0, r.y1));
    }
    if (r.x0 < 0 || r.y0 < 0 || r.x1 > width || r.y1 > height) {
      return absl::OutOfRangeError(fmt::format("region [{}, {}) x [{}, {}) leaves the {}x{} image",
                                               r.x0, r.x1, r.y0, r.y1, width, height));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<Image> renderFrame(const Integrator& integrator, const Camera& camera,
                                  const RenderSettings& settings, int frame,
                                  const FrameRenderOptions& options,
                                  RenderCounters* countersOut) {
  PBGI_RETURN_IF_ERROR(checkRegions(options.regions, camera.imageWidth(), camera.imageHeight()));
  Raster raster(camera.imageWidth(), camera.imageHeight(), options.regions);
  const int tileSize = options.tileSize > 0 ? options.tileSize : settings.tileSize;
  const std::vector<RenderUnit> units = makeUnits(integrator, camera, options.regions, tileSize);
  const size_t counterCount = integrator.counterSpecs().size();
  std::vector<RenderCounters> perUnit(units.size());
  for (RenderCounters& c : perUnit) c.values.assign(counterCount, 0);
  std::vector<absl::Status> errors(units.size());
  std::atomic<bool> failed{false};
  std::atomic<int> done{0};
  const int threads = options.threads > 0 ? options.threads : tbb::this_task_arena::max_concurrency();
  tbb::enumerable_thread_specific<UnitBuffers> buffers([&] {
    UnitBuffers b;
    b.scratch = integrator.newScratch();
    return b;
  });
  tbb::task_arena arena(threads);
  arena.execute([&] {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, units.size(), 1),
        [&](const tbb::blocked_range<size_t>& range) {
          for (size_t i = range.begin(); i != range.end(); ++i) {
            if (failed.load(std::memory_order_relaxed)) return;
            errors[i] = options.cancel && options.cancel->load()
                            ? cancelledError()
                            : renderUnit(integrator, camera, settings, frame, units[i], raster,
                                         buffers.local(), options.cancel, &perUnit[i]);
            if (!errors[i].ok()) failed = true;
            const int n = ++done;
            if (options.progress) options.progress(n, static_cast<int>(units.size()));
          }
        },
        tbb::simple_partitioner());
  });
  for (const absl::Status& e : errors) {
    if (!e.ok()) return e;
  }
  if (countersOut) {
    RenderCounters total;
    total.values.assign(counterCount, 0);
    for (const auto& c : perUnit) total.add(c);
    *countersOut = total;
  }
  return std::move(raster.image());
}

}  // namespace pbgi
