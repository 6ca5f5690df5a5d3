#include "core/pbgi/adaptive_gather.h"

#include <algorithm>
#include <cmath>

#include <fmt/format.h>

#include "core/pbgi/gather_internal.h"
#include "core/pbgi/microbuffer.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

using namespace gather_internal;

constexpr int kMaxBaseResolution = 16;
constexpr int kMaxLevel = 10;
constexpr int kMaxSamples = 1 << 16;
constexpr float kBelowOne = 1.0f - 1e-7f;
constexpr float kInvGolden = 0.618033988749895f;
// A far disk is splatted as a footprint while at most this many times the cell its centre is
// seen in, cut into pieces at most kMaxDiskSplits times; larger ones are ray-cast.
constexpr float kMaxFootprintCells = 16.0f;
constexpr int kMaxDiskSplits = 3;
// Where the cells' centres catch less than this share of the sampled BSDF weight, the lobe is
// narrower than the cells and the weights come from the samples themselves.
constexpr float kResolvedLobe = 0.5f;

}  // namespace

absl::Status AdaptiveGatherOptions::validate() const {
  auto bad = [](const char* field, auto value, const char* range) {
    return absl::InvalidArgumentError(
        fmt::format("adaptive gather options: {} must be {}, got {}", field, range, value));
  };
  if (baseResolution < 1 || baseResolution > kMaxBaseResolution) {
    return bad("baseResolution", baseResolution, "in [1, 16]");
  }
  if (maxLevel < 0 || maxLevel > kMaxLevel) return bad("maxLevel", maxLevel, "in [0, 10]");
  if (brdfSamples < 1 || brdfSamples > kMaxSamples) {
    return bad("brdfSamples", brdfSamples, "in [1, 65536]");
  }
  if (brdfCells < 1 || brdfCells > kMaxSamples) return bad("brdfCells", brdfCells, "in [1, 65536]");
  if (!(lightFraction > 0.0f && lightFraction <= 1.0f)) {
    return bad("lightFraction", lightFraction, "in (0, 1]");
  }
  if (!(splatFraction > 0.0f && splatFraction <= 1.0f)) {
    return bad("splatFraction", splatFraction, "in (0, 1]");
  }
  if (maxCells < 6 * baseResolution * baseResolution || maxCells > (1 << 20)) {
    return bad("maxCells", maxCells, "at least 6 baseResolution^2 and at most 2^20");
  }
  return gather_internal::validateNearField("adaptive gather options", nearFieldFactor,
                                            selfSkipRadius);
}

std::string AdaptiveGatherOptions::toString() const {
  return fmt::format(
      "adaptive_gather(baseResolution={} maxLevel={} brdfSamples={} brdfCells={} "
      "lightFraction={:g} maxCells={} splatFraction={:g} nearFieldFactor={:g} "
      "selfSkipRadius={:g})",
      baseResolution, maxLevel, brdfSamples, brdfCells, lightFraction, maxCells, splatFraction,
      nearFieldFactor, selfSkipRadius);
}

AdaptiveGatherer::AdaptiveGatherer(const AdaptiveGatherOptions& options) : options_(options) {
  PBGI_CHECK(options.validate().ok());
  cells_.reserve(static_cast<size_t>(options.maxCells) * 4 / 3 + 64);
}

void AdaptiveGatherer::initCells() {
  cells_.clear();
  const int b = options_.baseResolution;
  const float size = 2.0f / static_cast<float>(b);
  for (int f = 0; f < kCubeFaces; ++f) {
    for (int j = 0; j < b; ++j) {
      for (int i = 0; i < b; ++i) {
        Cell c{};
        c.face = static_cast<uint8_t>(f);
        c.level = 0;
        c.u0 = -1.0f + static_cast<float>(i) * size;
        c.v0 = -1.0f + static_cast<float>(j) * size;
        c.size = size;
        cells_.push_back(c);
      }
    }
  }
  for (Cell& c : cells_) shape(&c);
  leafCount_ = static_cast<int>(cells_.size());
}

void AdaptiveGatherer::shape(Cell* c) const {
  const float half = 0.5f * c->size;
  c->dir = cubeDirection(c->face, c->u0 + half, c->v0 + half);
  c->solidAngle = static_cast<float>(cubeRectSolidAngle(c->u0, c->u0 + c->size, c->v0, c->v0 + c->size));
  c->child = c->firstRecord = c->leafIndex = -1;
  c->smallestLeaf = c->solidAngle;
  // Entirely below the horizon when its four corners are: the square is planar, and the
  // height above a plane through the origin is linear on it. Its angular radius: the farthest
  // corner's angle from its centre.
  c->active = false;
  float cosRadius = 1.0f;
  for (int k = 0; k < 4; ++k) {
    const Vec3f corner = cubeDirection(c->face, c->u0 + (k & 1) * c->size, c->v0 + (k >> 1) * c->size);
    c->active = c->active || dot(corner, frame_.n) > 0.0f;
    cosRadius = std::min(cosRadius, dot(corner, c->dir));
  }
  c->cosRadius = std::clamp(cosRadius, -1.0f, 1.0f);
  c->sinRadius = std::sqrt(1.0f - c->cosRadius * c->cosRadius);
}

bool AdaptiveGatherer::reachesCellBelow(const Vec3f& dir, float sinRadius, float solidAngle) {
  // Cones of half-angles a (the query's, below pi / 2 unless it holds the receiver) and b (a
  // cell's, at most a face's) meet when the angle between their axes is at most a + b. Only
  // subtrees holding a leaf below `solidAngle` are looked at: most of the sphere is pruned by
  // one comparison.
  const bool everywhere = !(sinRadius < 1.0f);
  const float sinA = everywhere ? 1.0f : sinRadius;
  const float cosA = everywhere ? -1.0f : std::sqrt(1.0f - sinA * sinA);
  cellStack_.clear();
  const int roots = kCubeFaces * options_.baseResolution * options_.baseResolution;
  for (int c = 0; c < roots; ++c) {
    if (cells_[c].smallestLeaf < solidAngle) cellStack_.push_back(c);
  }
  while (!cellStack_.empty()) {
    const Cell& cell = cells_[cellStack_.back()];
    cellStack_.pop_back();
    if (!(cell.smallestLeaf < solidAngle)) continue;
    if (!everywhere && dot(dir, cell.dir) < cosA * cell.cosRadius - sinA * cell.sinRadius) {
      continue;  // the cone misses the cell
    }
    if (cell.child < 0) return true;
    for (int q = 0; q < 4; ++q) cellStack_.push_back(cell.child + q);
  }
  return false;
}

void AdaptiveGatherer::split(int c) {
  const int first = static_cast<int>(cells_.size());
  const Cell parent = cells_[c];
  const float half = 0.5f * parent.size;
  for (int q = 0; q < 4; ++q) {
    Cell k{};
    k.face = parent.face;
    k.level = static_cast<uint8_t>(parent.level + 1);
    k.u0 = parent.u0 + (q & 1) * half;
    k.v0 = parent.v0 + (q >> 1) * half;
    k.size = half;
    shape(&k);
    k.parent = c;
    cells_.push_back(k);
  }
  if (bsdf_ != nullptr) {
    // The children share the parent's weight (so that the weights' sum stays the sampled
    // albedo): in proportion to the BSDF at their centres where the centres resolve the lobe,
    // to their solid angles where the samples weigh or the centres see nothing.
    Rgb share[4], sum(0.0f);
    for (int q = 0; q < 4; ++q) {
      const Cell& k = cells_[first + q];
      const Vec3f wl = frame_.toLocal(k.dir);
      share[q] = !sampleWeights_ && k.active && wl.z > 0.0f ? bsdf_->f(wo_, wl) * (wl.z * k.solidAngle)
                                                           : Rgb(0.0f);
      sum += share[q];
    }
    for (int q = 0; q < 4; ++q) {
      Cell& k = cells_[first + q];
      for (int ch = 0; ch < 3; ++ch) {
        k.weight[ch] = sum[ch] > 0.0f ? parent.weight[ch] * (share[q][ch] / sum[ch])
                                      : parent.weight[ch] * (k.solidAngle / parent.solidAngle);
      }
    }
  }
  cells_[c].child = first;
  cells_[c].firstRecord = -1;
  // The smallest leaf below each ancestor (the four children are about equal: take the least).
  float smallest = cells_[first].solidAngle;
  for (int q = 1; q < 4; ++q) smallest = std::min(smallest, cells_[first + q].solidAngle);
  for (int a = c; a >= 0 && smallest < cells_[a].smallestLeaf; a = cells_[a].parent) {
    cells_[a].smallestLeaf = smallest;
  }
  leafCount_ += 3;
}

int AdaptiveGatherer::leafOf(const Vec3f& dir) const {
  const CubePoint p = cubePoint(dir);
  const int b = options_.baseResolution;
  const float scale = 0.5f * static_cast<float>(b);
  const int i = std::clamp(static_cast<int>(std::floor((p.u + 1.0f) * scale)), 0, b - 1);
  const int j = std::clamp(static_cast<int>(std::floor((p.v + 1.0f) * scale)), 0, b - 1);
  int c = (p.face * b + j) * b + i;
  while (cells_[c].child >= 0) {
    const Cell& cell = cells_[c];
    const float half = 0.5f * cell.size;
    c = cell.child + (p.u >= cell.u0 + half ? 1 : 0) + (p.v >= cell.v0 + half ? 2 : 0);
  }
  return c;
}

int AdaptiveGatherer::cellOf(const Vec3f& dir) const {
  if (cells_.empty() || !(dir.length2() > 0.0f)) return -1;
  return cells_[leafOf(dir)].leafIndex;
}

void AdaptiveGatherer::refineByBsdf(const Bsdf& bsdf, const Vec3f& wo, const Vec2f& jitter) {
  samples_.clear();
  sampledAlbedo_ = Rgb(0.0f);
  const int side = std::max(1, static_cast<int>(std::lround(std::sqrt(options_.brdfSamples))));
  const int count = side * side;
  const float inv = 1.0f / static_cast<float>(side);
  const float jx = jitter.x - std::floor(jitter.x), jy = jitter.y - std::floor(jitter.y);
  for (int k = 0; k < count; ++k) {
    const int i = k % side, j = k / side;
    const float t = (static_cast<float>(k) + 0.5f) * kInvGolden + jx + jy;
    const Vec2f u(std::min((static_cast<float>(i) + jx) * inv, kBelowOne),
                  std::min((static_cast<float>(j) + jy) * inv, kBelowOne));
    const auto s = bsdf.sample(wo, t - std::floor(t), u);
    if (!s || s->delta || s->transmission || !(s->wi.z > 0.0f) || !(s->pdf > 0.0f)) continue;
    const Vec3f local = normalize(s->wi);
    const Rgb w = s->f * (local.z / (s->pdf * static_cast<float>(count)));
    if (!isFinite(w)) continue;
    samples_.push_back({normalize(frame_.toWorld(local)), w});
    sampledAlbedo_ += w;
  }
  const float total = luminance(sampledAlbedo_);
  if (!(total > 0.0f)) return;
  const float limit = total / static_cast<float>(options_.brdfCells);
  std::vector<float>& mass = mass_;
  for (;;) {
    mass.assign(cells_.size(), 0.0f);
    for (const Sample& s : samples_) mass[leafOf(s.dir)] += luminance(s.weight);
    bool splitAny = false;
    const size_t before = cells_.size();
    for (size_t c = 0; c < before; ++c) {
      if (mass[c] <= limit || cells_[c].child >= 0 || cells_[c].level >= options_.maxLevel) continue;
      if (leafCount_ + 3 > options_.maxCells) break;
      split(static_cast<int>(c));
      splitAny = true;
    }
    if (!splitAny) break;
  }
}

void AdaptiveGatherer::weigh(const Bsdf& bsdf, const Vec3f& wo) {
  Rgb centred(0.0f);
  for (Cell& c : cells_) {
    c.weight = Rgb(0.0f);
    if (c.child >= 0 || !c.active) continue;
    const Vec3f wl = frame_.toLocal(c.dir);
    if (wl.z > 0.0f) c.weight = bsdf.f(wo, wl) * (wl.z * c.solidAngle);
    centred += c.weight;
  }
  sampleWeights_ = !(luminance(centred) >= kResolvedLobe * luminance(sampledAlbedo_));
  if (sampleWeights_) {
    // A lobe narrower than the cells: each cell weighs what the samples in it carry.
    for (Cell& c : cells_) c.weight = Rgb(0.0f);
    for (const Sample& s : samples_) {
      Cell& c = cells_[leafOf(s.dir)];
      if (c.active) c.weight += s.weight;
    }
    weightScale_ = Rgb(1.0f);
    return;
  }
  auto ratio = [](float sampled, float sum) { return sum > 0.0f ? sampled / sum : 0.0f; };
  weightScale_ = Rgb(ratio(sampledAlbedo_.x, centred.x), ratio(sampledAlbedo_.y, centred.y),
                     ratio(sampledAlbedo_.z, centred.z));
  for (Cell& c : cells_) c.weight = c.weight * weightScale_;
}

bool AdaptiveGatherer::place(int c, const Record& r, GatherStats* stats) {
  Cell& cell = cells_[c];
  float room = options_.splatFraction * cell.solidAngle;
  if (r.omega > room || r.boundOmega > kMaxExtentFactor * room) return false;
  // A node must also be small against every cell its bounds reach: one placed by its centroid
  // into a large cell beside or around small ones (a glossy lobe's) would leave those black.
  if (r.boundSin > 0.0f && reachesCellBelow(r.dir, r.boundSin, r.omega / options_.splatFraction)) {
    return false;
  }
  // Only a record small against the cells it reaches is invisible through a black cell: a
  // large node whose centroid falls beside a sharp lobe still covers the lobe's cells.
  if (!cell.active || isBlack(cell.weight)) {
    ++stats->clustersInvisible;
    return true;
  }
  compose(c, r);
  return true;
}

void AdaptiveGatherer::compose(int c, const Record& r) {
  Cell& cell = cells_[c];
  const float coverage = std::min(1.0f, r.omega / cell.solidAngle);
  cell.pixel.compose(r.distance, r.extent, coverage, r.radiance * coverage);
  Record kept = r;
  kept.next = cell.firstRecord;
  cell.firstRecord = static_cast<int32_t>(records_.size());
  records_.push_back(kept);
}

void AdaptiveGatherer::placeDisk(const Record& disk, GatherStats* stats) {
  pieces_.clear();
  pieces_.push_back({disk, 0});
  while (!pieces_.empty()) {
    const auto [r, depth] = pieces_.back();
    pieces_.pop_back();
    const int c = leafOf(r.dir);
    if (place(c, r, stats)) continue;
    if (depth >= kMaxDiskSplits) {
      compose(c, r);  // a piece still larger than its cell: it covers the cell
      continue;
    }
    // Four quarters of the footprint (a square of side sqrt(omega) around its direction).
    const Frame around(r.dir);
    const float offset = 0.25f * std::sqrt(r.omega);
    Record piece = r;
    piece.omega = 0.25f * r.omega;
    for (int q = 0; q < 4; ++q) {
      piece.dir = normalize(r.dir + around.s * ((q & 1) != 0 ? offset : -offset) +
                            around.t * ((q & 2) != 0 ? offset : -offset));
      pieces_.push_back({piece, depth + 1});
    }
  }
}

void AdaptiveGatherer::gatherSurfels(const TreePage& page, const TreeNode& leaf, const Vec3f& p,
                                     GatherStats* stats) {
  forEachSeenSurfel(
      page, leaf, p, frame_.n, options_.selfSkipRadius, options_.nearFieldFactor, stats,
      [&](const SeenSurfel& seen) {
        const Surfel& s = *seen.surfel;
        const Disk disk{s.position, seen.side.normal, s.radius, seen.side.radiance};
        if (!seen.near) {
          const FarDisk far = farDisk(seen);
          Record r{};
          r.surfel = 1;
          r.dir = far.dir;
          r.distance = far.distance;
          r.extent = kLayerExtentFactor * s.radius;
          r.omega = far.omega;
          r.boundOmega = 0.0f;
          r.radiance = seen.side.radiance;
          // Far and not much larger than the cell it is seen in: its footprint, cut into pieces as
          // small as the cells they land in (a disk about a cell's size placed whole by its centre
          // would leave that cell's coverage all or nothing).
          if (far.omega <= kMaxFootprintCells * cells_[leafOf(far.dir)].solidAngle &&
              !reachesCellBelow(far.dir, s.radius / far.distance, far.omega / kMaxFootprintCells)) {
            placeDisk(r, stats);
            ++stats->disksSplatted;
            return;
          }
        }
        // Near, or much larger than its cell: exact, after the traversal.
        rayCasts_.push_back(disk);
        ++stats->nearFieldRayCasts;
      });
}

absl::Status AdaptiveGatherer::traverse(TreePageSource& tree,
                                        std::span<const TreeWalk::StackEntry> starts,
                                        const Vec3f& p, GatherStats* stats) {
  auto splat = [&](const NodeAttributes& a, const NodeBounds& bounds,
                   const WaveletRadiance* wavelet) {
    const Vec3f toCentroid = a.centroid - p;
    const float distance2 = toCentroid.length2();
    if (!(distance2 > 0.0f)) return false;
    const float distance = std::sqrt(distance2);
    const Vec3f dir = toCentroid / distance;
    const int c = leafOf(dir);
    // A centroid below the horizon: refined, its children may be above.
    if (!cells_[c].active) return false;
    ClusterView view;
    viewCluster(a, dir, &view);
    Record r{};
    r.node = walk_.current();
    r.surfel = -1;
    r.dir = dir;
    r.distance = distance;
    r.omega = view.coverage() / distance2;  // both sides cover
    r.boundOmega = kPi * bounds.boundRadius2 / bounds.centerDistance2;
    r.boundSin = std::sqrt(bounds.boundRadius2 / bounds.centerDistance2);
    if (!(r.omega > 0.0f)) {
      ++stats->clustersInvisible;  // no area towards the receiver
      return true;
    }
    r.extent = clusterDepthExtent(a, dir);
    r.radiance = clusterRadiance(a, view, wavelet);
    if (!place(c, r, stats)) return false;
    ++stats->clustersSplatted;
    return true;
  };
  return walk_.runFrom(tree, starts, p, frame_.n, stats, splat,
                       [&](const TreePage& page, const TreeNode& leaf) {
                         gatherSurfels(page, leaf, p, stats);
                       });
}

absl::Status AdaptiveGatherer::refineByLight(TreePageSource& tree, const Vec3f& p,
                                             GatherStats* stats) {
  for (int pass = 0; pass < options_.maxLevel; ++pass) {
    // The cells that carry more than their share of what the receiver reflects.
    float total = 0.0f;
    work_.clear();
    for (size_t c = 0; c < cells_.size(); ++c) {
      const Cell& cell = cells_[c];
      if (cell.child >= 0 || !cell.active) continue;
      total += luminance(cell.pixel.radiance() * cell.weight);
    }
    if (!(total > 0.0f)) return absl::OkStatus();
    const float limit = options_.lightFraction * total;
    for (size_t c = 0; c < cells_.size(); ++c) {
      const Cell& cell = cells_[c];
      if (cell.child >= 0 || !cell.active || cell.level >= options_.maxLevel) continue;
      if (luminance(cell.pixel.radiance() * cell.weight) > limit) {
        work_.push_back(static_cast<int32_t>(c));
      }
    }
    // The brightest first when the cell budget runs out; ties by index (deterministic).
    std::sort(work_.begin(), work_.end(), [&](int32_t a, int32_t b) {
      const float la = luminance(cells_[a].pixel.radiance() * cells_[a].weight);
      const float lb = luminance(cells_[b].pixel.radiance() * cells_[b].weight);
      return la != lb ? la > lb : a < b;
    });
    rewalk_.clear();
    int splits = 0;
    for (const int32_t c : work_) {
      if (leafCount_ + 3 > options_.maxCells) break;
      int32_t record = cells_[c].firstRecord;
      split(c);
      ++splits;
      // What the cell held goes to its children, or is walked or ray-cast again.
      for (; record >= 0; record = records_[record].next) {
        const Record r = records_[record];
        if (r.surfel >= 0) {
          placeDisk(r, stats);
        } else if (!place(leafOf(r.dir), r, stats)) {
          rewalk_.push_back(r.node);
        }
      }
    }
    lightSplits_ += splits;
    if (splits == 0) return absl::OkStatus();
    if (!rewalk_.empty()) {
      if (absl::Status s = traverse(tree, rewalk_, p, stats); !s.ok()) return s;
    }
  }
  return absl::OkStatus();
}

void AdaptiveGatherer::rayCast(const Vec3f& p) {
  for (const Disk& d : rayCasts_) {
    const DiskHitTest disk(d.center, d.normal, d.radius, p);
    for (const int32_t c : leaves_) {
      Cell& cell = cells_[c];
      if (!cell.active || isBlack(cell.weight)) continue;
      float t;
      if (disk.hit(cell.dir, &t)) cell.pixel.compose(t, d.radius, 1.0f, d.radiance);
    }
  }
}

void AdaptiveGatherer::collectLeaves() {
  leaves_.clear();
  for (size_t c = 0; c < cells_.size(); ++c) {
    if (cells_[c].child >= 0) {
      cells_[c].leafIndex = -1;
      continue;
    }
    cells_[c].leafIndex = static_cast<int32_t>(leaves_.size());
    leaves_.push_back(static_cast<int32_t>(c));
  }
}

absl::StatusOr<Rgb> AdaptiveGatherer::reflect(TreePageSource& tree, const Vec3f& position,
                                              const Frame& frame, const Bsdf& bsdf,
                                              const Vec3f& woLocal, const Vec2f& jitter,
                                              GatherStats* stats) {
  const float woLength = length(woLocal);
  if (!isFinite(position) || !isFinite(frame.s) || !isFinite(frame.t) || !isFinite(frame.n) ||
      !(length(frame.n) > 0.0f) || !isFinite(woLocal) || !(woLength > 0.0f) ||
      !std::isfinite(woLength) || !std::isfinite(jitter.x) || !std::isfinite(jitter.y)) {
    return absl::InvalidArgumentError(fmt::format(
        "adaptive gather: needs a finite position and frame, a finite non-zero wo and a finite "
        "jitter, got position {} normal {} wo {} jitter ({}, {})",
        position, frame.n, woLocal, jitter.x, jitter.y));
  }
  frame_ = frame;
  wo_ = woLocal / woLength;
  bsdf_ = nullptr;
  lightSplits_ = 0;
  records_.clear();
  rayCasts_.clear();
  initCells();
  GatherStats local;
  local.gathers = 1;
  Rgb sum(0.0f);
  if (wo_.z > 0.0f && !bsdf.isDelta() && !bsdf.isBlack()) {
    refineByBsdf(bsdf, wo_, jitter);
    weigh(bsdf, wo_);
    bsdf_ = &bsdf;
  }
  if (bsdf_ != nullptr && luminance(sampledAlbedo_) > 0.0f) {
    const TreeWalk::StackEntry root{tree.root(), 0};
    absl::Status status = traverse(tree, std::span(&root, 1), position, &local);
    if (status.ok()) status = refineByLight(tree, position, &local);
    if (!status.ok()) {
      bsdf_ = nullptr;
      collectLeaves();
      if (stats != nullptr) *stats += local;
      return status;
    }
  }
  collectLeaves();
  if (bsdf_ != nullptr) {
    rayCast(position);
    for (const int32_t c : leaves_) {
      const Cell& cell = cells_[c];
      if (!cell.active) {
        ++local.pixelsSkipped;
        continue;
      }
      sum += cell.pixel.radiance() * cell.weight;
    }
  }
  bsdf_ = nullptr;
  if (stats != nullptr) *stats += local;
  if (!isFinite(sum)) {
    return absl::DataLossError(fmt::format(
        "adaptive gather: radiance {} at {} is not finite: the tree holds non-finite radiance",
        sum, position));
  }
  return sum;
}

}  // namespace pbgi
