#include "formats/util/atomic_file.h"

#include <gtest/gtest.h>

#include <fstream>
#include <iterator>

#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

std::string contents(const fs::path& p) {
  std::ifstream in(p, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

size_t entries(const fs::path& dir) {
  return static_cast<size_t>(std::distance(fs::directory_iterator(dir), fs::directory_iterator()));
}

TEST(AtomicFileTest, CommitReplacesTheFileOnlyAtTheEnd) {
  const fs::path dir = testing::makeTempDir("atomic");
  const fs::path target = dir / "sub" / "out.bin";
  auto file = AtomicFile::begin(target.string());
  ASSERT_TRUE(file.ok()) << file.status();
  EXPECT_TRUE(fs::is_directory(dir / "sub"));
  EXPECT_EQ(fs::path(file->tempPath()).parent_path(), target.parent_path());
  std::ofstream(file->tempPath()) << "new";
  EXPECT_FALSE(fs::exists(target));
  ASSERT_TRUE(file->commit().ok());
  EXPECT_EQ(contents(target), "new");
  EXPECT_EQ(entries(dir / "sub"), 1u);
  // A second commit has nothing to do.
  EXPECT_EQ(file->commit().code(), absl::StatusCode::kFailedPrecondition);
  fs::remove_all(dir);
}

TEST(AtomicFileTest, AbandonedTemporaryIsRemovedAndOldFileKept) {
  const fs::path dir = testing::makeTempDir("atomic");
  const fs::path target = dir / "out.bin";
  std::ofstream(target) << "old";
  {
    auto file = AtomicFile::begin(target.string());
    ASSERT_TRUE(file.ok());
    std::ofstream(file->tempPath()) << "partial";
    AtomicFile moved = std::move(*file);  // ownership moves; only one removal
    EXPECT_EQ(entries(dir), 2u);
  }
  EXPECT_EQ(contents(target), "old");
  EXPECT_EQ(entries(dir), 1u);
  fs::remove_all(dir);
}

TEST(AtomicFileTest, FailedRenameNamesBothPathsAndLeavesNoTemporary) {
  const fs::path dir = testing::makeTempDir("atomic");
  const fs::path target = dir / "taken";
  fs::create_directories(target / "child");  // a non-empty folder cannot be renamed over
  auto file = AtomicFile::begin(target.string());
  ASSERT_TRUE(file.ok());
  std::ofstream(file->tempPath()) << "x";
  const absl::Status s = file->commit();
  EXPECT_FALSE(s.ok());
  EXPECT_NE(s.message().find("cannot rename"), absl::string_view::npos) << s;
  EXPECT_NE(s.message().find(target.string()), absl::string_view::npos) << s;
  EXPECT_EQ(entries(dir), 1u);
  fs::remove_all(dir);
}

TEST(AtomicFileTest, FolderThatCannotBeMadeIsAnError) {
  const fs::path dir = testing::makeTempDir("atomic");
  std::ofstream(dir / "file") << "x";
  auto file = AtomicFile::begin((dir / "file" / "out.bin").string());
  EXPECT_FALSE(file.ok());
  EXPECT_NE(file.status().message().find("cannot create folder"), absl::string_view::npos);
  EXPECT_FALSE(AtomicFile::begin("").ok());
  fs::remove_all(dir);
}

}  // namespace
}  // namespace pbgi
