#include "core/bake/surfel_bounce.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <tbb/parallel_for.h>

#include "core/bake/surfel_sampler.h"
#include "core/sampling/rng.h"
#include "core/sampling/sampling.h"
#include "core/util/check.h"

namespace pbgi {

bool reflectsLight(const Surfel& s) {
  return s.materialClass == MaterialClass::kDiffuse && !isBlack(s.albedo);
}

CutOptions bounceCutOptions(const CutOptions& first, int bounce) {
  CutOptions o = first;
  // The first bounce's descents by cones, the later ones' by SH (bidirectional_cut.h).
  o.coneDescent = bounce <= 1;
  if (bounce <= 1) return o;
  const float hi = 4.0f * kPi;
  o.lightSolidAngle = std::min(hi, o.lightSolidAngle * kLaterBounceCoarsening);
  o.lightBound = std::min(hi, o.lightBound * kLaterBounceCoarsening);
  o.receiverBound = std::min(hi, o.receiverBound * kLaterBounceCoarsening);
  return o;
}

absl::StatusOr<CutOptions> bounceCutPreset(std::string_view quality) {
  absl::StatusOr<CutOptions> cut = cutPreset(quality);
  if (cut.ok()) {
    cut->nearRays = 0;
    cut->recordVisibility = false;
  }
  return cut;
}

int bounceReceiverSpacing(int first, int bounce) {
  if (bounce <= 1 || first <= 1) return first;
  // kLaterBounceSpacing times the first's at the second bounce, twice that at each later one.
  int64_t spacing = int64_t{first} * kLaterBounceSpacing;
  for (int b = 2; b < bounce && spacing < kMaxBounceSpacing; ++b) spacing *= 2;
  return static_cast<int>(std::min<int64_t>(kMaxBounceSpacing, spacing));
}

BounceGatherer::BounceGatherer(const CutOptions& options, int receiverSpacing)
    : options_(options), receiverSpacing_(receiverSpacing) {
  PBGI_CHECK_GE(receiverSpacing, 1);
}

namespace {

uint64_t cellKey(const std::array<int32_t, 3>& c) {
  return hashKeys(static_cast<uint32_t>(c[0]), static_cast<uint32_t>(c[1]),
                  static_cast<uint32_t>(c[2]));
}

constexpr uint8_t kFrontSeen = 1, kBackSeen = 2;

// On which of their sides two surfels of one surface see each other (kFrontSeen, kBackSeen):
// a wall between them hides one side or both. Each end is lifted by the bulge a convex surface
// whose normals turn by their angle has between them, (d / 2) tan(angle / 4), twice over.
uint8_t sidesSeen(const Scene& scene, const Surfel& a, const Surfel& b) {
  const float d = length(b.position - a.position);
  const float angle = std::acos(std::clamp(dot(a.normal, b.normal), -1.0f, 1.0f));
  const float lift = d * std::tan(0.25f * angle);
  uint8_t seen = 0;
  if (scene.seeAlongSurface(a.position, a.normal, b.position, b.normal, lift)) seen |= kFrontSeen;
  if (scene.seeAlongSurface(a.position, -a.normal, b.position, -b.normal, lift)) seen |= kBackSeen;
  return seen;
}

}  // namespace

void BounceGatherer::makePatches(const Scene& scene, std::span<const Surfel> surfels, size_t first,
                                 size_t end, Patches& out) const {
  out.recordOf.clear();
  out.cellOf.clear();
  out.inCell.clear();
  out.patchOf.assign(end - first, Patches::kNoPatch);
  // A cell holds about receiverSpacing surfels of a surface crossing it: each surfel's share
  // of its surface is pi r^2, r the group's mean radius.
  double radii = 0.0;
  size_t lit = 0;
  for (size_t i = first; i < end; ++i) {
    if (!reflectsLight(surfels[i])) continue;
    radii += surfels[i].radius;
    ++lit;
  }
  if (lit == 0) return;
  const auto r = static_cast<float>(radii / static_cast<double>(lit));
  out.cell = std::sqrt(static_cast<float>(receiverSpacing_) * kPi) * r;
  std::vector<Vec3f> sums, heads;  // each patch's sum of positions, and its first normal
  for (size_t i = first; i < end; ++i) {
    const Surfel& s = surfels[i];
    if (!reflectsLight(s)) continue;
    std::array<int32_t, 3> c;
    for (int a = 0; a < 3; ++a) c[a] = static_cast<int32_t>(std::floor(s.position[a] / out.cell));
    std::vector<uint32_t>& inCell = out.inCell[cellKey(c)];
    uint32_t patch = Patches::kNoPatch;
    // A spacing of 1: every surfel is its own patch and record.
    // A patch it faces the way of, whose first surfel it sees on both sides.
    for (const uint32_t k : receiverSpacing_ == 1 ? std::span<const uint32_t>{} : inCell) {
      if (out.cellOf[k] == c && dot(heads[k], s.normal) >= kPatchNormalCos &&
          sidesSeen(scene, surfels[out.recordOf[k]], s) == (kFrontSeen | kBackSeen)) {
        patch = k;
        break;
      }
    }
    if (patch == Patches::kNoPatch) {
      patch = static_cast<uint32_t>(heads.size());
      heads.push_back(s.normal);
      sums.push_back(Vec3f(0.0f));
      out.cellOf.push_back(c);
      out.recordOf.push_back(static_cast<uint32_t>(i));
      inCell.push_back(patch);
    }
    sums[patch] += s.position;
    out.patchOf[i - first] = patch;
  }
  // Each patch's record: the member nearest its centre (the first such in the tree's order).
  std::vector<uint32_t> counts(heads.size(), 0);
  for (const uint32_t k : out.patchOf) {
    if (k != Patches::kNoPatch) ++counts[k];
  }
  std::vector<float> best(heads.size(), std::numeric_limits<float>::infinity());
  for (size_t i = first; i < end; ++i) {
    const uint32_t k = out.patchOf[i - first];
    if (k == Patches::kNoPatch) continue;
    const float d = length(surfels[i].position - sums[k] / static_cast<float>(counts[k]));
    if (d < best[k]) {
      best[k] = d;
      out.recordOf[k] = static_cast<uint32_t>(i);
    }
  }
}

void BounceGatherer::spread(const Scene& scene, std::span<const Surfel> surfels, size_t first,
                            const Patches& patches, const Side& front, const Side& back,
                            std::span<SurfelIrradiance> irradiance) const {
  const float reach = kRecordReachCells * patches.cell;
  // Which sides of each patch's record see which other records, as asked.
  std::vector<std::vector<std::pair<uint32_t, uint8_t>>> seen(patches.recordOf.size());
  auto sides = [&](uint32_t own, uint32_t k) {
    for (const auto& [other, mask] : seen[own]) {
      if (other == k) return mask;
    }
    const uint8_t mask =
        sidesSeen(scene, surfels[patches.recordOf[own]], surfels[patches.recordOf[k]]);
    seen[own].emplace_back(k, mask);
    return mask;
  };
  for (size_t at = 0; at < patches.patchOf.size(); ++at) {
    const uint32_t own = patches.patchOf[at];
    if (own == Patches::kNoPatch) continue;
    const size_t i = first + at;
    if (patches.recordOf[own] == i) {
      irradiance[i] = {front.byRecord[own], back.byRecord[own]};
      continue;
    }
    const Surfel& s = surfels[i];
    const std::array<int32_t, 3>& c = patches.cellOf[own];
    SurfelIrradiance sum;
    float frontTotal = 0.0f, backTotal = 0.0f;
    for (int dz = -1; dz <= 1; ++dz) {
      for (int dy = -1; dy <= 1; ++dy) {
        for (int dx = -1; dx <= 1; ++dx) {
          const std::array<int32_t, 3> n{c[0] + dx, c[1] + dy, c[2] + dz};
          const auto cell = patches.inCell.find(cellKey(n));
          if (cell == patches.inCell.end()) continue;
          for (const uint32_t k : cell->second) {
            if (patches.cellOf[k] != n) continue;
            const Surfel& r = surfels[patches.recordOf[k]];
            if (k != own && dot(s.normal, r.normal) < kPatchNormalCos) continue;
            float w = std::max(0.0f, 1.0f - length(s.position - r.position) / reach);
            w *= w;
            // The surfel's own patch always counts: it joined it by the same tests. Another
            // counts on the sides its record and the own one see each other.
            if (k == own) w = std::max(w, 1e-3f);
            if (!(w > 0.0f)) continue;
            const uint8_t mask = k == own ? (kFrontSeen | kBackSeen) : sides(own, k);
            if (mask & kFrontSeen) {
              sum.front += front.byRecord[k] * w;
              frontTotal += w;
            }
            if (mask & kBackSeen) {
              sum.back += back.byRecord[k] * w;
              backTotal += w;
            }
          }
        }
      }
    }
    irradiance[i] = {sum.front / frontTotal, sum.back / backTotal};
  }
}

bool seesNoSurface(const Scene& scene, const Vec3f& p, const Vec3f& n, uint64_t key) {
  const Frame frame(n);
  Rng rng(key);
  constexpr int kSide = 4;  // kShutProbeRays strata, kSide x kSide
  static_assert(kSide * kSide == kShutProbeRays);
  for (int k = 0; k < kShutProbeRays; ++k) {
    const Vec2f u((static_cast<float>(k % kSide) + rng.uniform()) / kSide,
                  (static_cast<float>(k / kSide) + rng.uniform()) / kSide);
    const Ray ray = scene.spawnRay(p, n, frame.toWorld(sampleCosineHemisphere(u)));
    if (scene.occluded(ray)) return false;
  }
  return true;
}

absl::Status BounceGatherer::gather(TreePageSource& tree, const Scene& scene,
                                    std::span<const Surfel> surfels, size_t groupSize,
                                    std::span<const uint64_t> keys, size_t groupsTogether,
                                    std::span<SurfelIrradiance> irradiance, CutStats* stats,
                                    std::span<const SurfelIrradiance> previous,
                                    uint64_t* shutSides, bool probeBlackSides) {
  PBGI_CHECK_GT(groupSize, size_t{0});
  PBGI_CHECK_EQ(irradiance.size(), surfels.size());
  PBGI_CHECK(previous.empty() || previous.size() == surfels.size());
  const size_t groups = (surfels.size() + groupSize - 1) / groupSize;
  PBGI_CHECK_EQ(keys.size(), groups);
  std::fill(irradiance.begin(), irradiance.end(), SurfelIrradiance{});
  while (sides_.size() < 2 * groups) sides_.emplace_back(options_);
  // One cut per side: a receiver tree of both sides would pair every receiver with its
  // opposite in each node, whose normals no cone narrower than a hemisphere holds, and share
  // nothing.
  PBGI_CHECK_GT(groupsTogether, size_t{0});
  if (patches_.size() < std::min(groups, groupsTogether)) {
    patches_.resize(std::min(groups, groupsTogether));
  }
  std::vector<BidirectionalCut*> cuts;
  std::vector<CutJob> jobs;
  for (size_t batch = 0; batch < groups; batch += groupsTogether) {
    const size_t batchEnd = std::min(groups, batch + groupsTogether);
    cuts.clear();
    jobs.clear();
    // Each group's patches and the records each side gathers at, in parallel (their rays).
    std::vector<uint64_t> shut(batchEnd - batch, 0);
    tbb::parallel_for(batch, batchEnd, [&](size_t g) {
      const size_t first = g * groupSize, end = std::min(surfels.size(), first + groupSize);
      Patches& patches = patches_[g - batch];
      makePatches(scene, surfels, first, end, patches);
      for (const int side : {0, 1}) {
        Side& c = sides_[2 * g + side];
        c.receivers.clear();
        c.recordOf.clear();
        for (uint32_t k = 0; k < patches.recordOf.size(); ++k) {
          const uint32_t i = patches.recordOf[k];
          const Surfel& s = surfels[i];
          // A surfel lies on its triangle: its shadow rays leave from its centre along the
          // side's normal.
          const Vec3f n = side == 0 ? s.normal : -s.normal;
          if (!previous.empty() && isBlack(side == 0 ? previous[i].front : previous[i].back) &&
              (!probeBlackSides || seesNoSurface(scene, s.position, n, hashKeys(keys[g], side, k)))) {
            ++shut[g - batch];
            continue;
          }
          c.receivers.push_back({.p = s.position, .n = n, .ng = n});
          c.recordOf.push_back(k);
        }
        c.gathered.resize(c.receivers.size());
      }
    });
    for (size_t g = batch; g < batchEnd; ++g) {
      if (shutSides != nullptr) *shutSides += shut[g - batch];
      for (const int side : {0, 1}) {
        Side& c = sides_[2 * g + side];
        cuts.push_back(&c.cut);
        jobs.push_back(
            {.receivers = c.receivers, .key = hashKeys(keys[g], side), .out = c.gathered});
      }
    }
    if (absl::Status s = cutTogether(tree, scene, cuts, jobs, stats); !s.ok()) return s;
    for (size_t k = 2 * batch; k < 2 * batchEnd; ++k) {
      // By record, black where shut.
      Side& c = sides_[k];
      std::vector<Rgb>& byRecord = c.byRecord;
      byRecord.assign(patches_[k / 2 - batch].recordOf.size(), Rgb(0.0f));
      for (size_t r = 0; r < c.recordOf.size(); ++r) byRecord[c.recordOf[r]] = c.gathered[r];
    }
    tbb::parallel_for(batch, batchEnd, [&](size_t g) {
      spread(scene, surfels, g * groupSize, patches_[g - batch], sides_[2 * g], sides_[2 * g + 1],
             irradiance);
    });
  }
  return absl::OkStatus();
}

Rgb reflectedPower(const Surfel& s, const SurfelIrradiance& e) {
  return reflectsLight(s) ? s.albedo * (e.front + e.back) * (s.area() * kInvPi) : Rgb(0.0f);
}

void addReflected(Surfel& s, const SurfelIrradiance& e) {
  if (!reflectsLight(s)) return;
  s.radiance += s.albedo * kInvPi * e.front;
  s.backRadiance += s.albedo * kInvPi * e.back;
}

float largestBounceRatio(const Scene& scene) {
  float largest = 0.0f;
  for (const Material& m : scene.materials()) {
    if (materialClassOf(m) == MaterialClass::kEmissive) continue;
    const bool unbounded = m.albedoTexture != nullptr || m.type == MaterialType::kDielectric;
    largest = std::max(largest, unbounded ? 1.0f : maxComponent(hemisphericalAlbedo(m)));
  }
  return std::min(largest, kMaxBounceRatio);
}

Rgb tailFactor(std::span<const std::array<double, 3>> power, float maxRatio) {
  Rgb f(0.0f);
  const size_t k = power.size();
  const double held = std::clamp(std::isfinite(maxRatio) ? maxRatio : 0.0f, 0.0f, kMaxBounceRatio);
  if (k < 2) return f;
  const size_t steps = k > 3 ? 2 : 1;  // P_K over P_{K-2} from the third bounce (power[3]) on
  const std::array<double, 3>& last = power[k - 1];
  const std::array<double, 3>& before = power[k - 1 - steps];
  for (int c = 0; c < 3; ++c) {
    if (!(last[c] > 0.0) || !(before[c] > 0.0)) continue;
    const double ratio = last[c] / before[c];
    const double r = std::min<double>(steps == 2 ? std::sqrt(ratio) : ratio, held);
    f[c] = static_cast<float>(r / (1.0 - r));
  }
  return f;
}

}  // namespace pbgi
