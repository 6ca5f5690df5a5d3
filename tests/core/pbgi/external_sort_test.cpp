#include "core/pbgi/external_sort.h"

#include <gtest/gtest.h>

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cstring>
#include <filesystem>
#include <functional>
#include <limits>
#include <numeric>
#include <random>
#include <vector>

#include "core/pbgi/morton.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

using testing::filesIn;

namespace fs = std::filesystem;

struct Input {
  std::vector<uint64_t> keys;
  std::vector<Surfel> surfels;
};

float randomFloat(std::mt19937_64& rng) {
  return static_cast<float>(rng() >> 40) * (1.0f / static_cast<float>(1 << 24));
}

// Random surfels whose keys collide a lot (positions on a coarse grid), so that the sequence
// number decides much of the order; every field random so that a field lost or swapped in a
// spill file shows. A few carry odd floats (-0, NaN with payload) that must survive
// bit-exactly, and a few keys use the full 64 bits.
Input makeInput(size_t n, uint64_t seed) {
  std::mt19937_64 rng(seed);
  Bounds3f bounds;
  bounds.extend(Vec3f(0.0f));
  bounds.extend(Vec3f(1.0f));
  Input in;
  in.keys.reserve(n);
  in.surfels.reserve(n);
  for (size_t i = 0; i < n; ++i) {
    Surfel s;
    s.position = Vec3f(std::floor(randomFloat(rng) * 40.0f) / 40.0f,
                       std::floor(randomFloat(rng) * 40.0f) / 40.0f,
                       std::floor(randomFloat(rng) * 40.0f) / 40.0f);
    s.normal = normalize(Vec3f(randomFloat(rng) - 0.5f, randomFloat(rng) - 0.5f, 0.25f));
    s.radius = randomFloat(rng);
    s.albedo = Rgb(randomFloat(rng), randomFloat(rng), randomFloat(rng));
    s.radiance = Rgb(randomFloat(rng) * 10.0f, randomFloat(rng), randomFloat(rng));
    s.materialClass = static_cast<MaterialClass>(rng() % 4);
    s.triangle = static_cast<uint32_t>(rng());
    s.barycentric = Vec2f(randomFloat(rng), randomFloat(rng));
    uint64_t key = mortonKey(s.position, bounds);
    if (i % 1000 == 7) {
      s.radius = -0.0f;
      s.barycentric.y = std::bit_cast<float>(0x7fc12345u);  // NaN with a payload
      key = std::numeric_limits<uint64_t>::max() - (rng() % 3);
    }
    in.keys.push_back(key);
    in.surfels.push_back(s);
  }
  return in;
}

// The expected order: indices by (key, index), computed without the sorter.
std::vector<uint64_t> referenceOrder(const Input& in) {
  std::vector<uint64_t> order(in.keys.size());
  std::iota(order.begin(), order.end(), 0);
  std::stable_sort(order.begin(), order.end(),
                   [&](uint64_t a, uint64_t b) { return in.keys[a] < in.keys[b]; });
  return order;
}

// Field by field, by bit pattern (NaN == NaN, -0 != +0); independent of the record encoder.
bool sameSurfelBits(const Surfel& a, const Surfel& b) {
  auto bits = [](float f) { return std::bit_cast<uint32_t>(f); };
  auto same3 = [&](const Vec3f& x, const Vec3f& y) {
    return bits(x.x) == bits(y.x) && bits(x.y) == bits(y.y) && bits(x.z) == bits(y.z);
  };
  return same3(a.position, b.position) && same3(a.normal, b.normal) &&
         bits(a.radius) == bits(b.radius) && same3(a.albedo, b.albedo) &&
         same3(a.radiance, b.radiance) && same3(a.backRadiance, b.backRadiance) &&
         a.materialClass == b.materialClass &&
         a.triangle == b.triangle && bits(a.barycentric.x) == bits(b.barycentric.x) &&
         bits(a.barycentric.y) == bits(b.barycentric.y);
}

// A fresh folder, removed with everything in it when the test ends, failed or not.
struct ScratchDir {
  fs::path path = testing::makeTempDir("sort");
  ~ScratchDir() {
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

struct SortResult {
  std::vector<SortedSurfel> out;
  SortStats stats;
  size_t filesDuringMerge = 0;  // spill files on disk between finish() and the first next()
};

SortResult sortAll(const Input& in, size_t budget, int threads, const fs::path& dir) {
  SortResult r;
  ExternalSortOptions options;
  options.memoryBudgetBytes = budget;
  options.tempDir = dir.string();
  options.threads = threads;
  ExternalSurfelSorter sorter(options);
  for (size_t i = 0; i < in.keys.size(); ++i) {
    const absl::Status s = sorter.add(in.keys[i], in.surfels[i]);
    EXPECT_TRUE(s.ok()) << s;
    if (!s.ok()) return r;
  }
  const absl::Status s = sorter.finish();
  EXPECT_TRUE(s.ok()) << s;
  if (!s.ok()) return r;
  r.filesDuringMerge = filesIn(dir).size();
  r.out.reserve(in.keys.size());
  SortedSurfel record;
  while (true) {
    absl::StatusOr<bool> more = sorter.next(&record);
    EXPECT_TRUE(more.ok()) << more.status();
    if (!more.ok() || !*more) break;
    r.out.push_back(record);
  }
  r.stats = sorter.stats();
  return r;
}

void expectSameStream(const std::vector<SortedSurfel>& a, const std::vector<SortedSurfel>& b) {
  ASSERT_EQ(a.size(), b.size());
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_EQ(a[i].key, b[i].key) << i;
    ASSERT_EQ(a[i].sequence, b[i].sequence) << i;
    ASSERT_TRUE(sameSurfelBits(a[i].surfel, b[i].surfel)) << i;
  }
}

void expectMatchesReference(const Input& in, const std::vector<SortedSurfel>& out) {
  const std::vector<uint64_t> order = referenceOrder(in);
  ASSERT_EQ(out.size(), order.size());
  for (size_t i = 0; i < out.size(); ++i) {
    ASSERT_EQ(out[i].sequence, order[i]) << i;
    ASSERT_EQ(out[i].key, in.keys[order[i]]) << i;
    ASSERT_TRUE(sameSurfelBits(out[i].surfel, in.surfels[order[i]])) << i;
  }
}

TEST(SurfelRecord, LittleEndianFixedWidthLayout) {
  SortedSurfel r;
  r.key = 0x0102030405060708ull;
  r.sequence = 0x1112131415161718ull;
  r.surfel.position = Vec3f(1.0f, -2.0f, 0.5f);
  r.surfel.normal = Vec3f(0.0f, -0.0f, 1.0f);
  r.surfel.radius = 0.25f;
  r.surfel.albedo = Rgb(0.1f, 0.2f, 0.3f);
  r.surfel.radiance = Rgb(std::numeric_limits<float>::infinity(), 5.0f, 6.0f);
  r.surfel.backRadiance = Rgb(0.5f, 7.0f, -0.0f);
  r.surfel.materialClass = MaterialClass::kEmissive;
  r.surfel.triangle = 0xa1b2c3d4u;
  r.surfel.barycentric = Vec2f(0.75f, std::bit_cast<float>(0x7fc0beefu));
  uint8_t bytes[kSurfelRecordBytes + 1];
  bytes[kSurfelRecordBytes] = 0xee;  // the encoder must not write past the record
  encodeSurfelRecord(r, bytes);
  EXPECT_EQ(bytes[kSurfelRecordBytes], 0xee);
  const uint8_t key[] = {8, 7, 6, 5, 4, 3, 2, 1};
  EXPECT_EQ(std::memcmp(bytes, key, 8), 0);
  const uint8_t seq[] = {0x18, 0x17, 0x16, 0x15, 0x14, 0x13, 0x12, 0x11};
  EXPECT_EQ(std::memcmp(bytes + 8, seq, 8), 0);
  const uint8_t one[] = {0x00, 0x00, 0x80, 0x3f};  // 1.0f
  EXPECT_EQ(std::memcmp(bytes + 16, one, 4), 0);
  const uint8_t minusZero[] = {0x00, 0x00, 0x00, 0x80};
  EXPECT_EQ(std::memcmp(bytes + 32, minusZero, 4), 0);  // normal.y
  const uint8_t quarter[] = {0x00, 0x00, 0x80, 0x3e};
  EXPECT_EQ(std::memcmp(bytes + 40, quarter, 4), 0);  // radius
  const uint8_t half[] = {0x00, 0x00, 0x00, 0x3f};
  EXPECT_EQ(std::memcmp(bytes + 68, half, 4), 0);     // back radiance.r
  EXPECT_EQ(std::memcmp(bytes + 76, minusZero, 4), 0);  // back radiance.b
  EXPECT_EQ(bytes[80], 3);                            // material class
  const uint8_t tri[] = {0xd4, 0xc3, 0xb2, 0xa1};
  EXPECT_EQ(std::memcmp(bytes + 81, tri, 4), 0);
  const uint8_t nan[] = {0xef, 0xbe, 0xc0, 0x7f};
  EXPECT_EQ(std::memcmp(bytes + 89, nan, 4), 0);  // barycentric.y

  SortedSurfel back;
  ASSERT_TRUE(decodeSurfelRecord(bytes, &back).ok());
  EXPECT_EQ(back.key, r.key);
  EXPECT_EQ(back.sequence, r.sequence);
  EXPECT_TRUE(sameSurfelBits(back.surfel, r.surfel));
}

TEST(SurfelRecord, DecodeRejectsUnknownMaterialClass) {
  SortedSurfel r;
  uint8_t bytes[kSurfelRecordBytes];
  encodeSurfelRecord(r, bytes);
  bytes[80] = 4;
  SortedSurfel back;
  const absl::Status s = decodeSurfelRecord(bytes, &back);
  EXPECT_EQ(s.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("material class byte 4"), std::string::npos) << s;
}

// The acceptance test of the out-of-core build's first stage: in-core, spilled with one
// merge pass, and spilled with a multi-pass merge all give the same stream, which is the
// (key, sequence) order of the input; the budget holds; no file outlives the stream.
TEST(ExternalSurfelSorter, SameStreamForEveryBudget) {
  const Input in = makeInput(200000, 1);
  const ScratchDir scratch;
  const fs::path& dir = scratch.path;
  const SortResult inCore = sortAll(in, size_t{1} << 30, 0, dir);
  ASSERT_NO_FATAL_FAILURE(expectMatchesReference(in, inCore.out));
  EXPECT_EQ(inCore.stats.records, 200000u);
  EXPECT_EQ(inCore.stats.runsSpilled, 0u);
  EXPECT_EQ(inCore.stats.bytesWritten, 0u);
  EXPECT_EQ(inCore.filesDuringMerge, 0u);
  EXPECT_GE(inCore.stats.peakBufferedBytes, 200000u * ExternalSurfelSorter::kBufferedRecordBytes);

  struct Case {
    size_t budget;
    bool multiPass;
  };
  for (const Case c : {Case{4u << 20, false}, Case{1u << 20, true},
                       Case{ExternalSurfelSorter::kMinMemoryBudgetBytes, true}}) {
    SCOPED_TRACE(c.budget);
    const SortResult r = sortAll(in, c.budget, 0, dir);
    ASSERT_NO_FATAL_FAILURE(expectSameStream(inCore.out, r.out));
    const SortStats& st = r.stats;
    SCOPED_TRACE(st.toString());
    ASSERT_GT(st.bufferCapacityRecords, 0u);
    EXPECT_GT(st.runsSpilled, 1u);
    EXPECT_EQ(st.runsSpilled, (200000 + st.bufferCapacityRecords - 1) / st.bufferCapacityRecords);
    EXPECT_EQ(st.intermediateMerges > 0, c.multiPass);
    EXPECT_GE(st.finalMergeFanIn, 2u);
    EXPECT_EQ(r.filesDuringMerge, st.finalMergeFanIn);
    EXPECT_LE(st.peakBufferedBytes, c.budget);
    // The add buffer fills the budget up to the spill write buffer (at most budget/8).
    EXPECT_GE(st.peakBufferedBytes, c.budget * 7 / 8 - ExternalSurfelSorter::kBufferedRecordBytes);
    if (c.multiPass) {
      EXPECT_GT(st.bytesWritten, 200000u * kSurfelRecordBytes);
    } else {
      EXPECT_EQ(st.bytesWritten, 200000u * kSurfelRecordBytes);
    }
    EXPECT_EQ(st.bytesRead, st.bytesWritten);  // every byte spilled is read back once
    EXPECT_TRUE(filesIn(dir).empty());
  }
}

TEST(ExternalSurfelSorter, ThreadCountDoesNotChangeTheStream) {
  const Input in = makeInput(100000, 2);
  const ScratchDir scratch;
  const fs::path& dir = scratch.path;
  for (size_t budget : {size_t{1} << 30, size_t{1} << 20}) {
    SCOPED_TRACE(budget);
    const SortResult one = sortAll(in, budget, 1, dir);
    const SortResult two = sortAll(in, budget, 2, dir);
    ASSERT_NO_FATAL_FAILURE(expectMatchesReference(in, one.out));
    ASSERT_NO_FATAL_FAILURE(expectSameStream(one.out, two.out));
    EXPECT_EQ(one.stats.runsSpilled, two.stats.runsSpilled);
    EXPECT_EQ(one.stats.bytesWritten, two.stats.bytesWritten);
  }
  EXPECT_TRUE(filesIn(dir).empty());
}

// Two sorters spilling into one folder at the same time keep to their own files.
TEST(ExternalSurfelSorter, SortersSharingATempDirDoNotMix) {
  const Input a = makeInput(60000, 6), b = makeInput(60000, 7);
  const ScratchDir scratch;
  const fs::path& dir = scratch.path;
  ExternalSortOptions options;
  options.memoryBudgetBytes = 1 << 20;
  options.tempDir = dir.string();
  ExternalSurfelSorter sa(options), sb(options);
  for (size_t i = 0; i < a.keys.size(); ++i) {
    ASSERT_TRUE(sa.add(a.keys[i], a.surfels[i]).ok());
    ASSERT_TRUE(sb.add(b.keys[i], b.surfels[i]).ok());
  }
  ASSERT_TRUE(sa.finish().ok());
  ASSERT_TRUE(sb.finish().ok());
  EXPECT_EQ(filesIn(dir).size(), sa.stats().finalMergeFanIn + sb.stats().finalMergeFanIn);
  std::vector<SortedSurfel> outA, outB;
  SortedSurfel r;
  for (absl::StatusOr<bool> more; (more = sa.next(&r)).ok() && *more;) outA.push_back(r);
  EXPECT_EQ(filesIn(dir).size(), sb.stats().finalMergeFanIn);  // a's files went at its end
  for (absl::StatusOr<bool> more; (more = sb.next(&r)).ok() && *more;) outB.push_back(r);
  ASSERT_NO_FATAL_FAILURE(expectMatchesReference(a, outA));
  ASSERT_NO_FATAL_FAILURE(expectMatchesReference(b, outB));
  EXPECT_TRUE(filesIn(dir).empty());
}

TEST(ExternalSurfelSorter, EmptyAndSingleInput) {
  const ScratchDir scratch;
  const fs::path& dir = scratch.path;
  ExternalSurfelSorter empty(ExternalSortOptions{.tempDir = dir.string()});
  ASSERT_TRUE(empty.finish().ok());
  SortedSurfel r;
  absl::StatusOr<bool> more = empty.next(&r);
  ASSERT_TRUE(more.ok());
  EXPECT_FALSE(*more);

  ExternalSurfelSorter one(ExternalSortOptions{.tempDir = dir.string()});
  Surfel s;
  s.triangle = 42;
  ASSERT_TRUE(one.add(9, s).ok());
  ASSERT_TRUE(one.finish().ok());
  more = one.next(&r);
  ASSERT_TRUE(more.ok() && *more);
  EXPECT_EQ(r.key, 9u);
  EXPECT_EQ(r.sequence, 0u);
  EXPECT_EQ(r.surfel.triangle, 42u);
  more = one.next(&r);
  ASSERT_TRUE(more.ok());
  EXPECT_FALSE(*more);
  more = one.next(&r);  // stays at the end
  ASSERT_TRUE(more.ok());
  EXPECT_FALSE(*more);
}

TEST(ExternalSurfelSorter, BudgetBelowMinimumIsRejected) {
  ExternalSortOptions options;
  options.memoryBudgetBytes = 64 << 10;
  const absl::Status v = ExternalSurfelSorter::validateOptions(options);
  EXPECT_EQ(v.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(v.message().find("65536"), std::string::npos) << v;
  ExternalSurfelSorter sorter(options);
  EXPECT_EQ(sorter.add(0, Surfel()).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(sorter.finish().code(), absl::StatusCode::kInvalidArgument);
  options.memoryBudgetBytes = ExternalSurfelSorter::kMinMemoryBudgetBytes;
  EXPECT_TRUE(ExternalSurfelSorter::validateOptions(options).ok());
  options.threads = -1;
  EXPECT_EQ(ExternalSurfelSorter::validateOptions(options).code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(ExternalSurfelSorter, MissingTempDirIsAnErrorNamingTheFile) {
  const ScratchDir scratch;
  const fs::path& dir = scratch.path;
  const fs::path missing = dir / "missing";
  ExternalSortOptions options;
  options.memoryBudgetBytes = ExternalSurfelSorter::kMinMemoryBudgetBytes;
  options.tempDir = missing.string();
  ExternalSurfelSorter sorter(options);
  const Input in = makeInput(sorter.bufferCapacityRecords() + 1, 3);
  absl::Status s;
  for (size_t i = 0; i < in.keys.size() && s.ok(); ++i) s = sorter.add(in.keys[i], in.surfels[i]);
  EXPECT_EQ(s.code(), absl::StatusCode::kNotFound) << s;
  EXPECT_NE(s.message().find(missing.string() + "/pbgi-sort-"), std::string::npos) << s;
  // The error sticks.
  EXPECT_EQ(sorter.add(0, Surfel()), s);
  EXPECT_EQ(sorter.finish(), s);
}

// Spill files are removed when the sorter goes, whether or not the stream was read.
TEST(ExternalSurfelSorter, DestroyingMidwayRemovesSpillFiles) {
  const Input in = makeInput(50000, 4);
  const ScratchDir scratch;
  const fs::path& dir = scratch.path;
  ExternalSortOptions options;
  options.memoryBudgetBytes = 1 << 20;
  options.tempDir = dir.string();
  {
    ExternalSurfelSorter sorter(options);  // destroyed before finish()
    for (size_t i = 0; i < in.keys.size(); ++i)
      ASSERT_TRUE(sorter.add(in.keys[i], in.surfels[i]).ok());
    EXPECT_GT(filesIn(dir).size(), 1u);
  }
  EXPECT_TRUE(filesIn(dir).empty());
  {
    ExternalSurfelSorter sorter(options);  // destroyed in the middle of the stream
    for (size_t i = 0; i < in.keys.size(); ++i)
      ASSERT_TRUE(sorter.add(in.keys[i], in.surfels[i]).ok());
    ASSERT_TRUE(sorter.finish().ok());
    SortedSurfel r;
    for (int i = 0; i < 100; ++i) ASSERT_TRUE(sorter.next(&r).ok());
    EXPECT_GT(filesIn(dir).size(), 1u);
  }
  EXPECT_TRUE(filesIn(dir).empty());
}

// Damage to a spill file between writing and reading is an error naming the file, never a
// silently wrong stream; the files are removed at once.
class DamagedRunTest : public ::testing::Test {
 protected:
  // Spills 200k surfels in a 4 MiB budget (runs of ~45k records, read through buffers of
  // ~8k records), calls damage() on one run file after finish(), then reads to the end.
  absl::Status sortWithDamage(const std::function<void(const fs::path&)>& damage) {
    const Input in = makeInput(200000, 5);
    dir_ = scratch_.path;
    ExternalSortOptions options;
    options.memoryBudgetBytes = 4 << 20;
    options.tempDir = dir_.string();
    ExternalSurfelSorter sorter(options);
    for (size_t i = 0; i < in.keys.size(); ++i) {
      if (absl::Status s = sorter.add(in.keys[i], in.surfels[i]); !s.ok()) return s;
    }
    if (absl::Status s = sorter.finish(); !s.ok()) return s;
    std::vector<std::string> files = filesIn(dir_);
    EXPECT_GE(files.size(), 2u);
    std::sort(files.begin(), files.end());
    damaged_ = dir_ / files[0];
    damage(damaged_);
    SortedSurfel r;
    absl::StatusOr<bool> more;
    size_t n = 0;
    while ((more = sorter.next(&r)).ok() && *more) ++n;
    EXPECT_LT(n, in.keys.size());
    EXPECT_TRUE(filesIn(dir_).empty());
    if (more.ok()) return absl::OkStatus();
    EXPECT_EQ(sorter.next(&r).status(), more.status());  // the error sticks
    return more.status();
  }

  // Overwrites the file's bytes at offset with data.
  static void patch(const fs::path& path, off_t offset, const uint8_t* data, size_t n) {
    const int fd = ::open(path.c_str(), O_WRONLY);
    ASSERT_GE(fd, 0);
    ASSERT_EQ(::pwrite(fd, data, n, offset), static_cast<ssize_t>(n));
    ::close(fd);
  }
  static std::vector<uint8_t> readAt(const fs::path& path, off_t offset, size_t n) {
    std::vector<uint8_t> data(n);
    const int fd = ::open(path.c_str(), O_RDONLY);
    EXPECT_GE(fd, 0);
    EXPECT_EQ(::pread(fd, data.data(), n, offset), static_cast<ssize_t>(n));
    ::close(fd);
    return data;
  }

  ScratchDir scratch_;
  fs::path dir_;
  fs::path damaged_;
};

TEST_F(DamagedRunTest, TruncatedRunFile) {
  const absl::Status s =
      sortWithDamage([](const fs::path& p) { fs::resize_file(p, fs::file_size(p) / 2 + 7); });
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_NE(s.message().find(damaged_.string()), std::string::npos) << s;
  EXPECT_NE(s.message().find("truncated"), std::string::npos) << s;
}

TEST_F(DamagedRunTest, RecordOutOfOrder) {
  // Record 30000 (past the first read buffer) becomes a copy of record 29999.
  const absl::Status s = sortWithDamage([](const fs::path& p) {
    const std::vector<uint8_t> prev = readAt(p, 29999 * kSurfelRecordBytes, kSurfelRecordBytes);
    patch(p, 30000 * kSurfelRecordBytes, prev.data(), prev.size());
  });
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_NE(s.message().find(damaged_.string()), std::string::npos) << s;
  EXPECT_NE(s.message().find("record 30000"), std::string::npos) << s;
}

TEST_F(DamagedRunTest, BadMaterialByte) {
  const absl::Status s = sortWithDamage([](const fs::path& p) {
    const uint8_t bad = 200;
    patch(p, 20000 * kSurfelRecordBytes + 80, &bad, 1);
  });
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_NE(s.message().find(damaged_.string()), std::string::npos) << s;
  EXPECT_NE(s.message().find("record 20000"), std::string::npos) << s;
  EXPECT_NE(s.message().find("material class byte 200"), std::string::npos) << s;
}

TEST_F(DamagedRunTest, LongerRunFile) {
  const absl::Status s = sortWithDamage([](const fs::path& p) {
    const uint8_t extra = 0;
    patch(p, static_cast<off_t>(fs::file_size(p)), &extra, 1);
  });
  EXPECT_EQ(s.code(), absl::StatusCode::kDataLoss) << s;
  EXPECT_NE(s.message().find(damaged_.string()), std::string::npos) << s;
  EXPECT_NE(s.message().find("longer"), std::string::npos) << s;
}

}  // namespace
}  // namespace pbgi
