#include "formats/pbgi/page_file.h"

#include <cstdint>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <new>
#include <string>
#include <vector>

#include <absl/strings/match.h>
#include <gtest/gtest.h>

#include "tests/fuzz/page_file_fuzz_input.h"
#include "tests/support/test_paths.h"

// The largest single allocation made while a tracker is armed on this thread: how the
// hostile-file tests show that a header's claims are checked before anything is sized from
// them. Replacing the global operator new is the one portable hook; it forwards to malloc.
namespace {
thread_local bool gTrackAllocations = false;
thread_local size_t gLargestAllocation = 0;
}  // namespace

// gcc cannot see that these two belong together.
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmismatched-new-delete"
void* operator new(std::size_t size) {
  if (gTrackAllocations && size > gLargestAllocation) gLargestAllocation = size;
  if (void* p = std::malloc(size == 0 ? 1 : size)) return p;
  throw std::bad_alloc();
}
void operator delete(void* p) noexcept { std::free(p); }
void operator delete(void* p, std::size_t) noexcept { std::free(p); }
#pragma GCC diagnostic pop

namespace pbgi {
namespace {

namespace fs = std::filesystem;

class AllocationTracker {
 public:
  AllocationTracker() {
    gLargestAllocation = 0;
    gTrackAllocations = true;
  }
  ~AllocationTracker() { gTrackAllocations = false; }
  size_t largest() const { return gLargestAllocation; }
};

std::vector<uint8_t> readFile(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return std::vector<uint8_t>(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// ---------------------------------------------------------------------------------------------
// Hostile files (tests/data/pbgi, written by make_pbgi_files.py with valid checksums)

struct HostileCase {
  absl::StatusCode code;
  std::string message;
  bool opens = false;  // the damage is in a page: open succeeds, verifyAll fails
};

const std::map<std::string, HostileCase>& hostileCases() {
  static const std::map<std::string, HostileCase> cases = {
      {"valid.pbgi", {absl::StatusCode::kOk, "", true}},
      {"single.pbgi", {absl::StatusCode::kOk, "", true}},
      {"future_version.pbgi",
       {absl::StatusCode::kFailedPrecondition,
        "header: written by a newer pbgi: format version 7, this build reads 1"}},
      {"version_zero.pbgi",
       {absl::StatusCode::kFailedPrecondition,
        "header: format version 0 is older than this build reads (1)"}},
      {"wrong_magic.pbgi",
       {absl::StatusCode::kInvalidArgument,
        "header: expected the magic \"PBGITREE\" at offset 0, found \"This is \": not a .pbgi "
        "file"}},
      {"huge_page_count.pbgi",
       {absl::StatusCode::kDataLoss,
        "header: 4294967295 pages (offset 20) and 4 bytes of sections need at least "
        "107374182507 bytes, the file is 1024 bytes"}},
      {"huge_header_size.pbgi",
       {absl::StatusCode::kDataLoss,
        "header: header size (offset 12) is 4294967280; expected 24 to 65536"}},
      {"huge_sections.pbgi",
       {absl::StatusCode::kDataLoss,
        "header: sections size (offset 40) is 1099511627776; expected 4 to 268435456"}},
      {"huge_uncompressed_page.pbgi",
       {absl::StatusCode::kDataLoss,
        "directory: page 0 (entry at offset 4531) claims 4294967295 uncompressed bytes, more "
        "than the page size 4096"}},
      {"lying_frame.pbgi",
       {absl::StatusCode::kDataLoss,
        "page 0 (offset 128, 2010 bytes): the zstd frame holds 2000 bytes, the directory "
        "records 1000",
        true}},
      {"truncated.pbgi",
       {absl::StatusCode::kDataLoss,
        "header: the file is 3322 bytes, the header records 4984 (offset 24): truncated, 1662 "
        "bytes missing"}},
  };
  return cases;
}

TEST(PageFileHostileTest, EveryCommittedFileIsCoveredAndRejectedBeforeAllocating) {
  const fs::path dir = testing::testDataDir() / "pbgi";
  int files = 0;
  for (const auto& entry : fs::directory_iterator(dir)) {
    const std::string name = entry.path().filename().string();
    if (entry.path().extension() != ".pbgi") continue;
    ++files;
    SCOPED_TRACE(name);
    const auto found = hostileCases().find(name);
    ASSERT_NE(found, hostileCases().end()) << "no expectation for tests/data/pbgi/" << name;
    const HostileCase& c = found->second;

    absl::Status status;
    size_t largest = 0;
    {
      AllocationTracker tracker;
      auto reader = PageFileReader::open(entry.path().string());
      EXPECT_EQ(reader.ok(), c.opens) << reader.status();
      status = reader.ok() ? (*reader)->verifyAll() : reader.status();
      largest = tracker.largest();
    }
    EXPECT_EQ(status.code(), c.code) << status;
    if (!status.ok()) {
      EXPECT_TRUE(absl::StrContains(status.message(), entry.path().string() + ": " + c.message))
          << status;
    }
    // The largest buffer is the header read (a 64 KiB cap) or a real page of these small files.
    EXPECT_LE(largest, size_t{kPageFileMaxHeaderSize}) << "largest allocation " << largest;
  }
  EXPECT_EQ(files, static_cast<int>(hostileCases().size()));
}

TEST(PageFileHostileTest, AllocationTrackerSeesLargeAllocations) {
  // The tracker must be able to fail the test above.
  AllocationTracker tracker;
  std::vector<uint8_t> big(size_t{1} << 20);
  EXPECT_GE(tracker.largest(), size_t{1} << 20);
}

TEST(PageFileHostileTest, DecodingWithoutIoRejectsHugeClaims) {
  // The fuzz target's entry points, on a header that claims 2^32 - 1 pages in a 1 KiB file.
  const std::vector<uint8_t> file =
      readFile(testing::testDataDir() / "pbgi" / "huge_page_count.pbgi");
  AllocationTracker tracker;
  auto header = decodePageFileHeader(file, file.size());
  EXPECT_EQ(header.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_LT(tracker.largest(), size_t{4096});
  // A page entry that claims more than the page size is refused before zstd sees it.
  const PageEntry entry{128, 4, 0xffffffffu,
                        pageFileChecksum(std::span<const uint8_t>(file).first(4))};
  auto page = decodePage(0, entry, std::span<const uint8_t>(file).first(4), 4096);
  EXPECT_EQ(page.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_TRUE(absl::StrContains(page.status().message(), "claims 4294967295 uncompressed bytes"))
      << page.status();
  EXPECT_LT(tracker.largest(), size_t{4096});
}

TEST(PageFileFuzzCorpusTest, EverySeedReplaysThroughTheFuzzTarget) {
  const fs::path corpus = testing::testDataDir() / "pbgi" / "fuzz_corpus";
  std::map<std::string, std::pair<fuzz::PageFileStage, fuzz::PageFileStage>> stages;
  for (const auto& entry : fs::directory_iterator(corpus)) {
    const std::vector<uint8_t> input = readFile(entry.path());
    const fuzz::PageFileStage raw = fuzz::decodePageFileImage(input);
    const fuzz::PageFileStage repaired =
        fuzz::decodePageFileImage(fuzz::withRepairedChecksums(input));
    fuzz::decodeRawPage(input);
    stages[entry.path().filename().string()] = {raw, repaired};
  }
  EXPECT_GE(stages.size(), 12u);
  using S = fuzz::PageFileStage;
  // Valid seeds reach every page, as given and after repair (which then changes nothing).
  for (const char* name : {"valid.pbgi", "single.pbgi"}) {
    EXPECT_EQ(stages[name].first, S::kPages) << name;
    EXPECT_EQ(stages[name].second, S::kPages) << name;
  }
  // Hostile seeds stop where the reader stops them, repaired or not.
  EXPECT_EQ(stages["huge_page_count.pbgi"].second, S::kNothing);
  EXPECT_EQ(stages["huge_uncompressed_page.pbgi"].second, S::kHeader);
  EXPECT_EQ(stages["lying_frame.pbgi"].second, S::kSections);
  // Repair makes a truncated file consistent again as far as its sizes allow; as given, it
  // gets nowhere.
  EXPECT_EQ(stages["truncated.pbgi"].first, S::kNothing);

  // The raw-page mode decodes its seed.
  const std::vector<uint8_t> rawPage = readFile(corpus / "raw_page.bin");
  EXPECT_TRUE(fuzz::decodeRawPage(rawPage));
}

}  // namespace
}  // namespace pbgi
