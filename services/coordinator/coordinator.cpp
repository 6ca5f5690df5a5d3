#include "services/coordinator/coordinator.h"

#include <cmath>
#include <filesystem>
#include <mutex>
#include <thread>

#include <fmt/format.h>
#include <grpcpp/grpcpp.h>
#include <httplib.h>

#include "core/render/integrators.h"
#include "core/util/log.h"
#include "core/util/status.h"
#include "formats/image/image_io.h"
#include "formats/image/ocio_config.h"
#include "pbgi/farm/v1/farm.grpc.pb.h"
#include "services/coordinator/coordinator_metrics.h"
#include "services/coordinator/dashboard/dashboard.h"
#include "services/coordinator/dashboard/frame_previews.h"
#include "services/coordinator/farm_activity.h"
#include "services/coordinator/farm_auth.h"
#include "services/coordinator/farm_service.h"
#include "services/coordinator/file_service.h"
#include "services/coordinator/lease_reaper.h"
#include "services/coordinator/page_service.h"
#include "services/coordinator/parsed_job_cache.h"
#include "services/coordinator/status_report.h"
#include "services/farm/farm_json.h"
#include "services/farm/farm_wire.h"
#include "services/farm/job_rules.h"
#include "services/render/frame_assembly.h"
#include "services/render/shot_check.h"

namespace pbgi::farm {

namespace fs = std::filesystem;

namespace {

grpc::Status toGrpc(const absl::Status& s) {
  if (s.ok()) return grpc::Status::OK;
  return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
}

std::optional<int> optionalFrame(const auto& request) {
  return request.has_frame() ? std::optional<int>(request.frame()) : std::nullopt;
}
std::optional<int> optionalTile(const auto& request) {
  return request.has_tile() ? std::optional<int>(request.tile()) : std::nullopt;
}

// The RPCs of pbgi.farm.v1.Coordinator, each a request turned into calls of the job store.
// Every call that reaches one bore the farm token (farm_auth.h checks it before any handler).
class FarmService final : public v1::Coordinator::Service {
 public:
  FarmService(const CoordinatorOptions& options, JobStore& store, ParsedJobCache& jobs,
              PageService& pages, CoordinatorMetrics& metrics, FarmActivity& activity)
      : options_(options),
        store_(store),
        jobs_(jobs),
        pages_(pages),
        metrics_(metrics),
        activity_(activity),
        files_(store, jobs) {}

  grpc::Status SubmitJob(grpc::ServerContext*, const v1::SubmitJobRequest* request,
                         v1::SubmitJobResponse* response) override {
    auto id = submit(*request);
    if (!id.ok()) {
      log::warn("refused job shot={}: {}", request->shot_path(), id.status().message());
      return toGrpc(id.status());
    }
    response->set_job(*id);
    activity_.changed();
    return grpc::Status::OK;
  }

  grpc::Status GetStatus(grpc::ServerContext*, const v1::GetStatusRequest* request,
                         v1::GetStatusResponse* response) override {
    auto s = statusReport(store_, jobs_, *request,
                          liveWorkers(store_, activity_, wallClock(), options_.leaseSeconds));
    if (!s.ok()) return toGrpc(s.status());
    *response = *std::move(s);
    return grpc::Status::OK;
  }

  grpc::Status CancelJob(grpc::ServerContext*, const v1::CancelJobRequest* request,
                         v1::CancelJobResponse*) override {
    return changed(store_.cancel(request->job()));
  }

  grpc::Status RetryJob(grpc::ServerContext*, const v1::RetryJobRequest* request,
                        v1::RetryJobResponse* response) override {
    auto outcome = retry(*request);
    if (!outcome.ok()) return toGrpc(outcome.status());
    *response = *std::move(outcome);
    return changed(absl::OkStatus());
  }

  grpc::Status GetLogs(grpc::ServerContext*, const v1::GetLogsRequest* request,
                       v1::GetLogsResponse* response) override {
    auto events = store_.events(request->job(), optionalFrame(*request), optionalTile(*request));
    if (!events.ok()) return toGrpc(events.status());
    int unknown = 0;
    std::string firstUnknown;
    for (const TaskEvent& e : *events) {
      v1::LogEntry* entry = response->add_entries();
      entry->set_time(e.time);
      entry->set_task(e.task);
      setKind(e.ref.kind, entry);
      entry->set_frame(e.ref.frame);
      entry->set_tile(e.ref.tile);
      entry->set_attempt(e.attempt);
      entry->set_worker(e.worker);
      if (const auto kind = parseTaskEventKind(e.event); kind.ok()) {
        setEvent(*kind, entry);
      } else {
        // A word this coordinator does not know (a newer one's, in a shared database): the
        // line is still shown, with its word and no enum, and reported here once per call.
        entry->set_event(e.event);
        if (unknown++ == 0) {
          firstUnknown =
              fmt::format("task {} attempt {}: {}", e.task, e.attempt, kind.status().message());
        }
      }
      entry->set_text(e.text);
    }
    if (unknown > 0) {
      log::warn(
          "logs job={}: {} event(s) of kinds this coordinator does not know, sent as words "
          "only; the first: {}",
          request->job(), unknown, firstUnknown);
    }
    return grpc::Status::OK;
  }

  grpc::Status RegisterWorker(grpc::ServerContext*, const v1::RegisterWorkerRequest* request,
                              v1::RegisterWorkerResponse* response) override {
    WorkerInfo w;
    w.id = request->worker();
    w.host = request->host();
    w.cores = request->cores();
    w.memoryBytes = request->memory_bytes();
    w.cacheBytes = request->cache_bytes();
    w.lastSeen = wallClock();
    if (absl::Status s = store_.registerWorker(w); !s.ok()) return toGrpc(s);
    log::info("registered worker={} cores={} memory={:.1f}GiB cache={:.0f}MiB", w.id, w.cores,
              double(w.memoryBytes) / (1 << 30), double(w.cacheBytes) / (1 << 20));
    response->set_lease_seconds(options_.leaseSeconds);
    return grpc::Status::OK;
  }

  grpc::Status ListWorkers(grpc::ServerContext*, const v1::ListWorkersRequest*,
                           v1::ListWorkersResponse* response) override {
    auto workers = store_.workers();
    if (!workers.ok()) return toGrpc(workers.status());
    const std::map<std::string, WorkerActivity> heard = activity_.workers();
    const Seconds now = wallClock();
    for (const WorkerInfo& w : *workers) {
      const auto it = heard.find(w.id);
      const WorkerActivity a = it == heard.end() ? WorkerActivity{} : it->second;
      v1::WorkerStatus* out = response->add_workers();
      out->set_worker(w.id);
      out->set_host(w.host);
      out->set_cores(w.cores);
      out->set_memory_bytes(w.memoryBytes);
      out->set_cache_bytes(w.cacheBytes);
      out->set_last_seen(w.lastSeen);
      out->set_last_heard(std::max(a.lastHeard, w.lastSeen));
      out->set_state(workerState(a, w.lastSeen, now, options_.leaseSeconds));
      out->set_current(a.current);
    }
    return grpc::Status::OK;
  }

  grpc::Status LeaseTask(grpc::ServerContext*, const v1::LeaseTaskRequest* request,
                         v1::LeaseTaskResponse* response) override {
    return lease(*request, response);
  }

  grpc::Status Heartbeat(grpc::ServerContext*, const v1::HeartbeatRequest* request,
                         v1::HeartbeatResponse* response) override {
    if (request->poll()) return pollLease(*request, response);
    const absl::Status s =
        request->audit()
            ? store_.heartbeatAudit(request->task(), request->attempt(), wallClock(),
                                    options_.leaseSeconds)
            : store_.heartbeat(request->task(), request->attempt(), request->progress(),
                               wallClock(), options_.leaseSeconds);
    if (s.ok())
      activity_.heartbeat(request->worker(), clampProgress(request->progress()), wallClock());
    return answerLease(s, response);
  }

  // A lost lease (a stale attempt, or a task or audit gone) is an answer, not an error: the
  // worker stops.
  static grpc::Status answerLease(const absl::Status& held, v1::HeartbeatResponse* response) {
    if (held.code() == absl::StatusCode::kFailedPrecondition ||
        held.code() == absl::StatusCode::kNotFound) {
      response->set_keep_going(false);
      return grpc::Status::OK;
    }
    response->set_keep_going(held.ok());
    return toGrpc(held);
  }

  // A read: whether the attempt still holds its lease (a cancel or retry took it, or the lease
  // expired), without extending it.
  grpc::Status pollLease(const v1::HeartbeatRequest& request, v1::HeartbeatResponse* response) {
    absl::Status held;
    if (request.audit()) {
      const absl::StatusOr<AuditInfo> audit = store_.audit(request.task());
      held = audit.ok() ? checkCurrentLease(*audit, request.attempt()) : audit.status();
    } else {
      const absl::StatusOr<TaskInfo> task = store_.task(request.task());
      held = task.ok() ? checkCurrentLease(*task, request.attempt()) : task.status();
    }
    return answerLease(held, response);
  }

  grpc::Status CompleteTask(grpc::ServerContext*, const v1::CompleteTaskRequest* request,
                            v1::CompleteTaskResponse* response) override {
    const grpc::Status done = request->audit() ? completeAudit(*request) : complete(*request);
    if (!done.ok() || !request->has_next()) return done;
    // The completion stands whatever the lease does: a lease that fails here leaves no next
    // task, and the worker asks again with LeaseTask.
    if (const grpc::Status leased = lease(request->next(), response->mutable_next());
        !leased.ok()) {
      response->clear_next();
      log::warn("worker={}: no next lease with its completion: {}", request->worker(),
                leased.error_message());
    }
    return grpc::Status::OK;
  }

  grpc::Status FailTask(grpc::ServerContext*, const v1::FailTaskRequest* request,
                        v1::FailTaskResponse*) override {
    const absl::Status s =
        request->audit()
            ? store_.failAudit(request->task(), request->attempt(), request->error(), wallClock())
            : store_.fail(request->task(), request->attempt(), request->error(), wallClock(),
                          request->log());
    if (!s.ok()) return toGrpc(s);
    metrics_.failures->add();
    activity_.taskFinished(request->worker(), false, 0, 0, 0, wallClock());
    log::warn("failed {}={} attempt={} worker={}: {}", request->audit() ? "audit" : "task",
              request->task(), request->attempt(), request->worker(), request->error());
    return grpc::Status::OK;
  }

  grpc::Status OpenTree(grpc::ServerContext*, const v1::OpenTreeRequest* request,
                        v1::OpenTreeResponse* response) override {
    return toGrpc(pages_.openTree(*request, response));
  }

  grpc::Status PutFile(grpc::ServerContext*, grpc::ServerReader<v1::PutFileChunk>* reader,
                       v1::PutFileResponse*) override {
    const absl::StatusOr<std::string> path =
        files_.put([reader](v1::PutFileChunk* chunk) { return reader->Read(chunk); });
    if (!path.ok()) {
      if (path.status().code() == absl::StatusCode::kFailedPrecondition) {
        metrics_.staleCompletions->add();  // an upload of a lost lease, like its completion
      }
      log::warn("refused an upload: {}", path.status().message());
      return toGrpc(path.status());
    }
    return grpc::Status::OK;
  }

  grpc::Status GetFile(grpc::ServerContext*, const v1::GetFileRequest* request,
                       grpc::ServerWriter<v1::FileChunk>* writer) override {
    return toGrpc(files_.get(
        *request, [writer](const v1::FileChunk& chunk) { return writer->Write(chunk); }));
  }

  grpc::Status FetchPages(grpc::ServerContext*, const v1::FetchPagesRequest* request,
                          grpc::ServerWriter<v1::PageChunk>* writer) override {
    return toGrpc(pages_.fetchPages(
        *request, [writer](const v1::PageChunk& chunk) { return writer->Write(chunk); }));
  }

 private:
  // LeaseTask's work, also done for a completion that asks for its worker's next task.
  grpc::Status lease(const v1::LeaseTaskRequest& request, v1::LeaseTaskResponse* response) {
    // A job whose stored shot no longer parses (a newer file format, a damaged row) must not
    // stop the farm: its task fails with the reason and the next one is offered.
    std::vector<HeldFrame> held;
    for (const v1::HeldFrame& h : request.held()) held.push_back({h.job(), h.frame()});
    const std::span<const HeldFrame> prefer =
        options_.localityDispatch ? std::span<const HeldFrame>(held) : std::span<const HeldFrame>();
    for (;;) {
      auto lease = store_.lease(request.worker(), wallClock(), options_.leaseSeconds, prefer);
      if (!lease.ok()) return toGrpc(lease.status());
      if (!lease->has_value()) {
        // Nothing of any job's frames is ready for this worker: an audit, if it runs them.
        std::optional<AuditLease> audit;
        if (request.runs_audits()) {
          auto a = store_.leaseAudit(request.worker(), wallClock(), options_.leaseSeconds);
          if (!a.ok()) return toGrpc(a.status());
          audit = *std::move(a);
        }
        if (audit) {
          auto view = jobs_.get(audit->job);
          if (!view.ok()) {
            (void)store_.failAudit(audit->audit, audit->attempt,
                                   std::string(view.status().message()), wallClock());
            continue;
          }
          activity_.leaseAsked(request.worker(), std::move(held),
                               auditLabel(audit->job, audit->spec.frame), wallClock());
          describeAudit(*audit, **view, response);
          return grpc::Status::OK;
        }
        activity_.leaseAsked(request.worker(), std::move(held), std::nullopt, wallClock());
        response->set_has_task(false);
        return grpc::Status::OK;
      }
      const Lease& l = **lease;
      auto view = jobs_.get(l.ref.job);
      if (!view.ok()) {
        (void)store_.fail(l.task, l.attempt, std::string(view.status().message()), wallClock());
        continue;
      }
      metrics_.leases->add();
      activity_.leaseAsked(request.worker(), std::move(held), l.ref.toString(), wallClock());
      describeLease(l, **view, response);
      return grpc::Status::OK;
    }
  }

  // CompleteTask's work for a task (not an audit).
  grpc::Status complete(const v1::CompleteTaskRequest& request) {
    const absl::StatusOr<TaskRef> done =
        store_.complete(request.task(), request.attempt(), wallClock(), request.log());
    if (done.status().code() == absl::StatusCode::kFailedPrecondition) {
      metrics_.staleCompletions->add();
      log::warn("dropped stale completion worker={}: {}", request.worker(),
                done.status().message());
    }
    if (!done.ok()) return toGrpc(done.status());
    metrics_.cacheHits->add(request.cache_hits());
    metrics_.cacheMisses->add(request.cache_misses());
    metrics_.treeBytesStreamed->add(request.tree_bytes_streamed());
    metrics_.taskSeconds->observe(toString(done->kind), request.seconds());
    activity_.taskTook(done->job, done->kind, request.seconds());
    activity_.taskFinished(request.worker(), true, request.cache_hits(), request.cache_misses(),
                           request.tree_bytes_streamed(), wallClock());
    return grpc::Status::OK;
  }

  // A store call's status; when it succeeded, the dashboard hears that a job changed.
  grpc::Status changed(const absl::Status& s) {
    if (s.ok()) activity_.changed();
    return toGrpc(s);
  }
  absl::StatusOr<int64_t> submit(const v1::SubmitJobRequest& request);
  absl::StatusOr<v1::RetryJobResponse> retry(const v1::RetryJobRequest& request);
  absl::Status planAudits(const v1::SubmitJobRequest& request, const ShotDesc& shot,
                          const IntegratorInfo& integrator, OutputFormat format,
                          JobSpec* spec) const;
  grpc::Status completeAudit(const v1::CompleteTaskRequest& request);
  void describeLease(const Lease& lease, const ParsedJob& view, v1::LeaseTaskResponse* out) const;
  void describeAudit(const AuditLease& audit, const ParsedJob& view,
                     v1::LeaseTaskResponse* out) const;

  const CoordinatorOptions& options_;
  JobStore& store_;
  ParsedJobCache& jobs_;
  PageService& pages_;
  CoordinatorMetrics& metrics_;
  FarmActivity& activity_;
  FileService files_;
};

absl::StatusOr<int64_t> FarmService::submit(const v1::SubmitJobRequest& request) {
  JobSpec spec;
  PBGI_ASSIGN_OR_RETURN(spec.overrides, submittedOverrides(request));
  PBGI_ASSIGN_OR_RETURN(const ShotDesc shot,
                        jobShot(request.shot_text(), request.shot_path(), spec.overrides));
  spec.name = shot.name;
  spec.shotPath = fs::absolute(request.shot_path()).lexically_normal().string();
  spec.shotText = request.shot_text();
  spec.priority = request.priority();
  if (request.frames().empty()) {
    for (int f = shot.firstFrame; f <= shot.lastFrame; ++f) spec.frames.push_back(f);
  }
  for (const int f : request.frames()) {
    PBGI_RETURN_IF_ERROR(checkShotFrame(shot, f));
    spec.frames.push_back(f);
  }
  // The first frame checked as `pbgi check` does, its scene loaded as a worker will load it:
  // geometry that does not parse, a texture that is not there, is refused now, naming the
  // file, rather than failing on every worker until the job stalls. (Frames share their
  // files; keyframes only move them.)
  if (!spec.frames.empty()) {
    PBGI_RETURN_IF_ERROR(checkShot(shot, {spec.frames.front()}, /*glossy=*/false).status());
  }
  std::string pattern = shot.output;
  if (!request.output_dir().empty()) {
    const fs::path dir = fs::path(request.output_dir()).is_absolute()
                             ? fs::path(request.output_dir())
                             : fs::path(options_.outputRoot) / request.output_dir();
    pattern = (dir / fs::path(shot.output).filename()).string();
  }
  PBGI_ASSIGN_OR_RETURN(spec.outputPattern, confineToRoot(pattern, options_.outputRoot));
  PBGI_ASSIGN_OR_RETURN(const OutputFormat format, outputFormatFor(spec.outputPattern));
  spec.tileCount = static_cast<int>(farmTiles(shot, jobs_.tileSize()).size());
  PBGI_ASSIGN_OR_RETURN(const IntegratorInfo* integrator, findIntegrator(shot.render.integrator));
  spec.needsBake = integrator->needsTree;
  PBGI_RETURN_IF_ERROR(planAudits(request, shot, *integrator, format, &spec));
  PBGI_ASSIGN_OR_RETURN(const int64_t id, store_.submit(spec, wallClock()));
  std::error_code ec;
  fs::create_directories(jobs_.workDir(id), ec);
  log::info("submitted job={} shot={} frames={} tiles={} integrator={} output={}", id, spec.name,
            spec.frames.size(), spec.tileCount, shot.render.integrator, spec.outputPattern);
  return id;
}

// What a retry will revive is read first (the store's retry changes it all in one
// transaction; a task that dies between the two reads is counted the next time).
absl::StatusOr<v1::RetryJobResponse> FarmService::retry(const v1::RetryJobRequest& request) {
  const std::optional<int> frame = optionalFrame(request), tile = optionalTile(request);
  PBGI_ASSIGN_OR_RETURN(const std::vector<TaskInfo> tasks, store_.tasks(request.job()));
  PBGI_ASSIGN_OR_RETURN(const std::vector<AuditInfo> audits, store_.audits(request.job()));
  PBGI_ASSIGN_OR_RETURN(const std::vector<std::string> blocked,
                        store_.blocklistedWorkers(request.job()));
  v1::RetryJobResponse response;
  for (const TaskInfo& t : tasks) {
    const bool revived = t.state == TaskState::kDead || t.state == TaskState::kCancelled;
    const bool matches = (!frame || t.ref.frame == *frame) &&
                         (!tile || t.ref.kind != TaskKind::kTile || t.ref.tile == *tile);
    if (revived && matches) response.set_tasks(response.tasks() + 1);
  }
  for (const AuditInfo& a : audits) {
    const bool revived = a.state == AuditState::kFailed || a.state == AuditState::kCancelled;
    if (revived && (!frame || a.spec.frame == *frame)) response.set_audits(response.audits() + 1);
  }
  for (const std::string& w : blocked) response.add_unblocked_workers(w);
  PBGI_RETURN_IF_ERROR(store_.retry(request.job(), frame, tile, wallClock()));
  log::info("retried job={} frame={} tile={}: {} tasks, {} audits, {} workers unblocked",
            request.job(), frame ? std::to_string(*frame) : "all",
            tile ? std::to_string(*tile) : "all", response.tasks(), response.audits(),
            blocked.size());
  return response;
}

// The job's accuracy audits: per frame, tiles chosen by the seeded rule, unless the request
// or the integrator (the path tracer is its own reference) says none. An audit compares the
// frame's linear light, so a frame written in 8 bits has none by default and refuses one
// asked for.
absl::Status FarmService::planAudits(const v1::SubmitJobRequest& request, const ShotDesc& shot,
                                     const IntegratorInfo& integrator, OutputFormat format,
                                     JobSpec* spec) const {
  const bool hdr = format != OutputFormat::kDisplay8;
  const int tiles = request.has_audit_tiles()     ? request.audit_tiles()
                    : integrator.needsTree && hdr ? kDefaultAuditTiles
                                                  : 0;
  if (tiles > 0 && !hdr) {
    return absl::InvalidArgumentError(fmt::format(
        "an audit of {} tiles compares the frame's linear light, which {} does not hold in 8 "
        "bits: write .exr (the shot's output or --output-dir) or pass --audit-tiles 0",
        tiles, spec->outputPattern));
  }
  const int spp = request.audit_spp() != 0 ? request.audit_spp() : kDefaultAuditSpp;
  const double threshold =
      request.audit_threshold() != 0 ? request.audit_threshold() : kDefaultAuditThreshold;
  if (tiles < 0 || spp < 0 || !(std::isfinite(threshold) && threshold > 0)) {
    return absl::InvalidArgumentError(fmt::format(
        "audit of {} tiles at {} spp, threshold {}: expected tiles >= 0, spp >= 0 and a "
        "positive threshold",
        tiles, spp, threshold));
  }
  if (tiles == 0) return absl::OkStatus();
  for (const int f : spec->frames) {
    spec->audits.push_back(
        {f, chooseAuditTiles(shot.name, f, spec->tileCount, tiles), spp, threshold});
  }
  return absl::OkStatus();
}

grpc::Status FarmService::completeAudit(const v1::CompleteTaskRequest& request) {
  AuditResult result;
  result.relMse = request.audit_rel_mse();
  result.bias = request.audit_bias();
  result.seconds = request.seconds();
  if (!std::isfinite(result.relMse) || !std::isfinite(result.bias) || result.relMse < 0) {
    // A result that is no measurement is a failed audit, not a number on the dashboard.
    const std::string error = fmt::format("the audit's result is not a measurement: relMSE {}, "
                                          "bias {}", result.relMse, result.bias);
    return changed(store_.failAudit(request.task(), request.attempt(), error, wallClock()));
  }
  const absl::Status s = store_.completeAudit(request.task(), request.attempt(), result, wallClock());
  if (s.code() == absl::StatusCode::kFailedPrecondition) metrics_.staleCompletions->add();
  if (!s.ok()) return toGrpc(s);
  activity_.taskFinished(request.worker(), true, 0, 0, 0, wallClock());
  log::info("audit={} worker={}: relMSE {:.4g}, bias {:+.2f} %", request.task(), request.worker(),
            result.relMse, 100.0 * result.bias);
  return grpc::Status::OK;
}

namespace {

// The shot a leased task renders: its text and the job's overrides (typed, and as text for
// workers from before the typed form).
void describeShot(const JobSpec& spec, v1::LeaseTaskResponse* response) {
  response->set_shot_path(spec.shotPath);
  response->set_shot_text(spec.shotText);
  *response->mutable_render() = toWire(spec.overrides);
  for (const std::string& line : overrideLines(spec.overrides)) response->add_overrides(line);
}

}  // namespace

// What a worker needs to audit a frame: the shot, the assembled frame, the tiles and samples.
void FarmService::describeAudit(const AuditLease& audit, const ParsedJob& view,
                                v1::LeaseTaskResponse* response) const {
  const JobSpec& spec = view.spec;
  response->set_has_task(true);
  response->set_task(audit.audit);
  response->set_attempt(audit.attempt);
  setAuditKind(response);
  response->set_job(audit.job);
  response->set_frame(audit.spec.frame);
  response->set_tile(-1);
  describeShot(spec, response);
  response->set_work_dir(jobs_.workDir(audit.job));
  response->set_output_path(ParsedJobCache::frameOutput(view, audit.spec.frame));
  for (const int t : audit.spec.tiles) response->add_audit_tiles(t);
  response->set_audit_spp(audit.spec.spp);
  response->set_lease_seconds(options_.leaseSeconds);
  response->set_tiles_per_frame(spec.tileCount);
  response->set_tile_size(jobs_.tileSize());
}

// What a worker needs to run the leased task: the shot, where its result goes, its tile.
void FarmService::describeLease(const Lease& l, const ParsedJob& view,
                                v1::LeaseTaskResponse* response) const {
  const JobSpec& spec = view.spec;
  response->set_has_task(true);
  response->set_task(l.task);
  response->set_attempt(l.attempt);
  setKind(l.ref.kind, response);
  response->set_job(l.ref.job);
  response->set_frame(l.ref.frame);
  response->set_tile(l.ref.tile);
  describeShot(spec, response);
  const std::string dir = jobs_.workDir(l.ref.job);
  response->set_work_dir(dir);
  switch (l.ref.kind) {
    case TaskKind::kBake:
      response->set_output_path(jobBakeDir(dir));
      break;
    case TaskKind::kTile: {
      response->set_output_path(farmTilePath(dir, l.ref.frame, l.ref.tile));
      // The tile's rectangles of the mosaic frame, explicitly.
      const std::vector<FarmTile>& tiles = view.tiles;
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
      response->set_output_path(ParsedJobCache::frameOutput(view, l.ref.frame));
      break;
  }
  response->set_lease_seconds(options_.leaseSeconds);
  response->set_tiles_per_frame(spec.tileCount);
  response->set_tile_size(jobs_.tileSize());
}

}  // namespace

std::unique_ptr<v1::Coordinator::Service> makeFarmService(const CoordinatorOptions& options,
                                                          JobStore& store, ParsedJobCache& jobs,
                                                          PageService& pages,
                                                          CoordinatorMetrics& metrics,
                                                          FarmActivity& activity) {
  return std::make_unique<FarmService>(options, store, jobs, pages, metrics, activity);
}

// The coordinator's parts, in the order they are made (and the reverse of their ending).
struct Coordinator::Impl {
  CoordinatorOptions options;
  std::unique_ptr<JobStore> store;
  std::shared_ptr<CoordinatorMetrics> metrics;  // shared with the token check (farm_auth.h)
  std::unique_ptr<ParsedJobCache> jobs;
  std::unique_ptr<PageService> pages;
  FarmActivity activity;
  std::unique_ptr<FramePreviews> previews;
  std::unique_ptr<FarmService> service;
  std::unique_ptr<grpc::Server> server;
  std::string address;
  std::string transport;  // for the log: "plaintext", "TLS", ...

  httplib::Server http;
  std::unique_ptr<DashboardParts> dashboard;  // what the page's handlers read
  std::string httpAddress;
  std::thread httpThread;

  std::unique_ptr<LeaseReaper> reaper;

  std::mutex stopMutex;
  bool stopped = false;

  absl::Status listen();
  absl::Status serveHttp();
};

absl::Status Coordinator::Impl::listen() {
  PBGI_ASSIGN_OR_RETURN(const std::optional<TlsPem> tls, readServerTls(options.tls));
  if (tls) watchTlsHandshakes();
  transport = !tls ? "plaintext" : tls->ca.empty() ? "TLS" : "TLS, client certificates required";
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(
      options.listen,
      coordinatorCredentials(tls, options.token, !options.readsNeedToken,
                             std::shared_ptr<metrics::Counter>(metrics, metrics->refused)),
      &port);
  builder.RegisterService(service.get());
  builder.SetMaxReceiveMessageSize(64 << 20);
  // gRPC's sync server keeps 1 to 2 idle polling threads by default, starts a thread for each
  // call it takes beyond them and ends it afterwards: with handlers that wait on a group commit,
  // a thread made and unmade per call (perf: clone, mprotect, munmap). More idle ones keep
  // lease round trips from paying for a thread each (farm_bench measures them; README).
  builder.SetSyncServerOption(grpc::ServerBuilder::SyncServerOption::MIN_POLLERS, 16);
  builder.SetSyncServerOption(grpc::ServerBuilder::SyncServerOption::MAX_POLLERS, 256);
  server = builder.BuildAndStart();
  if (server == nullptr || port == 0) {
    return absl::UnavailableError(fmt::format("cannot listen on {} (in use?)", options.listen));
  }
  const std::string host = options.listen.substr(0, options.listen.rfind(':'));
  address = fmt::format("{}:{}", host, port);
  return absl::OkStatus();
}

absl::Status Coordinator::Impl::serveHttp() {
  http.Get("/metrics", [this](const httplib::Request&, httplib::Response& res) {
    res.set_content(metrics->registry.text(), "text/plain; version=0.0.4");
  });
  http.Get("/status", [this](const httplib::Request&, httplib::Response& res) {
    auto status = statusReport(*store, *jobs, v1::GetStatusRequest(),
                               liveWorkers(*store, activity, wallClock(), options.leaseSeconds));
    if (!status.ok()) {
      res.status = 500;
      res.set_content(std::string(status.status().message()), "text/plain");
      return;
    }
    res.set_content(toJson(*status), "application/json");
  });
  previews = std::make_unique<FramePreviews>(defaultOcioConfigPath());
  dashboard = std::make_unique<DashboardParts>(
      DashboardParts{*store, *jobs, activity, *previews, *metrics->refused, options.token,
                     isPostgresUri(options.store), options.leaseSeconds, options.readsNeedToken});
  addDashboard(http, *dashboard);
  const size_t colon = options.httpListen.rfind(':');
  const std::string httpHost = options.httpListen.substr(0, colon);
  int httpPort = colon == std::string::npos ? 0 : std::atoi(options.httpListen.c_str() + colon + 1);
  if (httpPort == 0) {
    httpPort = http.bind_to_any_port(httpHost);
  } else if (!http.bind_to_port(httpHost, httpPort)) {
    httpPort = -1;
  }
  if (httpPort <= 0) {
    return absl::UnavailableError(
        fmt::format("cannot listen for HTTP on {} (in use?)", options.httpListen));
  }
  httpAddress = fmt::format("{}:{}", httpHost, httpPort);
  httpThread = std::thread([this] { http.listen_after_bind(); });
  return absl::OkStatus();
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
  impl->metrics = std::make_shared<CoordinatorMetrics>(*impl->store);
  impl->jobs = std::make_unique<ParsedJobCache>(
      *impl->store, impl->options.stateDir,
      options.tileSize > 0 ? options.tileSize : kDefaultFarmTileSize);
  impl->pages = std::make_unique<PageService>(*impl->jobs, *impl->metrics);
  impl->service = std::make_unique<FarmService>(impl->options, *impl->store, *impl->jobs,
                                                *impl->pages, *impl->metrics, impl->activity);
  // The lease period of grace after a start begins here, before any worker can call.
  impl->reaper = std::make_unique<LeaseReaper>(
      *impl->store, *impl->metrics->expired, options.leaseSeconds, options.expiryIntervalSeconds,
      [activity = &impl->activity](const std::vector<ExpiredLease>& expired) {
        for (const ExpiredLease& e : expired) activity->leaseExpired(e.worker, e.what);
        activity->changed();
      });
  PBGI_RETURN_IF_ERROR(impl->listen());
  if (!options.httpListen.empty()) {
    if (absl::Status s = impl->serveHttp(); !s.ok()) {
      impl->server->Shutdown();
      return s;
    }
  }
  log::info(
      "coordinator on {} ({}; state {}, output root {}{})", impl->address, impl->transport,
      impl->options.stateDir, impl->options.outputRoot,
      impl->httpAddress.empty()
          ? ""
          : ", dashboard on http://" + impl->httpAddress + "/, metrics at /metrics");
  return std::unique_ptr<Coordinator>(new Coordinator(std::move(impl)));
}

const std::string& Coordinator::address() const { return impl_->address; }
const std::string& Coordinator::httpAddress() const { return impl_->httpAddress; }
JobStore& Coordinator::store() { return *impl_->store; }
std::string Coordinator::metricsText() { return impl_->metrics->registry.text(); }

void Coordinator::shutdown() {
  {
    std::lock_guard lock(impl_->stopMutex);
    if (impl_->stopped) return;
    impl_->stopped = true;
  }
  // In-flight calls get a moment to finish; a worker streaming a tree is cut off.
  impl_->server->Shutdown(std::chrono::system_clock::now() + std::chrono::seconds(5));
  if (impl_->httpThread.joinable()) {
    impl_->activity.stop();  // the dashboard's event streams end
    impl_->http.stop();
    impl_->httpThread.join();
  }
  impl_->reaper->stop();
}

}  // namespace pbgi::farm
