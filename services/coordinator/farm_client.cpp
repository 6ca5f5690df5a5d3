#include "services/coordinator/farm_client.h"

#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>

#include <unistd.h>

#include <fmt/format.h>
#include <grpcpp/grpcpp.h>

#include "pbgi/farm/v1/farm.grpc.pb.h"
#include "services/util/daemon.h"

namespace pbgi::farm {

namespace {

// gRPC's codes are absl's, number for number.
absl::Status fromGrpc(const grpc::Status& s, const std::string& address, const char* call) {
  if (s.ok()) return absl::OkStatus();
  std::string message = s.error_message();
  if (s.error_code() == grpc::StatusCode::UNAVAILABLE ||
      s.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED) {
    message = fmt::format("coordinator {} did not answer {}: {}", address, call, message);
  }
  return absl::Status(static_cast<absl::StatusCode>(s.error_code()), message);
}

}  // namespace

absl::StatusOr<std::string> loadClientToken(const std::string& tokenFile) {
  if (!tokenFile.empty()) return readTokenFile(tokenFile);
  if (const char* env = std::getenv("PBGI_TOKEN"); env != nullptr && *env != '\0') return std::string(env);
  return absl::NotFoundError(
      "no farm token: pass --token-file FILE (the coordinator writes <state>/token) or set "
      "PBGI_TOKEN");
}

bool isTransient(const absl::Status& status) {
  return status.code() == absl::StatusCode::kUnavailable ||
         status.code() == absl::StatusCode::kDeadlineExceeded;
}

struct FarmClient::Impl {
  std::string token;
  double deadlineSeconds;
  std::unique_ptr<v1::Coordinator::Stub> stub;

  void prepare(grpc::ClientContext& context) const {
    context.AddMetadata("authorization", "Bearer " + token);
    context.set_deadline(std::chrono::system_clock::now() +
                         std::chrono::milliseconds(static_cast<int64_t>(deadlineSeconds * 1000)));
  }
};

FarmClient::FarmClient(const std::string& address, std::string token, double deadlineSeconds)
    : address_(address), impl_(std::make_unique<Impl>()) {
  impl_->token = std::move(token);
  impl_->deadlineSeconds = deadlineSeconds;
  grpc::ChannelArguments args;
  // Tree streams are chunked well below this; status of a large job is not.
  args.SetMaxReceiveMessageSize(64 << 20);
  // A coordinator restarting on its port is found again within a second or two.
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 200);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 2000);
  impl_->stub = v1::Coordinator::NewStub(
      grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), args));
}

FarmClient::~FarmClient() = default;

#define PBGI_FARM_CALL(method, Rpc)                                                    \
  absl::StatusOr<v1::Rpc##Response> FarmClient::method(const v1::Rpc##Request& request) { \
    grpc::ClientContext context;                                                       \
    impl_->prepare(context);                                                           \
    v1::Rpc##Response response;                                                        \
    const grpc::Status s = impl_->stub->Rpc(&context, request, &response);             \
    if (!s.ok()) return fromGrpc(s, address_, #Rpc);                                   \
    return response;                                                                   \
  }

PBGI_FARM_CALL(submitJob, SubmitJob)
PBGI_FARM_CALL(getStatus, GetStatus)
PBGI_FARM_CALL(cancelJob, CancelJob)
PBGI_FARM_CALL(retryJob, RetryJob)
PBGI_FARM_CALL(getLogs, GetLogs)
PBGI_FARM_CALL(registerWorker, RegisterWorker)
PBGI_FARM_CALL(listWorkers, ListWorkers)
PBGI_FARM_CALL(leaseTask, LeaseTask)
PBGI_FARM_CALL(heartbeat, Heartbeat)
PBGI_FARM_CALL(completeTask, CompleteTask)
PBGI_FARM_CALL(failTask, FailTask)

#undef PBGI_FARM_CALL

absl::StatusOr<uint64_t> FarmClient::fetchTree(int64_t job, int frame, const std::string& outPath) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(fs::path(outPath).parent_path(), ec);
  const std::string temp = fmt::format("{}.part{}", outPath, static_cast<long>(::getpid()));
  std::FILE* out = std::fopen(temp.c_str(), "wb");
  if (out == nullptr) {
    return absl::PermissionDeniedError(
        fmt::format("{}: cannot write the streamed tree", temp));
  }
  grpc::ClientContext context;
  impl_->prepare(context);
  // A tree takes longer than one call: the deadline covers the whole stream, at 10 MB/s.
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(30));
  v1::FetchPagesRequest request;
  request.set_job(job);
  request.set_frame(frame);
  auto reader = impl_->stub->FetchPages(&context, request);
  v1::PageChunk chunk;
  uint64_t received = 0;
  absl::Status failed;
  while (reader->Read(&chunk)) {
    if (chunk.offset() != received) {
      failed = absl::DataLossError(fmt::format(
          "tree of job {} frame {} from {}: chunk at byte {} where {} was expected", job, frame,
          address_, chunk.offset(), received));
      context.TryCancel();
      break;
    }
    if (std::fwrite(chunk.data().data(), 1, chunk.data().size(), out) != chunk.data().size()) {
      failed = absl::ResourceExhaustedError(fmt::format("{}: write failed (disk full?)", temp));
      context.TryCancel();
      break;
    }
    received += chunk.data().size();
  }
  const grpc::Status finished = reader->Finish();
  const bool closed = std::fclose(out) == 0;
  if (failed.ok() && !finished.ok()) failed = fromGrpc(finished, address_, "FetchPages");
  if (failed.ok() && !closed) failed = absl::ResourceExhaustedError(fmt::format("{}: write failed", temp));
  if (!failed.ok()) {
    fs::remove(temp, ec);
    return failed;
  }
  fs::rename(temp, outPath, ec);
  if (ec) {
    fs::remove(temp, ec);
    return absl::InternalError(fmt::format("{}: cannot rename into place: {}", outPath, ec.message()));
  }
  return received;
}

}  // namespace pbgi::farm
