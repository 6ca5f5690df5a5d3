#pragma once
// Vector quantization of the nodes' spherical functions after Buchholz and Boubekeur 2012
// ("Quantized Point-Based Global Illumination"): a k-means codebook trained on a sample of
// the vectors (27 floats: 9 SH coefficients x RGB), each node then storing only the index of
// its nearest entry. Entry 0 is always black (all zeros), so that nodes that send out nothing
// stay exactly dark instead of picking up the nearest dim cluster.
//
// Deterministic: the same vectors and options give the same codebook bit for bit, whatever
// the thread count. The training sample is stratified (one vector drawn from each of equal
// runs of the input, keyed by the seed), k-means++ seeding draws from the seed, and Lloyd's
// sums are accumulated in double per fixed block of points and combined in block order.

#include <cstdint>
#include <span>
#include <vector>

namespace pbgi {

struct Codebook {
  int dimension = 0;
  std::vector<float> entries;  // size() x dimension, row-major; entry 0 is all zeros

  int size() const { return dimension == 0 ? 0 : static_cast<int>(entries.size() / dimension); }
  std::span<const float> entry(int i) const {
    return std::span<const float>(entries).subspan(static_cast<size_t>(i) * dimension, dimension);
  }
};

struct KMeansOptions {
  int centres = 100;  // plus the black entry
  int iterations = 10;
  uint64_t seed = 0;
  double sampleFraction = 0.1;  // of the input, then clamped to [minSample, maxSample]
  size_t minSample = 1000;
  size_t maxSample = 200000;
};

struct QuantizationError {
  size_t count = 0;          // finite vectors measured
  size_t nonFinite = 0;      // vectors with a NaN or infinity, left out of the measures
  double rms = 0.0;          // sqrt(mean |v - q|^2)
  double relativeRms = 0.0;  // sqrt(sum |v - q|^2 / sum |v|^2); 0 when every v is zero
  double maxRelative = 0.0;  // max |v - q| / |v| over the non-zero v
};

// Trains a codebook on `vectors` (n x dim floats, row-major). All-zero vectors are left out
// of training (entry 0 serves them), and so are vectors with a NaN or infinity, which the
// caller is expected to have counted and reported: one of them must not drag a centre to NaN.
// The codebook has 1 + min(centres, distinct non-zero vectors in the sample) entries: with
// fewer distinct vectors than centres each becomes an entry of its own, and empty input gives
// the black entry alone.
Codebook trainCodebook(std::span<const float> vectors, int dim, const KMeansOptions& options);

// The index of the entry nearest to v in Euclidean distance (the lowest index on a tie);
// 0 (black) for a vector with a NaN.
uint32_t nearestEntry(const Codebook& codebook, std::span<const float> v);

// Quantizes every vector of `vectors` (n x codebook.dimension) and measures the error.
QuantizationError measureError(const Codebook& codebook, std::span<const float> vectors);

}  // namespace pbgi
