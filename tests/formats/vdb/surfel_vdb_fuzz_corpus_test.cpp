// The surfel cloud's fuzz corpus (tests/data/vdb/fuzz_corpus) replayed through the fuzz
// target's body, so that builds without libFuzzer (CI's gcc) run every seed too; and the
// stream entry points it reads through.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "formats/vdb/surfel_vdb.h"
#include "tests/fuzz/surfel_vdb_fuzz_input.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

std::string readBytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream bytes;
  bytes << in.rdbuf();
  return bytes.str();
}

TEST(SurfelVdbFuzzCorpusTest, EverySeedKeepsTheReadersPromises) {
  const fs::path corpus = testing::testDataDir() / "vdb" / "fuzz_corpus";
  int seeds = 0;
  for (const auto& entry : fs::directory_iterator(corpus)) {
    const std::string name = entry.path().filename().string();
    const std::string bytes = readBytes(entry.path());
    EXPECT_EQ(fuzz::readSurfelVdbInput(bytes, fuzz::SurfelVdbFuzzMode::kFrontDoor).broken, "")
        << name;
    // The seeds are files that OpenVDB wrote, and the hazards of its parser are not in them.
    const fuzz::SurfelVdbFuzzResult result =
        fuzz::readSurfelVdbInput(bytes, fuzz::SurfelVdbFuzzMode::kRehashed);
    EXPECT_EQ(result.broken, "") << name << " rehashed";
    if (name == "valid_small.vdb") EXPECT_TRUE(result.read) << name;
    ++seeds;
  }
  EXPECT_GE(seeds, 10);
}

TEST(SurfelVdbFuzzCorpusTest, RehashingGivesTheUuidTheWriterGave) {
  const std::string valid = readBytes(testing::testDataDir() / "vdb" / "valid_small.vdb");
  EXPECT_EQ(fuzz::withContentUuid(valid), valid);
  std::string damaged = valid;
  damaged.back() = static_cast<char>(damaged.back() ^ 1);
  EXPECT_NE(fuzz::withContentUuid(damaged).substr(21, 36), valid.substr(21, 36));
}

TEST(SurfelVdbStreamTest, AStreamReadsAsTheFileDoesAndErrorsNameIt) {
  const fs::path path = testing::testDataDir() / "vdb" / "valid_small.vdb";
  const auto fromFile = readSurfelVdb(path.string());
  ASSERT_TRUE(fromFile.ok()) << fromFile.status();
  std::istringstream in(readBytes(path));
  const auto fromStream = readSurfelVdb(in, "memory.vdb");
  ASSERT_TRUE(fromStream.ok()) << fromStream.status();
  ASSERT_EQ(fromStream->size(), fromFile->size());
  for (size_t i = 0; i < fromFile->size(); ++i) {
    EXPECT_EQ((*fromStream)[i].position, (*fromFile)[i].position) << i;
    EXPECT_EQ((*fromStream)[i].radiance, (*fromFile)[i].radiance) << i;
  }
  std::istringstream again(readBytes(path));
  const auto info = inspectSurfelVdb(again, "memory.vdb");
  ASSERT_TRUE(info.ok()) << info.status();
  EXPECT_EQ(info->path, "memory.vdb");
  EXPECT_EQ(info->fileBytes, fs::file_size(path));
  EXPECT_EQ(info->pointCount, fromFile->size());

  std::istringstream empty("");
  const auto none = readSurfelVdb(empty, "memory.vdb");
  EXPECT_EQ(none.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(none.status().message(), "memory.vdb: empty file; expected an OpenVDB file");
  std::istringstream truncated(readBytes(testing::testDataDir() / "vdb" / "truncated.vdb"));
  const auto cut = readSurfelVdb(truncated, "memory.vdb");
  EXPECT_EQ(cut.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_TRUE(std::string(cut.status().message()).starts_with("memory.vdb: damaged or truncated"))
      << cut.status();
}

}  // namespace
}  // namespace pbgi
