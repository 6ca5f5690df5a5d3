#include "core/pbgi/warped_gather.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include <fmt/format.h>

#include "core/pbgi/gather_internal.h"
#include "core/pbgi/microbuffer.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

using namespace gather_internal;

constexpr int kMinResolution = 2;  // one pixel would have no corner inside the hemisphere
// Warped corners this close to the horizon (z below it) are put on it: the cosine warp's rim
// lands there up to float rounding, and the pixels' regions must tile the hemisphere up to
// its very edge for their solid angles to add up.
constexpr float kHorizonSnap = 1e-3f;
// Triangles with less solid angle are degenerate (the warp collapses a lattice row to one
// direction, as the visible-normal warp does at its centre): they hold no direction.
constexpr float kMinTriangleSolidAngle = 1e-12f;
// Corners closer than this (squared chord) are one direction: a seam or a collapsed side.
constexpr float kSameDirection2 = 1e-8f;
constexpr float kBelowOne = 1.0f - 1e-7f;
constexpr float kNudge = 1e-5f;
// Directions this far below the horizon (z) are in no pixel.
constexpr float kBelowHorizon = -1e-4f;
// The lobe choice of pixel k is frac((k + 1/2) / golden ratio + offset): stratified in one
// dimension, the offset drawn from the jitter so that it is uniform over receivers too.
constexpr float kInvGolden = 0.618033988749895f;

enum CornerState : uint8_t { kSampled = 0, kMoved = 1, kUnusable = 2 };

Vec3f onHorizon(float x, float y) {
  const float len = std::sqrt(x * x + y * y);
  return Vec3f(x / len, y / len, 0.0f);
}

// Where the great circle from `from` through `to` (unit, both above the horizon, or `from`
// on the pole's side) crosses the horizon beyond `to`; straight down the meridian when the
// two coincide.
Vec3f horizonBeyond(const Vec3f& from, const Vec3f& to) {
  const Vec3f w = to - from * dot(to, from);
  if (!(from.z > 0.0f) || !(w.length2() > 1e-12f)) return onHorizon(to.x, to.y);
  // z(t) = from.z cos t + u.z sin t falls from from.z > 0 to its first zero at t*.
  const Vec3f u = normalize(w);
  const float t = std::atan2(from.z, -u.z);
  const Vec3f h = from * std::cos(t) + u * std::sin(t);
  return onHorizon(h.x, h.y);
}

// Stereographic chart of the upper hemisphere (from the south pole): conformal and bounded,
// the horizon on the unit circle; great circles map to circles of radius >= 1 (or lines).
Vec2f chart(const Vec3f& w) { return Vec2f(w.x, w.y) / (1.0f + w.z); }

// Signed solid angle of the geodesic triangle abc (Van Oosterom and Strackee 1983),
// positive when abc turn counter-clockwise seen from outside the sphere.
float triangleSolidAngle(const Vec3f& a, const Vec3f& b, const Vec3f& c) {
  return 2.0f * std::atan2(dot(a, cross(b, c)), 1.0f + dot(a, b) + dot(b, c) + dot(c, a));
}


}  // namespace

absl::Status WarpedGatherOptions::validate() const {
  if (resolution < kMinResolution || resolution > kMaxMicrobufferResolution) {
    return absl::InvalidArgumentError(
        fmt::format("warped gather options: resolution must be in [{}, {}], got {}", kMinResolution,
                    kMaxMicrobufferResolution, resolution));
  }
  return gather_internal::validateNearField("warped gather options", nearFieldFactor, selfSkipRadius);
}

std::string WarpedGatherOptions::toString() const {
  return fmt::format("warped_gather(resolution={} nearFieldFactor={:g} selfSkipRadius={:g})",
                     resolution, nearFieldFactor, selfSkipRadius);
}

WarpedGatherer::WarpedGatherer(const WarpedGatherOptions& options)
    : options_(options), n_(checkedResolution(options)) {
  const size_t pixels = static_cast<size_t>(n_) * n_;
  const size_t corners = static_cast<size_t>(n_ + 1) * (n_ + 1);
  corner_.resize(corners);
  cornerState_.resize(corners);
  dirWorld_.resize(pixels);
  weight_.resize(pixels);
  sampled_.resize(pixels);
  solidAngle_.resize(pixels);
  quadEdge_.resize(5 * pixels);
  triKept_.resize(2 * pixels);
  triArea_.resize(2 * pixels);
  quadRect_.resize(4 * pixels);
  cornerChart_.resize(corners);
  scratch_.reserve(corners);
  bucketStart_.resize(pixels + 1);
  bucketPixels_.reserve(8 * pixels);
  pixels_.resize(pixels);
  rayCasts_.reserve(4 * pixels);
}

absl::Status WarpedGatherer::warp(const Frame& frame, const Bsdf& bsdf, const Vec3f& woLocal,
                                  const Vec2f& jitter) {
  const float woLength = length(woLocal);
  if (!isFinite(frame.s) || !isFinite(frame.t) || !isFinite(frame.n) || !(length(frame.n) > 0.0f) ||
      !isFinite(woLocal) || !(woLength > 0.0f) || !std::isfinite(woLength) ||
      !std::isfinite(jitter.x) || !std::isfinite(jitter.y)) {
    return absl::InvalidArgumentError(fmt::format(
        "warped gather: needs a finite frame, a finite non-zero wo and a finite jitter, got "
        "normal {} wo {} jitter ({}, {})",
        frame.n, woLocal, jitter.x, jitter.y));
  }
  frame_ = frame;
  const Vec3f wo = woLocal / woLength;
  std::fill(weight_.begin(), weight_.end(), Rgb(0.0f));
  std::fill(sampled_.begin(), sampled_.end(), uint8_t{0});
  std::fill(dirWorld_.begin(), dirWorld_.end(), Vec3f(0.0f));
  std::fill(solidAngle_.begin(), solidAngle_.end(), 0.0f);
  std::fill(triKept_.begin(), triKept_.end(), uint8_t{0});
  std::fill(bucketStart_.begin(), bucketStart_.end(), 0u);
  bucketPixels_.clear();
  if (!(wo.z > 0.0f) || bsdf.isDelta() || bsdf.isBlack()) return absl::OkStatus();  // all black
  sampleCorners(bsdf, wo);
  samplePixels(bsdf, wo, jitter);
  buildRegions();
  buildBuckets();
  return absl::OkStatus();
}

void WarpedGatherer::sampleCorners(const Bsdf& bsdf, const Vec3f& wo) {
  const int n = n_, side = n + 1;
  const float inv = 1.0f / static_cast<float>(n);
  Vec3f lobe(0.0f);
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      const int c = j * side + i;
      const Vec2f u(static_cast<float>(i) * inv, static_cast<float>(j) * inv);
      auto s = bsdf.sample(wo, 0.0f, u);
      // Where the density vanishes (the cosine warp's rim) the BSDF gives no sample: a hair
      // inside the square it does, at the same direction up to the hair.
      if (!s) s = bsdf.sample(wo, 0.0f, u + (Vec2f(0.5f, 0.5f) - u) * kNudge);
      if (!s || s->delta || !(s->wi.z > 0.0f)) {
        cornerState_[c] = kUnusable;
        continue;
      }
      Vec3f w = normalize(s->wi);
      if (w.z < kHorizonSnap) w = onHorizon(w.x, w.y);
      corner_[c] = w;
      cornerState_[c] = kSampled;
      lobe += w;
    }
  }
  lobe = lobe.length2() > 0.0f ? normalize(lobe) : Vec3f(0, 0, 1);
  // Corner t along side s of the square: u.x = 0, u.x = 1, u.y = 0, u.y = 1.
  auto at = [&](int s, int t) {
    return s < 2 ? t * side + (s == 1 ? n : 0) : (s == 3 ? n * side : 0) + t;
  };
  // The square's sides are where the warp meets the hemisphere's rim, unless two opposite
  // sides coincide (a seam: the azimuth of a polar warp) or a side collapses to one direction
  // (the pole of a polar warp). A warp that clamps its inverse CDFs stops short of the rim
  // there: its corners go on to the horizon, away from the lobe's centre.
  bool seams[2] = {false, false};  // u.x = 0 is u.x = 1; u.y = 0 is u.y = 1
  for (int sideIndex = 0; sideIndex < 4; ++sideIndex) {
    bool seam = true, collapsed = true;
    int pairs = 0, sampled = 0, first = -1;
    for (int t = 0; t <= n; ++t) {
      const int c = at(sideIndex, t), o = at(sideIndex ^ 1, t);
      if (cornerState_[c] != kSampled) continue;
      if (first < 0) first = c;
      ++sampled;
      if ((corner_[c] - corner_[first]).length2() > kSameDirection2) collapsed = false;
      if (cornerState_[o] == kSampled) {
        ++pairs;
        if ((corner_[c] - corner_[o]).length2() > kSameDirection2) seam = false;
      }
    }
    seam = seam && pairs > 0;
    seams[sideIndex >> 1] = seam;
    if (seam || (collapsed && sampled > 1)) continue;
    for (int t = 0; t <= n; ++t) {
      const int c = at(sideIndex, t);
      if (cornerState_[c] == kSampled && corner_[c].z > 0.0f) {
        corner_[c] = horizonBeyond(lobe, corner_[c]);
      }
    }
  }
  moveUnsampledCorners(lobe, seams);
  for (int axis = 0; axis < 2; ++axis) {
    if (!seams[axis]) continue;
    for (int t = 0; t <= n; ++t) {
      corner_[at(2 * axis + 1, t)] = corner_[at(2 * axis, t)];
      cornerState_[at(2 * axis + 1, t)] = cornerState_[at(2 * axis, t)];
    }
  }
}

void WarpedGatherer::moveUnsampledCorners(const Vec3f& lobe, const bool seams[2]) {
  const int n = n_, side = n + 1;
  // A corner the BSDF could not sample next to one it could lies past the horizon (where the
  // warp leaves the hemisphere) or on it (where its density vanishes). It goes where the warp
  // crosses the horizon, taken to be on the great circle from the lobe's centre through its
  // sampled neighbours (edge neighbours first; across a seam too, and the seam's two sides
  // then made one); then the pixels reach the horizon and tile the hemisphere.
  auto wrap = [n](int v, bool seam) { return !seam ? v : v < 0 ? n - 1 : v > n ? 1 : v; };
  for (int j = 0; j <= n; ++j) {
    for (int i = 0; i <= n; ++i) {
      const int c = j * side + i;
      if (cornerState_[c] != kUnusable) continue;
      Vec3f v(0.0f);
      for (const bool diagonal : {false, true}) {
        for (int dj = -1; dj <= 1; ++dj) {
          for (int di = -1; di <= 1; ++di) {
            const int ii = wrap(i + di, seams[0]), jj = wrap(j + dj, seams[1]);
            if ((di != 0 && dj != 0) != diagonal || (di == 0 && dj == 0) || ii < 0 || ii > n ||
                jj < 0 || jj > n || cornerState_[jj * side + ii] != kSampled) {
              continue;
            }
            v += corner_[jj * side + ii];
          }
        }
        if (v.length2() > 0.0f) break;
      }
      if (v.length2() > 0.0f) {
        corner_[c] = horizonBeyond(lobe, normalize(v));
        cornerState_[c] = kMoved;
      }
    }
  }
}

void WarpedGatherer::samplePixels(const Bsdf& bsdf, const Vec3f& wo, const Vec2f& jitter) {
  const int n = n_;
  const float inv = 1.0f / static_cast<float>(n);
  const float strata = static_cast<float>(n * n);
  const float jx = jitter.x - std::floor(jitter.x), jy = jitter.y - std::floor(jitter.y);
  for (int j = 0; j < n; ++j) {
    for (int i = 0; i < n; ++i) {
      const int k = j * n + i;
      const float t = (static_cast<float>(k) + 0.5f) * kInvGolden + jx + jy;
      const Vec2f u(std::min((static_cast<float>(i) + jx) * inv, kBelowOne),
                    std::min((static_cast<float>(j) + jy) * inv, kBelowOne));
      const auto s = bsdf.sample(wo, t - std::floor(t), u);
      if (!s || s->delta || !(s->wi.z > 0.0f)) continue;  // black, and never hit
      const Vec3f local = normalize(s->wi);
      dirWorld_[k] = normalize(frame_.toWorld(local));
      weight_[k] = s->f * (local.z / (s->pdf * strata));
      sampled_[k] = 1;
    }
  }
}

std::array<int, 4> WarpedGatherer::quadCorners(int k) const {
  const int side = n_ + 1, c00 = (k / n_) * side + k % n_;
  return {c00, c00 + 1, c00 + side + 1, c00 + side};
}

void WarpedGatherer::buildRegions() {
  // Pixel k's quad c0 c1 c2 c3 is cut along c0 c2 into triangles c0 c1 c2 and c0 c2 c3, all
  // oriented alike: the warp's orientation is the sign of the total area.
  const int pixels = n_ * n_;
  double total = 0.0;  // double: the sum of many small areas
  for (int t = 0; t < 2 * pixels; ++t) {
    const auto c = quadCorners(t >> 1);
    const int a = c[0], b = c[1 + (t & 1)], d = c[2 + (t & 1)];
    triArea_[t] = 0.0f;
    // Three corners on the horizon span no solid angle (or, far apart, a whole hemisphere).
    if (cornerState_[a] == kUnusable || cornerState_[b] == kUnusable ||
        cornerState_[d] == kUnusable ||
        (corner_[a].z == 0.0f && corner_[b].z == 0.0f && corner_[d].z == 0.0f)) {
      continue;
    }
    triArea_[t] = triangleSolidAngle(corner_[a], corner_[b], corner_[d]);
    total += triArea_[t];
  }
  const float sign = total < 0.0 ? -1.0f : 1.0f;
  for (int k = 0; k < pixels; ++k) {
    const float area0 = sign * triArea_[2 * k], area1 = sign * triArea_[2 * k + 1];
    solidAngle_[k] = std::max(0.0f, area0 + area1);
    triKept_[2 * k] = area0 > kMinTriangleSolidAngle;
    triKept_[2 * k + 1] = area1 > kMinTriangleSolidAngle;
    // The quad's four sides, then its diagonal c0 c2, as inward normals. cross(q, p) is
    // exactly -cross(p, q), so pixels sharing an edge split the directions near it with
    // neither gap nor overlap.
    const auto c = quadCorners(k);
    Vec3f* e = &quadEdge_[5 * k];
    for (int i = 0; i < 4; ++i) e[i] = cross(corner_[c[i]], corner_[c[(i + 1) & 3]]) * sign;
    e[4] = cross(corner_[c[0]], corner_[c[2]]) * sign;
  }
}

void WarpedGatherer::buildBuckets() {
  const int grid = n_, pixels = n_ * n_;
  for (size_t c = 0; c < corner_.size(); ++c) cornerChart_[c] = chart(corner_[c]);
  // Split each chart axis at quantiles of the corners, so that a lobe that packs every pixel
  // into a few degrees still spreads them over the buckets.
  auto splits = [&](bool useX, std::vector<float>* out) {
    scratch_.clear();
    for (size_t c = 0; c < corner_.size(); ++c) {
      if (cornerState_[c] != kUnusable) {
        scratch_.push_back(useX ? cornerChart_[c].x : cornerChart_[c].y);
      }
    }
    std::sort(scratch_.begin(), scratch_.end());
    out->clear();
    for (int g = 1; g < grid && !scratch_.empty(); ++g) {
      out->push_back(scratch_[g * scratch_.size() / grid]);
    }
  };
  splits(true, &splitX_);
  splits(false, &splitY_);
  auto bucket = [](const std::vector<float>& split, float v) {
    return static_cast<uint8_t>(std::upper_bound(split.begin(), split.end(), v) - split.begin());
  };
  // A pixel goes into every bucket its chart box meets. Its edges are circular arcs in the
  // chart of radius >= 1, which bulge past the chord by at most 1 - sqrt(1 - chord^2 / 4).
  for (int k = 0; k < pixels; ++k) {
    if (!triKept_[2 * k] && !triKept_[2 * k + 1]) continue;
    const auto c = quadCorners(k);
    Vec2f lo(2.0f), hi(-2.0f);
    float chord2 = (cornerChart_[c[0]] - cornerChart_[c[2]]).length2();
    for (int i = 0; i < 4; ++i) {
      const Vec2f& p = cornerChart_[c[i]];
      lo = Vec2f(std::min(lo.x, p.x), std::min(lo.y, p.y));
      hi = Vec2f(std::max(hi.x, p.x), std::max(hi.y, p.y));
      chord2 = std::max(chord2, (p - cornerChart_[c[(i + 1) & 3]]).length2());
    }
    const float pad = 1.0f - std::sqrt(std::max(0.0f, 1.0f - 0.25f * chord2)) + 1e-5f;
    uint8_t* r = &quadRect_[4 * k];
    r[0] = bucket(splitX_, lo.x - pad);
    r[1] = bucket(splitX_, hi.x + pad);
    r[2] = bucket(splitY_, lo.y - pad);
    r[3] = bucket(splitY_, hi.y + pad);
    for (int y = r[2]; y <= r[3]; ++y) {
      for (int x = r[0]; x <= r[1]; ++x) ++bucketStart_[y * grid + x + 1];
    }
  }
  for (int b = 0; b < grid * grid; ++b) bucketStart_[b + 1] += bucketStart_[b];
  bucketPixels_.resize(bucketStart_[grid * grid]);
  // Fill each bucket from the back of its range: its end becomes its start.
  for (int k = pixels; k-- > 0;) {
    if (!triKept_[2 * k] && !triKept_[2 * k + 1]) continue;
    const uint8_t* r = &quadRect_[4 * k];
    for (int y = r[2]; y <= r[3]; ++y) {
      for (int x = r[0]; x <= r[1]; ++x) bucketPixels_[--bucketStart_[y * grid + x + 1]] = k;
    }
  }
  for (int b = 0; b < grid * grid; ++b) bucketStart_[b] = bucketStart_[b + 1];
  bucketStart_[grid * grid] = static_cast<uint32_t>(bucketPixels_.size());
}

double WarpedGatherer::coveredSolidAngle() const {
  double sum = 0.0;
  for (float omega : solidAngle_) sum += omega;
  return sum;
}

int WarpedGatherer::pixelOf(const Vec3f& dir) const {
  const float len = length(dir);
  if (!(len > 0.0f) || !std::isfinite(len)) return -1;
  return pixelOfLocal(frame_.toLocal(dir / len));
}

int WarpedGatherer::pixelOfLocal(const Vec3f& w) const {
  if (!(w.z > kBelowHorizon) || bucketPixels_.empty()) return -1;
  const Vec2f p = chart(w);
  const int x =
      static_cast<int>(std::upper_bound(splitX_.begin(), splitX_.end(), p.x) - splitX_.begin());
  const int y =
      static_cast<int>(std::upper_bound(splitY_.begin(), splitY_.end(), p.y) - splitY_.begin());
  const int b = y * n_ + x;
  for (uint32_t q = bucketStart_[b]; q < bucketStart_[b + 1]; ++q) {
    const uint32_t k = bucketPixels_[q];
    const Vec3f* e = &quadEdge_[5 * k];
    // The diagonal picks the triangle, its two sides on the quad's outline decide.
    const float side = dot(e[4], w);
    if (side <= 0.0f ? triKept_[2 * k] && dot(e[0], w) >= 0.0f && dot(e[1], w) >= 0.0f
                     : triKept_[2 * k + 1] && dot(e[2], w) >= 0.0f && dot(e[3], w) >= 0.0f) {
      return static_cast<int>(k);
    }
  }
  return -1;
}

Rgb WarpedGatherer::pixelRadiance(int k) const {
  return pixels_[k].radiance();
}

void WarpedGatherer::compose(int k, float distance, float extent, float coverage,
                             const Rgb& radiance) {
  pixels_[k].compose(distance, extent, coverage, radiance);
}

void WarpedGatherer::gatherSurfels(const TreePage& page, const TreeNode& leaf, const Vec3f& p,
                                   GatherStats* stats) {
  forEachSeenSurfel(
      page, leaf, p, frame_.n, options_.selfSkipRadius, options_.nearFieldFactor, stats,
      [&](const SeenSurfel& seen) {
        const Surfel& s = *seen.surfel;
        if (!seen.near) {
          const FarDisk far = farDisk(seen);
          const int k = pixelOfLocal(frame_.toLocal(far.dir));
          if (k >= 0 && far.omega <= solidAngle_[k]) {
            if (sampled_[k]) {
              const float coverage = far.omega / solidAngle_[k];
              compose(k, far.distance, kLayerExtentFactor * s.radius, coverage,
                      seen.side.radiance * coverage);
              ++stats->disksSplatted;
            }
            return;
          }
        }
        // Near, larger than its pixel, or in none: exact, after the traversal.
        rayCasts_.push_back({s.position, seen.side.normal, s.radius, seen.side.radiance});
        ++stats->nearFieldRayCasts;
      });
}

absl::Status WarpedGatherer::traverse(TreePageSource& tree, const Vec3f& p, GatherStats* stats) {
  auto splat = [&](const NodeAttributes& a, const NodeBounds& bounds,
                   const WaveletRadiance* wavelet) {
    const Vec3f toCentroid = a.centroid - p;
    const float distance2 = toCentroid.length2();
    const float distance = std::sqrt(distance2);
    // The pixel the node's centroid falls in sets how small it must be; a node in no pixel
    // (its centroid below the horizon) is refined.
    const int k = distance2 > 0.0f ? pixelOfLocal(frame_.toLocal(toCentroid / distance)) : -1;
    const float omega = k >= 0 ? solidAngle_[k] : 0.0f;
    if (k < 0 || kPi * bounds.boundRadius2 > kMaxExtentFactor * omega * bounds.centerDistance2) {
      return false;
    }
    ClusterView view;
    viewCluster(a, toCentroid / distance, &view);
    if (view.coverage() > omega * distance2) return false;
    const float nodeOmega = view.coverage() / distance2;  // both sides cover
    if (!(nodeOmega > 0.0f) || !sampled_[k]) {
      ++stats->clustersInvisible;  // no area towards the receiver, or a black pixel
      return true;
    }
    const float coverage = nodeOmega / omega;
    compose(k, distance, clusterDepthExtent(a, toCentroid / distance), coverage,
            clusterRadiance(a, view, wavelet) * coverage);
    ++stats->clustersSplatted;
    return true;
  };
  return walk_.run(tree, p, frame_.n, stats, splat,
                   [&](const TreePage& page, const TreeNode& leaf) {
                     gatherSurfels(page, leaf, p, stats);
                   });
}

void WarpedGatherer::rayCast(const Vec3f& p) {
  const int pixels = n_ * n_;
  for (const Disk& d : rayCasts_) {
    // Black pixels have a zero direction: never hit.
    const DiskHitTest disk(d.center, d.normal, d.radius, p);
    for (int k = 0; k < pixels; ++k) {
      float t;
      if (disk.hit(dirWorld_[k], &t)) compose(k, t, d.radius, 1.0f, d.radiance);
    }
  }
}

absl::StatusOr<Rgb> WarpedGatherer::reflect(TreePageSource& tree, const Vec3f& position,
                                            const Frame& frame, const Bsdf& bsdf,
                                            const Vec3f& woLocal, const Vec2f& jitter,
                                            GatherStats* stats) {
  if (!isFinite(position)) {
    return absl::InvalidArgumentError(
        fmt::format("warped gather: receiver needs a finite position, got {}", position));
  }
  if (absl::Status s = warp(frame, bsdf, woLocal, jitter); !s.ok()) return s;
  GatherStats local;
  local.gathers = 1;
  const int pixels = n_ * n_;
  for (int k = 0; k < pixels; ++k) local.pixelsSkipped += sampled_[k] ? 0 : 1;
  Rgb sum(0.0f);
  std::fill(pixels_.begin(), pixels_.end(), Pixel{});
  if (local.pixelsSkipped < static_cast<uint64_t>(pixels)) {
    rayCasts_.clear();
    absl::Status status = traverse(tree, position, &local);
    if (!status.ok()) {
      if (stats != nullptr) *stats += local;
      return status;
    }
    rayCast(position);
    for (int k = 0; k < pixels; ++k) sum += pixelRadiance(k) * weight_[k];
  }
  if (stats != nullptr) *stats += local;
  if (!isFinite(sum)) {
    return absl::DataLossError(fmt::format(
        "warped gather: radiance {} at {} is not finite: the tree holds non-finite radiance", sum,
        position));
  }
  return sum;
}

}  // namespace pbgi
