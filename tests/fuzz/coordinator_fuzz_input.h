#pragma once
// The body of the coordinator's fuzz target (tests/fuzz/coordinator_fuzz.cpp). It lives in a
// header so that tests/services/coordinator/coordinator_fuzz_corpus_test.cpp replays every
// seed through the same code in builds without libFuzzer (CI builds with gcc), and writes the
// seeds.
//
// An input is a sequence of farm RPCs, each a record
//
//   offset  size  field
//   0       1     which RPC: FarmRpc, modulo kFarmRpcCount
//   1       2     n, the request's length (u16 LE; cut to what is left of the input)
//   3       n     the request, protobuf wire format (ParseFromArray; a request that does not
//                 parse is skipped, as gRPC would refuse it)
//
// applied in order to the coordinator's handlers (services/coordinator/farm_service.h),
// in-process, over a fresh SQLite job store in a scratch folder (its output/ is the output
// root). The token check runs before any handler in a real coordinator (farm_auth.h), so none
// is made here. A relative shot_path is taken relative to the shot parser target's scratch
// folder (shot_fuzz_input.h), whose shots/ holds an empty file for every geometry and texture
// the seeds name. Two things stand for what happens around the handlers: the record
// kExpireLeases (a lease period passes and the lease reaper reclaims every lease), and, when
// LeaseTask hands out a bake, a copy of tests/data/pbgi/valid.pbgi where the frame's tree goes
// (what the bake's worker would write), so that OpenTree and FetchPages find one.
//
// What must hold, beyond "no crash, no sanitizer report":
//   - a handler refuses a request with a status of the request's making (InvalidArgument,
//     NotFound, FailedPrecondition, OutOfRange, PermissionDenied, ...), never Internal,
//     Unknown, DataLoss or Unavailable: those would mean the coordinator broke;
//   - after the sequence, every job's state is what its tasks' states settle to, its counts
//     by state are its tasks', and it has a task per frame and kind that its spec implies.

#include <unistd.h>

#include <algorithm>
#include <array>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <memory>
#include <span>
#include <string>
#include <string_view>
#include <system_error>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <grpcpp/grpcpp.h>

#include "pbgi/farm/v1/farm.grpc.pb.h"
#include "services/coordinator/coordinator.h"
#include "services/coordinator/coordinator_metrics.h"
#include "services/coordinator/farm_activity.h"
#include "services/coordinator/farm_service.h"
#include "services/coordinator/lease_reaper.h"
#include "services/coordinator/page_service.h"
#include "services/coordinator/parsed_job_cache.h"
#include "services/farm/job_rules.h"
#include "services/job_store/job_store.h"
#include "tests/fuzz/shot_fuzz_input.h"

namespace pbgi::fuzz {

namespace v1 = ::pbgi::farm::v1;

enum class FarmRpc : uint8_t {
  kSubmitJob,
  kGetStatus,
  kCancelJob,
  kRetryJob,
  kGetLogs,
  kRegisterWorker,
  kListWorkers,
  kLeaseTask,
  kHeartbeat,
  kCompleteTask,
  kFailTask,
  kOpenTree,
  kFetchPages,
  kExpireLeases,  // no request: every lease expires, as if its lease period had passed
};
inline constexpr int kFarmRpcCount = 14;
// Records per input at most: enough for a job's life, few enough to stay fast.
inline constexpr int kMaxFarmRecords = 64;

// One record, for writing seeds.
inline std::string farmRecord(FarmRpc rpc, const google::protobuf::Message& request) {
  const std::string body = request.SerializeAsString();
  std::string record(3, '\0');
  record[0] = static_cast<char>(rpc);
  record[1] = static_cast<char>(body.size() & 0xff);
  record[2] = static_cast<char>((body.size() >> 8) & 0xff);
  return record + body.substr(0, 0xffff);
}

// A coordinator's parts without its servers, over a fresh store: what one input runs against.
class FarmFuzzCoordinator {
 public:
  // `tree`: the file a bake "writes" (tests/data/pbgi/valid.pbgi).
  explicit FarmFuzzCoordinator(std::filesystem::path tree) : tree_(std::move(tree)) {
    namespace fs = std::filesystem;
    std::error_code ec;
    fs::remove_all(scratch() / "state", ec);
    fs::remove_all(scratch() / "output", ec);
    fs::create_directories(scratch() / "state");
    fs::create_directories(scratch() / "output");
    options_.stateDir = (scratch() / "state").string();
    options_.outputRoot = (scratch() / "output").string();
    options_.token = "fuzz";
    options_.tileSize = 32;
    options_.retry = {.maxAttempts = 2, .backoffBase = 0, .backoffMax = 0, .blocklistAfter = 2};
    // A copy of an empty store made once: creating the schema was most of a short input's time.
    const fs::path db = scratch() / "state" / "jobs.db";
    fs::copy_file(emptyStore(), db, ec);
    auto store = farm::openSqliteJobStore(db.string(), options_.retry);
    if (!store.ok()) {
      std::fprintf(stderr, "coordinator fuzz: %s\n", store.status().ToString().c_str());
      std::abort();
    }
    store_ = *std::move(store);
    metrics_ = std::make_unique<farm::CoordinatorMetrics>(*store_);
    jobs_ = std::make_unique<farm::ParsedJobCache>(*store_, options_.stateDir, options_.tileSize);
    pages_ = std::make_unique<farm::PageService>(*jobs_, *metrics_);
    service_ = farm::makeFarmService(options_, *store_, *jobs_, *pages_, *metrics_, activity_);
  }
  ~FarmFuzzCoordinator() {
    service_.reset();
    pages_.reset();
    jobs_.reset();
    metrics_.reset();
    store_.reset();
  }

  // Applies one record's request; returns the promise it broke, empty when none.
  std::string apply(FarmRpc rpc, std::span<const uint8_t> body) {
    switch (rpc) {
      case FarmRpc::kSubmitJob: {
        v1::SubmitJobRequest r;
        if (!parse(body, r)) return {};
        if (!r.shot_path().empty() && r.shot_path()[0] != '/') {
          r.set_shot_path((shotFuzzDir() / r.shot_path()).string());
        }
        v1::SubmitJobResponse out;
        return check("SubmitJob", service_->SubmitJob(nullptr, &r, &out));
      }
      case FarmRpc::kGetStatus:
        return call<v1::GetStatusRequest, v1::GetStatusResponse>(
            "GetStatus", body, &v1::Coordinator::Service::GetStatus);
      case FarmRpc::kCancelJob:
        return call<v1::CancelJobRequest, v1::CancelJobResponse>(
            "CancelJob", body, &v1::Coordinator::Service::CancelJob);
      case FarmRpc::kRetryJob:
        return call<v1::RetryJobRequest, v1::RetryJobResponse>("RetryJob", body,
                                                               &v1::Coordinator::Service::RetryJob);
      case FarmRpc::kGetLogs:
        return call<v1::GetLogsRequest, v1::GetLogsResponse>("GetLogs", body,
                                                             &v1::Coordinator::Service::GetLogs);
      case FarmRpc::kRegisterWorker:
        return call<v1::RegisterWorkerRequest, v1::RegisterWorkerResponse>(
            "RegisterWorker", body, &v1::Coordinator::Service::RegisterWorker);
      case FarmRpc::kListWorkers:
        return call<v1::ListWorkersRequest, v1::ListWorkersResponse>(
            "ListWorkers", body, &v1::Coordinator::Service::ListWorkers);
      case FarmRpc::kLeaseTask: {
        v1::LeaseTaskRequest r;
        if (!parse(body, r)) return {};
        v1::LeaseTaskResponse out;
        if (std::string broken = check("LeaseTask", service_->LeaseTask(nullptr, &r, &out));
            !broken.empty()) {
          return broken;
        }
        if (out.has_task() && out.task_kind() == v1::TASK_KIND_BAKE) writeTree(out);
        return {};
      }
      case FarmRpc::kHeartbeat:
        return call<v1::HeartbeatRequest, v1::HeartbeatResponse>(
            "Heartbeat", body, &v1::Coordinator::Service::Heartbeat);
      case FarmRpc::kCompleteTask:
        return call<v1::CompleteTaskRequest, v1::CompleteTaskResponse>(
            "CompleteTask", body, &v1::Coordinator::Service::CompleteTask);
      case FarmRpc::kFailTask:
        return call<v1::FailTaskRequest, v1::FailTaskResponse>("FailTask", body,
                                                               &v1::Coordinator::Service::FailTask);
      case FarmRpc::kOpenTree:
        return call<v1::OpenTreeRequest, v1::OpenTreeResponse>("OpenTree", body,
                                                               &v1::Coordinator::Service::OpenTree);
      case FarmRpc::kFetchPages: {
        // The handler only hands the page service a writer of its stream; a fuzz run has none.
        v1::FetchPagesRequest r;
        if (!parse(body, r)) return {};
        size_t chunks = 0;
        const absl::Status s = pages_->fetchPages(r, [&chunks](const v1::PageChunk&) {
          return ++chunks < 4;  // a worker that goes away after a few pages
        });
        return check("FetchPages", grpc::Status(static_cast<grpc::StatusCode>(s.code()),
                                                std::string(s.message())));
      }
      case FarmRpc::kExpireLeases: {
        // Past every lease's end. The expired tasks' back-off starts then too, so they are not
        // leased again within the input: the handlers read the wall clock, and an input must
        // run the same way every time.
        const absl::StatusOr<int> expired =
            store_->expireLeases(farm::wallClock() + options_.leaseSeconds + 1);
        if (!expired.ok()) return fmt::format("expireLeases: {}", expired.status().ToString());
        return {};
      }
    }
    return {};
  }

  farm::JobStore& store() { return *store_; }
  const farm::CoordinatorMetrics& metrics() const { return *metrics_; }

  // The store's promises about every job, checked once the sequence has run.
  std::string checkJobs() {
    const auto jobs = store_->jobs();
    if (!jobs.ok()) return fmt::format("jobs(): {}", jobs.status().ToString());
    for (const farm::JobInfo& job : *jobs) {
      const auto tasks = store_->tasks(job.id);
      if (!tasks.ok()) return fmt::format("tasks({}): {}", job.id, tasks.status().ToString());
      farm::PerTaskState<int> counts{};
      farm::PerTaskState<bool> present{};
      for (const farm::TaskInfo& t : *tasks) {
        ++counts[static_cast<size_t>(t.state)];
        present[static_cast<size_t>(t.state)] = true;
      }
      if (counts != job.tasksByState) {
        return fmt::format("job {}: counts by state {} but its tasks say {}", job.id,
                           fmt::join(job.tasksByState, " "), fmt::join(counts, " "));
      }
      const farm::JobState settled = farm::settledJobState(job.state, present);
      if (settled != job.state) {
        return fmt::format("job {} is {} but its tasks ({}) settle to {}", job.id,
                           farm::toString(job.state), fmt::join(counts, " "),
                           farm::toString(settled));
      }
      const size_t perFrame = size_t(job.spec.tileCount) + 1 + (job.spec.needsBake ? 1 : 0);
      if (tasks->size() != job.spec.frames.size() * perFrame) {
        return fmt::format("job {}: {} tasks for {} frames of {} tiles{}", job.id, tasks->size(),
                           job.spec.frames.size(), job.spec.tileCount,
                           job.spec.needsBake ? " and a bake" : "");
      }
    }
    return {};
  }

 private:
  template <typename Request>
  static bool parse(std::span<const uint8_t> body, Request& r) {
    return r.ParseFromArray(body.data(), static_cast<int>(body.size()));
  }

  template <typename Request, typename Response>
  std::string call(std::string_view name, std::span<const uint8_t> body,
                   grpc::Status (v1::Coordinator::Service::*handler)(grpc::ServerContext*,
                                                                     const Request*, Response*)) {
    Request r;
    if (!parse(body, r)) return {};
    Response out;
    return check(name, (service_.get()->*handler)(nullptr, &r, &out));
  }

  static std::string check(std::string_view rpc, const grpc::Status& s) {
    switch (s.error_code()) {
      case grpc::StatusCode::INTERNAL:
      case grpc::StatusCode::UNKNOWN:
      case grpc::StatusCode::DATA_LOSS:
      case grpc::StatusCode::UNAVAILABLE:
        return fmt::format("{} answered {}: {}", rpc, static_cast<int>(s.error_code()),
                           s.error_message());
      default:
        return {};
    }
  }

  // What the leased bake's worker would leave: the frame's tree where tiles and the page
  // service look for it.
  void writeTree(const v1::LeaseTaskResponse& lease) {
    auto view = jobs_->get(lease.job());
    if (!view.ok()) return;
    auto path = farm::jobTreePath((*view)->shot, jobs_->workDir(lease.job()), lease.frame());
    if (!path.ok()) return;
    std::error_code ec;
    std::filesystem::create_directories(std::filesystem::path(*path).parent_path(), ec);
    std::filesystem::copy_file(tree_, *path, std::filesystem::copy_options::overwrite_existing, ec);
  }

  // The process's scratch folder, on /dev/shm where there is one (the store's fsyncs cost
  // nothing there).
  static const std::filesystem::path& scratch() {
    static const ScratchFolder dir([] {
      namespace fs = std::filesystem;
      const fs::path shm = "/dev/shm";
      const fs::path base = fs::is_directory(shm) && ::access(shm.c_str(), W_OK) == 0
                                ? shm
                                : fs::temp_directory_path();
      return base / fmt::format("pbgi-coordinator-fuzz-{}", ::getpid());
    }());
    return dir.path();
  }
  static const std::filesystem::path& emptyStore() {
    static const std::filesystem::path db = [] {
      const std::filesystem::path path = scratch() / "empty.db";
      auto store = farm::openSqliteJobStore(path.string(), farm::RetryPolicy());
      if (!store.ok()) {
        std::fprintf(stderr, "coordinator fuzz: %s\n", store.status().ToString().c_str());
        std::abort();
      }
      return path;
    }();
    return db;
  }

  std::filesystem::path tree_;
  farm::CoordinatorOptions options_;
  std::unique_ptr<farm::JobStore> store_;
  std::unique_ptr<farm::CoordinatorMetrics> metrics_;
  std::unique_ptr<farm::ParsedJobCache> jobs_;
  std::unique_ptr<farm::PageService> pages_;
  farm::FarmActivity activity_;
  std::unique_ptr<v1::Coordinator::Service> service_;
};

// Runs one input against a fresh coordinator; returns the promise it broke, empty when none.
inline std::string runFarmInput(std::span<const uint8_t> input, const std::filesystem::path& tree) {
  FarmFuzzCoordinator coordinator(tree);
  for (int n = 0; n < kMaxFarmRecords && input.size() >= 3; ++n) {
    const auto rpc = static_cast<FarmRpc>(input[0] % kFarmRpcCount);
    const size_t size = std::min<size_t>(input[1] | size_t{input[2]} << 8, input.size() - 3);
    const std::span<const uint8_t> body = input.subspan(3, size);
    input = input.subspan(3 + size);
    if (std::string broken = coordinator.apply(rpc, body); !broken.empty()) return broken;
  }
  return coordinator.checkJobs();
}

}  // namespace pbgi::fuzz
