// FarmClient's file transfers against a real gRPC server on loopback whose PutFile and GetFile
// move their chunks slowly or not at all: a transfer longer than the client's deadline goes
// through as long as chunks keep moving, and one where nothing moves for the deadline is
// cancelled, saying how far it got. (file_service_test.cpp covers what the coordinator does
// with the files.)

#include <gtest/gtest.h>

#include <fmt/format.h>
#include <grpcpp/grpcpp.h>
#include <httplib.h>

#include <atomic>
#include <chrono>
#include <fstream>
#include <string>
#include <thread>

#include "pbgi/farm/v1/farm.grpc.pb.h"
#include "services/farm/farm_client.h"
#include "services/farm/file_transfer.h"
#include "tests/support/test_paths.h"

namespace pbgi::farm {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

// PutFile and GetFile only, pausing `chunkPause` per chunk, or (`stallAfterFirst`) after the
// first chunk until the test is over.
class SlowFiles final : public v1::Coordinator::Service {
 public:
  SlowFiles(std::chrono::milliseconds chunkPause, bool stallAfterFirst, fs::path served)
      : pause_(chunkPause), stall_(stallAfterFirst), served_(std::move(served)) {}
  ~SlowFiles() override { over_.store(true); }

  grpc::Status PutFile(grpc::ServerContext* context, grpc::ServerReader<v1::PutFileChunk>* reader,
                       v1::PutFileResponse*) override {
    v1::PutFileChunk chunk;
    while (reader->Read(&chunk)) {
      received_ += chunk.data().size();
      if (!wait(context)) return grpc::Status::CANCELLED;
    }
    return grpc::Status::OK;
  }

  grpc::Status GetFile(grpc::ServerContext* context, const v1::GetFileRequest*,
                       grpc::ServerWriter<v1::FileChunk>* writer) override {
    const absl::Status sent =
        sendChunks(served_.string(), v1::FileChunk(), [&](const v1::FileChunk& chunk) {
          return writer->Write(chunk) && wait(context);
        });
    return sent.ok() ? grpc::Status::OK : grpc::Status(grpc::StatusCode::ABORTED, "stopped");
  }

  uint64_t received() const { return received_.load(); }

 private:
  // After a chunk: the pause, or the stall (until the client gives up or the test ends).
  bool wait(grpc::ServerContext* context) {
    if (!stall_) {
      std::this_thread::sleep_for(pause_);
      return true;
    }
    while (!context->IsCancelled() && !over_.load()) {
      std::this_thread::sleep_for(std::chrono::milliseconds(10));
    }
    return false;
  }

  const std::chrono::milliseconds pause_;
  const bool stall_;
  const fs::path served_;
  std::atomic<uint64_t> received_{0};
  std::atomic<bool> over_{false};
};

class FarmClientFiles : public ::testing::Test {
 protected:
  void SetUp() override { dir_ = pbgi::testing::makeTempDir("farm-client"); }
  void TearDown() override {
    if (server_) server_->Shutdown(std::chrono::system_clock::now());
    server_.reset();
    service_.reset();
    fs::remove_all(dir_);
  }
  // Serves `served` slowly; the client's deadline is 1.5 s (well above a chunk's pause: this
  // machine may be loaded).
  FarmClient& serve(std::chrono::milliseconds chunkPause, bool stallAfterFirst,
                    const fs::path& served = {}) {
    service_ = std::make_unique<SlowFiles>(chunkPause, stallAfterFirst, served);
    grpc::ServerBuilder builder;
    int port = 0;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port);
    builder.RegisterService(service_.get());
    server_ = builder.BuildAndStart();
    client_ = std::make_unique<FarmClient>("127.0.0.1:" + std::to_string(port), "token", 1.5);
    return *client_;
  }
  // A file of `chunks` whole chunks (kFileChunkBytes each) of varied bytes.
  fs::path makeFile(const std::string& name, int chunks) {
    const fs::path path = dir_ / name;
    std::ofstream out(path, std::ios::binary);
    std::string chunk(kFileChunkBytes, '\0');
    for (int c = 0; c < chunks; ++c) {
      for (size_t i = 0; i < chunk.size(); ++i) chunk[i] = static_cast<char>((i * 31 + c) & 255);
      out.write(chunk.data(), static_cast<std::streamsize>(chunk.size()));
    }
    return path;
  }

  fs::path dir_;
  std::unique_ptr<SlowFiles> service_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<FarmClient> client_;
};

TEST_F(FarmClientFiles, AnUploadLongerThanTheDeadlineGoesThroughWhileChunksKeepMoving) {
  // 48 MiB read at 20 MiB/s: what the transport buffers past the client's last write (a few
  // MiB) drains well within the deadline, as on a real link; the whole takes 2.4 s.
  const fs::path file = makeFile("tree.pbgi", 48);
  FarmClient& client = serve(std::chrono::milliseconds(50), false);
  const auto t0 = Clock::now();
  const absl::Status sent = client.putFile(v1::PutFileChunk(), file.string());
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  ASSERT_TRUE(sent.ok()) << sent;
  EXPECT_GT(seconds, 2.0) << "the transfer took longer than the 1.5 s deadline";
  EXPECT_EQ(service_->received(), 48u * kFileChunkBytes);
}

TEST_F(FarmClientFiles, AStalledUploadIsCancelledSayingHowFarItGot) {
  // More than gRPC's flow-control windows hold, so that the client's writes block.
  const fs::path file = makeFile("tree.pbgi", 64);
  FarmClient& client = serve(std::chrono::milliseconds(0), true);
  const auto t0 = Clock::now();
  const absl::Status sent = client.putFile(v1::PutFileChunk(), file.string());
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  EXPECT_EQ(sent.code(), absl::StatusCode::kDeadlineExceeded) << sent;
  EXPECT_TRUE(isTransient(sent)) << "a worker tries such an upload again";
  EXPECT_NE(sent.message().find("PutFile: nothing moved for 1.5 s"), std::string::npos) << sent;
  EXPECT_NE(sent.message().find("of 67108864 bytes moved"), std::string::npos) << sent;
  EXPECT_LT(seconds, 10.0);
}

TEST_F(FarmClientFiles, ADownloadLongerThanTheDeadlineArrivesWholeWhileChunksKeepMoving) {
  const fs::path served = makeFile("frame.exr", 6);
  FarmClient& client = serve(std::chrono::milliseconds(400), false, served);
  const fs::path got = dir_ / "got" / "frame.exr";
  const auto t0 = Clock::now();
  const absl::Status received = client.getFile(v1::GetFileRequest(), got.string());
  const double seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  ASSERT_TRUE(received.ok()) << received;
  EXPECT_GT(seconds, 2.0);
  EXPECT_EQ(fs::file_size(got), 6u * kFileChunkBytes);
}

TEST_F(FarmClientFiles, AStalledDownloadIsCancelledAndLeavesNoFile) {
  const fs::path served = makeFile("frame.exr", 8);
  FarmClient& client = serve(std::chrono::milliseconds(0), true, served);
  const fs::path got = dir_ / "got" / "frame.exr";
  const absl::Status received = client.getFile(v1::GetFileRequest(), got.string());
  EXPECT_EQ(received.code(), absl::StatusCode::kDeadlineExceeded) << received;
  EXPECT_NE(received.message().find("GetFile: nothing moved"), std::string::npos) << received;
  EXPECT_FALSE(fs::exists(got));
}

// A client pointed at an HTTP/1 server (the dashboard's port) is told so at once, not left
// retrying: the error is not transient and names the address to use instead.
TEST(FarmClientAddress, AnHttpServerIsNotTakenForACoordinatorThatWillComeBack) {
  httplib::Server http;
  http.Get("/", [](const httplib::Request&, httplib::Response& res) {
    res.set_content("hi", "text/plain");
  });
  const int port = http.bind_to_any_port("127.0.0.1");
  ASSERT_GT(port, 0);
  std::thread serving([&] { http.listen_after_bind(); });
  FarmClient client(fmt::format("127.0.0.1:{}", port), "token", 10.0);
  const auto status = client.getStatus(v1::GetStatusRequest());
  http.stop();
  serving.join();
  EXPECT_EQ(status.status().code(), absl::StatusCode::kFailedPrecondition) << status.status();
  EXPECT_FALSE(isTransient(status.status()));
  EXPECT_NE(status.status().message().find("HTTP/1 server, not a coordinator's gRPC port"),
            std::string::npos)
      << status.status();
  EXPECT_NE(status.status().message().find("--listen"), std::string::npos) << status.status();
}

}  // namespace
}  // namespace pbgi::farm
