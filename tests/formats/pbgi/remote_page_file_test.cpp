#include "formats/pbgi/remote_page_file.h"

#include <sched.h>
#include <sys/mount.h>
#include <sys/wait.h>
#include <unistd.h>

#include <atomic>
#include <filesystem>
#include <cstring>
#include <fstream>
#include <iterator>
#include <thread>
#include <vector>

#include <fmt/format.h>
#include <gtest/gtest.h>

#include "tests/support/test_paths.h"

namespace pbgi {
namespace {

namespace fs = std::filesystem;

// Incompressible pages of a few sizes, so that stored sizes differ.
std::vector<uint8_t> pageBytes(int i) {
  std::vector<uint8_t> out(2000 + 700 * (i % 5));
  uint32_t x = 7u + static_cast<uint32_t>(i);
  for (uint8_t& b : out) {
    x = (x * 1103515245u + 12345u) & 0x7fffffffu;
    b = static_cast<uint8_t>(x >> 16);
  }
  return out;
}

// What a page service serves: a local file's head and stored pages. `damage` flips a byte of
// the first `damaged` answers for each page (the network's fault, or the source's).
class FileFetcher : public PageFetcher {
 public:
  explicit FileFetcher(const std::string& path) : name_("file " + path) {
    reader_ = *PageFileReader::open(path);
  }
  const std::string& name() const override { return name_; }
  absl::StatusOr<PageFileHead> head() override { return reader_->head(); }
  absl::StatusOr<std::vector<uint8_t>> page(uint64_t treeId, uint32_t id) override {
    if (treeId != reader_->head().treeId()) return absl::FailedPreconditionError("another tree");
    auto bytes = reader_->readStoredPage(id);
    if (bytes.ok() && served_[id]++ < damaged) (*bytes)[bytes->size() / 2] ^= 0x40;
    return bytes;
  }
  int damaged = 0;

 private:
  std::string name_;
  std::unique_ptr<PageFileReader> reader_;
  std::map<uint32_t, int> served_;
};

class RemotePageFileTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = testing::makeTempDir("remote-page-file");
    path_ = (dir_ / "tree.pbgi").string();
    auto writer = PageFileWriter::create(path_, {.pageSize = 4096 * 2});
    ASSERT_TRUE(writer.ok()) << writer.status();
    for (int i = 0; i < kPages; ++i) ASSERT_TRUE(writer->appendPage(pageBytes(i)).ok());
    PageFileMetadata m;
    m.sections.push_back({"tree", {1, 2, 3}});
    ASSERT_TRUE(writer->finish(m).ok());
    fetcher_ = std::make_shared<FileFetcher>(path_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  std::unique_ptr<PageFileReader> remote(std::shared_ptr<PageDiskCache> disk,
                                         std::shared_ptr<RemoteFetchStats> stats) {
    auto head = fetcher_->head();
    EXPECT_TRUE(head.ok()) << head.status();
    auto reader = PageFileReader::open(openRemotePageFile(*head, fetcher_, disk, stats));
    EXPECT_TRUE(reader.ok()) << reader.status();
    return reader.ok() ? *std::move(reader) : nullptr;
  }

  static constexpr int kPages = 12;
  fs::path dir_;
  std::string path_;
  std::shared_ptr<FileFetcher> fetcher_;
};

TEST_F(RemotePageFileTest, ReadsWhatTheFileHoldsAndFetchesEachPageOnceAcrossReaders) {
  auto disk = PageDiskCache::open((dir_ / "cache").string(), 1 << 20);
  ASSERT_TRUE(disk.ok()) << disk.status();
  auto stats = std::make_shared<RemoteFetchStats>();
  auto local = PageFileReader::open(path_);
  ASSERT_TRUE(local.ok());
  auto first = remote(*disk, stats);
  ASSERT_NE(first, nullptr);
  EXPECT_EQ(first->info().pageCount, static_cast<uint32_t>(kPages));
  EXPECT_EQ(first->info().sections, (*local)->info().sections);
  uint64_t stored = 0;
  for (uint32_t id = 0; id < kPages; id += 2) {  // half the pages: only those are fetched
    auto page = first->readPage(id);
    ASSERT_TRUE(page.ok()) << page.status();
    EXPECT_EQ(*page, pageBytes(static_cast<int>(id)));
    stored += (*local)->directory()[id].compressedSize;
  }
  EXPECT_EQ(stats->pagesFetched.load(), kPages / 2u);
  EXPECT_EQ(stats->bytesFetched.load(), stored);
  EXPECT_EQ(stats->headBytes.load(), (*local)->head().bytes());
  // A later reader of the same tree (another task) finds them on disk.
  auto second = remote(*disk, stats);
  for (uint32_t id = 0; id < kPages; ++id) {
    auto page = second->readPage(id);
    ASSERT_TRUE(page.ok()) << page.status();
    EXPECT_EQ(*page, pageBytes(static_cast<int>(id)));
  }
  EXPECT_EQ(stats->diskHits.load(), kPages / 2u);
  EXPECT_EQ(stats->pagesFetched.load(), static_cast<uint64_t>(kPages));
  // Bytes that are pages are not served from the head.
  std::vector<uint8_t> out(16);
  EXPECT_FALSE(second->store().read(kPageFileHeaderSize, out).ok());
}

TEST_F(RemotePageFileTest, APageDamagedOnTheWayIsFetchedOnceMoreThenNamed) {
  auto stats = std::make_shared<RemoteFetchStats>();
  fetcher_->damaged = 1;
  auto reader = remote(nullptr, stats);
  auto page = reader->readPage(3);
  ASSERT_TRUE(page.ok()) << page.status();
  EXPECT_EQ(*page, pageBytes(3));
  EXPECT_EQ(stats->damaged.load(), 1u);
  EXPECT_EQ(stats->pagesFetched.load(), 2u);

  fetcher_->damaged = 100;
  auto bad = reader->readPage(4);
  ASSERT_FALSE(bad.ok());
  EXPECT_TRUE(absl::IsDataLoss(bad.status())) << bad.status();
  EXPECT_NE(bad.status().message().find("page 4"), std::string::npos) << bad.status();
  EXPECT_NE(bad.status().message().find("arrived damaged twice"), std::string::npos)
      << bad.status();
  EXPECT_NE(bad.status().message().find(path_), std::string::npos) << bad.status();
}

TEST_F(RemotePageFileTest, TheDiskCacheVerifiesOnReadAndCleansUpAfterAKilledProcess) {
  const fs::path cacheDir = dir_ / "cache";
  auto local = PageFileReader::open(path_);
  ASSERT_TRUE(local.ok());
  const uint64_t tree = (*local)->head().treeId();
  {
    auto disk = PageDiskCache::open(cacheDir.string(), 1 << 20);
    ASSERT_TRUE(disk.ok()) << disk.status();
    // One process per folder.
    auto other = PageDiskCache::open(cacheDir.string(), 1 << 20);
    EXPECT_TRUE(absl::IsFailedPrecondition(other.status())) << other.status();
    for (uint32_t id = 0; id < 4; ++id) {
      ASSERT_TRUE((*disk)->put(tree, id, *(*local)->readStoredPage(id)).ok());
    }
  }
  // A killed process's half-written page, and a page damaged on disk.
  std::ofstream(cacheDir / fmt::format("{:016x}.{:08x}.page.tmp3", tree, 5)) << "half";
  std::vector<fs::path> pages;
  for (const auto& e : fs::directory_iterator(cacheDir)) {
    if (e.path().extension() == ".page") pages.push_back(e.path());
  }
  ASSERT_EQ(pages.size(), 4u);
  std::sort(pages.begin(), pages.end());
  {
    std::fstream f(pages[1], std::ios::in | std::ios::out | std::ios::binary);
    f.seekp(10);
    f.put('\x5a');
  }
  auto disk = PageDiskCache::open(cacheDir.string(), 1 << 20);
  ASSERT_TRUE(disk.ok()) << disk.status();
  EXPECT_EQ((*disk)->stats().pages, 4u);
  EXPECT_FALSE(fs::exists(cacheDir / fmt::format("{:016x}.{:08x}.page.tmp3", tree, 5)));
  int held = 0;
  for (uint32_t id = 0; id < 4; ++id) {
    held += (*disk)->get(tree, id, (*local)->directory()[id]).has_value();
  }
  EXPECT_EQ(held, 3);
  EXPECT_EQ((*disk)->stats().damaged, 1u);
  EXPECT_FALSE(fs::exists(pages[1]));
  EXPECT_EQ((*disk)->stats().pages, 3u);
}

TEST_F(RemotePageFileTest, TheDiskCacheKeepsItsBudgetUnderConcurrentReaders) {
  auto local = PageFileReader::open(path_);
  ASSERT_TRUE(local.ok());
  uint64_t largest = 0;
  for (const PageEntry& e : (*local)->directory()) largest = std::max<uint64_t>(largest, e.compressedSize);
  const uint64_t budget = 3 * largest + largest / 2;
  const fs::path cacheDir = dir_ / "cache";
  auto disk = PageDiskCache::open(cacheDir.string(), budget);
  ASSERT_TRUE(disk.ok()) << disk.status();
  std::atomic<int> wrong{0};
  std::atomic<uint64_t> over{0};
  std::vector<std::thread> threads;
  for (int t = 0; t < 4; ++t) {
    threads.emplace_back([&, t] {
      auto reader = remote(*disk, nullptr);
      for (int k = 0; k < 60; ++k) {
        const auto id = static_cast<uint32_t>((k * 7 + t * 3) % kPages);
        auto page = reader->readPage(id);
        if (!page.ok() || *page != pageBytes(static_cast<int>(id))) ++wrong;
        const uint64_t held = (*disk)->stats().bytes;
        if (held > budget) over = held;
      }
    });
  }
  for (std::thread& t : threads) t.join();
  EXPECT_EQ(wrong.load(), 0);
  EXPECT_EQ(over.load(), 0u);
  uint64_t onDisk = 0;
  for (const auto& e : fs::directory_iterator(cacheDir)) {
    if (e.path().extension() == ".page") onDisk += e.file_size();
  }
  EXPECT_LE(onDisk, budget);
  EXPECT_GT((*disk)->stats().evicted, 0u);
}

// A real full disk: a 64 KiB tmpfs in a mount namespace of a child process (root, as CI runs).
TEST_F(RemotePageFileTest, AFullDiskIsANamedError) {
  const fs::path mountPoint = dir_ / "small-disk";
  fs::create_directories(mountPoint);
  int pipeFds[2];
  ASSERT_EQ(::pipe(pipeFds), 0);
  const pid_t child = ::fork();
  ASSERT_GE(child, 0);
  if (child == 0) {
    ::close(pipeFds[0]);
    auto say = [&](const std::string& text, int code) {
      (void)!::write(pipeFds[1], text.data(), text.size());
      ::_exit(code);
    };
    if (::unshare(CLONE_NEWNS) != 0 ||
        ::mount(nullptr, "/", nullptr, MS_REC | MS_PRIVATE, nullptr) != 0 ||
        ::mount("tmpfs", mountPoint.c_str(), "tmpfs", 0, "size=64k") != 0) {
      say(fmt::format("cannot mount a small tmpfs here: {}", std::strerror(errno)), 3);
    }
    auto disk = PageDiskCache::open((mountPoint / "cache").string(), 1 << 20);
    if (!disk.ok()) say(std::string(disk.status().message()), 1);
    const std::vector<uint8_t> page(6000, 7);
    for (uint32_t id = 0; id < 100; ++id) {
      absl::Status s = (*disk)->put(42, id, page);
      if (!s.ok()) {
        say(fmt::format("{}|{}", absl::IsResourceExhausted(s) ? "full" : "other", std::string(s.message())),
            0);
      }
    }
    say("100 pages fitted", 1);
  }
  ::close(pipeFds[1]);
  std::string said;
  char buffer[512];
  for (ssize_t n; (n = ::read(pipeFds[0], buffer, sizeof buffer)) > 0;) said.append(buffer, n);
  ::close(pipeFds[0]);
  int status = 0;
  ASSERT_EQ(::waitpid(child, &status, 0), child);
  ASSERT_TRUE(WIFEXITED(status));
  if (WEXITSTATUS(status) == 3) GTEST_SKIP() << said;
  ASSERT_EQ(WEXITSTATUS(status), 0) << said;
  EXPECT_TRUE(said.starts_with("full|")) << said;
  EXPECT_NE(said.find("the disk is full"), std::string::npos) << said;
  EXPECT_NE(said.find("page disk cache"), std::string::npos) << said;
  EXPECT_NE(said.find("000000000000002a"), std::string::npos) << said;
}

}  // namespace
}  // namespace pbgi
