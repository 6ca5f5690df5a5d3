#pragma once
// The out-of-core build of a paged, quantized PBGI tree from surfels sorted by Morton key:
// the sweep of tree_build.h, the codebooks of quantize.h (Buchholz and Boubekeur 2012) and the
// page packing of tree_pager.h, in bounded memory whatever the point count.
//
// A float tree takes one pass: nodes go from the sweep straight into pages. A quantized tree
// takes two, because its codebooks must be trained before the first node is encoded: the
// sweep spills every node (float attributes and leaf surfels) to a temporary file and keeps a
// bounded training sample of the nodes' shape vectors; the codebooks are trained on the
// sample; a second pass reads the spill back, looks up each node's codebook entries,
// measures the error, and packs the pages. The sample is chosen by a hash of the node's
// post-order index and the seed, keeping the lowest hashes (a bottom-k sketch): it holds at
// most maxSample vectors and is the same whatever the thread count.
#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <string>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/pbgi/tree_build.h"
#include "core/pbgi/tree_pager.h"

namespace pbgi {

// Glossy light as wavelets (Wang et al. 2015, section 3.1). `leaf` is called for
// each leaf holding a glossy or transmissive surfel (by MaterialClass), with the leaf's
// surfels (triangles as sampled) and a key unique to the leaf within the tree (its post-order
// index, the same whatever the threads); it returns the leaf's wavelet intensity (W/sr by
// direction; empty for none) and may set those surfels' radiance and back radiance to their
// mean over each side, which gathers that see them as disks use. It runs in parallel and must
// be thread-safe. An interior node's vector is the sum of its children's (the Haar transform
// is linear). Every node's vector keeps the fewest quadtree nodes that hold it within
// relativeError (L2, relative to its norm; WaveletRadiance::fromDense), at most maxNodes. Null
// (every scene without such materials): no wavelets, and the tree is byte for byte what it was.
// One leaf of a batch (TreeWaveletOptions::leaves): its surfels, its key, and its vector.
struct WaveletLeafJob {
  std::span<Surfel> surfels;
  uint64_t key = 0;
  WaveletRadiance out;
};

struct TreeWaveletOptions {
  std::function<WaveletRadiance(std::span<Surfel> surfels, uint64_t leafKey)> leaf;
  // Optional, beside `leaf`: a batch of leaves at once (the quantized writer's batches), each
  // job's `out` set as `leaf` would, so that work leaves share (the glossy bake's pair gather)
  // is done once for the batch. Called from one thread; it may run its own in parallel.
  std::function<void(std::span<WaveletLeafJob> jobs)> leaves;
  float relativeError = 0.2f;
  size_t maxNodes = 0;  // 0: as many as a page holds beside the largest node
};

struct TreeWriteOptions {
  TreeBuildOptions build;
  TreeEncoding encoding = TreeEncoding::kQuantized;
  uint32_t pageSize = 64 * 1024;
  int powerCentres = 254;  // plus the black entry; at most 254 for 8-bit indices
  int areaCentres = 62;
  // The biggest nodes keep their SH in float: few nodes, carrying most of the light. A node
  // is exact when it holds at least max(kMinExactPoints, points / exactNodes) surfels, which
  // bounds the exact nodes to about exactNodes per tree level. 0 quantizes every node.
  uint64_t exactNodes = 4096;
  int kmeansIterations = 10;
  double sampleFraction = 0.1;  // of the nodes, at most maxSample
  size_t maxSample = 50000;
  uint64_t seed = 0;
  std::string tempDir;  // for the spill; empty: the system's temporary folder
  TreeWaveletOptions wavelets;
};

// What the tree's wavelets hold (all 0 without them).
struct TreeWaveletReport {
  uint64_t leaves = 0;        // leaves whose vector `leaf` computed
  uint64_t nodes = 0;         // nodes with a vector, leaves included
  uint64_t stored = 0;        // vectors in the pages (ghosts' face averages included)
  uint64_t differences = 0;   // of them, coded against their parent's
  uint64_t keptNodes = 0;     // quadtree nodes stored
  uint64_t coefficients = 0;  // scaling and detail coefficients stored, each channel counted
  uint64_t bytes = 0;         // the pages' wavelet sections
  // The larger of the worst relative L2 errors of the writer's threshold (against the exact
  // sum of a node's leaves) and of the pages' coding (against the writer's vector); a node's
  // whole error is at most their sum.
  double maxRelativeError = 0.0;
};

// How far the quantized spherical functions are from the float ones, over every node.
struct TreeQuantizationReport {
  QuantizationError power;  // of the 27-float power SH vectors
  QuantizationError area;   // of the 9-float projected-area SH vectors
  // Surfel radiance beyond half's range over its leaf's scale (tree_page.h), clamped.
  uint64_t clampedSurfelRadiance = 0;
};

inline constexpr uint64_t kMinExactPoints = 64;

struct TreeWriteResult {
  NodeRef root;
  uint64_t exactFromPoints = 0;  // the threshold used (0: none exact)
  uint64_t exactNodeCount = 0;
  NodeAttributes rootAttributes;  // in float, as built
  TreeBuildStats build;
  TreePagerStats pages;
  TreeCodebooks codebooks;  // empty for float trees
  TreeQuantizationReport quantization;
  TreeWaveletReport wavelets;
  uint64_t spillBytes = 0;
  std::string toString() const;
};

// The most quadtree nodes a wavelet vector keeps: options.wavelets.maxNodes, or when 0 as many
// as fit a page beside the largest node (0 when not even one does).
size_t waveletNodeBudget(const TreeWriteOptions& options);

class TreeWriter {
 public:
  // Checks the options (leaf size, page size against the largest node, centre counts).
  static absl::Status validateOptions(const TreeWriteOptions& options);

  TreeWriter(const TreeWriteOptions& options, PageSink sink);
  ~TreeWriter();
  TreeWriter(const TreeWriter&) = delete;
  TreeWriter& operator=(const TreeWriter&) = delete;

  // The next surfel in (key, sequence) order.
  absl::Status add(const SortedSurfel& point);
  // Builds what is left, trains the codebooks, writes every page. A tree needs at least one
  // surfel (FailedPrecondition otherwise).
  absl::StatusOr<TreeWriteResult> finish();

 private:
  class Impl;
  std::unique_ptr<Impl> impl_;
};

// A tree whose pages live in memory as payloads, decoded on each page() call: for tests, and
// for trees small enough not to need a file.
class MemoryTree : public TreePageSource {
 public:
  MemoryTree(std::vector<std::vector<uint8_t>> pages, TreeCodebooks codebooks, NodeRef root)
      : pages_(std::move(pages)), codebooks_(std::move(codebooks)), root_(root) {}
  NodeRef root() const override { return root_; }
  absl::StatusOr<std::shared_ptr<const TreePage>> page(uint32_t id) override;
  const std::vector<std::vector<uint8_t>>& payloads() const { return pages_; }
  const TreeCodebooks& codebooks() const { return codebooks_; }

 private:
  std::vector<std::vector<uint8_t>> pages_;
  TreeCodebooks codebooks_;
  NodeRef root_;
};

// Builds the tree of sorted surfels into memory (spilling to options.tempDir as a file build
// would). `result` may be null.
absl::StatusOr<std::unique_ptr<MemoryTree>> buildMemoryTree(std::span<const SortedSurfel> sorted,
                                                            const TreeWriteOptions& options,
                                                            TreeWriteResult* result = nullptr);

}  // namespace pbgi
