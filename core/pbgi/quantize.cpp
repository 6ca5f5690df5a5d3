#include "core/pbgi/quantize.h"

#include <algorithm>
#include <cmath>
#include <limits>

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include "core/sampling/rng.h"
#include "core/util/check.h"

namespace pbgi {

namespace {

constexpr uint64_t kSampleDomain = 0x4b4d53414d504c45ull;   // the training sample's offset
constexpr uint64_t kSeedingDomain = 0x4b4d2b2b53454544ull;  // k-means++ draws

// Lloyd's sums are split into at most this many blocks, a number fixed by the sample size
// alone, never by the threads that happen to run them.
constexpr size_t kMaxBlocks = 64;
constexpr size_t kMinBlockSize = 1024;

float distance2(const float* a, const float* b, int dim) {
  float d = 0.0f;
  for (int i = 0; i < dim; ++i) {
    const float t = a[i] - b[i];
    d += t * t;
  }
  return d;
}

// Squared distance, or early out with something >= bound once the partial sum reaches it.
// Float sums of non-negative terms never decrease, so the partial sum is a lower bound and
// the nearest entry found this way is the one the full sums would pick.
float distance2Bounded(const float* a, const float* b, int dim, float bound) {
  float d = 0.0f;
  for (int i = 0; i < dim; ++i) {
    const float t = a[i] - b[i];
    d += t * t;
    if (d >= bound) return d;
  }
  return d;
}

// Nearest of `count` row-major centres; ties go to the lowest index.
uint32_t nearest(const float* centres, int count, int dim, const float* v, float* bestD2) {
  uint32_t best = 0;
  float bestD = std::numeric_limits<float>::infinity();
  for (int c = 0; c < count; ++c) {
    const float d = distance2Bounded(v, centres + static_cast<size_t>(c) * dim, dim, bestD);
    if (d < bestD) {
      bestD = d;
      best = static_cast<uint32_t>(c);
    }
  }
  if (bestD2 != nullptr) *bestD2 = bestD;
  return best;
}

bool isZero(const float* v, int dim) {
  for (int i = 0; i < dim; ++i) {
    if (v[i] != 0.0f) return false;
  }
  return true;
}

bool isFiniteVector(const float* v, int dim) {
  for (int i = 0; i < dim; ++i) {
    if (!std::isfinite(v[i])) return false;
  }
  return true;
}

struct Blocks {
  size_t size = 0;   // points per block
  size_t count = 0;  // blocks
};

Blocks blocksFor(size_t points) {
  Blocks b;
  b.size = std::max(kMinBlockSize, (points + kMaxBlocks - 1) / kMaxBlocks);
  b.count = (points + b.size - 1) / b.size;
  return b;
}

// Sum of d2 in fixed blocks, combined in order.
double deterministicSum(const std::vector<float>& d2) {
  const Blocks blocks = blocksFor(d2.size());
  std::vector<double> partial(blocks.count, 0.0);
  tbb::parallel_for(size_t{0}, blocks.count, [&](size_t b) {
    const size_t end = std::min(d2.size(), (b + 1) * blocks.size);
    double s = 0.0;
    for (size_t i = b * blocks.size; i < end; ++i) s += d2[i];
    partial[b] = s;
  });
  double total = 0.0;
  for (double s : partial) total += s;
  return total;
}

// k-means++ (Arthur and Vassilvitskii 2007): each next centre drawn in proportion to the
// squared distance to the nearest centre so far. Stops early when every point coincides with
// a centre (fewer distinct points than centres).
std::vector<float> seedCentres(const std::vector<float>& points, size_t m, int dim, int k,
                               uint64_t seed) {
  Rng rng = Rng::forKeys(seed, kSeedingDomain);
  std::vector<float> centres;
  centres.reserve(static_cast<size_t>(k) * dim);
  const size_t first = std::min(m - 1, static_cast<size_t>(rng.uniform() * static_cast<double>(m)));
  centres.insert(centres.end(), points.begin() + first * dim, points.begin() + (first + 1) * dim);
  std::vector<float> d2(m);
  auto update = [&](const float* centre) {
    tbb::parallel_for(
        tbb::blocked_range<size_t>(0, m, 1024), [&](const tbb::blocked_range<size_t>& r) {
          for (size_t i = r.begin(); i != r.end(); ++i) {
            const float d = distance2(points.data() + i * dim, centre, dim);
            d2[i] = centres.size() == static_cast<size_t>(dim) ? d : std::min(d2[i], d);
          }
        });
  };
  update(centres.data());
  while (centres.size() < static_cast<size_t>(k) * dim) {
    const double total = deterministicSum(d2);
    if (!(total > 0.0)) break;
    const double target = static_cast<double>(rng.uniform()) * total;
    size_t pick = m;
    size_t lastPositive = m;
    double cumulative = 0.0;
    for (size_t i = 0; i < m; ++i) {
      if (d2[i] <= 0.0f) continue;
      lastPositive = i;
      cumulative += d2[i];
      if (cumulative > target) {
        pick = i;
        break;
      }
    }
    if (pick == m) pick = lastPositive;  // rounding left the target at the very end
    const size_t offset = centres.size();
    centres.insert(centres.end(), points.begin() + pick * dim, points.begin() + (pick + 1) * dim);
    update(centres.data() + offset);
  }
  return centres;
}

}  // namespace

Codebook trainCodebook(std::span<const float> vectors, int dim, const KMeansOptions& options) {
  PBGI_CHECK_GT(dim, 0);
  PBGI_CHECK_EQ(vectors.size() % static_cast<size_t>(dim), size_t{0});
  PBGI_CHECK_GE(options.centres, 0);
  PBGI_CHECK_GE(options.iterations, 0);
  Codebook codebook;
  codebook.dimension = dim;
  codebook.entries.assign(dim, 0.0f);  // the black entry
  const size_t n = vectors.size() / dim;

  // The training sample: one vector drawn from each of s equal strata of the input, so that
  // it covers the input evenly in its given order (which for tree nodes follows space) and
  // yet cannot alias with a period in it, as every-k-th sampling would.
  size_t s = static_cast<size_t>(std::llround(static_cast<double>(n) * options.sampleFraction));
  s = std::min(n, std::clamp(s, options.minSample, std::max(options.minSample, options.maxSample)));
  if (s == 0 || options.centres == 0) return codebook;
  Rng sampleRng = Rng::forKeys(options.seed, kSampleDomain);
  std::vector<float> points;
  points.reserve(s * dim);
  for (size_t i = 0; i < s; ++i) {
    const double jitter = sampleRng.uniform();
    const size_t index =
        std::min(n - 1, static_cast<size_t>((static_cast<double>(i) + jitter) *
                                            static_cast<double>(n) / static_cast<double>(s)));
    const float* v = vectors.data() + index * dim;
    if (isZero(v, dim) || !isFiniteVector(v, dim)) continue;
    points.insert(points.end(), v, v + dim);
  }
  const size_t m = points.size() / dim;
  if (m == 0) return codebook;

  std::vector<float> centres = seedCentres(points, m, dim, options.centres, options.seed);
  const int k = static_cast<int>(centres.size() / dim);

  // Lloyd's iterations.
  std::vector<uint32_t> assignment(m, ~0u);
  std::vector<float> d2(m);
  const Blocks blocks = blocksFor(m);
  std::vector<double> sums(blocks.count * k * dim);
  std::vector<uint64_t> counts(blocks.count * k);
  for (int iteration = 0; iteration < options.iterations; ++iteration) {
    std::fill(sums.begin(), sums.end(), 0.0);
    std::fill(counts.begin(), counts.end(), 0);
    std::vector<uint8_t> blockChanged(blocks.count, 0);
    tbb::parallel_for(size_t{0}, blocks.count, [&](size_t b) {
      double* blockSums = sums.data() + b * k * dim;
      uint64_t* blockCounts = counts.data() + b * k;
      const size_t end = std::min(m, (b + 1) * blocks.size);
      for (size_t i = b * blocks.size; i < end; ++i) {
        const float* p = points.data() + i * dim;
        const uint32_t c = nearest(centres.data(), k, dim, p, &d2[i]);
        if (c != assignment[i]) blockChanged[b] = 1;
        assignment[i] = c;
        ++blockCounts[c];
        for (int j = 0; j < dim; ++j) blockSums[c * dim + j] += p[j];
      }
    });
    if (std::none_of(blockChanged.begin(), blockChanged.end(), [](uint8_t c) { return c != 0; })) {
      break;  // converged: the centres below would come out the same
    }
    std::vector<double> total(static_cast<size_t>(k) * dim, 0.0);
    std::vector<uint64_t> totalCount(k, 0);
    for (size_t b = 0; b < blocks.count; ++b) {
      for (size_t j = 0; j < total.size(); ++j) total[j] += sums[b * k * dim + j];
      for (int c = 0; c < k; ++c) totalCount[c] += counts[b * k + c];
    }
    for (int c = 0; c < k; ++c) {
      if (totalCount[c] == 0) {
        // An empty cluster takes the worst-served point (lowest index on a tie), which then
        // counts as served.
        const size_t worst =
            static_cast<size_t>(std::max_element(d2.begin(), d2.end()) - d2.begin());
        std::copy_n(points.data() + worst * dim, dim,
                    centres.data() + static_cast<size_t>(c) * dim);
        d2[worst] = 0.0f;
        continue;
      }
      for (int j = 0; j < dim; ++j) {
        centres[static_cast<size_t>(c) * dim + j] = static_cast<float>(
            total[static_cast<size_t>(c) * dim + j] / static_cast<double>(totalCount[c]));
      }
    }
  }
  codebook.entries.insert(codebook.entries.end(), centres.begin(), centres.end());
  return codebook;
}

uint32_t nearestEntry(const Codebook& codebook, std::span<const float> v) {
  PBGI_CHECK_EQ(v.size(), static_cast<size_t>(codebook.dimension));
  PBGI_CHECK_GT(codebook.size(), 0);
  return nearest(codebook.entries.data(), codebook.size(), codebook.dimension, v.data(), nullptr);
}

QuantizationError measureError(const Codebook& codebook, std::span<const float> vectors) {
  const int dim = codebook.dimension;
  PBGI_CHECK_GT(dim, 0);
  PBGI_CHECK_EQ(vectors.size() % static_cast<size_t>(dim), size_t{0});
  const size_t n = vectors.size() / dim;
  struct Partial {
    double error2 = 0.0;
    double norm2 = 0.0;
    double maxRelative = 0.0;
    size_t nonFinite = 0;
  };
  const Blocks blocks = blocksFor(n);
  std::vector<Partial> partial(blocks.count);
  tbb::parallel_for(size_t{0}, blocks.count, [&](size_t b) {
    Partial p;
    const size_t end = std::min(n, (b + 1) * blocks.size);
    for (size_t i = b * blocks.size; i < end; ++i) {
      const float* v = vectors.data() + i * dim;
      if (!isFiniteVector(v, dim)) {
        ++p.nonFinite;
        continue;
      }
      const uint32_t e = nearestEntry(codebook, std::span<const float>(v, dim));
      const float* q = codebook.entries.data() + static_cast<size_t>(e) * dim;
      double err = 0.0, norm = 0.0;
      for (int j = 0; j < dim; ++j) {
        err += (double(v[j]) - q[j]) * (double(v[j]) - q[j]);
        norm += double(v[j]) * v[j];
      }
      p.error2 += err;
      p.norm2 += norm;
      if (norm > 0.0) p.maxRelative = std::max(p.maxRelative, std::sqrt(err / norm));
    }
    partial[b] = p;
  });
  Partial all;
  for (const Partial& p : partial) {
    all.error2 += p.error2;
    all.norm2 += p.norm2;
    all.maxRelative = std::max(all.maxRelative, p.maxRelative);
    all.nonFinite += p.nonFinite;
  }
  QuantizationError result;
  result.nonFinite = all.nonFinite;
  result.count = n - all.nonFinite;
  if (result.count == 0) return result;
  result.rms = std::sqrt(all.error2 / static_cast<double>(result.count));
  result.relativeRms = all.norm2 > 0.0 ? std::sqrt(all.error2 / all.norm2) : 0.0;
  result.maxRelative = all.maxRelative;
  return result;
}

}  // namespace pbgi
