// The shot parser's fuzz corpus (tests/data/shots/fuzz_corpus) replayed through the fuzz
// target's body, so that builds without libFuzzer (CI's gcc) run every seed too.
#include <gtest/gtest.h>

#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "tests/fuzz/shot_fuzz_input.h"
#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

std::string readText(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream text;
  text << in.rdbuf();
  return text.str();
}

TEST(ShotFuzzCorpusTest, EverySeedKeepsTheParsersPromises) {
  const fs::path corpus = testing::testDataDir() / "shots" / "fuzz_corpus";
  int seeds = 0, parsed = 0;
  for (const auto& entry : fs::directory_iterator(corpus)) {
    const std::string name = entry.path().filename().string();
    const fuzz::ShotFuzzResult result = fuzz::parseShotInput(readText(entry.path()));
    EXPECT_EQ(result.broken, "") << name;
    // The valid shots must parse, or the fuzzer would never get past their geometry: a file
    // they name is missing from kShotFuzzFiles.
    if (name.ends_with(".shot.toml")) EXPECT_TRUE(result.parsed) << name;
    ++seeds;
    parsed += result.parsed;
  }
  EXPECT_GE(seeds, 60);
  EXPECT_GE(parsed, 6);
}

TEST(ShotFuzzCorpusTest, ARefusalMustNameFileLineAndColumn) {
  EXPECT_TRUE(fuzz::startsWithLocation("/a/b.toml:12:3: [camera]: bad", "/a/b.toml"));
  EXPECT_FALSE(fuzz::startsWithLocation("/a/b.toml:12: [camera]: bad", "/a/b.toml"));
  EXPECT_FALSE(fuzz::startsWithLocation("/a/b.toml:0:3: bad", "/a/b.toml"));
  EXPECT_FALSE(fuzz::startsWithLocation("/a/b.toml: bad", "/a/b.toml"));
  EXPECT_FALSE(fuzz::startsWithLocation("bad", "/a/b.toml"));
}

}  // namespace
}  // namespace pbgi
