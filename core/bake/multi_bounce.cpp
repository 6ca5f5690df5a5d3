#include "core/bake/multi_bounce.h"

#include <algorithm>
#include <array>
#include <vector>

#include <fmt/format.h>

#include "core/sampling/rng.h"
#include "core/util/bytes.h"
#include "core/util/check.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

// A surfel's spilled irradiance: front then back, 3 x f32 each, little-endian.
constexpr size_t kIrradianceBytes = 24;

absl::Status readSurfels(SpillFile& sorted, size_t n, std::vector<uint8_t>& bytes,
                         std::vector<SortedSurfel>& batch) {
  bytes.resize(n * kSurfelRecordBytes);
  if (auto s = sorted.read(bytes); !s.ok()) return s;
  batch.resize(n);
  for (size_t i = 0; i < n; ++i) {
    if (auto s = decodeSurfelRecord(bytes.data() + i * kSurfelRecordBytes, &batch[i]); !s.ok()) {
      return absl::DataLossError(fmt::format("{}: {}", sorted.name(), s.message()));
    }
  }
  return absl::OkStatus();
}

// n surfels' irradiance from `spill`, or black when there is none (before the first bounce).
absl::Status readIrradiance(SpillFile* spill, size_t n, std::vector<uint8_t>& bytes,
                            std::vector<SurfelIrradiance>& out) {
  out.assign(n, SurfelIrradiance{});
  if (spill == nullptr) return absl::OkStatus();
  bytes.resize(n * kIrradianceBytes);
  if (auto s = spill->read(bytes); !s.ok()) return s;
  for (size_t i = 0; i < n; ++i) {
    const uint8_t* p = bytes.data() + i * kIrradianceBytes;
    for (int c = 0; c < 3; ++c) {
      out[i].front[c] = loadF32(p + 4 * c);
      out[i].back[c] = loadF32(p + 12 + 4 * c);
    }
  }
  return absl::OkStatus();
}

absl::Status writeIrradiance(SpillFile& spill, std::span<const SurfelIrradiance> e,
                             std::vector<uint8_t>& bytes) {
  bytes.resize(e.size() * kIrradianceBytes);
  for (size_t i = 0; i < e.size(); ++i) {
    uint8_t* p = bytes.data() + i * kIrradianceBytes;
    for (int c = 0; c < 3; ++c) {
      storeF32(p + 4 * c, e[i].front[c]);
      storeF32(p + 12 + 4 * c, e[i].back[c]);
    }
  }
  return spill.write(bytes);
}

}  // namespace

absl::StatusOr<Rgb> runBounce(const BounceRequest& request, CutStats* stats) {
  if (auto s = request.sorted->rewind(); !s.ok()) return s;
  if (request.previous != nullptr) {
    if (auto s = request.previous->rewind(); !s.ok()) return s;
  }
  BounceGatherer bouncer(request.cut, request.receiverSpacing);
  std::vector<SortedSurfel> batch;
  std::vector<Surfel> chunk;
  std::vector<SurfelIrradiance> previous, added, total;
  std::vector<uint64_t> keys;
  std::vector<uint8_t> bytes;
  double sum[3] = {0.0, 0.0, 0.0};
  PBGI_CHECK(request.batchSurfels > 0 && request.batchSurfels % kBounceChunkSurfels == 0);
  for (uint64_t done = 0; done < request.surfels;) {
    if (request.cancel && request.cancel->load(std::memory_order_relaxed)) {
      return absl::CancelledError(fmt::format("bounce {} was cancelled", request.bounce));
    }
    const size_t n =
        static_cast<size_t>(std::min<uint64_t>(request.surfels - done, request.batchSurfels));
    if (auto s = readSurfels(*request.sorted, n, bytes, batch); !s.ok()) return s;
    if (auto s = readIrradiance(request.previous, n, bytes, previous); !s.ok()) return s;
    chunk.resize(n);
    for (size_t i = 0; i < n; ++i) chunk[i] = batch[i].surfel;
    added.assign(n, SurfelIrradiance{});
    // The cuts' groups start at multiples of kBounceChunkSurfels in the sorted order and key
    // their random numbers by it, whatever the threads; the batch's cuts sweep together.
    keys.clear();
    for (size_t first = 0; first < n; first += kBounceChunkSurfels) {
      keys.push_back(hashKeys(request.seed, request.frame, request.bounce, done + first));
    }
    // After the first bounce, sides that gathered nothing so far are shut; in the second,
    // only those that see no surface (BounceGatherer::gather).
    if (auto s = bouncer.gather(*request.from, *request.scene, chunk, kBounceChunkSurfels, keys,
                                request.groupsTogether, added, stats,
                                request.previous != nullptr
                                    ? std::span<const SurfelIrradiance>(previous)
                                    : std::span<const SurfelIrradiance>(),
                                request.shutSides, request.bounce == 2);
        !s.ok()) {
      return s;
    }
    total.resize(n);
    for (size_t i = 0; i < n; ++i) {
      total[i] = {previous[i].front + added[i].front, previous[i].back + added[i].back};
    }
    if (auto s = writeIrradiance(*request.next, total, bytes); !s.ok()) return s;
    for (size_t i = 0; i < n; ++i) {
      const Rgb p = reflectedPower(chunk[i], added[i]);
      for (int c = 0; c < 3; ++c) sum[c] += p[c];
      if (!request.added) continue;
      SortedSurfel lit = batch[i];
      lit.surfel.radiance = Rgb(0.0f);
      lit.surfel.backRadiance = Rgb(0.0f);
      addReflected(lit.surfel, added[i]);
      if (auto s = request.added(lit); !s.ok()) return s;
    }
    done += n;
    if (request.progress) request.progress(done, request.surfels);
  }
  return Rgb(static_cast<float>(sum[0]), static_cast<float>(sum[1]), static_cast<float>(sum[2]));
}

Rgb tailLight(const Rgb& added, const Rgb& addedBefore, const Rgb& addedEarlier, const Rgb& tail,
              bool local) {
  Rgb out(0.0f);
  for (int c = 0; c < 3; ++c) {
    const float f = tail[c];
    if (!(f > 0.0f)) continue;
    out[c] = added[c] * f;
    if (!local) continue;
    const float r = f / (1.0f + f);
    // x_k = dE_k - r dE_{k-1}: the part of the light that does not go as r^k, C q^(k-1) (q - r).
    const float x = added[c] - r * addedBefore[c];
    const float xBefore = addedBefore[c] - r * addedEarlier[c];
    if (!(x * xBefore > 0.0f)) continue;  // not one exponential: the geometric tail
    const float q = std::min(x / xBefore, r);
    out[c] = std::max(0.0f, out[c] + x * q / ((1.0f - q) * (1.0f - r)));
  }
  return out;
}

absl::Status finalLight(SpillFile& sorted, std::span<SpillFile* const> cumulative, const Rgb& tail,
                        uint64_t surfels, const SurfelSink& out) {
  PBGI_CHECK(!cumulative.empty() && cumulative.size() <= kTailBounces &&
             cumulative.back() != nullptr);
  if (auto s = sorted.rewind(); !s.ok()) return s;
  for (SpillFile* f : cumulative) {
    if (auto s = f->rewind(); !s.ok()) return s;
  }
  // E_K, E_{K-1}, ... (the irradiance so far after each of the last bounces), black before the
  // first: with three bounces or more, each surfel's light past the last follows its own.
  const size_t kept = cumulative.size();
  const bool local = kept >= 3;
  std::array<std::vector<SurfelIrradiance>, kTailBounces> e;
  std::vector<SortedSurfel> batch;
  std::vector<uint8_t> bytes;
  const auto withTail = [&](size_t i, bool front) {
    std::array<Rgb, kTailBounces> sums;  // sums[j]: E_{K-j}
    for (size_t j = 0; j < kTailBounces; ++j) {
      sums[j] = front ? e[j][i].front : e[j][i].back;
    }
    const auto addedAt = [&](size_t j) {
      return j + 1 < kTailBounces ? vmax(sums[j] - sums[j + 1], Rgb(0.0f)) : Rgb(0.0f);
    };
    return sums[0] + tailLight(addedAt(0), addedAt(1), addedAt(2), tail, local);
  };
  for (uint64_t done = 0; done < surfels;) {
    const size_t n = static_cast<size_t>(std::min<uint64_t>(surfels - done, kBounceBatchSurfels));
    if (auto s = readSurfels(sorted, n, bytes, batch); !s.ok()) return s;
    for (size_t j = 0; j < kTailBounces; ++j) {
      SpillFile* spill = j < kept ? cumulative[kept - 1 - j] : nullptr;
      if (auto s = readIrradiance(spill, n, bytes, e[j]); !s.ok()) return s;
    }
    for (size_t i = 0; i < n; ++i) {
      addReflected(batch[i].surfel, {withTail(i, true), withTail(i, false)});
      if (auto s = out(batch[i]); !s.ok()) return s;
    }
    done += n;
  }
  return absl::OkStatus();
}

}  // namespace pbgi
