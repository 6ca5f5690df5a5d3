// PutFile and GetFile on a real coordinator: an upload is taken only from the current attempt
// of the task that makes the file, whole and unchanged; nothing else reaches the job folder.

#include <gtest/gtest.h>

#include <fstream>

#include "services/farm/file_transfer.h"
#include "services/farm/job_rules.h"
#include "tests/support/coordinator_fixture.h"

namespace pbgi::farm {
namespace {

namespace fs = std::filesystem;
using pbgi::testing::CoordinatorTest;

class FileServiceTest : public CoordinatorTest {
 protected:
  std::string localFile(const std::string& name, const std::string& bytes) {
    const fs::path path = dir_ / name;
    std::ofstream(path, std::ios::binary) << bytes;
    return path.string();
  }
};

TEST_F(FileServiceTest, OnlyTheCurrentAttemptOfTheTaskThatMakesAFileMaySendIt) {
  start();
  v1::SubmitJobRequest request = shotRequest({});
  request.add_frames(1);
  const int64_t job = client_->submitJob(request)->job();
  v1::LeaseTaskRequest ask;
  ask.set_worker("remote");
  auto lease = client_->leaseTask(ask);
  ASSERT_TRUE(lease.ok() && lease->has_task()) << lease.status();
  ASSERT_EQ(lease->task_kind(), v1::TASK_KIND_TILE);
  const std::string tile = farmTilePath(jobWorkDir(options_.stateDir, job), 1, lease->tile());
  const std::string bytes(3 << 20, 'x');  // several chunks
  const std::string local = localFile("tile.exr", bytes);
  v1::PutFileChunk head;
  head.set_task(lease->task());
  head.set_attempt(lease->attempt());
  head.set_kind(v1::FILE_KIND_TILE);

  // Another tile's file, a frame, or an attempt that is not the lease's: refused, nothing made.
  v1::PutFileChunk other = head;
  other.set_tile(lease->tile() + 1);
  EXPECT_EQ(client_->putFile(other, local).code(), absl::StatusCode::kPermissionDenied);
  other = head;
  other.set_tile(lease->tile());
  other.set_kind(v1::FILE_KIND_FRAME);
  EXPECT_EQ(client_->putFile(other, local).code(), absl::StatusCode::kPermissionDenied);
  other = head;
  other.set_tile(lease->tile());
  other.set_attempt(lease->attempt() + 1);
  EXPECT_EQ(client_->putFile(other, local).code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_FALSE(fs::exists(tile));

  // The lease's own tile arrives whole, and comes back the same.
  head.set_tile(lease->tile());
  ASSERT_TRUE(client_->putFile(head, local).ok());
  std::ifstream in(tile, std::ios::binary);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), bytes);
  v1::GetFileRequest get;
  get.set_job(job);
  get.set_kind(v1::FILE_KIND_TILE);
  get.set_frame(1);
  get.set_tile(lease->tile());
  const std::string back = (dir_ / "back.exr").string();
  ASSERT_TRUE(client_->getFile(get, back).ok());
  std::ifstream again(back, std::ios::binary);
  EXPECT_EQ(std::string(std::istreambuf_iterator<char>(again), {}), bytes);
  // Trees are not files a worker fetches whole; unknown tiles and frames are named.
  get.set_kind(v1::FILE_KIND_TREE);
  EXPECT_EQ(client_->getFile(get, back).code(), absl::StatusCode::kInvalidArgument);
  get.set_kind(v1::FILE_KIND_TILE);
  get.set_tile(99);
  const absl::Status missing = client_->getFile(get, back);
  EXPECT_EQ(missing.code(), absl::StatusCode::kNotFound);
  EXPECT_NE(missing.message().find("tiles 0..3"), std::string::npos) << missing;
}

TEST(FileReceiverTest, ADamagedOrShortFileIsNeverRenamedIntoPlace) {
  const fs::path dir = pbgi::testing::makeTempDir("file-receiver");
  const std::string path = (dir / "out.bin").string();
  // The hash a sender announces, in the last of its chunks.
  auto hashOf = [&](const std::string& bytes) {
    std::ofstream((dir / "src").string(), std::ios::binary) << bytes;
    uint64_t last = 0;
    int chunks = 0;
    EXPECT_TRUE(sendFile((dir / "src").string(),
                         [&](uint64_t size, std::string_view data, std::optional<uint64_t> xxh3) {
                           EXPECT_EQ(size, bytes.size());
                           EXPECT_EQ(data, bytes);
                           EXPECT_TRUE(xxh3.has_value()) << "one chunk: the last, with the hash";
                           last = xxh3.value_or(0);
                           ++chunks;
                           return true;
                         })
                    .ok());
    EXPECT_EQ(chunks, 1);
    return last;
  };
  const uint64_t hello = hashOf("hello world");
  EXPECT_NE(hashOf("hello wurld"), hello);
  auto r = FileReceiver::begin(path, 11);
  ASSERT_TRUE(r.ok());
  ASSERT_TRUE(r->add("hello").ok());
  EXPECT_EQ(r->finish(hello).code(), absl::StatusCode::kDataLoss);  // cut short
  EXPECT_FALSE(fs::exists(path));
  r = FileReceiver::begin(path, 11);
  ASSERT_TRUE(r->add("hello wurld").ok());
  const absl::Status damaged = r->finish(hello);
  EXPECT_EQ(damaged.code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(damaged.message().find("damaged"), std::string::npos) << damaged;
  EXPECT_FALSE(fs::exists(path));
  r = FileReceiver::begin(path, 2);
  EXPECT_EQ(r->add("hello").code(), absl::StatusCode::kDataLoss);  // more than announced
  r = FileReceiver::begin(path, 11);
  ASSERT_TRUE(r->add("hello ").ok() && r->add("world").ok());
  ASSERT_TRUE(r->finish(hello).ok());
  EXPECT_TRUE(fs::exists(path));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace pbgi::farm
