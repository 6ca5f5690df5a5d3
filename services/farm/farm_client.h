#pragma once
// A connection to a coordinator, for workers and for `pbgi submit/status/...`. Every call
// carries the farm's token and a deadline (for a file transfer, a limit on how long nothing
// moves rather than on the whole transfer), and comes back as a Status whose message says
// which coordinator did not answer or what it refused. Over TLS when given a CA (farm_tls.h);
// a connection that TLS refuses (either way) comes back UNAUTHENTICATED saying why, not as a
// coordinator that is away. gRPC itself stays inside the .cpp.
#include <algorithm>
#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <thread>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include <span>
#include <vector>

#include "formats/pbgi/remote_page_file.h"
#include "pbgi/farm/v1/farm.pb.h"
#include "services/farm/farm_tls.h"

namespace pbgi::farm {

// The token a client sends: the file's first line when a file is named, else the PBGI_TOKEN
// environment variable; NotFound/InvalidArgument saying where it looked otherwise.
absl::StatusOr<std::string> loadClientToken(const std::string& tokenFile);

class FarmClient {
 public:
  // `tls`: from readClientTls; nullopt: plaintext.
  FarmClient(const std::string& address, std::string token, double deadlineSeconds = 30.0,
             std::optional<TlsPem> tls = std::nullopt);
  ~FarmClient();
  FarmClient(const FarmClient&) = delete;
  FarmClient& operator=(const FarmClient&) = delete;

  const std::string& address() const { return address_; }

  absl::StatusOr<v1::SubmitJobResponse> submitJob(const v1::SubmitJobRequest& request);
  absl::StatusOr<v1::GetStatusResponse> getStatus(const v1::GetStatusRequest& request);
  absl::StatusOr<v1::CancelJobResponse> cancelJob(const v1::CancelJobRequest& request);
  absl::StatusOr<v1::RetryJobResponse> retryJob(const v1::RetryJobRequest& request);
  absl::StatusOr<v1::GetLogsResponse> getLogs(const v1::GetLogsRequest& request);
  absl::StatusOr<v1::RegisterWorkerResponse> registerWorker(
      const v1::RegisterWorkerRequest& request);
  absl::StatusOr<v1::ListWorkersResponse> listWorkers(const v1::ListWorkersRequest& request);
  absl::StatusOr<v1::LeaseTaskResponse> leaseTask(const v1::LeaseTaskRequest& request);
  absl::StatusOr<v1::HeartbeatResponse> heartbeat(const v1::HeartbeatRequest& request);
  absl::StatusOr<v1::CompleteTaskResponse> completeTask(const v1::CompleteTaskRequest& request);
  absl::StatusOr<v1::FailTaskResponse> failTask(const v1::FailTaskRequest& request);

  // The coordinator's page service: the head of a frame's tree (header, directory, sections),
  // then the stored bytes of single pages of it, in the order asked. Pages are not checked
  // here (remote_page_file.h does that).
  absl::StatusOr<PageFileHead> openTree(int64_t job, int frame);
  absl::StatusOr<std::vector<std::vector<uint8_t>>> fetchPages(int64_t job, int frame,
                                                               uint64_t treeId,
                                                               std::span<const uint32_t> pages);

  // File transfer for a worker that does not see the job folder (farm.proto: PutFile,
  // GetFile): sends the file at `path` as what `head` says it is (task, attempt, kind, tile),
  // and receives a tile or frame into `path` (renamed into place once whole and checked).
  // However long a transfer takes, it fails (DeadlineExceeded, saying how far it got) only
  // when no chunk moved for the client's deadline.
  absl::Status putFile(const v1::PutFileChunk& head, const std::string& path);
  absl::Status getFile(const v1::GetFileRequest& request, const std::string& path);

 private:
  struct Impl;
  std::string address_;
  std::unique_ptr<Impl> impl_;
};

// True for the errors that mean "the coordinator is not there right now" (UNAVAILABLE,
// DEADLINE_EXCEEDED): a worker waits and calls again rather than giving up its task.
bool isTransient(const absl::Status& status);

// Says a call will be tried again (a warning in the log).
void logRetry(const char* what, const absl::Status& status, double waitSeconds);

// Calls `rpc` until it answers with anything but "the coordinator is not there", waiting a
// little longer each time. A worker that has finished a task keeps its result until the
// coordinator can take it (within `patienceSeconds`; after that the lease has long expired
// and the task runs again elsewhere).
template <typename Rpc>
auto callPatiently(Rpc&& rpc, double patienceSeconds, const char* what) -> decltype(rpc()) {
  using Clock = std::chrono::steady_clock;
  const auto giveUp = Clock::now() + std::chrono::duration<double>(patienceSeconds);
  double wait = 0.2;
  for (;;) {
    auto result = rpc();
    if (result.ok() || !isTransient(result.status()) || Clock::now() >= giveUp) return result;
    logRetry(what, result.status(), wait);
    std::this_thread::sleep_for(std::chrono::duration<double>(wait));
    wait = std::min(wait * 2.0, 2.0);
  }
}

// A frame's tree at the coordinator's page service, a page a call (remote_page_file.h checks
// and keeps them). A coordinator that does not answer (restarting) is waited for, a minute.
class FarmPageFetcher final : public PageFetcher {
 public:
  FarmPageFetcher(FarmClient& client, int64_t job, int frame);
  const std::string& name() const override { return name_; }
  absl::StatusOr<PageFileHead> head() override;
  absl::StatusOr<std::vector<uint8_t>> page(uint64_t treeId, uint32_t id) override;

 private:
  FarmClient& client_;
  int64_t job_;
  int frame_;
  std::string name_;
};

}  // namespace pbgi::farm
