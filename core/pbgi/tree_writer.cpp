#include "core/pbgi/tree_writer.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <optional>

#include <Imath/half.h>
#include <fmt/format.h>
#include <tbb/parallel_for.h>

#include "core/sampling/rng.h"
#include "core/util/check.h"
#include "core/util/spill_file.h"
#include "core/util/status.h"

namespace pbgi {

namespace {

// Spill record: u32 child count, u32 surfel count, u64 point count, the float attributes,
// then the surfels as float surfel records.
constexpr size_t kSpillHeaderBytes = 16;
constexpr size_t kFloatAttributeBytes = 212;  // nodeRecordBytes(kFloat) less its 10-byte head
constexpr size_t kFloatSurfelBytes = 65;
static_assert(nodeRecordBytes(TreeEncoding::kFloat) == 10 + kFloatAttributeBytes);
static_assert(surfelRecordBytes(TreeEncoding::kFloat) == kFloatSurfelBytes);
constexpr size_t kSpillSurfelBytes = kFloatSurfelBytes + 4;  // and its triangle

// Whether a leaf's surfels send light the SH cannot hold: glossy or transmissive ones.
bool hasDirectionalSurfels(std::span<const Surfel> surfels) {
  return std::any_of(surfels.begin(), surfels.end(), [](const Surfel& s) {
    return s.materialClass == MaterialClass::kGlossy ||
           s.materialClass == MaterialClass::kTransmissive;
  });
}

// Nodes quantized per parallel batch in the second pass.
constexpr size_t kBatchNodes = 4096;

struct ShapeSample {
  uint64_t hash = 0;
  std::array<float, kPowerShapeDims> power{};
  std::array<float, kAreaShapeDims> area{};
};

// Squared-error sums of one family of vectors, combined in node order.
struct ErrorSums {
  double diff2 = 0.0, norm2 = 0.0, maxRelative = 0.0;
  size_t count = 0, nonFinite = 0;
  void add(double d2, double n2, bool finite) {
    if (!finite) {
      ++nonFinite;
      return;
    }
    ++count;
    diff2 += d2;
    norm2 += n2;
    if (n2 > 0.0) maxRelative = std::max(maxRelative, std::sqrt(d2 / n2));
  }
  QuantizationError report() const {
    QuantizationError e;
    e.count = count;
    e.nonFinite = nonFinite;
    e.rms = count > 0 ? std::sqrt(diff2 / static_cast<double>(count)) : 0.0;
    e.relativeRms = norm2 > 0.0 ? std::sqrt(diff2 / norm2) : 0.0;
    e.maxRelative = maxRelative;
    return e;
  }
};

template <size_t N>
void squaredError(const float (&v)[N], const float (&q)[N], double* d2, double* n2, bool* finite) {
  *d2 = *n2 = 0.0;
  *finite = true;
  for (size_t i = 0; i < N; ++i) {
    if (!std::isfinite(v[i])) *finite = false;
    *d2 += double(v[i] - q[i]) * double(v[i] - q[i]);
    *n2 += double(v[i]) * double(v[i]);
  }
}

}  // namespace

std::string TreeWriteResult::toString() const {
  return fmt::format(
      "{}; pages={} payload_bytes={} power_codebook={} area_codebook={} power_rel_rms={:.4g} "
      "area_rel_rms={:.4g} spill_bytes={}",
      build.toString(), pages.pages, pages.payloadBytes, codebooks.power.size(),
      codebooks.area.size(), quantization.power.relativeRms, quantization.area.relativeRms,
      spillBytes);
}

class TreeWriter::Impl {
 public:
  Impl(const TreeWriteOptions& options, PageSink sink)
      : options_(options),
        sink_(std::move(sink)),
        builder_(options.build, [this](const BuiltNode& n) { return onNode(n); }) {
    PBGI_CHECK(validateOptions(options_).ok());
    if (!quantized(options_.encoding)) {
      pager_.emplace(pagerOptions(), nullptr, sink_);
    }
    const double f = std::clamp(options_.sampleFraction, 0.0, 1.0);
    sampleThreshold_ = f >= 1.0 ? UINT64_MAX : static_cast<uint64_t>(f * 0x1p64);
  }

  absl::Status add(const SortedSurfel& point) {
    if (!failure_.ok()) return failure_;
    if (quantized(options_.encoding) && !spill_) {
      auto spill = SpillFile::create(options_.tempDir, "pbgi-tree-spill");
      if (!spill.ok()) return failure_ = spill.status();
      spill_.emplace(std::move(*spill));
    }
    failure_ = builder_.add(point);
    return failure_;
  }

  absl::StatusOr<TreeWriteResult> finish() {
    if (!failure_.ok()) return failure_;
    if (auto s = builder_.finish(); !s.ok()) return s;
    if (builder_.stats().nodes == 0) {
      return absl::FailedPreconditionError("a tree needs at least one surfel; none were given");
    }
    TreeWriteResult result;
    result.rootAttributes = root_;
    result.build = builder_.stats();
    if (!quantized(options_.encoding)) {
      auto root = pager_->finish();
      if (!root.ok()) return root.status();
      result.root = *root;
      result.pages = pager_->stats();
      result.wavelets = waveletReport();
      return result;
    }
    trainCodebooks(&result.codebooks);
    codebooks_ = result.codebooks;
    pager_.emplace(pagerOptions(), &codebooks_, sink_);
    if (auto s = secondPass(&result); !s.ok()) return s;
    auto root = pager_->finish();
    if (!root.ok()) return root.status();
    result.root = *root;
    result.pages = pager_->stats();
    result.spillBytes = spill_->bytesWritten();
    result.wavelets = waveletReport();
    return result;
  }

  // The vectors the pages get are held this close to the exact sums: a fifth of the error the
  // pages code them within (hierarchically, tree_page.h), so that what the writer drops
  // first adds little to it.
  float preThreshold() const { return options_.wavelets.relativeError / 5.0f; }

  TreeWaveletReport waveletReport() const {
    TreeWaveletReport r = waveletReport_;
    r.leaves = leafWavelets_.load();
    const WaveletPageStats& pages = pager_->stats().wavelets;
    r.stored = pages.entries;
    r.differences = pages.differences;
    r.keptNodes = pages.keptNodes;
    r.coefficients = 3 * (6 * pages.entries + 3 * pages.keptNodes);
    r.bytes = pages.bytes;
    r.maxRelativeError = std::max(r.maxRelativeError, pages.maxRelativeError);
    return r;
  }

 private:
  TreePagerOptions pagerOptions() const {
    return TreePagerOptions{options_.encoding, options_.pageSize, options_.wavelets.relativeError};
  }

  absl::Status onNode(const BuiltNode& n) {
    root_ = n.attributes;
    if (!quantized(options_.encoding)) {
      PageNode node;
      node.attributes = n.attributes;
      node.surfels.assign(n.surfels.begin(), n.surfels.end());
      if (n.leaf() && options_.wavelets.leaf && hasDirectionalSurfels(node.surfels)) {
        node.wavelet = leafWavelet(node.surfels, waveletNodes_);
      }
      ++waveletNodes_;
      attachWavelet(node, n.childCount);
      return pager_->add(std::move(node), n.childCount);
    }
    record_.clear();
    ByteWriter w(&record_);
    w.u32(n.childCount);
    w.u32(static_cast<uint32_t>(n.surfels.size()));
    w.u64(n.attributes.pointCount);
    writeFloatAttributes(w, n.attributes);
    for (const Surfel& s : n.surfels) {
      writeFloatSurfel(w, s);
      w.u32(s.triangle);  // the wavelet stage looks materials up by triangle
    }
    sample(n.attributes);
    ++spilledNodes_;
    return spill_->write(record_);
  }

  // Bottom-k by hash: the sample is the maxSample lowest hashes under the fraction's
  // threshold, whatever the order nodes arrive in.
  void sample(const NodeAttributes& a) {
    const uint64_t hash = hashKeys(options_.seed, spilledNodes_, 0x7e5a3ull);
    if (hash >= sampleThreshold_) return;
    auto byHash = [](const ShapeSample& x, const ShapeSample& y) { return x.hash < y.hash; };
    if (samples_.size() == options_.maxSample) {
      if (options_.maxSample == 0 || hash >= samples_.front().hash) return;
      std::pop_heap(samples_.begin(), samples_.end(), byHash);
      samples_.pop_back();
    }
    ShapeSample s;
    s.hash = hash;
    const ShRotation rotation = shapeRotation(a.cone.axis);
    powerShape(rotation.apply(a.powerSh), s.power.data());
    areaShape(rotation.apply(a.areaSh), s.area.data());
    samples_.push_back(s);
    std::push_heap(samples_.begin(), samples_.end(), byHash);
  }

  void trainCodebooks(TreeCodebooks* books) {
    // Training order follows the hashes, not the heap's layout.
    std::sort(samples_.begin(), samples_.end(),
              [](const ShapeSample& x, const ShapeSample& y) { return x.hash < y.hash; });
    std::vector<float> power, area;
    power.reserve(samples_.size() * kPowerShapeDims);
    area.reserve(samples_.size() * kAreaShapeDims);
    for (const ShapeSample& s : samples_) {
      power.insert(power.end(), s.power.begin(), s.power.end());
      area.insert(area.end(), s.area.begin(), s.area.end());
    }
    KMeansOptions k;
    k.iterations = options_.kmeansIterations;
    k.seed = options_.seed;
    k.sampleFraction = 1.0;  // the sample is already drawn
    k.minSample = 0;
    k.maxSample = SIZE_MAX;
    k.centres = options_.powerCentres;
    books->power = trainCodebook(power, kPowerShapeDims, k);
    k.centres = options_.areaCentres;
    books->area = trainCodebook(area, kAreaShapeDims, k);
    samples_.clear();
    samples_.shrink_to_fit();
  }

  absl::Status readSpilled(PageNode* node, uint32_t* childCount) {
    uint8_t head[kSpillHeaderBytes + kFloatAttributeBytes];
    if (auto s = spill_->read(head); !s.ok()) return s;
    ByteReader r(head);
    *childCount = r.u32();
    const uint32_t surfels = r.u32();
    node->attributes.pointCount = r.u64();
    readFloatAttributes(r, &node->attributes);
    record_.resize(size_t{surfels} * kSpillSurfelBytes);
    if (auto s = spill_->read(record_); !s.ok()) return s;
    ByteReader sr(record_.data());
    node->surfels.resize(surfels);
    for (Surfel& surfel : node->surfels) {
      if (auto s = readFloatSurfel(sr, &surfel); !s.ok()) {
        return absl::DataLossError(fmt::format("spill file {}: {}", spill_->name(), s.message()));
      }
      surfel.triangle = sr.u32();
    }
    return absl::OkStatus();
  }

  absl::Status secondPass(TreeWriteResult* result) {
    if (auto s = spill_->rewind(); !s.ok()) return s;
    struct Quantized {
      double powerD2, powerN2, areaD2, areaN2;
      bool powerFinite, areaFinite;
    };
    const uint64_t exactFrom =
        options_.exactNodes == 0
            ? 0
            : std::max(kMinExactPoints, builder_.stats().points / options_.exactNodes);
    result->exactFromPoints = exactFrom;
    std::vector<PageNode> batch;
    std::vector<uint32_t> childCounts;
    std::vector<Quantized> errors;
    std::vector<WaveletLeafJob> jobs;
    constexpr size_t kNoJob = ~size_t{0};
    std::vector<size_t> jobOf;
    ErrorSums powerSums, areaSums;
    uint64_t remaining = spilledNodes_;
    while (remaining > 0) {
      const size_t n = static_cast<size_t>(std::min<uint64_t>(remaining, kBatchNodes));
      batch.assign(n, PageNode{});
      childCounts.assign(n, 0);
      errors.assign(n, Quantized{});
      for (size_t i = 0; i < n; ++i) {
        if (auto s = readSpilled(&batch[i], &childCounts[i]); !s.ok()) return s;
      }
      const uint64_t firstKey = spilledNodes_ - remaining;
      // The batch's leaves' wavelets together, when the bake shares work between them.
      jobs.clear();
      jobOf.assign(n, kNoJob);
      if (options_.wavelets.leaf && options_.wavelets.leaves) {
        for (size_t i = 0; i < n; ++i) {
          if (childCounts[i] == 0 && hasDirectionalSurfels(batch[i].surfels)) {
            jobOf[i] = jobs.size();
            jobs.push_back({std::span<Surfel>(batch[i].surfels), firstKey + i, {}});
          }
        }
        if (!jobs.empty()) options_.wavelets.leaves(jobs);
      }
      // Codebook lookups (and leaves' wavelets) are the cost; each node's is independent.
      tbb::parallel_for(size_t{0}, n, [&](size_t i) {
        PageNode& node = batch[i];
        if (jobOf[i] != kNoJob) {
          node.wavelet = keptWavelet(std::move(jobs[jobOf[i]].out));
        } else if (childCounts[i] == 0 && options_.wavelets.leaf &&
                   hasDirectionalSurfels(node.surfels)) {
          node.wavelet = leafWavelet(node.surfels, firstKey + i);
        }
        const NodeAttributes& a = node.attributes;
        node.exact = exactFrom > 0 && a.pointCount >= exactFrom;
        if (node.exact) {
          // Stored as built: no error, but its size counts towards the relative error.
          float v[Sh9Rgb::kFloats];
          a.powerSh.toFloats(v);
          squaredError(v, v, &errors[i].powerD2, &errors[i].powerN2, &errors[i].powerFinite);
          errors[i].areaFinite = true;
          return;
        }
        const ShRotation rotation = shapeRotation(a.cone.axis);
        float shape[kPowerShapeDims];
        powerShape(rotation.apply(a.powerSh), shape);
        node.powerIndex = nearestEntry(codebooks_.power, shape);
        float areaShapeV[kAreaShapeDims];
        areaShape(rotation.apply(a.areaSh), areaShapeV);
        node.areaIndex = nearestEntry(codebooks_.area, areaShapeV);
        // The error is measured on what a reader will decode, in world space.
        float v[Sh9Rgb::kFloats], q[Sh9Rgb::kFloats];
        a.powerSh.toFloats(v);
        rotation
            .applyInverse(
                powerFromShape(a.powerSh.c[0], codebooks_.power.entry(int(node.powerIndex))))
            .toFloats(q);
        squaredError(v, q, &errors[i].powerD2, &errors[i].powerN2, &errors[i].powerFinite);
        float av[kShCoefficients], aq[kShCoefficients];
        std::copy(a.areaSh.c.begin(), a.areaSh.c.end(), av);
        const Sh9 areaQ = rotation.applyInverse(
            areaFromShape(areaShDc(a.area), codebooks_.area.entry(int(node.areaIndex))));
        std::copy(areaQ.c.begin(), areaQ.c.end(), aq);
        squaredError(av, aq, &errors[i].areaD2, &errors[i].areaN2, &errors[i].areaFinite);
      });
      for (size_t i = 0; i < n; ++i) {
        if (batch[i].exact) ++result->exactNodeCount;
        powerSums.add(errors[i].powerD2, errors[i].powerN2, errors[i].powerFinite);
        areaSums.add(errors[i].areaD2, errors[i].areaN2, errors[i].areaFinite);
        const NodeAttributes& leaf = batch[i].attributes;
        const float scale = surfelRadianceScale(leaf.area, leaf.powerSh.c[0], leaf.backPower);
        for (const Surfel& s : batch[i].surfels) {
          if (std::max(maxComponent(s.radiance), maxComponent(s.backRadiance)) / scale >
              static_cast<float>(HALF_MAX)) {
            ++result->quantization.clampedSurfelRadiance;
          }
        }
        attachWavelet(batch[i], childCounts[i]);
        if (auto s = pager_->add(std::move(batch[i]), childCounts[i]); !s.ok()) return s;
      }
      remaining -= n;
    }
    result->quantization.power = powerSums.report();
    result->quantization.area = areaSums.report();
    return absl::OkStatus();
  }

  std::shared_ptr<const WaveletRadiance> leafWavelet(std::span<Surfel> surfels, uint64_t key) {
    return keptWavelet(options_.wavelets.leaf(surfels, key));
  }

  // A leaf's vector as the tree keeps it (none for a black one).
  std::shared_ptr<const WaveletRadiance> keptWavelet(const WaveletRadiance& w) {
    // Black (glossy surfels no light reaches): no vector, the same as none.
    const bool black = w.keptNodes() == 0 &&
                       std::all_of(w.faces().begin(), w.faces().end(),
                                   [](const WaveletFace& f) { return isBlack(f.scaling); });
    if (w.empty() || black) return nullptr;
    leafWavelets_.fetch_add(1, std::memory_order_relaxed);
    // Thresholded as every node's vector is.
    const WaveletRadiance* own = &w;
    return std::make_shared<const WaveletRadiance>(
        WaveletRadiance::sum(std::span(&own, 1), 0.0f, preThreshold(),
                             waveletNodeBudget(options_)));
  }

  // In post-order: a leaf's vector (computed already, or none) waits for its parent; an
  // interior node's is the sum of its children's, which it takes off the stack.
  void attachWavelet(PageNode& node, uint32_t childCount) {
    if (!options_.wavelets.leaf) return;
    if (childCount > 0) {
      PBGI_CHECK_LE(childCount, waveletStack_.size());
      std::vector<const WaveletRadiance*> parts;
      for (size_t c = waveletStack_.size() - childCount; c < waveletStack_.size(); ++c) {
        if (waveletStack_[c]) parts.push_back(waveletStack_[c].get());
      }
      if (!parts.empty()) {
        node.wavelet = std::make_shared<const WaveletRadiance>(
            WaveletRadiance::sum(parts, 0.0f, preThreshold(), waveletNodeBudget(options_)));
      }
      waveletStack_.resize(waveletStack_.size() - childCount);
    }
    waveletStack_.push_back(node.wavelet);
    if (node.wavelet) {
      node.waveletWhole = std::make_shared<const WaveletRadiance>(WaveletRadiance::fromDense(
          node.wavelet->dense(), node.wavelet->resolution(), 0.0f,
          options_.wavelets.relativeError));  // as the page codes it whole
      ++waveletReport_.nodes;
      waveletReport_.maxRelativeError =
          std::max(waveletReport_.maxRelativeError, double{node.wavelet->relativeError()});
    }
  }

  TreeWriteOptions options_;
  PageSink sink_;
  TreeBuilder builder_;
  std::optional<TreePager> pager_;
  std::optional<SpillFile> spill_;
  TreeCodebooks codebooks_;
  std::vector<uint8_t> record_;
  std::vector<ShapeSample> samples_;
  uint64_t sampleThreshold_ = 0;
  uint64_t spilledNodes_ = 0;
  uint64_t waveletNodes_ = 0;  // nodes seen by the float path, its leaves' keys
  std::atomic<uint64_t> leafWavelets_{0};
  std::vector<std::shared_ptr<const WaveletRadiance>> waveletStack_;
  TreeWaveletReport waveletReport_;
  NodeAttributes root_;
  absl::Status failure_;
};

size_t waveletNodeBudget(const TreeWriteOptions& o) {
  if (o.wavelets.maxNodes > 0) return o.wavelets.maxNodes;
  const size_t minPage = TreePager::minPageSize(o.encoding, o.build.leafSize);
  const size_t whole = maxWaveletEntryBytes(0) + kWaveletSectionHeaderBytes;
  if (o.pageSize < minPage + whole) return 0;
  return (o.pageSize - minPage - whole) / (maxWaveletEntryBytes(1) - maxWaveletEntryBytes(0));
}

absl::Status TreeWriter::validateOptions(const TreeWriteOptions& o) {
  if (o.build.leafSize < 1 || o.build.leafSize > kMaxLeafSize) {
    return absl::InvalidArgumentError(
        fmt::format("leaf size {}: expected 1..{}", o.build.leafSize, kMaxLeafSize));
  }
  const uint32_t minPage = TreePager::minPageSize(o.encoding, o.build.leafSize);
  if (o.pageSize < minPage) {
    return absl::InvalidArgumentError(
        fmt::format("page size {} bytes: leaves of {} surfels need at least {}", o.pageSize,
                    o.build.leafSize, minPage));
  }
  const int maxCentres = maxCodebookEntries(o.encoding) - 1;  // less the black entry
  for (int centres : {o.powerCentres, o.areaCentres}) {
    if (quantized(o.encoding) && (centres < 1 || centres > maxCentres)) {
      return absl::InvalidArgumentError(fmt::format(
          "{} codebook centres: expected 1..{} for this index width", centres, maxCentres));
    }
  }
  if (o.wavelets.leaf) {
    if (!(o.wavelets.relativeError >= 0.0f && o.wavelets.relativeError < 1.0f)) {
      return absl::InvalidArgumentError(fmt::format(
          "wavelet error {}: expected a fraction in [0, 1)", o.wavelets.relativeError));
    }
    const size_t nodes = waveletNodeBudget(o);
    const size_t needed =
        size_t{minPage} + kWaveletSectionHeaderBytes + maxWaveletEntryBytes(std::max<size_t>(nodes, 1));
    if (nodes < 1 || o.pageSize < needed) {
      return absl::InvalidArgumentError(fmt::format(
          "wavelets of at most {} quadtree nodes a vector need pages of at least {} bytes; page "
          "size {}",
          std::max<size_t>(nodes, 1), needed, o.pageSize));
    }
  }
  if (o.kmeansIterations < 0) {
    return absl::InvalidArgumentError("k-means iterations must not be negative");
  }
  return absl::OkStatus();
}

TreeWriter::TreeWriter(const TreeWriteOptions& options, PageSink sink)
    : impl_(std::make_unique<Impl>(options, std::move(sink))) {}
TreeWriter::~TreeWriter() = default;
absl::Status TreeWriter::add(const SortedSurfel& point) { return impl_->add(point); }
absl::StatusOr<TreeWriteResult> TreeWriter::finish() { return impl_->finish(); }

absl::StatusOr<std::shared_ptr<const TreePage>> MemoryTree::page(uint32_t id) {
  if (id >= pages_.size()) {
    return absl::DataLossError(fmt::format("page {}: the tree has {} pages", id, pages_.size()));
  }
  return decodeTreePage(id, pages_[id], &codebooks_);
}

absl::StatusOr<std::unique_ptr<MemoryTree>> buildMemoryTree(std::span<const SortedSurfel> sorted,
                                                            const TreeWriteOptions& options,
                                                            TreeWriteResult* result) {
  if (auto s = TreeWriter::validateOptions(options); !s.ok()) return s;
  std::vector<std::vector<uint8_t>> pages;
  TreeWriter writer(options, [&](std::span<const uint8_t> bytes) -> absl::StatusOr<uint32_t> {
    pages.emplace_back(bytes.begin(), bytes.end());
    return static_cast<uint32_t>(pages.size() - 1);
  });
  for (const SortedSurfel& p : sorted) {
    if (auto s = writer.add(p); !s.ok()) return s;
  }
  auto written = writer.finish();
  if (!written.ok()) return written.status();
  if (result != nullptr) *result = *written;
  return std::make_unique<MemoryTree>(std::move(pages), written->codebooks, written->root);
}

}  // namespace pbgi
