#include "formats/pbgi/page_file.h"

#include <sys/resource.h>

#include <algorithm>
#include <bit>
#include <cmath>
#include <csignal>
#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <limits>
#include <map>
#include <random>
#include <string>
#include <thread>
#include <vector>

#include <absl/strings/match.h>
#include <fmt/format.h>
#include <gtest/gtest.h>

#include "core/util/status.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

using testing::filesIn;

namespace fs = std::filesystem;

std::vector<uint8_t> readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

void writeFile(const fs::path& path, std::span<const uint8_t> bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out.write(reinterpret_cast<const char*>(bytes.data()),
            static_cast<std::streamsize>(bytes.size()));
  ASSERT_TRUE(out.good()) << path;
}

// The generator's reproducible incompressible bytes (tests/data/pbgi/make_pbgi_files.py).
std::vector<uint8_t> lcgBytes(size_t n, uint32_t seed) {
  std::vector<uint8_t> out(n);
  uint32_t x = seed;
  for (uint8_t& b : out) {
    x = (x * 1103515245u + 12345u) & 0x7fffffffu;
    b = static_cast<uint8_t>(x >> 16);
  }
  return out;
}

std::vector<uint8_t> bytesOf(std::string_view s) { return {s.begin(), s.end()}; }

uint32_t loadU32(std::span<const uint8_t> b, size_t at) {
  return uint32_t{b[at]} | uint32_t{b[at + 1]} << 8 | uint32_t{b[at + 2]} << 16 |
         uint32_t{b[at + 3]} << 24;
}
void storeU32(std::span<uint8_t> b, size_t at, uint32_t v) {
  for (int i = 0; i < 4; ++i) b[at + i] = static_cast<uint8_t>(v >> (8 * i));
}
void storeU64(std::span<uint8_t> b, size_t at, uint64_t v) {
  for (int i = 0; i < 8; ++i) b[at + i] = static_cast<uint8_t>(v >> (8 * i));
}
// Makes a header edited by a test valid again, as an attacker would.
void resealHeader(std::vector<uint8_t>& file) {
  storeU64(file, 120, pageFileChecksum(std::span<const uint8_t>(file).first(120)));
}

struct Sample {
  std::vector<std::vector<uint8_t>> pages;
  PageFileMetadata metadata;
};

// Pages of every kind a writer sees: compressible, incompressible and exactly full, small,
// empty; and the two sections the baker writes.
Sample makeSample(uint32_t pageSize, int pageCount) {
  Sample s;
  for (int i = 0; i < pageCount; ++i) {
    switch (i % 4) {
      case 0: {
        std::vector<uint8_t> p(pageSize / 2);
        for (size_t j = 0; j < p.size(); ++j) p[j] = static_cast<uint8_t>((j / 16 + i) % 7);
        s.pages.push_back(std::move(p));
        break;
      }
      case 1:
        s.pages.push_back(lcgBytes(pageSize, 1000 + i));
        break;
      case 2:
        s.pages.push_back(lcgBytes(37 + i, 77 + i));
        break;
      default:
        s.pages.emplace_back();
        break;
    }
  }
  PageFileMetadata& m = s.metadata;
  m.sceneBounds.min = Vec3f(-1.5f, 0.0f, -2.25f);
  m.sceneBounds.max = Vec3f(3.0f, 4.5f, 0.125f);
  m.pointCount = 123456789012ull;
  m.nodeCount = 4567;
  m.leafCount = 3210;
  m.sceneHash = 0xfeedfacecafebeefull;
  m.rootPage = 0;
  m.rootOffset = 8;
  std::vector<uint8_t> codebook(101 * 27 * 4);
  for (size_t i = 0; i < codebook.size(); ++i) codebook[i] = static_cast<uint8_t>(i * 31);
  m.sections = {{"codebook", codebook}, {"bake", bytesOf("{\"points_per_leaf\": 16}")}};
  return s;
}

// A small file for the exhaustive damage tests: every page kind, two small sections.
Sample makeTinySample() {
  Sample s;
  s.pages = {bytesOf("root node bytes, root node bytes, root node bytes"),
             lcgBytes(60, 5),
             {},
             bytesOf("a leaf")};
  s.metadata.sceneBounds.extend(Vec3f(0, 0, 0));
  s.metadata.sceneBounds.extend(Vec3f(1, 2, 3));
  s.metadata.pointCount = 40;
  s.metadata.nodeCount = 5;
  s.metadata.leafCount = 4;
  s.metadata.sceneHash = 42;
  s.metadata.rootOffset = 5;
  s.metadata.sections = {{"codebook", lcgBytes(24, 9)}, {"bake", bytesOf("seed=7")}};
  return s;
}

absl::Status writeSample(const fs::path& path, const Sample& sample,
                         const PageFileWriterOptions& options) {
  absl::StatusOr<PageFileWriter> writer = PageFileWriter::create(path.string(), options);
  if (!writer.ok()) return writer.status();
  for (size_t i = 0; i < sample.pages.size(); ++i) {
    absl::StatusOr<uint32_t> id = writer->appendPage(sample.pages[i]);
    if (!id.ok()) return id.status();
    EXPECT_EQ(*id, i);
  }
  return writer->finish(sample.metadata);
}

PageFileWriterOptions smallPages() { return {.pageSize = 4096, .zstdLevel = 3}; }

void expectMetadataEq(const PageFileMetadata& a, const PageFileMetadata& b) {
  EXPECT_EQ(a.sceneBounds.min, b.sceneBounds.min);
  EXPECT_EQ(a.sceneBounds.max, b.sceneBounds.max);
  EXPECT_EQ(a.pointCount, b.pointCount);
  EXPECT_EQ(a.nodeCount, b.nodeCount);
  EXPECT_EQ(a.leafCount, b.leafCount);
  EXPECT_EQ(a.sceneHash, b.sceneHash);
  EXPECT_EQ(a.rootPage, b.rootPage);
  EXPECT_EQ(a.rootOffset, b.rootOffset);
  EXPECT_EQ(a.sections, b.sections);
}

class PageFileTest : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = testing::makeTempDir("page-file"); }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

// ---------------------------------------------------------------------------------------------
// Round trips

TEST_F(PageFileTest, RoundTripsPagesAndSections) {
  const Sample sample = makeSample(4096, 9);
  const fs::path path = dir_ / "frame.pbgi";
  ASSERT_TRUE(writeSample(path, sample, smallPages()).ok());

  absl::StatusOr<std::unique_ptr<PageFileReader>> reader = PageFileReader::open(path.string());
  ASSERT_TRUE(reader.ok()) << reader.status();
  const PageFileInfo& info = (*reader)->info();
  EXPECT_EQ(info.version, kPageFileVersion);
  EXPECT_EQ(info.pageSize, 4096u);
  EXPECT_EQ(info.pageCount, 9u);
  EXPECT_EQ(info.fileSize, fs::file_size(path));
  expectMetadataEq(info, sample.metadata);
  ASSERT_NE(info.findSection("codebook"), nullptr);
  EXPECT_EQ(info.findSection("codebook")->bytes.size(), 101u * 27 * 4);
  EXPECT_EQ(info.findSection("nonexistent"), nullptr);
  for (uint32_t id = 0; id < 9; ++id) {
    absl::StatusOr<std::vector<uint8_t>> page = (*reader)->readPage(id);
    ASSERT_TRUE(page.ok()) << page.status();
    EXPECT_EQ(*page, sample.pages[id]) << "page " << id;
  }
  EXPECT_TRUE((*reader)->verifyAll().ok());
  // The compressible half-page shrinks; the incompressible full page stays within zstd's bound.
  EXPECT_LT((*reader)->directory()[0].compressedSize, 4096u / 8);
  EXPECT_EQ((*reader)->directory()[1].uncompressedSize, 4096u);
}

TEST_F(PageFileTest, DefaultOptionsUse64KiBPages) {
  Sample sample = makeSample(kDefaultPageSize, 3);
  const fs::path path = dir_ / "default.pbgi";
  ASSERT_TRUE(writeSample(path, sample, {}).ok());
  auto reader = PageFileReader::open(path.string());
  ASSERT_TRUE(reader.ok()) << reader.status();
  EXPECT_EQ((*reader)->info().pageSize, 65536u);
  for (uint32_t id = 0; id < 3; ++id) EXPECT_EQ(*(*reader)->readPage(id), sample.pages[id]);
}

TEST_F(PageFileTest, WritesAreDeterministic) {
  const Sample sample = makeSample(4096, 6);
  ASSERT_TRUE(writeSample(dir_ / "a.pbgi", sample, smallPages()).ok());
  ASSERT_TRUE(writeSample(dir_ / "b.pbgi", sample, smallPages()).ok());
  EXPECT_EQ(readFile(dir_ / "a.pbgi"), readFile(dir_ / "b.pbgi"));
}

TEST_F(PageFileTest, HeaderFieldsSitWhereTheLayoutSays) {
  // The layout comment in page_file.h is the format's definition; spot-check it on the bytes.
  const Sample sample = makeTinySample();
  const fs::path path = dir_ / "layout.pbgi";
  ASSERT_TRUE(writeSample(path, sample, smallPages()).ok());
  const std::vector<uint8_t> file = readFile(path);
  ASSERT_GE(file.size(), kPageFileHeaderSize);
  EXPECT_EQ(std::string(file.begin(), file.begin() + 8), "PBGITREE");
  EXPECT_EQ(loadU32(file, 8), 1u);
  EXPECT_EQ(loadU32(file, 12), 128u);
  EXPECT_EQ(loadU32(file, 16), 4096u);
  EXPECT_EQ(loadU32(file, 20), 4u);
  EXPECT_EQ(loadU32(file, 24), file.size());
  EXPECT_EQ(loadU32(file, 60), 5u);                                  // root offset
  EXPECT_EQ(loadU32(file, 64 + 20), std::bit_cast<uint32_t>(3.0f));  // max z
  EXPECT_EQ(loadU32(file, 112), 42u);                                // scene hash
  // Page 0 starts right after the header, as a zstd frame.
  EXPECT_EQ(loadU32(file, 128), 0xfd2fb528u);
}

TEST_F(PageFileTest, GeneratedFileReadsAsWritten) {
  // valid.pbgi comes from make_pbgi_files.py, an encoder written from the layout comment alone.
  auto reader = PageFileReader::open((testing::testDataDir() / "pbgi" / "valid.pbgi").string());
  ASSERT_TRUE(reader.ok()) << reader.status();
  const PageFileInfo& info = (*reader)->info();
  EXPECT_EQ(info.version, 1u);
  EXPECT_EQ(info.pageSize, 4096u);
  EXPECT_EQ(info.pageCount, 3u);
  EXPECT_EQ(info.sceneBounds.min, Vec3f(-1, -2, -3));
  EXPECT_EQ(info.sceneBounds.max, Vec3f(4, 5, 6));
  EXPECT_EQ(info.pointCount, 1000u);
  EXPECT_EQ(info.nodeCount, 150u);
  EXPECT_EQ(info.leafCount, 120u);
  EXPECT_EQ(info.sceneHash, 0x0123456789abcdefu);
  EXPECT_EQ(info.rootPage, 0u);
  EXPECT_EQ(info.rootOffset, 16u);
  std::vector<uint8_t> codebook(81 * 4);
  for (int i = 0; i < 81; ++i) {
    storeU32(codebook, 4 * i, std::bit_cast<uint32_t>(0.25f * static_cast<float>(i)));
  }
  const std::vector<PageFileSection> sections = {
      {"codebook", codebook}, {"bake", bytesOf("{\"points_per_leaf\":16,\"seed\":7}")}};
  EXPECT_EQ(info.sections, sections);
  std::vector<uint8_t> page0;
  for (int r = 0; r < 4; ++r)
    for (int i = 0; i < 256; ++i) page0.push_back(static_cast<uint8_t>(i));
  std::vector<uint8_t> page2;
  for (int r = 0; r < 100; ++r)
    for (char c : std::string("leaf")) page2.push_back(static_cast<uint8_t>(c));
  EXPECT_EQ(*(*reader)->readPage(0), page0);
  EXPECT_EQ(*(*reader)->readPage(1), lcgBytes(4096, 12345));
  EXPECT_EQ(*(*reader)->readPage(2), page2);

  // Written again by the C++ writer with the same contents, the file keeps the same header,
  // directory layout and sections; page bytes may differ only if zstd's two APIs do.
  Sample again;
  again.pages = {page0, lcgBytes(4096, 12345), page2};
  again.metadata = info;
  const fs::path path = dir_ / "again.pbgi";
  ASSERT_TRUE(writeSample(path, again, smallPages()).ok());
  auto rewritten = PageFileReader::open(path.string());
  ASSERT_TRUE(rewritten.ok()) << rewritten.status();
  expectMetadataEq((*rewritten)->info(), info);
  const std::vector<uint8_t> ours = readFile(path);
  const std::vector<uint8_t> theirs = readFile(testing::testDataDir() / "pbgi" / "valid.pbgi");
  if ((*rewritten)->directory() == (*reader)->directory()) {
    EXPECT_EQ(ours, theirs);
  }
}

TEST_F(PageFileTest, ConcurrentReadsReturnTheSameBytes) {
  const Sample sample = makeSample(4096, 32);
  const fs::path path = dir_ / "shared.pbgi";
  ASSERT_TRUE(writeSample(path, sample, smallPages()).ok());
  auto reader = PageFileReader::open(path.string());
  ASSERT_TRUE(reader.ok()) << reader.status();
  const uint64_t openBytes = (*reader)->bytesRead();

  constexpr int kThreads = 8;
  constexpr int kRounds = 10;
  std::vector<int> mismatches(kThreads, 0);
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      std::mt19937 rng(t);
      std::vector<uint32_t> order(32);
      for (uint32_t i = 0; i < 32; ++i) order[i] = i;
      for (int round = 0; round < kRounds; ++round) {
        std::shuffle(order.begin(), order.end(), rng);
        for (uint32_t id : order) {
          absl::StatusOr<std::vector<uint8_t>> page = (*reader)->readPage(id);
          if (!page.ok() || *page != sample.pages[id]) ++mismatches[t];
        }
      }
    });
  }
  for (std::thread& t : threads) t.join();
  for (int t = 0; t < kThreads; ++t) EXPECT_EQ(mismatches[t], 0) << "thread " << t;

  uint64_t compressed = 0;
  for (const PageEntry& e : (*reader)->directory()) compressed += e.compressedSize;
  EXPECT_EQ((*reader)->pagesRead(), uint64_t{kThreads} * kRounds * 32);
  EXPECT_EQ((*reader)->bytesRead(), openBytes + uint64_t{kThreads} * kRounds * compressed);
}

TEST_F(PageFileTest, BytesReadCountsOnlyWhatWasRead) {
  const Sample sample = makeSample(4096, 5);
  const fs::path path = dir_ / "count.pbgi";
  ASSERT_TRUE(writeSample(path, sample, smallPages()).ok());
  auto reader = PageFileReader::open(path.string());
  ASSERT_TRUE(reader.ok()) << reader.status();
  const std::vector<PageEntry>& dir = (*reader)->directory();
  uint64_t pageBytes = 0;
  for (const PageEntry& e : dir) pageBytes += e.compressedSize;
  // Open reads the header, the directory and the sections, and no page.
  EXPECT_EQ((*reader)->bytesRead(), fs::file_size(path) - pageBytes);
  EXPECT_EQ((*reader)->pagesRead(), 0u);
  ASSERT_TRUE((*reader)->readPage(3).ok());
  EXPECT_EQ((*reader)->bytesRead(), fs::file_size(path) - pageBytes + dir[3].compressedSize);
  EXPECT_EQ((*reader)->pagesRead(), 1u);
}

TEST_F(PageFileTest, ReadingAPageThatDoesNotExistIsOutOfRange) {
  ASSERT_TRUE(writeSample(dir_ / "f.pbgi", makeSample(4096, 2), smallPages()).ok());
  auto reader = PageFileReader::open((dir_ / "f.pbgi").string());
  ASSERT_TRUE(reader.ok());
  absl::StatusOr<std::vector<uint8_t>> page = (*reader)->readPage(2);
  EXPECT_EQ(page.status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_TRUE(absl::StrContains(page.status().message(), "page 2 does not exist; the file has 2"))
      << page.status();
}

// ---------------------------------------------------------------------------------------------
// The writer

TEST_F(PageFileTest, PageLargerThanThePageSizeIsRejectedAtAppend) {
  auto writer = PageFileWriter::create((dir_ / "big.pbgi").string(), smallPages());
  ASSERT_TRUE(writer.ok()) << writer.status();
  const std::vector<uint8_t> tooBig(4097, 1);
  absl::StatusOr<uint32_t> id = writer->appendPage(tooBig);
  EXPECT_EQ(id.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StrContains(id.status().message(), "4097 bytes, more than the page size 4096"))
      << id.status();
  // Nothing was written: the next page is still page 0, and a full page fits.
  const std::vector<uint8_t> full(4096, 2);
  id = writer->appendPage(full);
  ASSERT_TRUE(id.ok()) << id.status();
  EXPECT_EQ(*id, 0u);
  EXPECT_EQ(writer->pageCount(), 1u);
}

TEST_F(PageFileTest, InvalidOptionsAreRejected) {
  const std::string path = (dir_ / "x.pbgi").string();
  for (uint32_t pageSize : {0u, 1000u, 2048u, 6000u, 32u << 20}) {
    auto writer = PageFileWriter::create(path, {.pageSize = pageSize});
    EXPECT_EQ(writer.status().code(), absl::StatusCode::kInvalidArgument) << pageSize;
    EXPECT_TRUE(absl::StrContains(writer.status().message(), fmt::format("page size {}", pageSize)))
        << writer.status();
  }
  auto writer = PageFileWriter::create(path, {.pageSize = 4096, .zstdLevel = 1000});
  EXPECT_EQ(writer.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StrContains(writer.status().message(), "zstd level 1000")) << writer.status();
  EXPECT_TRUE(filesIn(dir_).empty());
}

TEST_F(PageFileTest, OnlyATemporaryExistsUntilFinish) {
  const fs::path path = dir_ / "frame.pbgi";
  auto writer = PageFileWriter::create(path.string(), smallPages());
  ASSERT_TRUE(writer.ok()) << writer.status();
  ASSERT_TRUE(writer->appendPage(bytesOf("root")).ok());
  std::vector<std::string> during = filesIn(dir_);
  ASSERT_EQ(during.size(), 1u);
  EXPECT_TRUE(during[0].starts_with("frame.pbgi.tmp-")) << during[0];
  EXPECT_FALSE(fs::exists(path));
  PageFileMetadata m;
  ASSERT_TRUE(writer->finish(m).ok());
  EXPECT_EQ(filesIn(dir_), std::vector<std::string>{"frame.pbgi"});
  // A finished writer takes nothing more.
  EXPECT_EQ(writer->appendPage(bytesOf("late")).status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(writer->finish(m).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(filesIn(dir_), std::vector<std::string>{"frame.pbgi"});
}

TEST_F(PageFileTest, AbandonedWriterLeavesTheOldFileAndNoTemporary) {
  const fs::path path = dir_ / "frame.pbgi";
  ASSERT_TRUE(writeSample(path, makeSample(4096, 2), smallPages()).ok());
  const std::vector<uint8_t> old = readFile(path);
  {
    auto writer = PageFileWriter::create(path.string(), smallPages());
    ASSERT_TRUE(writer.ok()) << writer.status();
    ASSERT_TRUE(writer->appendPage(bytesOf("a different root")).ok());
    EXPECT_EQ(filesIn(dir_).size(), 2u);
  }
  EXPECT_EQ(filesIn(dir_), std::vector<std::string>{"frame.pbgi"});
  EXPECT_EQ(readFile(path), old);

  // A finished one replaces it whole.
  Sample other = makeTinySample();
  ASSERT_TRUE(writeSample(path, other, smallPages()).ok());
  auto reader = PageFileReader::open(path.string());
  ASSERT_TRUE(reader.ok()) << reader.status();
  EXPECT_EQ((*reader)->info().pageCount, 4u);
  EXPECT_EQ(filesIn(dir_), std::vector<std::string>{"frame.pbgi"});
}

TEST_F(PageFileTest, MovedWriterKeepsItsTemporary) {
  const fs::path path = dir_ / "moved.pbgi";
  auto created = PageFileWriter::create(path.string(), smallPages());
  ASSERT_TRUE(created.ok());
  PageFileWriter writer = std::move(*created);
  { PageFileWriter dropped = std::move(*created); }  // a moved-from writer owns nothing
  ASSERT_TRUE(writer.appendPage(bytesOf("root page")).ok());
  ASSERT_TRUE(writer.finish({}).ok());
  EXPECT_EQ(filesIn(dir_), std::vector<std::string>{"moved.pbgi"});
  EXPECT_EQ(created->appendPage(bytesOf("x")).status().code(),
            absl::StatusCode::kFailedPrecondition);
}

TEST_F(PageFileTest, FailedFinishLeavesNothingBehind) {
  struct Case {
    std::string name;
    std::function<void(PageFileMetadata&)> edit;
    std::string expected;
  };
  const std::vector<Case> cases = {
      {"root page", [](PageFileMetadata& m) { m.rootPage = 4; },
       "root page 4 is not one of the 4 pages written"},
      {"root offset", [](PageFileMetadata& m) { m.rootPage = 2; },  // the empty page
       "root offset 5 is not inside root page 2, which holds 0 bytes"},
      {"NaN", [](PageFileMetadata& m) { m.sceneBounds.max.y = std::nanf(""); },
       "scene bounds hold a NaN"},
      {"duplicate",
       [](PageFileMetadata& m) {
         m.sections.push_back({"bake", {}});
       },
       "two sections are called \"bake\""},
      {"long name",
       [](PageFileMetadata& m) {
         m.sections.push_back({std::string(33, 'n'), {}});
       },
       "is 33 bytes; expected 1 to 32"},
      {"empty name",
       [](PageFileMetadata& m) {
         m.sections.push_back({"", {}});
       },
       "is 0 bytes; expected 1 to 32"},
      {"space",
       [](PageFileMetadata& m) {
         m.sections.push_back({"bake params", {}});
       },
       "holds byte 0x20"},
  };
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    const fs::path path = dir_ / "frame.pbgi";
    Sample sample = makeTinySample();
    c.edit(sample.metadata);
    const absl::Status status = writeSample(path, sample, smallPages());
    EXPECT_EQ(status.code(), absl::StatusCode::kInvalidArgument) << status;
    EXPECT_TRUE(absl::StrContains(status.message(), c.expected)) << status;
    EXPECT_TRUE(absl::StrContains(status.message(), path.string())) << status;
    EXPECT_TRUE(filesIn(dir_).empty());
  }
  auto writer = PageFileWriter::create((dir_ / "empty.pbgi").string(), smallPages());
  ASSERT_TRUE(writer.ok());
  const absl::Status status = writer->finish({});
  EXPECT_EQ(status.code(), absl::StatusCode::kFailedPrecondition) << status;
  EXPECT_TRUE(absl::StrContains(status.message(), "no pages")) << status;
  EXPECT_TRUE(filesIn(dir_).empty());
  EXPECT_EQ(writer->appendPage(bytesOf("late")).status().code(),
            absl::StatusCode::kFailedPrecondition);
}

TEST_F(PageFileTest, FailedRenameLeavesNothingBehind) {
  // A folder where the file should go: everything works until the rename.
  const fs::path path = dir_ / "frame.pbgi";
  fs::create_directory(path);
  const absl::Status status = writeSample(path, makeTinySample(), smallPages());
  EXPECT_FALSE(status.ok());
  EXPECT_TRUE(absl::StrContains(status.message(), "cannot rename")) << status;
  // No file anywhere (filesIn lists regular files): the folder stands alone, untouched.
  EXPECT_TRUE(filesIn(dir_).empty());
  EXPECT_TRUE(fs::is_directory(path));
  EXPECT_TRUE(fs::is_empty(path));
}

TEST_F(PageFileTest, WriteFailureIsStickyAndLeavesNothing) {
  // A file size limit makes writes fail with EFBIG, as a full disk would with ENOSPC.
  struct FileSizeLimit {
    rlimit old{};
    void (*oldHandler)(int) = nullptr;
    bool set = false;
    explicit FileSizeLimit(rlim_t bytes) {
      if (getrlimit(RLIMIT_FSIZE, &old) != 0 || old.rlim_max < bytes) return;
      oldHandler = std::signal(SIGXFSZ, SIG_IGN);
      rlimit limited = old;
      limited.rlim_cur = bytes;
      set = setrlimit(RLIMIT_FSIZE, &limited) == 0;
    }
    ~FileSizeLimit() { restore(); }
    void restore() {
      if (!set) return;
      setrlimit(RLIMIT_FSIZE, &old);
      std::signal(SIGXFSZ, oldHandler);
      set = false;
    }
  };
  const fs::path path = dir_ / "full.pbgi";
  absl::Status failure;
  auto writer = PageFileWriter::create(path.string(), smallPages());
  ASSERT_TRUE(writer.ok()) << writer.status();
  {
    FileSizeLimit limit(16 * 1024);
    ASSERT_TRUE(limit.set) << "cannot lower RLIMIT_FSIZE";
    for (uint32_t i = 0; i < 16 && failure.ok(); ++i) {
      failure = writer->appendPage(lcgBytes(4096, i)).status();
    }
  }
  ASSERT_FALSE(failure.ok()) << "16 incompressible 4 KiB pages fit under a 16 KiB limit";
  EXPECT_TRUE(absl::StrContains(failure.message(), path.string())) << failure;
  EXPECT_TRUE(absl::StrContains(failure.message(), "cannot write")) << failure;
  EXPECT_TRUE(filesIn(dir_).empty());  // the temporary went with the failure
  // Sticky: the writer reports the same failure, never a file with a page missing.
  EXPECT_EQ(writer->appendPage(bytesOf("small")).status(), failure);
  EXPECT_EQ(writer->finish({}), failure);
  EXPECT_TRUE(filesIn(dir_).empty());
}

TEST_F(PageFileTest, CreateFailsWhereNoFolderCanBeMade) {
  writeFile(dir_ / "plain", bytesOf("a file, not a folder"));
  auto writer = PageFileWriter::create((dir_ / "plain" / "frame.pbgi").string(), smallPages());
  EXPECT_FALSE(writer.ok());
  EXPECT_TRUE(absl::StrContains(writer.status().message(), "frame.pbgi")) << writer.status();
}

// ---------------------------------------------------------------------------------------------
// Damage: every byte, every length

// Where a byte of a clean file lies, as the error for damage there must name it.
std::string regionOf(uint64_t offset, const PageFileReader& reader) {
  if (offset < kPageFileHeaderSize) return "header:";
  const std::vector<PageEntry>& dir = reader.directory();
  for (uint32_t id = 0; id < dir.size(); ++id) {
    if (offset >= dir[id].offset && offset < dir[id].offset + dir[id].compressedSize) {
      return fmt::format("page {} (", id);
    }
  }
  const uint64_t directoryEnd =
      dir.back().offset + dir.back().compressedSize + dir.size() * kPageFileDirectoryEntrySize;
  return offset < directoryEnd ? "directory:" : "sections:";
}

TEST_F(PageFileTest, EveryFlippedByteIsDetectedAndNamed) {
  const Sample sample = makeTinySample();
  const fs::path clean = dir_ / "clean.pbgi";
  ASSERT_TRUE(writeSample(clean, sample, smallPages()).ok());
  auto cleanReader = PageFileReader::open(clean.string());
  ASSERT_TRUE(cleanReader.ok()) << cleanReader.status();
  const std::vector<uint8_t> file = readFile(clean);
  ASSERT_LT(file.size(), 1000u);  // keeps the loop quick

  const fs::path damaged = dir_ / "damaged.pbgi";
  std::map<std::string, int> seen;  // region -> flips detected there
  int failures = 0;
  for (uint8_t mask : {uint8_t{0x01}, uint8_t{0x80}, uint8_t{0xff}}) {
    for (size_t offset = 0; offset < file.size(); ++offset) {
      std::vector<uint8_t> bytes = file;
      bytes[offset] ^= mask;
      writeFile(damaged, bytes);
      const std::string region = regionOf(offset, **cleanReader);
      const std::string expected = damaged.string() + ": " + region;

      absl::Status status;
      auto reader = PageFileReader::open(damaged.string());
      if (!reader.ok()) {
        status = reader.status();
      } else {
        status = (*reader)->verifyAll();
        // Damage in one page stays there: the others still read, the damaged one does not.
        for (uint32_t id = 0; id < sample.pages.size(); ++id) {
          const bool hit = region == fmt::format("page {} (", id);
          absl::StatusOr<std::vector<uint8_t>> page = (*reader)->readPage(id);
          if (hit == page.ok() || (page.ok() && *page != sample.pages[id])) {
            if (++failures <= 10) {
              ADD_FAILURE() << "byte " << offset << " ^ " << int{mask} << ": page " << id
                            << (page.ok() ? " read" : " failed: ") << page.status();
            }
          }
        }
      }
      const bool named = !status.ok() && absl::StrContains(status.message(), expected);
      const bool magic = offset < kPageFileMagic.size();
      const absl::StatusCode code =
          magic ? absl::StatusCode::kInvalidArgument : absl::StatusCode::kDataLoss;
      if (named && status.code() == code) {
        ++seen[region];
      } else if (++failures <= 10) {
        ADD_FAILURE() << "byte " << offset << " ^ " << int{mask} << " (" << region
                      << "): " << (status.ok() ? "not detected" : status.ToString());
      }
    }
  }
  EXPECT_EQ(failures, 0);
  // Every region was exercised.
  for (const char* region :
       {"header:", "directory:", "sections:", "page 0 (", "page 1 (", "page 2 (", "page 3 ("}) {
    EXPECT_GT(seen[region], 0) << region;
  }
}

TEST_F(PageFileTest, DamageInSeveralPagesIsCounted) {
  const fs::path path = dir_ / "f.pbgi";
  ASSERT_TRUE(writeSample(path, makeSample(4096, 6), smallPages()).ok());
  auto clean = PageFileReader::open(path.string());
  ASSERT_TRUE(clean.ok());
  std::vector<uint8_t> bytes = readFile(path);
  bytes[(*clean)->directory()[2].offset + 3] ^= 0x10;
  bytes[(*clean)->directory()[4].offset + 5] ^= 0x10;
  writeFile(path, bytes);
  auto reader = PageFileReader::open(path.string());
  ASSERT_TRUE(reader.ok()) << reader.status();
  const absl::Status status = (*reader)->verifyAll();
  EXPECT_EQ(status.code(), absl::StatusCode::kDataLoss);
  EXPECT_TRUE(absl::StrContains(status.message(), "page 2 (")) << status;
  EXPECT_TRUE(absl::StrContains(status.message(), "checksum mismatch")) << status;
  EXPECT_TRUE(absl::StrContains(status.message(), "(2 of 6 pages failed)")) << status;
}

TEST_F(PageFileTest, TruncationAtEveryLengthIsDetected) {
  const fs::path clean = dir_ / "clean.pbgi";
  ASSERT_TRUE(writeSample(clean, makeTinySample(), smallPages()).ok());
  const std::vector<uint8_t> file = readFile(clean);
  const fs::path cut = dir_ / "cut.pbgi";
  int failures = 0;
  for (size_t length = 0; length < file.size(); ++length) {
    writeFile(cut, std::span<const uint8_t>(file).first(length));
    auto reader = PageFileReader::open(cut.string());
    const bool clear = !reader.ok() && reader.status().code() == absl::StatusCode::kDataLoss &&
                       absl::StrContains(reader.status().message(), "truncated");
    if (!clear && ++failures <= 10) {
      ADD_FAILURE() << "cut at " << length << " of " << file.size() << ": "
                    << (reader.ok() ? "opened" : reader.status().ToString());
    }
  }
  EXPECT_EQ(failures, 0);
}

TEST_F(PageFileTest, TrailingBytesAreDetected) {
  const fs::path path = dir_ / "long.pbgi";
  ASSERT_TRUE(writeSample(path, makeTinySample(), smallPages()).ok());
  std::vector<uint8_t> bytes = readFile(path);
  const size_t size = bytes.size();
  bytes.push_back(0);
  writeFile(path, bytes);
  auto reader = PageFileReader::open(path.string());
  EXPECT_EQ(reader.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_TRUE(absl::StrContains(
      reader.status().message(),
      fmt::format("the file is {} bytes, the header records {} (offset 24): 1 trailing bytes",
                  size + 1, size)))
      << reader.status();
}

TEST_F(PageFileTest, NewerAndOlderVersionsAreNamed) {
  const fs::path path = dir_ / "v.pbgi";
  ASSERT_TRUE(writeSample(path, makeTinySample(), smallPages()).ok());
  std::vector<uint8_t> bytes = readFile(path);
  storeU32(bytes, 8, kPageFileVersion + 1);
  resealHeader(bytes);
  writeFile(path, bytes);
  auto reader = PageFileReader::open(path.string());
  EXPECT_EQ(reader.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_TRUE(absl::StrContains(
      reader.status().message(),
      fmt::format("written by a newer pbgi: format version {}, this build reads {}",
                  kPageFileVersion + 1, kPageFileVersion)))
      << reader.status();

  // A newer version may have a header of another size; it is still a newer version, not damage.
  storeU32(bytes, 12, 256);
  storeU64(bytes, 256 - 8, pageFileChecksum(std::span<const uint8_t>(bytes).first(256 - 8)));
  writeFile(path, bytes);
  reader = PageFileReader::open(path.string());
  EXPECT_EQ(reader.status().code(), absl::StatusCode::kFailedPrecondition) << reader.status();
  storeU32(bytes, 12, 1 << 20);  // beyond any header a version may have: still named
  writeFile(path, bytes);
  reader = PageFileReader::open(path.string());
  EXPECT_EQ(reader.status().code(), absl::StatusCode::kFailedPrecondition) << reader.status();
}

TEST_F(PageFileTest, MissingFileAndFolderAreNamed) {
  auto missing = PageFileReader::open((dir_ / "absent.pbgi").string());
  EXPECT_EQ(missing.status().code(), absl::StatusCode::kNotFound);
  EXPECT_TRUE(absl::StrContains(missing.status().message(), "absent.pbgi")) << missing.status();
  auto folder = PageFileReader::open(dir_.string());
  EXPECT_EQ(folder.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_TRUE(absl::StrContains(folder.status().message(), "not a regular file"))
      << folder.status();
}

}  // namespace
}  // namespace pbgi
