#include "services/coordinator/coordinator.h"

#include <array>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <filesystem>
#include <map>
#include <mutex>
#include <thread>
#include <unordered_map>

#include <sys/stat.h>

#include <fmt/format.h>
#include <google/protobuf/util/json_util.h>
#include <grpcpp/grpcpp.h>
#include <httplib.h>

#include "core/render/integrators.h"
#include "core/util/log.h"
#include "core/util/status.h"
#include "formats/pbgi/page_file.h"
#include "pbgi/farm/v1/farm.grpc.pb.h"
#include "services/bake/frame_bake.h"
#include "services/coordinator/farm_job.h"
#include "services/coordinator/farm_wire.h"
#include "services/render/frame_assembly.h"

namespace pbgi::farm {

namespace fs = std::filesystem;
namespace v1 = ::pbgi::farm::v1;

namespace {

Seconds wallClock() {
  return std::chrono::duration<double>(std::chrono::system_clock::now().time_since_epoch())
      .count();
}

grpc::Status toGrpc(const absl::Status& s) {
  if (s.ok()) return grpc::Status::OK;
  return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
}

// Tokens of equal length compare in a time that does not depend on where they differ.
bool sameToken(std::string_view given, std::string_view expected) {
  if (expected.empty() || given.size() != expected.size()) return false;
  unsigned char diff = 0;
  for (size_t i = 0; i < given.size(); ++i) diff |= given[i] ^ expected[i];
  return diff == 0;
}

// Upper bounds of the task-duration histogram, in seconds.
constexpr std::array<double, 10> kDurationBuckets = {0.5, 1, 2, 5, 10, 30, 60, 120, 300, 600};

struct Histogram {
  std::array<uint64_t, kDurationBuckets.size()> buckets{};
  uint64_t count = 0;
  double sum = 0.0;
  void add(double seconds) {
    for (size_t i = 0; i < kDurationBuckets.size(); ++i) {
      if (seconds <= kDurationBuckets[i]) ++buckets[i];
    }
    ++count;
    sum += seconds;
  }
};

void fillTask(const TaskInfo& t, v1::TaskStatus* out) {
  out->set_task(t.id);
  setKindAndState(t.ref.kind, t.state, out);
  out->set_frame(t.ref.frame);
  out->set_tile(t.ref.tile);
  out->set_attempt(t.attempt);
  out->set_failures(t.failures);
  out->set_worker(t.worker);
  out->set_last_error(t.lastError);
  out->set_progress(t.progress);
}

}  // namespace

struct CoordinatorMetrics {
  std::mutex mutex;
  std::atomic<uint64_t> refused{0};
  std::atomic<uint64_t> leases{0};
  std::atomic<uint64_t> failures{0};
  std::atomic<uint64_t> expired{0};
  std::atomic<uint64_t> staleCompletions{0};
  std::atomic<uint64_t> cacheHits{0};
  std::atomic<uint64_t> cacheMisses{0};
  std::atomic<uint64_t> treeBytesStreamed{0};
  std::atomic<uint64_t> treesOpened{0};
  std::atomic<uint64_t> pagesServed{0};
  std::atomic<uint64_t> pageBytesServed{0};
  std::map<std::string, Histogram> durations;  // by task kind; under mutex
};

struct Coordinator::Impl final : public v1::Coordinator::Service {
  CoordinatorOptions options;
  std::unique_ptr<JobStore> store;
  CoordinatorMetrics metrics;
  std::unique_ptr<grpc::Server> server;
  std::string address;
  Seconds started = 0;

  httplib::Server http;
  std::string httpAddress;
  std::thread httpThread;

  std::mutex stopMutex;
  std::condition_variable stopChanged;
  bool stopping = false;
  std::thread expiryThread;

  // What a job renders, parsed once: the spec never changes after submission.
  struct JobView {
    JobSpec spec;
    ShotDesc shot;
  };
  std::mutex jobsMutex;
  std::unordered_map<int64_t, std::shared_ptr<const JobView>> jobs;

  // Trees the page service has open, oldest first: a file is known by path, inode and
  // modification time, so a frame baked again is opened again.
  struct OpenTreeKey {
    std::string path;
    uint64_t inode = 0;
    int64_t mtimeNs = 0;
    bool operator==(const OpenTreeKey&) const = default;
  };
  std::mutex treesMutex;
  std::vector<std::pair<OpenTreeKey, std::shared_ptr<const PageFileReader>>> openTrees;

  // ---- helpers ----

  bool authorized(grpc::ServerContext* context) {
    const auto& md = context->client_metadata();
    const auto it = md.find("authorization");
    constexpr std::string_view kPrefix = "Bearer ";
    if (it != md.end()) {
      const std::string_view value(it->second.data(), it->second.size());
      if (value.substr(0, kPrefix.size()) == kPrefix &&
          sameToken(value.substr(kPrefix.size()), options.token)) {
        return true;
      }
    }
    metrics.refused.fetch_add(1);
    log::warn("refused peer={}: missing or wrong farm token", context->peer());
    return false;
  }

  static grpc::Status refusedStatus() {
    return grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                        "the farm token is missing or wrong (authorization: Bearer <token>)");
  }

  absl::StatusOr<std::shared_ptr<const JobView>> jobView(int64_t id) {
    {
      std::lock_guard lock(jobsMutex);
      if (auto it = jobs.find(id); it != jobs.end()) return it->second;
    }
    PBGI_ASSIGN_OR_RETURN(JobInfo info, store->job(id));
    auto view = std::make_shared<JobView>();
    view->spec = std::move(info.spec);
    PBGI_ASSIGN_OR_RETURN(view->shot, jobShot(view->spec.shotText, view->spec.shotPath,
                                              splitOverrides(view->spec.overrides)));
    std::lock_guard lock(jobsMutex);
    return jobs.emplace(id, std::move(view)).first->second;
  }

  std::string workDir(int64_t job) const { return jobWorkDir(options.stateDir, job); }

  std::string frameOutput(const JobView& view, int frame) const {
    return outputPathForFrame(view.spec.outputPattern, frame,
                              view.shot.lastFrame > view.shot.firstFrame);
  }

  absl::StatusOr<int64_t> submit(const v1::SubmitJobRequest& request) {
    const std::vector<std::string> overrides(request.overrides().begin(),
                                             request.overrides().end());
    PBGI_ASSIGN_OR_RETURN(const ShotDesc shot,
                          jobShot(request.shot_text(), request.shot_path(), overrides));
    JobSpec spec;
    spec.name = shot.name;
    spec.shotPath = fs::absolute(request.shot_path()).lexically_normal().string();
    spec.shotText = request.shot_text();
    spec.overrides = joinOverrides(overrides);
    spec.priority = request.priority();
    if (request.frames().empty()) {
      for (int f = shot.firstFrame; f <= shot.lastFrame; ++f) spec.frames.push_back(f);
    }
    for (const int f : request.frames()) {
      PBGI_RETURN_IF_ERROR(checkShotFrame(shot, f));
      spec.frames.push_back(f);
    }
    std::string pattern = shot.output;
    if (!request.output_dir().empty()) {
      const fs::path dir = fs::path(request.output_dir()).is_absolute()
                               ? fs::path(request.output_dir())
                               : fs::path(options.outputRoot) / request.output_dir();
      pattern = (dir / fs::path(shot.output).filename()).string();
    }
    PBGI_ASSIGN_OR_RETURN(spec.outputPattern, confineToRoot(pattern, options.outputRoot));
    spec.tileCount = static_cast<int>(farmTiles(shot, tileSize()).size());
    PBGI_ASSIGN_OR_RETURN(const IntegratorInfo* integrator,
                          findIntegrator(shot.render.integrator));
    spec.needsBake = integrator->needsTree;
    PBGI_ASSIGN_OR_RETURN(const int64_t id, store->submit(spec, wallClock()));
    std::error_code ec;
    fs::create_directories(workDir(id), ec);
    log::info("submitted job={} shot={} frames={} tiles={} integrator={} output={}", id,
              spec.name, spec.frames.size(), spec.tileCount, shot.render.integrator,
              spec.outputPattern);
    return id;
  }

  int tileSize() const { return options.tileSize > 0 ? options.tileSize : kDefaultFarmTileSize; }

  absl::StatusOr<v1::GetStatusResponse> status(const v1::GetStatusRequest& request) {
    std::vector<JobInfo> infos;
    if (request.job() != 0) {
      PBGI_ASSIGN_OR_RETURN(JobInfo one, store->job(request.job()));
      infos.push_back(std::move(one));
    } else {
      PBGI_ASSIGN_OR_RETURN(infos, store->jobs());
    }
    v1::GetStatusResponse response;
    for (const JobInfo& info : infos) {
      v1::JobStatus* job = response.add_jobs();
      job->set_job(info.id);
      job->set_name(info.spec.name);
      setState(info.state, info.tasksByState, job);
      job->set_priority(info.spec.priority);
      for (int f : info.spec.frames) job->add_frames(f);
      job->set_tiles_per_frame(info.spec.tileCount);
      for (const TaskInfo& t : info.dead) fillTask(t, job->add_dead());
      // Every task of a job is a large read: only for callers that ask for them.
      if (!request.with_tasks()) continue;
      PBGI_ASSIGN_OR_RETURN(const std::vector<TaskInfo> tasks, store->tasks(info.id));
      auto view = jobView(info.id);
      for (const TaskInfo& t : tasks) {
        fillTask(t, job->add_tasks());
        if (view.ok() && t.ref.kind == TaskKind::kAssemble && t.state == TaskState::kDone) {
          job->add_outputs(frameOutput(**view, t.ref.frame));
        }
      }
    }
    return response;
  }

  // ---- RPCs ----

  grpc::Status SubmitJob(grpc::ServerContext* context, const v1::SubmitJobRequest* request,
                         v1::SubmitJobResponse* response) override {
    if (!authorized(context)) return refusedStatus();
    auto id = submit(*request);
    if (!id.ok()) {
      log::warn("refused job shot={}: {}", request->shot_path(), id.status().message());
      return toGrpc(id.status());
    }
    response->set_job(*id);
    return grpc::Status::OK;
  }

  grpc::Status GetStatus(grpc::ServerContext* context, const v1::GetStatusRequest* request,
                         v1::GetStatusResponse* response) override {
    if (!authorized(context)) return refusedStatus();
    auto s = status(*request);
    if (!s.ok()) return toGrpc(s.status());
    *response = *std::move(s);
    return grpc::Status::OK;
  }

  grpc::Status CancelJob(grpc::ServerContext* context, const v1::CancelJobRequest* request,
                         v1::CancelJobResponse*) override {
    if (!authorized(context)) return refusedStatus();
    return toGrpc(store->cancel(request->job()));
  }

  grpc::Status RetryJob(grpc::ServerContext* context, const v1::RetryJobRequest* request,
                        v1::RetryJobResponse*) override {
    if (!authorized(context)) return refusedStatus();
    return toGrpc(store->retry(
        request->job(), request->has_frame() ? std::optional<int>(request->frame()) : std::nullopt,
        request->has_tile() ? std::optional<int>(request->tile()) : std::nullopt, wallClock()));
  }

  grpc::Status GetLogs(grpc::ServerContext* context, const v1::GetLogsRequest* request,
                       v1::GetLogsResponse* response) override {
    if (!authorized(context)) return refusedStatus();
    auto events = store->events(
        request->job(), request->has_frame() ? std::optional<int>(request->frame()) : std::nullopt,
        request->has_tile() ? std::optional<int>(request->tile()) : std::nullopt);
    if (!events.ok()) return toGrpc(events.status());
    for (const TaskEvent& e : *events) {
      v1::LogEntry* entry = response->add_entries();
      entry->set_time(e.time);
      entry->set_task(e.task);
      setKind(e.ref.kind, entry);
      entry->set_frame(e.ref.frame);
      entry->set_tile(e.ref.tile);
      entry->set_attempt(e.attempt);
      entry->set_worker(e.worker);
      entry->set_event(e.event);
      entry->set_text(e.text);
    }
    return grpc::Status::OK;
  }

  grpc::Status RegisterWorker(grpc::ServerContext* context,
                              const v1::RegisterWorkerRequest* request,
                              v1::RegisterWorkerResponse* response) override {
    if (!authorized(context)) return refusedStatus();
    WorkerInfo w;
    w.id = request->worker();
    w.host = request->host();
    w.cores = request->cores();
    w.memoryBytes = request->memory_bytes();
    w.cacheBytes = request->cache_bytes();
    w.lastSeen = wallClock();
    if (absl::Status s = store->registerWorker(w); !s.ok()) return toGrpc(s);
    log::info("registered worker={} cores={} memory={:.1f}GiB cache={:.0f}MiB", w.id, w.cores,
              double(w.memoryBytes) / (1 << 30), double(w.cacheBytes) / (1 << 20));
    response->set_lease_seconds(options.leaseSeconds);
    return grpc::Status::OK;
  }

  grpc::Status ListWorkers(grpc::ServerContext* context, const v1::ListWorkersRequest*,
                           v1::ListWorkersResponse* response) override {
    if (!authorized(context)) return refusedStatus();
    auto workers = store->workers();
    if (!workers.ok()) return toGrpc(workers.status());
    for (const WorkerInfo& w : *workers) {
      v1::WorkerStatus* out = response->add_workers();
      out->set_worker(w.id);
      out->set_host(w.host);
      out->set_cores(w.cores);
      out->set_memory_bytes(w.memoryBytes);
      out->set_cache_bytes(w.cacheBytes);
      out->set_last_seen(w.lastSeen);
    }
    return grpc::Status::OK;
  }

  grpc::Status LeaseTask(grpc::ServerContext* context, const v1::LeaseTaskRequest* request,
                         v1::LeaseTaskResponse* response) override {
    if (!authorized(context)) return refusedStatus();
    // A job whose stored shot no longer parses (a newer file format, a damaged row) must not
    // stop the farm: its task fails with the reason and the next one is offered.
    std::vector<HeldFrame> held;
    if (options.localityDispatch) {
      for (const v1::HeldFrame& h : request->held()) held.push_back({h.job(), h.frame()});
    }
    for (;;) {
      auto lease = store->lease(request->worker(), wallClock(), options.leaseSeconds, held);
      if (!lease.ok()) return toGrpc(lease.status());
      if (!lease->has_value()) {
        response->set_has_task(false);
        return grpc::Status::OK;
      }
      const Lease& l = **lease;
      auto view = jobView(l.ref.job);
      if (!view.ok()) {
        (void)store->fail(l.task, l.attempt, std::string(view.status().message()), wallClock());
        continue;
      }
      metrics.leases.fetch_add(1);
      const JobSpec& spec = (*view)->spec;
      response->set_has_task(true);
      response->set_task(l.task);
      response->set_attempt(l.attempt);
      setKind(l.ref.kind, response);
      response->set_job(l.ref.job);
      response->set_frame(l.ref.frame);
      response->set_tile(l.ref.tile);
      response->set_shot_path(spec.shotPath);
      response->set_shot_text(spec.shotText);
      for (const std::string& o : splitOverrides(spec.overrides)) response->add_overrides(o);
      const std::string dir = workDir(l.ref.job);
      response->set_work_dir(dir);
      switch (l.ref.kind) {
        case TaskKind::kBake: response->set_output_path(jobBakeDir(dir)); break;
        case TaskKind::kTile: {
          response->set_output_path(farmTilePath(dir, l.ref.frame, l.ref.tile));
          // The tile's rectangles of the mosaic frame, explicitly.
          const std::vector<FarmTile> tiles = farmTiles((*view)->shot, tileSize());
          if (l.ref.tile >= 0 && static_cast<size_t>(l.ref.tile) < tiles.size()) {
            for (const TileRect& r : tiles[static_cast<size_t>(l.ref.tile)]) {
              v1::Rect* rect = response->add_regions();
              rect->set_x0(r.x0);
              rect->set_y0(r.y0);
              rect->set_x1(r.x1);
              rect->set_y1(r.y1);
            }
          }
          break;
        }
        case TaskKind::kAssemble:
          response->set_output_path(frameOutput(**view, l.ref.frame));
          break;
      }
      response->set_lease_seconds(options.leaseSeconds);
      response->set_tiles_per_frame(spec.tileCount);
      response->set_tile_size(tileSize());
      return grpc::Status::OK;
    }
  }

  grpc::Status Heartbeat(grpc::ServerContext* context, const v1::HeartbeatRequest* request,
                         v1::HeartbeatResponse* response) override {
    if (!authorized(context)) return refusedStatus();
    const absl::Status s = store->heartbeat(request->task(), request->attempt(),
                                            request->progress(), wallClock(), options.leaseSeconds);
    if (s.code() == absl::StatusCode::kFailedPrecondition ||
        s.code() == absl::StatusCode::kNotFound) {
      response->set_keep_going(false);
      return grpc::Status::OK;
    }
    response->set_keep_going(s.ok());
    return toGrpc(s);
  }

  grpc::Status CompleteTask(grpc::ServerContext* context, const v1::CompleteTaskRequest* request,
                            v1::CompleteTaskResponse*) override {
    if (!authorized(context)) return refusedStatus();
    const absl::StatusOr<TaskRef> done =
        store->complete(request->task(), request->attempt(), wallClock(), request->log());
    if (done.status().code() == absl::StatusCode::kFailedPrecondition) {
      metrics.staleCompletions.fetch_add(1);
      log::warn("dropped stale completion worker={}: {}", request->worker(),
                done.status().message());
    }
    if (!done.ok()) return toGrpc(done.status());
    metrics.cacheHits.fetch_add(request->cache_hits());
    metrics.cacheMisses.fetch_add(request->cache_misses());
    metrics.treeBytesStreamed.fetch_add(request->tree_bytes_streamed());
    {
      std::lock_guard lock(metrics.mutex);
      metrics.durations[toString(done->kind)].add(request->seconds());
    }
    return grpc::Status::OK;
  }

  grpc::Status FailTask(grpc::ServerContext* context, const v1::FailTaskRequest* request,
                        v1::FailTaskResponse*) override {
    if (!authorized(context)) return refusedStatus();
    const absl::Status s = store->fail(request->task(), request->attempt(), request->error(),
                                       wallClock(), request->log());
    if (!s.ok()) return toGrpc(s);
    metrics.failures.fetch_add(1);
    log::warn("failed task={} attempt={} worker={}: {}", request->task(), request->attempt(),
              request->worker(), request->error());
    return grpc::Status::OK;
  }

  // The frame's tree, opened (its head read and checked) once and kept while its file is the
  // same one: a worker asks for a page at a time.
  absl::StatusOr<std::shared_ptr<const PageFileReader>> openTree(int64_t job, int frame) {
    PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const JobView> view, jobView(job));
    PBGI_ASSIGN_OR_RETURN(const std::string path,
                          jobTreePath(view->shot, workDir(job), frame));
    struct stat st {};
    if (::stat(path.c_str(), &st) != 0) {
      return absl::NotFoundError(fmt::format(
          "job {} frame {}: no tree at {} (has the frame's bake run?)", job, frame, path));
    }
    const OpenTreeKey key{path, static_cast<uint64_t>(st.st_ino),
                          static_cast<int64_t>(st.st_mtim.tv_sec) * 1000000000 +
                              st.st_mtim.tv_nsec};
    {
      std::lock_guard lock(treesMutex);
      for (const auto& [k, reader] : openTrees) {
        if (k == key) return reader;
      }
    }
    PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageFileReader> opened, PageFileReader::open(path));
    std::shared_ptr<const PageFileReader> reader = std::move(opened);
    std::lock_guard lock(treesMutex);
    std::erase_if(openTrees, [&](const auto& t) { return t.first.path == path; });
    openTrees.emplace_back(key, reader);
    constexpr size_t kOpenTrees = 16;  // each holds its head and a descriptor
    if (openTrees.size() > kOpenTrees) openTrees.erase(openTrees.begin());
    return reader;
  }

  grpc::Status OpenTree(grpc::ServerContext* context, const v1::OpenTreeRequest* request,
                        v1::OpenTreeResponse* response) override {
    if (!authorized(context)) return refusedStatus();
    auto tree = openTree(request->job(), request->frame());
    if (!tree.ok()) return toGrpc(tree.status());
    const PageFileHead& head = (*tree)->head();
    response->set_header(head.header.data(), head.header.size());
    response->set_tail_offset(head.tailOffset);
    response->set_tail(head.tail.data(), head.tail.size());
    response->set_file_size(head.fileSize);
    metrics.treesOpened.fetch_add(1);
    metrics.pageBytesServed.fetch_add(head.bytes());
    return grpc::Status::OK;
  }

  grpc::Status FetchPages(grpc::ServerContext* context, const v1::FetchPagesRequest* request,
                          grpc::ServerWriter<v1::PageChunk>* writer) override {
    if (!authorized(context)) return refusedStatus();
    if (request->pages_size() == 0) {
      return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                          "FetchPages: name the pages (whole trees are not served)");
    }
    auto tree = openTree(request->job(), request->frame());
    if (!tree.ok()) return toGrpc(tree.status());
    const PageFileReader& reader = **tree;
    if (reader.head().treeId() != request->tree_id()) {
      return grpc::Status(
          grpc::StatusCode::FAILED_PRECONDITION,
          fmt::format("job {} frame {}: the tree is {:016x} now, not {:016x} (baked again); open "
                      "it again",
                      request->job(), request->frame(), reader.head().treeId(),
                      request->tree_id()));
    }
    v1::PageChunk chunk;
    for (const uint32_t id : request->pages()) {
      // Checked here too: a page damaged on this disk is named as such, not as the network's.
      auto bytes = reader.readStoredPage(id);
      if (!bytes.ok()) {
        return toGrpc(withContext(bytes.status(), fmt::format("page service of job {} frame {}",
                                                              request->job(), request->frame())));
      }
      chunk.set_page(id);
      chunk.set_offset(reader.directory()[id].offset);
      chunk.set_data(bytes->data(), bytes->size());
      if (!writer->Write(chunk)) break;  // the worker went away
      metrics.pagesServed.fetch_add(1);
      metrics.pageBytesServed.fetch_add(bytes->size());
    }
    return grpc::Status::OK;
  }

  // ---- background ----

  void expiryLoop() {
    std::unique_lock lock(stopMutex);
    while (!stopping) {
      stopChanged.wait_for(lock, std::chrono::duration<double>(options.expiryIntervalSeconds));
      if (stopping) break;
      lock.unlock();
      const Seconds now = wallClock();
      // Grace after a start: leases from before it belong to workers that may only have lost
      // sight of this coordinator.
      if (now >= started + options.leaseSeconds) {
        auto n = store->expireLeases(now);
        if (!n.ok()) {
          log::error("reclaiming expired leases: {}", n.status().message());
        } else if (*n > 0) {
          metrics.expired.fetch_add(static_cast<uint64_t>(*n));
          log::warn("{} lease(s) expired; their tasks are retried", *n);
        }
      }
      lock.lock();
    }
  }

  std::string metricsText();
};

std::string Coordinator::Impl::metricsText() {
  std::string out;
  auto add = [&](std::string_view text) { out.append(text); };
  std::array<uint64_t, 6> tasks{};
  std::array<uint64_t, 4> jobStates{};
  if (auto all = store->jobs(); all.ok()) {
    for (const JobInfo& j : *all) {
      ++jobStates[static_cast<size_t>(j.state)];
      for (size_t s = 0; s < tasks.size(); ++s) tasks[s] += j.tasksByState[s];
    }
  }
  add("# HELP pbgi_tasks Tasks of every job by state.\n# TYPE pbgi_tasks gauge\n");
  for (size_t s = 0; s < tasks.size(); ++s) {
    add(fmt::format("pbgi_tasks{{state=\"{}\"}} {}\n", toString(static_cast<TaskState>(s)), tasks[s]));
  }
  add("# HELP pbgi_jobs Jobs by state.\n# TYPE pbgi_jobs gauge\n");
  for (size_t s = 0; s < jobStates.size(); ++s) {
    add(fmt::format("pbgi_jobs{{state=\"{}\"}} {}\n", toString(static_cast<JobState>(s)), jobStates[s]));
  }
  const auto counter = [&](const char* name, const char* help, uint64_t value) {
    add(fmt::format("# HELP {0} {1}\n# TYPE {0} counter\n{0} {2}\n", name, help, value));
  };
  counter("pbgi_leases_total", "Tasks leased to workers.", metrics.leases.load());
  counter("pbgi_task_failures_total", "Attempts that failed on a worker (each is retried or dead).",
          metrics.failures.load());
  counter("pbgi_leases_expired_total", "Leases reclaimed after their worker stopped heartbeating.",
          metrics.expired.load());
  counter("pbgi_stale_completions_total", "Completions dropped because their attempt had lost the lease.",
          metrics.staleCompletions.load());
  counter("pbgi_rpc_refused_total", "Calls refused for a missing or wrong token.",
          metrics.refused.load());
  counter("pbgi_page_cache_hits_total", "Tree page cache hits reported with completed tasks.",
          metrics.cacheHits.load());
  counter("pbgi_page_cache_misses_total", "Tree page cache misses reported with completed tasks.",
          metrics.cacheMisses.load());
  counter("pbgi_trees_opened_total", "Trees workers opened through the page service.",
          metrics.treesOpened.load());
  counter("pbgi_tree_pages_served_total", "Tree pages the page service sent.",
          metrics.pagesServed.load());
  counter("pbgi_tree_bytes_served_total",
          "Bytes the page service sent: pages, and the heads of the trees opened.",
          metrics.pageBytesServed.load());
  counter("pbgi_tree_bytes_streamed_total",
          "Bytes of trees fetched from the page service, as completed tasks reported them.",
          metrics.treeBytesStreamed.load());
  const uint64_t hits = metrics.cacheHits.load();
  const uint64_t misses = metrics.cacheMisses.load();
  add(fmt::format("# HELP pbgi_page_cache_hit_rate Hits over lookups, over completed tasks.\n"
                  "# TYPE pbgi_page_cache_hit_rate gauge\npbgi_page_cache_hit_rate {}\n",
                  hits + misses > 0 ? double(hits) / double(hits + misses) : 0.0));
  add("# HELP pbgi_task_seconds Run time of completed tasks, as the worker measured it.\n"
      "# TYPE pbgi_task_seconds histogram\n");
  std::lock_guard lock(metrics.mutex);
  for (const auto& [kind, h] : metrics.durations) {
    for (size_t i = 0; i < kDurationBuckets.size(); ++i) {
      add(fmt::format("pbgi_task_seconds_bucket{{kind=\"{}\",le=\"{}\"}} {}\n", kind,
                      kDurationBuckets[i], h.buckets[i]));
    }
    add(fmt::format("pbgi_task_seconds_bucket{{kind=\"{}\",le=\"+Inf\"}} {}\n", kind, h.count));
    add(fmt::format("pbgi_task_seconds_sum{{kind=\"{}\"}} {}\n", kind, h.sum));
    add(fmt::format("pbgi_task_seconds_count{{kind=\"{}\"}} {}\n", kind, h.count));
  }
  return out;
}

Coordinator::Coordinator(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

Coordinator::~Coordinator() { shutdown(); }

absl::StatusOr<std::unique_ptr<Coordinator>> Coordinator::start(const CoordinatorOptions& options) {
  if (options.token.empty()) {
    return absl::InvalidArgumentError("the coordinator needs a farm token (every call must carry it)");
  }
  if (options.stateDir.empty() || options.outputRoot.empty()) {
    return absl::InvalidArgumentError("the coordinator needs a state folder and an output root");
  }
  if (!(options.leaseSeconds > 0) || !(options.expiryIntervalSeconds > 0)) {
    return absl::InvalidArgumentError(fmt::format(
        "lease {} s, expiry interval {} s: expected positive times", options.leaseSeconds,
        options.expiryIntervalSeconds));
  }
  std::error_code ec;
  fs::create_directories(options.stateDir, ec);
  if (ec) {
    return absl::PermissionDeniedError(
        fmt::format("state folder {}: {}", options.stateDir, ec.message()));
  }
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->options.stateDir = fs::absolute(options.stateDir).lexically_normal().string();
  impl->options.outputRoot = fs::absolute(options.outputRoot).lexically_normal().string();
  const std::string store = options.store.empty()
                                ? (fs::path(impl->options.stateDir) / "jobs.db").string()
                                : options.store;
  PBGI_ASSIGN_OR_RETURN(impl->store, openJobStore(store, options.retry));
  impl->started = wallClock();

  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(options.listen, grpc::InsecureServerCredentials(), &port);
  builder.RegisterService(impl.get());
  builder.SetMaxReceiveMessageSize(64 << 20);
  impl->server = builder.BuildAndStart();
  if (impl->server == nullptr || port == 0) {
    return absl::UnavailableError(fmt::format("cannot listen on {} (in use?)", options.listen));
  }
  const std::string host = options.listen.substr(0, options.listen.rfind(':'));
  impl->address = fmt::format("{}:{}", host, port);

  if (!options.httpListen.empty()) {
    Impl* self = impl.get();
    impl->http.Get("/metrics", [self](const httplib::Request&, httplib::Response& res) {
      res.set_content(self->metricsText(), "text/plain; version=0.0.4");
    });
    impl->http.Get("/status", [self](const httplib::Request&, httplib::Response& res) {
      std::string json;
      auto status = self->status(v1::GetStatusRequest());
      if (!status.ok()) {
        res.status = 500;
        res.set_content(std::string(status.status().message()), "text/plain");
        return;
      }
      (void)google::protobuf::util::MessageToJsonString(*status, &json);
      res.set_content(json, "application/json");
    });
    const size_t colon = options.httpListen.rfind(':');
    const std::string httpHost = options.httpListen.substr(0, colon);
    int httpPort = colon == std::string::npos ? 0 : std::atoi(options.httpListen.c_str() + colon + 1);
    if (httpPort == 0) {
      httpPort = impl->http.bind_to_any_port(httpHost);
    } else if (!impl->http.bind_to_port(httpHost, httpPort)) {
      httpPort = -1;
    }
    if (httpPort <= 0) {
      impl->server->Shutdown();
      return absl::UnavailableError(
          fmt::format("cannot listen for HTTP on {} (in use?)", options.httpListen));
    }
    impl->httpAddress = fmt::format("{}:{}", httpHost, httpPort);
    impl->httpThread = std::thread([self] { self->http.listen_after_bind(); });
  }
  Impl* self = impl.get();
  impl->expiryThread = std::thread([self] { self->expiryLoop(); });
  log::info("coordinator on {} (state {}, output root {}{})", impl->address,
            impl->options.stateDir, impl->options.outputRoot,
            impl->httpAddress.empty() ? "" : ", metrics on http://" + impl->httpAddress + "/metrics");
  return std::unique_ptr<Coordinator>(new Coordinator(std::move(impl)));
}

const std::string& Coordinator::address() const { return impl_->address; }
const std::string& Coordinator::httpAddress() const { return impl_->httpAddress; }
JobStore& Coordinator::store() { return *impl_->store; }
std::string Coordinator::metricsText() { return impl_->metricsText(); }

void Coordinator::shutdown() {
  {
    std::lock_guard lock(impl_->stopMutex);
    if (impl_->stopping) return;
    impl_->stopping = true;
  }
  impl_->stopChanged.notify_all();
  // In-flight calls get a moment to finish; a worker streaming a tree is cut off.
  impl_->server->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(5));
  if (impl_->httpThread.joinable()) {
    impl_->http.stop();
    impl_->httpThread.join();
  }
  if (impl_->expiryThread.joinable()) impl_->expiryThread.join();
}


}  // namespace pbgi::farm
