#include "services/farm/farm_client.h"

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <mutex>
#include <optional>
#include <thread>

#include <unistd.h>

#include <fmt/format.h>
#include <grpcpp/grpcpp.h>

#include "core/util/log.h"
#include "core/util/status.h"
#include "pbgi/farm/v1/farm.grpc.pb.h"
#include "services/farm/file_transfer.h"
#include "services/util/daemon.h"

namespace pbgi::farm {

namespace {

// gRPC's codes are absl's, number for number.
absl::Status fromGrpc(const grpc::Status& s, const std::string& address, const char* call) {
  if (s.ok()) return absl::OkStatus();
  std::string message = s.error_message();
  // An HTTP/1 server at the address (the coordinator's dashboard port, say) answers every
  // connection the same way: not a coordinator that will come back, so not worth waiting for.
  if (message.find("http1.x server") != std::string::npos) {
    return absl::FailedPreconditionError(fmt::format(
        "{} is an HTTP/1 server, not a coordinator's gRPC port (the dashboard's --http "
        "address?): give --coordinator the coordinator's --listen address (its state folder's "
        "coordinator.addr)",
        address));
  }
  if (s.error_code() == grpc::StatusCode::UNAVAILABLE ||
      s.error_code() == grpc::StatusCode::DEADLINE_EXCEEDED) {
    message = fmt::format("coordinator {} did not answer {}: {}", address, call, message);
  }
  return absl::Status(static_cast<absl::StatusCode>(s.error_code()), message);
}

// How gRPC 1.51 words a connection that TLS refused: a failed handshake on this side, or the
// other side hanging up (a TLS coordinator and a plaintext client, a client certificate
// refused, or a coordinator going away).
bool mayBeTls(const grpc::Status& s) {
  if (s.error_code() != grpc::StatusCode::UNAVAILABLE) return false;
  const std::string& m = s.error_message();
  return m.find("andshake") != std::string::npos || m.find("Socket closed") != std::string::npos ||
         m.find("Connection reset") != std::string::npos;
}

// A file transfer's deadline is its silence, not its length: a tree of several GB over a slow
// link takes as long as it takes, but a stream that moves no chunk for `idleSeconds` (a link
// gone, a peer that stopped reading or writing) is cancelled. An upload's last chunk leaves
// the peer that long to drain what the transport still holds (a flow-control window) and
// answer.
class StallWatch {
 public:
  StallWatch(grpc::ClientContext& context, double idleSeconds)
      : context_(context),
        idle_(std::chrono::duration_cast<Clock::duration>(
            std::chrono::duration<double>(idleSeconds))),
        last_(Clock::now().time_since_epoch().count()),
        thread_([this] { watch(); }) {}
  ~StallWatch() {
    {
      std::lock_guard lock(mutex_);
      done_ = true;
    }
    wake_.notify_all();
    thread_.join();
  }
  StallWatch(const StallWatch&) = delete;
  StallWatch& operator=(const StallWatch&) = delete;

  // A chunk went or came.
  void moved(uint64_t bytes) {
    bytes_ += bytes;
    last_.store(Clock::now().time_since_epoch().count());
  }
  // Whether the watch cancelled the call; then why, for `call` of `size` bytes.
  bool stalled() const { return stalled_.load(); }
  absl::Status why(const std::string& address, const char* call, uint64_t size) const {
    return absl::DeadlineExceededError(fmt::format(
        "coordinator {} did not answer {}: nothing moved for {:g} s ({} of {} bytes moved)",
        address, call, std::chrono::duration<double>(idle_).count(), bytes_.load(), size));
  }

 private:
  using Clock = std::chrono::steady_clock;
  void watch() {
    std::unique_lock lock(mutex_);
    while (!done_) {
      const Clock::time_point due = Clock::time_point(Clock::duration(last_.load())) + idle_;
      if (Clock::now() >= due) {
        stalled_.store(true);
        context_.TryCancel();
        return;
      }
      wake_.wait_until(lock, due);
    }
  }

  grpc::ClientContext& context_;
  const Clock::duration idle_;
  std::atomic<Clock::rep> last_;
  std::atomic<uint64_t> bytes_{0};
  std::atomic<bool> stalled_{false};
  std::mutex mutex_;
  std::condition_variable wake_;
  bool done_ = false;
  std::thread thread_;  // last: it reads the members above
};

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
  std::string address;
  std::string token;
  double deadlineSeconds;
  std::optional<TlsPem> tls;
  std::unique_ptr<v1::Coordinator::Stub> stub;

  // A refusal by TLS says why (farm_tls.h diagnoses it with a handshake of its own); anything
  // else as fromGrpc.
  absl::Status failed(const grpc::Status& s, const char* call) const {
    if (mayBeTls(s)) {
      if (std::optional<std::string> why = diagnoseTls(address, tls)) {
        return absl::UnauthenticatedError(
            fmt::format("coordinator {}: {} failed at TLS: {} (gRPC: {})", address, call, *why,
                        s.error_message()));
      }
    }
    return fromGrpc(s, address, call);
  }

  void prepare(grpc::ClientContext& context) const {
    prepareStream(context);
    context.set_deadline(std::chrono::system_clock::now() +
                         std::chrono::milliseconds(static_cast<int64_t>(deadlineSeconds * 1000)));
  }
  // A file transfer: no deadline on the whole call (a StallWatch instead).
  void prepareStream(grpc::ClientContext& context) const {
    context.AddMetadata("authorization", "Bearer " + token);
  }
};

FarmClient::FarmClient(const std::string& address, std::string token, double deadlineSeconds,
                       std::optional<TlsPem> tls)
    : address_(address), impl_(std::make_unique<Impl>()) {
  impl_->address = address;
  impl_->token = std::move(token);
  impl_->deadlineSeconds = deadlineSeconds;
  impl_->tls = std::move(tls);
  grpc::ChannelArguments args;
  // A tree's head holds its codebooks (sections of at most 256 MiB); a page is at most
  // 16 MiB; status of a large job is large too.
  args.SetMaxReceiveMessageSize(320 << 20);
  // A coordinator restarting on its port is found again within a second or two.
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 200);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 2000);
  impl_->stub = v1::Coordinator::NewStub(
      grpc::CreateCustomChannel(address, channelCredentials(impl_->tls), args));
}

FarmClient::~FarmClient() = default;

#define PBGI_FARM_CALL(method, Rpc)                                                       \
  absl::StatusOr<v1::Rpc##Response> FarmClient::method(const v1::Rpc##Request& request) { \
    grpc::ClientContext context;                                                          \
    impl_->prepare(context);                                                              \
    v1::Rpc##Response response;                                                           \
    const grpc::Status s = impl_->stub->Rpc(&context, request, &response);                \
    if (!s.ok()) return impl_->failed(s, #Rpc);                                           \
    return response;                                                                      \
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

absl::StatusOr<PageFileHead> FarmClient::openTree(int64_t job, int frame) {
  grpc::ClientContext context;
  impl_->prepare(context);
  v1::OpenTreeRequest request;
  request.set_job(job);
  request.set_frame(frame);
  v1::OpenTreeResponse response;
  const grpc::Status s = impl_->stub->OpenTree(&context, request, &response);
  if (!s.ok()) return impl_->failed(s, "OpenTree");
  PageFileHead head;
  head.header.assign(response.header().begin(), response.header().end());
  head.tailOffset = response.tail_offset();
  head.tail.assign(response.tail().begin(), response.tail().end());
  head.fileSize = response.file_size();
  return head;
}

absl::Status FarmClient::putFile(const v1::PutFileChunk& head, const std::string& path) {
  grpc::ClientContext context;
  impl_->prepareStream(context);
  v1::PutFileResponse response;
  uint64_t total = 0;
  absl::Status sent, stalled;
  grpc::Status finished;
  {
    StallWatch watch(context, impl_->deadlineSeconds);
    auto writer = impl_->stub->PutFile(&context, &response);
    sent = sendChunks(path, head, [&](const v1::PutFileChunk& chunk) {
      if (chunk.size() > 0) total = chunk.size();  // the first chunk's
      const bool written = writer->Write(chunk);
      if (written) watch.moved(chunk.data().size());
      return written;
    });
    writer->WritesDone();
    finished = writer->Finish();
    if (watch.stalled()) stalled = watch.why(address_, "PutFile", total);
  }
  if (!stalled.ok()) return stalled;
  // The coordinator's reason beats "it stopped reading".
  if (!finished.ok()) return impl_->failed(finished, "PutFile");
  return sent;
}

absl::Status FarmClient::getFile(const v1::GetFileRequest& request, const std::string& path) {
  grpc::ClientContext context;
  impl_->prepareStream(context);
  absl::Status received, stalled;
  bool arrived = false, ended = false;
  uint64_t total = 0;
  grpc::Status finished;
  {
    StallWatch watch(context, impl_->deadlineSeconds);
    auto reader = impl_->stub->GetFile(&context, request);
    const auto next = [&](v1::FileChunk* chunk) {
      ended = !reader->Read(chunk);
      if (!ended) watch.moved(chunk->data().size());
      return !ended;
    };
    v1::FileChunk chunk;
    arrived = next(&chunk);
    if (arrived) {
      total = chunk.size();
      received = receiveChunks(path, chunk, next);
    }
    // This side failed while the stream was open (a full disk): its reason, and no more.
    if (!ended) {
      context.TryCancel();
      (void)reader->Finish();
      return received;
    }
    finished = reader->Finish();
    if (watch.stalled()) stalled = watch.why(address_, "GetFile", total);
  }
  if (!stalled.ok()) return stalled;
  // A stream cut short says why (a coordinator away, to try again), not that the file is short.
  if (!finished.ok()) return impl_->failed(finished, "GetFile");
  if (!arrived) return absl::DataLossError(fmt::format("{}: nothing arrived", path));
  return received;
}

absl::StatusOr<std::vector<std::vector<uint8_t>>> FarmClient::fetchPages(
    int64_t job, int frame, uint64_t treeId, std::span<const uint32_t> pages) {
  grpc::ClientContext context;
  impl_->prepare(context);
  v1::FetchPagesRequest request;
  request.set_job(job);
  request.set_frame(frame);
  request.set_tree_id(treeId);
  for (const uint32_t id : pages) request.add_pages(id);
  auto reader = impl_->stub->FetchPages(&context, request);
  std::vector<std::vector<uint8_t>> out;
  v1::PageChunk chunk;
  absl::Status failed;
  while (reader->Read(&chunk)) {
    if (out.size() >= pages.size() || chunk.page() != pages[out.size()]) {
      failed = absl::DataLossError(fmt::format(
          "tree of job {} frame {} from {}: page {} arrived where page {} was expected", job,
          frame, address_, chunk.page(),
          out.size() < pages.size() ? fmt::format("{}", pages[out.size()]) : "none"));
      context.TryCancel();
      break;
    }
    out.emplace_back(chunk.data().begin(), chunk.data().end());
  }
  const grpc::Status finished = reader->Finish();
  if (failed.ok() && !finished.ok()) failed = impl_->failed(finished, "FetchPages");
  if (failed.ok() && out.size() != pages.size()) {
    failed = absl::DataLossError(fmt::format("tree of job {} frame {} from {}: {} of {} pages arrived",
                                             job, frame, address_, out.size(), pages.size()));
  }
  if (!failed.ok()) return failed;
  return out;
}

void logRetry(const char* what, const absl::Status& status, double waitSeconds) {
  log::warn("{}: {}; trying again in {:.1f} s", what, status.message(), waitSeconds);
}

namespace {
constexpr double kPagePatienceSeconds = 60.0;
}  // namespace

FarmPageFetcher::FarmPageFetcher(FarmClient& client, int64_t job, int frame)
    : client_(client),
      job_(job),
      frame_(frame),
      name_(fmt::format("tree of job {} frame {} from {}", job, frame, client.address())) {}

absl::StatusOr<PageFileHead> FarmPageFetcher::head() {
  auto head = callPatiently([&] { return client_.openTree(job_, frame_); }, kPagePatienceSeconds,
                            "OpenTree");
  if (!head.ok()) return withContext(head.status(), name_);
  return head;
}

absl::StatusOr<std::vector<uint8_t>> FarmPageFetcher::page(uint64_t treeId, uint32_t id) {
  const uint32_t ids[1] = {id};
  auto pages = callPatiently([&] { return client_.fetchPages(job_, frame_, treeId, ids); },
                             kPagePatienceSeconds, "FetchPages");
  if (!pages.ok()) return withContext(pages.status(), fmt::format("{}: page {}", name_, id));
  return std::move(pages->front());
}

}  // namespace pbgi::farm
