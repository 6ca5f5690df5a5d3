#include "services/worker/worker.h"

#include <algorithm>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <functional>
#include <map>
#include <mutex>
#include <optional>
#include <thread>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <malloc.h>
#include <unistd.h>

#include <cstdio>
#include <memory>

#include "core/render/integrators.h"
#include "core/util/log.h"
#include "core/util/status.h"
#include "formats/image/compare.h"
#include "formats/image/image_io.h"
#include "formats/pbgi/remote_page_file.h"
#include "formats/pbgi/tree_file.h"
#include "formats/scene/frame_scene.h"
#include "services/bake/frame_bake.h"
#include "services/farm/farm_client.h"
#include "services/farm/farm_model.h"
#include "services/farm/farm_wire.h"
#include "services/farm/job_rules.h"
#include "services/render/frame_assembly.h"
#include "services/render/frame_render.h"

namespace pbgi::farm {

namespace fs = std::filesystem;

namespace {

using Clock = std::chrono::steady_clock;

std::string hostName() {
  char name[256] = {};
  if (::gethostname(name, sizeof name - 1) != 0) return "localhost";
  return name;
}

// Resident memory of this process (bytes), after handing freed heap back to the system.
uint64_t residentBytes() {
  ::malloc_trim(0);
  long pages = 0, resident = 0;
  if (std::FILE* f = std::fopen("/proc/self/statm", "r")) {
    if (std::fscanf(f, "%ld %ld", &pages, &resident) != 2) resident = 0;
    std::fclose(f);
  }
  return resident > 0 ? uint64_t(resident) * uint64_t(::sysconf(_SC_PAGESIZE)) : 0;
}

// The frames' scenes a worker keeps between tasks: a bake and the tiles of its frame load the
// scene once. Found by the shot's bytes, its folder and the frame; each counted at the
// resident memory its loading took; the least recently used goes first when the budget is
// exceeded (a scene bigger than the whole budget is used once and not kept).
class SceneKeeper {
 public:
  explicit SceneKeeper(size_t budgetBytes) : budget_(budgetBytes) {}

  // The frame's scene, and a line for the task's log.
  absl::StatusOr<std::shared_ptr<const FrameScene>> get(const ShotDesc& shot, int frame,
                                                        std::string* log) {
    ++clock_;
    for (Entry& e : entries_) {
      if (e.frame == frame && e.dir == shot.dir && e.source == shot.source) {
        e.lastUse = clock_;
        *log += fmt::format("scene: kept from an earlier task ({} MiB; {} kept, {} MiB)\n",
                            e.bytes >> 20, entries_.size(), total() >> 20);
        return e.scene;
      }
    }
    const uint64_t before = residentBytes();
    PBGI_ASSIGN_OR_RETURN(FrameScene loaded, loadFrameScene(shot, frame));
    auto scene = std::make_shared<const FrameScene>(std::move(loaded));
    const uint64_t after = residentBytes();
    const size_t bytes = after > before ? after - before : 0;
    if (bytes > budget_ || budget_ == 0) {
      *log += fmt::format("scene: loaded ({} MiB, over the {} MiB kept between tasks: not kept)\n",
                          bytes >> 20, budget_ >> 20);
      return scene;
    }
    entries_.push_back({frame, shot.source, shot.dir, scene, bytes, clock_});
    while (total() > budget_) {
      auto oldest = std::min_element(entries_.begin(), entries_.end(),
                                     [](const Entry& a, const Entry& b) { return a.lastUse < b.lastUse; });
      entries_.erase(oldest);
    }
    *log += fmt::format("scene: loaded ({} MiB; {} kept, {} MiB of {} MiB)\n", bytes >> 20,
                        entries_.size(), total() >> 20, budget_ >> 20);
    return scene;
  }

 private:
  struct Entry {
    int frame;
    std::string source, dir;
    std::shared_ptr<const FrameScene> scene;
    size_t bytes;
    uint64_t lastUse;
  };
  size_t total() const {
    size_t sum = 0;
    for (const Entry& e : entries_) sum += e.bytes;
    return sum;
  }
  size_t budget_;
  uint64_t clock_ = 0;
  std::vector<Entry> entries_;
};

uint64_t physicalMemory() {
  const long pages = ::sysconf(_SC_PHYS_PAGES);
  const long pageSize = ::sysconf(_SC_PAGESIZE);
  return pages > 0 && pageSize > 0 ? uint64_t(pages) * uint64_t(pageSize) : 0;
}

// "tile=7", "bake", "assemble": for log lines.
std::string taskLabel(const v1::LeaseTaskResponse& task) {
  const v1::TaskKind kind = taskKindOf(task);
  return kind == v1::TASK_KIND_TILE ? fmt::format("tile={}", task.tile()) : wireWord(kind);
}

void sleepUnlessStopped(double seconds, const std::atomic<bool>& stop) {
  const auto until = Clock::now() + std::chrono::duration<double>(seconds);
  while (!stop.load() && Clock::now() < until) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
  }
}

// Reports progress and keeps the lease alive while a task runs. Between beats it polls (a read
// at the coordinator) so that a cancel, a retry or an expiry stops the task within a second:
// lost() is then set, and the renders given cancelFlag() stop at their next pixel.
class Heartbeat {
 public:
  Heartbeat(FarmClient& client, const std::string& worker, const v1::LeaseTaskResponse& task)
      : client_(client) {
    request_.set_worker(worker);
    request_.set_task(task.task());
    request_.set_attempt(task.attempt());
    request_.set_audit(taskKindOf(task) == v1::TASK_KIND_AUDIT);
    // Four beats per lease: one lost call does not lose the lease.
    const double period = std::clamp(task.lease_seconds() / 4.0, 0.05, 10.0);
    thread_ = std::thread([this, period] { loop(period, std::min(period, kPollSeconds)); });
  }
  ~Heartbeat() {
    {
      std::lock_guard lock(mutex_);
      done_ = true;
    }
    changed_.notify_all();
    thread_.join();
  }
  void progress(double fraction) { progress_.store(fraction); }
  bool lost() const { return lost_.load(); }
  const std::atomic<bool>* cancelFlag() const { return &lost_; }

 private:
  static constexpr double kPollSeconds = 0.4;

  void loop(double period, double pollPeriod) {
    std::unique_lock lock(mutex_);
    auto nextBeat = Clock::now() + std::chrono::duration<double>(period);
    while (!done_ && !lost_.load()) {
      changed_.wait_for(lock, std::chrono::duration<double>(pollPeriod));
      if (done_) break;
      lock.unlock();
      const bool beat = Clock::now() >= nextBeat;
      if (beat) nextBeat = Clock::now() + std::chrono::duration<double>(period);
      request_.set_poll(!beat);
      request_.set_progress(progress_.load());
      auto answer = client_.heartbeat(request_);
      if (answer.ok() && !answer->keep_going() && !lost_.exchange(true)) {
        log::warn(
            "task={} attempt={}: the lease is lost (expired, or the job was cancelled or "
            "retried); stopping the task",
            request_.task(), request_.attempt());
      }
      lock.lock();
    }
  }

  FarmClient& client_;
  v1::HeartbeatRequest request_;
  std::atomic<double> progress_{0.0};
  std::atomic<bool> lost_{false};
  std::mutex mutex_;
  std::condition_variable changed_;
  bool done_ = false;
  std::thread thread_;
};

// A frame's tree read through the page service, and what it has cost so far.
struct RemoteTree {
  std::shared_ptr<TreeFile> tree;
  std::shared_ptr<RemoteFetchStats> stats;
};

struct TaskResult {
  std::string log;
  uint64_t cacheHits = 0;
  uint64_t cacheMisses = 0;
  uint64_t treeBytesStreamed = 0;
  std::optional<AuditResult> audit;  // an audit's measurement
};

class Worker {
 public:
  Worker(const WorkerOptions& options, std::string id)
      : options_(options),
        id_(std::move(id)),
        client_(options.coordinator, options.token, 30.0, options.tls),
        scenes_(options.sceneCacheBytes) {
    cacheDir_ = options.cacheDir.empty()
                    ? (fs::temp_directory_path() / fmt::format("pbgi-worker-{}", sanitized(id_)))
                          .string()
                    : options.cacheDir;
  }

  int run(const std::atomic<bool>& stop);

 private:
  static std::string sanitized(std::string text) {
    for (char& c : text) {
      if (!std::isalnum(static_cast<unsigned char>(c)) && c != '-' && c != '_') c = '_';
    }
    return text;
  }

  absl::StatusOr<TaskResult> execute(const v1::LeaseTaskResponse& task, Heartbeat& beat);
  absl::StatusOr<TaskResult> bake(const ShotDesc& shot, const v1::LeaseTaskResponse& task,
                                  Heartbeat& beat);
  absl::StatusOr<TaskResult> tile(const ShotDesc& shot, const v1::LeaseTaskResponse& task,
                                  Heartbeat& beat);
  absl::StatusOr<TaskResult> assemble(const ShotDesc& shot, const v1::LeaseTaskResponse& task);
  absl::StatusOr<TaskResult> audit(const ShotDesc& shot, const v1::LeaseTaskResponse& task,
                                   Heartbeat& beat);
  // A worker that does not see the job folder works in a copy of it (FileSource): the lease
  // with its paths moved there, the inputs fetched before and the results sent after.
  bool worksInCopy(const v1::LeaseTaskResponse& task) const;
  v1::LeaseTaskResponse inCopy(const v1::LeaseTaskResponse& task) const;
  absl::Status fetchInputs(const ShotDesc& shot, const v1::LeaseTaskResponse& copy);
  absl::Status sendResults(const ShotDesc& shot, const v1::LeaseTaskResponse& copy,
                           std::string* log);
  // Sends a task's result; with `next`, asks for the next task in the same call, and returns
  // it when the coordinator took the result.
  std::optional<v1::LeaseTaskResponse> report(const v1::LeaseTaskResponse& task,
                                              const absl::StatusOr<TaskResult>& result,
                                              double seconds, const v1::LeaseTaskRequest* next);

  // The disk cache of streamed pages, opened at the first tile that streams.
  absl::StatusOr<std::shared_ptr<PageDiskCache>> pageDisk();

  // Remembers that this worker holds the frame's scene and pages now, most recent first.
  void hold(int64_t job, int frame);
  // A frame's tree through the page service, opened (its head fetched) once and kept while the
  // worker holds the frame. `opened`: whether this call opened it.
  absl::StatusOr<RemoteTree> remoteTree(int64_t job, int frame, bool* opened);

  const WorkerOptions& options_;
  const std::string id_;
  FarmClient client_;
  std::vector<HeldFrame> held_;
  std::map<std::pair<int64_t, int>, RemoteTree> remoteTrees_;
  std::string cacheDir_;
  SceneKeeper scenes_;
  std::shared_ptr<PageDiskCache> pageDisk_;
};

void Worker::hold(int64_t job, int frame) {
  // As many as the scenes kept between tasks could hold; the oldest drop off.
  constexpr size_t kHeldFrames = 8;
  std::erase(held_, HeldFrame{job, frame});
  held_.insert(held_.begin(), HeldFrame{job, frame});
  if (held_.size() > kHeldFrames) held_.resize(kHeldFrames);
  std::erase_if(remoteTrees_, [&](const auto& t) {
    return std::find(held_.begin(), held_.end(), HeldFrame{t.first.first, t.first.second}) ==
           held_.end();
  });
}

absl::StatusOr<RemoteTree> Worker::remoteTree(int64_t job, int frame, bool* opened) {
  *opened = false;
  if (auto it = remoteTrees_.find({job, frame}); it != remoteTrees_.end()) return it->second;
  PBGI_ASSIGN_OR_RETURN(std::shared_ptr<PageDiskCache> disk, pageDisk());
  auto fetcher = std::make_shared<FarmPageFetcher>(client_, job, frame);
  PBGI_ASSIGN_OR_RETURN(PageFileHead head, fetcher->head());
  RemoteTree remote{.stats = std::make_shared<RemoteFetchStats>()};
  PBGI_ASSIGN_OR_RETURN(remote.tree,
                        TreeFile::open(openRemotePageFile(std::move(head), fetcher, disk,
                                                          remote.stats)));
  *opened = true;
  remoteTrees_[{job, frame}] = remote;
  return remote;
}

absl::StatusOr<std::shared_ptr<PageDiskCache>> Worker::pageDisk() {
  if (!pageDisk_) {
    PBGI_ASSIGN_OR_RETURN(pageDisk_,
                          PageDiskCache::open((fs::path(cacheDir_) / "pages").string(),
                                              options_.diskCacheBytes));
  }
  return pageDisk_;
}

absl::StatusOr<TaskResult> Worker::bake(const ShotDesc& shot, const v1::LeaseTaskResponse& task,
                                        Heartbeat& beat) {
  PBGI_ASSIGN_OR_RETURN(FrameBakeRequest request, shotBakeRequest(shot, task.frame()));
  request.outDir = task.output_path();
  request.threads = options_.threads;
  request.progress = [&beat](const std::string&, uint64_t done, uint64_t total) {
    if (total > 0) beat.progress(double(done) / double(total));
  };
  request.cancel = beat.cancelFlag();
  TaskResult result;
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const FrameScene> scene,
                        scenes_.get(shot, task.frame(), &result.log));
  PBGI_ASSIGN_OR_RETURN(const FrameBakeReport report,
                        bakeShotFrame(shot, request, scene->scene.get()));
  for (const std::string& w : scene->warnings) result.log += "warning: " + w + "\n";
  result.log += fmt::format("tree {} ({} bytes)\n{}", report.treePath, report.treeFileBytes,
                            formatStages(report.stages));
  for (const std::string& w : report.warnings) result.log += "warning: " + w + "\n";
  return result;
}

absl::StatusOr<TaskResult> Worker::tile(const ShotDesc& shot, const v1::LeaseTaskResponse& task,
                                        Heartbeat& beat) {
  // The tile's rectangles come with the lease; they must be this frame's.
  const std::vector<FarmTile> tiles = farmTiles(shot, task.tile_size());
  std::vector<TileRect> regions;
  for (const v1::Rect& r : task.regions()) regions.push_back({r.x0(), r.y0(), r.x1(), r.y1()});
  if (task.tile() < 0 || static_cast<size_t>(task.tile()) >= tiles.size() ||
      static_cast<int>(tiles.size()) != task.tiles_per_frame() ||
      regions != tiles[static_cast<size_t>(task.tile())]) {
    return absl::InvalidArgumentError(fmt::format(
        "tile {} of {} at tile size {} with regions '{}': this worker makes {} tiles of a {}x{} "
        "frame of {}x{} views",
        task.tile(), task.tiles_per_frame(), task.tile_size(), regionsText(regions), tiles.size(),
        shot.width, shot.height, shot.camera.views.x, shot.camera.views.y));
  }
  FrameRenderRequest request;
  request.frame = task.frame();
  request.threads = options_.threads;
  request.outPath = task.output_path();
  request.preview = false;
  request.output = OutputOptions{};  // every layer, losslessly: the assembly applies the job's
  request.regions = regions;
  request.cacheBytes = options_.cacheBytes;
  request.bakeDir = jobBakeDir(task.work_dir());
  request.progress = [&beat](int done, int total) {
    if (total > 0) beat.progress(double(done) / double(total));
  };
  request.cancel = beat.cancelFlag();
  TaskResult result;
  RemoteTree remote;
  bool opened = false;
  RemoteFetchCounts before;
  PBGI_ASSIGN_OR_RETURN(const IntegratorInfo* integrator, findIntegrator(shot.render.integrator));
  if (integrator->needsTree) {
    // The bake task made the tree; a tile never bakes one of its own.
    PBGI_ASSIGN_OR_RETURN(const std::string shared,
                          jobTreePath(shot, task.work_dir(), task.frame()));
    const bool visible = fs::exists(shared);
    if (options_.treeSource == TreeSource::kShared && !visible) {
      return absl::NotFoundError(fmt::format(
          "{}: the frame's tree is not visible here (run the worker with --tree-source auto to "
          "stream it from the coordinator)",
          shared));
    }
    if (options_.treeSource == TreeSource::kStream ||
        (options_.treeSource == TreeSource::kAuto && !visible)) {
      // Single pages as the traversals reach them, through this worker's disk cache; the tree
      // stays open for the frame's later tiles.
      PBGI_ASSIGN_OR_RETURN(remote, remoteTree(task.job(), task.frame(), &opened));
      before = remote.stats->counts();
      request.openTree = [tree = remote.tree]() -> absl::StatusOr<std::shared_ptr<TreeFile>> {
        return tree;
      };
    } else {
      request.treePath = shared;
    }
  }
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const FrameScene> scene,
                        scenes_.get(shot, task.frame(), &result.log));
  request.scene = scene.get();
  PBGI_ASSIGN_OR_RETURN(const FrameRenderReport report, renderShotFrame(shot, request));
  result.log += fmt::format("wrote {} (regions {})\n{}", report.imagePath,
                            regionsText(request.regions), formatStages(report.stages));
  if (report.tree) {
    result.cacheHits = report.tree->cache.hits;
    result.cacheMisses = report.tree->cache.misses;
    result.log += fmt::format("tree {}; cache {}; pages read {} of {}\n", report.tree->treePath,
                              report.tree->cache.toString(), report.tree->pagesRead,
                              report.tree->pagesInFile);
  }
  if (remote.tree) {
    // What the tile cost the network, against the file.
    const RemoteFetchCounts cost = remote.stats->counts() - before;
    const uint64_t headBytes = opened ? remote.stats->headBytes.load() : 0;
    result.treeBytesStreamed = headBytes + cost.bytesFetched;
    result.log += fmt::format(
        "pages over the network {} ({} bytes) and the head ({} bytes{}): {} of the file's {} "
        "bytes; pages from the disk cache {}; damaged on the way and fetched again {}\n",
        cost.pagesFetched, cost.bytesFetched, headBytes,
        opened ? "" : ", open from an earlier tile", result.treeBytesStreamed,
        remote.tree->container().info().fileSize, cost.diskHits, cost.damaged);
  }
  result.log += fmt::format("samples {}, discarded (NaN/Inf) {}\n", report.counters.cameraSamples,
                            report.counters.discardedSamples);
  result.log += formatCounters(report);
  for (const std::string& w : report.warnings) result.log += "warning: " + w + "\n";
  return result;
}

absl::StatusOr<TaskResult> Worker::assemble(const ShotDesc& shot,
                                            const v1::LeaseTaskResponse& task) {
  const std::vector<FarmTile> tiles = farmTiles(shot, task.tile_size());
  std::vector<std::string> paths;
  for (size_t t = 0; t < tiles.size(); ++t) {
    paths.push_back(farmTilePath(task.work_dir(), task.frame(), static_cast<int>(t)));
  }
  std::vector<std::string> warnings;
  PBGI_ASSIGN_OR_RETURN(const Image frame,
                        assembleFrame(paths, tiles, shot.width * shot.camera.views.x,
                                      shot.height * shot.camera.views.y, task.output_path(),
                                      &warnings, shot.outputOptions));
  TaskResult result;
  result.log = fmt::format("assembled {} tiles into {}\n", tiles.size(), task.output_path());
  const std::string preview = writePreviewBeside(frame, task.output_path(), "", &warnings);
  if (!preview.empty()) result.log += fmt::format("preview {}\n", preview);
  for (const std::string& w : warnings) result.log += "warning: " + w + "\n";
  return result;
}

// The frame's audit: the window of each audited tile (auditWindows) path traced at the
// audit's spp (into the job folder's audit/ beside the tiles) and compared with the same
// pixels of the assembled frame.
absl::StatusOr<TaskResult> Worker::audit(const ShotDesc& shot, const v1::LeaseTaskResponse& task,
                                         Heartbeat& beat) {
  const std::vector<FarmTile> tiles = farmTiles(shot, task.tile_size());
  if (static_cast<int>(tiles.size()) != task.tiles_per_frame() || task.audit_tiles().empty() ||
      task.audit_spp() <= 0) {
    return absl::InvalidArgumentError(fmt::format(
        "audit of tiles [{}] at {} spp: this worker makes {} tiles of the frame, not {}",
        fmt::join(task.audit_tiles(), " "), task.audit_spp(), tiles.size(),
        task.tiles_per_frame()));
  }
  PBGI_ASSIGN_OR_RETURN(const Image frame, readImage(task.output_path()));
  TaskResult result;
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const FrameScene> scene,
                        scenes_.get(shot, task.frame(), &result.log));
  double weightedRelMse = 0, pixels = 0, sumJob = 0, sumPath = 0;
  for (int i = 0; i < task.audit_tiles_size(); ++i) {
    const int t = task.audit_tiles(i);
    if (t < 0 || static_cast<size_t>(t) >= tiles.size()) {
      return absl::InvalidArgumentError(
          fmt::format("audit tile {}: the frame has tiles 0..{}", t, tiles.size() - 1));
    }
    FrameRenderRequest request;
    request.frame = task.frame();
    request.overrides.integrator = "path";
    request.overrides.spp = task.audit_spp();
    request.threads = options_.threads;
    request.outPath = (fs::path(task.work_dir()) / "audit" /
                       fmt::format("frame.{:04d}.tile.{:04d}.exr", task.frame(), t))
                          .string();
    request.preview = false;
    request.output = OutputOptions{};
    request.regions = auditWindows(tiles[static_cast<size_t>(t)]);
    request.scene = scene.get();
    request.cancel = beat.cancelFlag();
    const int n = task.audit_tiles_size();
    request.progress = [&beat, i, n](int done, int total) {
      if (total > 0) beat.progress((i + double(done) / total) / n);
    };
    PBGI_ASSIGN_OR_RETURN(const FrameRenderReport report, renderShotFrame(shot, request));
    PBGI_ASSIGN_OR_RETURN(const Image reference, readImage(report.imagePath));
    PBGI_ASSIGN_OR_RETURN(const Image job, cropRegions(frame, request.regions));
    PBGI_ASSIGN_OR_RETURN(const ImageMetrics m, compareImages(job, reference));
    if (m.nonFiniteImage > 0 || m.nonFiniteReference > 0) {
      return absl::DataLossError(fmt::format(
          "audit tile {}: {} non-finite pixels in the job's frame, {} in the path tracer's", t,
          m.nonFiniteImage, m.nonFiniteReference));
    }
    const double n_pixels = static_cast<double>(m.comparedPixels);
    weightedRelMse += m.relMse * n_pixels;
    pixels += n_pixels;
    for (const ChannelMetrics& c : m.channels) {
      sumJob += c.meanImage * n_pixels;
      sumPath += c.meanReference * n_pixels;
    }
    result.log += fmt::format("audit tile {} ({} pixels, path {} spp): relMSE {:.4g}\n", t,
                              m.comparedPixels, task.audit_spp(), m.relMse);
  }
  AuditResult audit;
  audit.relMse = pixels > 0 ? weightedRelMse / pixels : 0.0;
  // A black reference (a dark frame) has no relative bias to speak of.
  audit.bias = sumPath > 0 ? sumJob / sumPath - 1.0 : 0.0;
  result.audit = audit;
  result.log += fmt::format("audit: relMSE {:.4g}, bias {:+.2f} %\n", audit.relMse,
                            100.0 * audit.bias);
  return result;
}

// A file transfer, tried again while the coordinator is away (a minute and more: the lease is
// heartbeaten meanwhile).
absl::Status patiently(const std::function<absl::Status()>& transfer, const char* what) {
  constexpr double kFilePatienceSeconds = 120.0;
  return callPatiently(
             [&]() -> absl::StatusOr<bool> {
               PBGI_RETURN_IF_ERROR(transfer());
               return true;
             },
             kFilePatienceSeconds, what)
      .status();
}

bool Worker::worksInCopy(const v1::LeaseTaskResponse& task) const {
  switch (options_.fileSource) {
    case FileSource::kShared: return false;
    case FileSource::kCopy: return true;
    case FileSource::kAuto: break;
  }
  std::error_code ec;
  return !fs::is_directory(task.work_dir(), ec);
}

v1::LeaseTaskResponse Worker::inCopy(const v1::LeaseTaskResponse& task) const {
  v1::LeaseTaskResponse copy = task;
  const std::string dir = (fs::path(cacheDir_) / "jobs" / std::to_string(task.job())).string();
  copy.set_work_dir(dir);
  switch (taskKindOf(task)) {
    case v1::TASK_KIND_BAKE:
      copy.set_output_path(jobBakeDir(dir));
      break;
    case v1::TASK_KIND_TILE:
      copy.set_output_path(farmTilePath(dir, task.frame(), task.tile()));
      break;
    default:  // the assembled frame (audits read it)
      copy.set_output_path(
          (fs::path(dir) / "output" / fs::path(task.output_path()).filename()).string());
      break;
  }
  return copy;
}

absl::Status Worker::fetchInputs(const ShotDesc& shot, const v1::LeaseTaskResponse& copy) {
  v1::GetFileRequest request;
  request.set_job(copy.job());
  request.set_frame(copy.frame());
  const auto fetch = [&](const std::string& path) {
    return patiently([&] { return client_.getFile(request, path); }, "GetFile");
  };
  switch (taskKindOf(copy)) {
    case v1::TASK_KIND_ASSEMBLE: {
      // Every tile, as the coordinator has it (another worker may have rendered any of them).
      request.set_kind(v1::FILE_KIND_TILE);
      const size_t tiles = farmTiles(shot, copy.tile_size()).size();
      for (size_t t = 0; t < tiles; ++t) {
        request.set_tile(static_cast<int>(t));
        PBGI_RETURN_IF_ERROR(
            fetch(farmTilePath(copy.work_dir(), copy.frame(), static_cast<int>(t))));
      }
      return absl::OkStatus();
    }
    case v1::TASK_KIND_AUDIT:
      request.set_kind(v1::FILE_KIND_FRAME);
      return fetch(copy.output_path());
    default:  // a bake reads the scene; a tile its tree, through the page service
      return absl::OkStatus();
  }
}

absl::Status Worker::sendResults(const ShotDesc& shot, const v1::LeaseTaskResponse& copy,
                                 std::string* log) {
  v1::PutFileChunk head;
  head.set_task(copy.task());
  head.set_attempt(copy.attempt());
  const auto send = [&](v1::FileKind kind, const std::string& path) -> absl::Status {
    head.set_kind(kind);
    PBGI_RETURN_IF_ERROR(patiently([&] { return client_.putFile(head, path); }, "PutFile"));
    *log += fmt::format("sent {} to the coordinator\n", path);
    return absl::OkStatus();
  };
  switch (taskKindOf(copy)) {
    case v1::TASK_KIND_BAKE: {
      PBGI_ASSIGN_OR_RETURN(const std::string tree,
                            jobTreePath(shot, copy.work_dir(), copy.frame()));
      return send(v1::FILE_KIND_TREE, tree);
    }
    case v1::TASK_KIND_TILE:
      head.set_tile(copy.tile());
      return send(v1::FILE_KIND_TILE, copy.output_path());
    case v1::TASK_KIND_ASSEMBLE: {
      PBGI_RETURN_IF_ERROR(send(v1::FILE_KIND_FRAME, copy.output_path()));
      const std::string preview = fs::path(copy.output_path()).replace_extension(".png").string();
      return fs::exists(preview) ? send(v1::FILE_KIND_PREVIEW, preview) : absl::OkStatus();
    }
    default:  // an audit's result travels in its completion
      return absl::OkStatus();
  }
}

absl::StatusOr<TaskResult> Worker::execute(const v1::LeaseTaskResponse& leased, Heartbeat& beat) {
  PBGI_ASSIGN_OR_RETURN(const RenderOverrides overrides, fromWire(leased.render()));
  PBGI_ASSIGN_OR_RETURN(const ShotDesc shot,
                        jobShot(leased.shot_text(), leased.shot_path(), overrides));
  const bool copied = worksInCopy(leased);
  const v1::LeaseTaskResponse task = copied ? inCopy(leased) : leased;
  if (copied) PBGI_RETURN_IF_ERROR(fetchInputs(shot, task));
  absl::StatusOr<TaskResult> result;
  switch (taskKindOf(task)) {
    case v1::TASK_KIND_BAKE:
      result = bake(shot, task, beat);
      break;
    case v1::TASK_KIND_TILE:
      result = tile(shot, task, beat);
      break;
    case v1::TASK_KIND_ASSEMBLE:
      result = assemble(shot, task);
      break;
    case v1::TASK_KIND_AUDIT:
      result = audit(shot, task, beat);
      break;
    default:
      return absl::InvalidArgumentError(
          fmt::format("task kind {} ('{}'): this worker runs bake, tile, assemble and audit",
                      static_cast<int>(task.task_kind()), task.kind()));
  }
  if (copied && result.ok()) PBGI_RETURN_IF_ERROR(sendResults(shot, task, &result->log));
  return result;
}

std::optional<v1::LeaseTaskResponse> Worker::report(const v1::LeaseTaskResponse& task,
                                                    const absl::StatusOr<TaskResult>& result,
                                                    double seconds,
                                                    const v1::LeaseTaskRequest* next) {
  // The coordinator may be restarting; a result is worth waiting for.
  const double patience = std::max(120.0, 4.0 * task.lease_seconds());
  absl::Status sent;
  if (result.ok()) {
    v1::CompleteTaskRequest request;
    request.set_worker(id_);
    request.set_task(task.task());
    request.set_attempt(task.attempt());
    request.set_seconds(seconds);
    request.set_log(result->log);
    request.set_cache_hits(result->cacheHits);
    request.set_cache_misses(result->cacheMisses);
    request.set_tree_bytes_streamed(result->treeBytesStreamed);
    if (result->audit) {
      request.set_audit(true);
      request.set_audit_rel_mse(result->audit->relMse);
      request.set_audit_bias(result->audit->bias);
    }
    if (next != nullptr) *request.mutable_next() = *next;
    auto answer =
        callPatiently([&] { return client_.completeTask(request); }, patience, "CompleteTask");
    sent = answer.status();
    if (sent.ok()) {
      log::info("done job={} frame={} {} task={} attempt={} seconds={:.2f}", task.job(),
                task.frame(), taskLabel(task), task.task(), task.attempt(), seconds);
      if (answer->has_next()) return std::move(*answer->mutable_next());
    }
  } else {
    log::warn("failed job={} frame={} {} task={} attempt={}: {}", task.job(), task.frame(),
              taskLabel(task), task.task(), task.attempt(), result.status().message());
    v1::FailTaskRequest request;
    request.set_worker(id_);
    request.set_task(task.task());
    request.set_attempt(task.attempt());
    request.set_error(std::string(result.status().message()));
    request.set_audit(taskKindOf(task) == v1::TASK_KIND_AUDIT);
    sent = callPatiently([&] { return client_.failTask(request); }, patience, "FailTask").status();
  }
  if (!sent.ok()) {
    // A stale attempt (the lease expired while the coordinator was away, and the task went to
    // another worker): nothing to do, the other attempt's result counts.
    log::warn("task={} attempt={}: the coordinator did not take the result: {}", task.task(),
              task.attempt(), sent.message());
  }
  return std::nullopt;
}

int Worker::run(const std::atomic<bool>& stop) {
  v1::RegisterWorkerRequest hello;
  hello.set_worker(id_);
  hello.set_host(hostName());
  hello.set_cores(static_cast<int>(std::thread::hardware_concurrency()));
  hello.set_memory_bytes(physicalMemory());
  hello.set_cache_bytes(options_.cacheBytes);
  for (double wait = 0.2;; wait = std::min(wait * 2.0, 2.0)) {
    auto answer = client_.registerWorker(hello);
    if (answer.ok()) break;
    if (!isTransient(answer.status())) {
      log::error("worker={}: the coordinator refused the worker: {}", id_, answer.status().message());
      return 1;
    }
    if (stop.load()) return 0;
    log::warn("worker={}: {}; trying again", id_, answer.status().message());
    sleepUnlessStopped(wait, stop);
  }
  log::info("worker={} registered with {} over {} (tree source {}, disk cache {})", id_,
            options_.coordinator,
            !options_.tls                ? "plaintext"
            : options_.tls->cert.empty() ? "TLS"
                                         : "TLS with a client certificate",
            options_.treeSource == TreeSource::kAuto     ? "auto"
            : options_.treeSource == TreeSource::kShared ? "shared"
                                                         : "stream",
            cacheDir_);
  v1::LeaseTaskRequest ask;
  ask.set_worker(id_);
  ask.set_runs_audits(true);
  double backoff = options_.pollSeconds;
  // The next task, when the last completion brought one.
  std::optional<v1::LeaseTaskResponse> next;
  while (!stop.load()) {
    absl::StatusOr<v1::LeaseTaskResponse> task;
    if (next) {
      task = *std::move(next);
      next.reset();
    } else {
      task = client_.leaseTask(ask);
    }
    if (!task.ok()) {
      if (!isTransient(task.status())) {
        log::error("worker={}: lease refused: {}", id_, task.status().message());
        return 1;
      }
      sleepUnlessStopped(backoff, stop);
      backoff = std::min(backoff * 2.0, 2.0);
      continue;
    }
    backoff = options_.pollSeconds;
    if (!task->has_task()) {
      sleepUnlessStopped(options_.pollSeconds, stop);
      continue;
    }
    const auto started = Clock::now();
    absl::StatusOr<TaskResult> result;
    bool lost = false;
    {
      Heartbeat beat(client_, id_, *task);
      result = execute(*task, beat);
      lost = beat.lost();
    }
    if (lost) {
      // Cancelled, retried or expired: the attempt can commit nothing, so nothing is reported.
      log::info("stopped job={} frame={} {} task={} attempt={} after {:.2f} s: the lease is lost",
                task->job(), task->frame(), taskLabel(*task), task->task(), task->attempt(),
                std::chrono::duration<double>(Clock::now() - started).count());
      continue;
    }
    const v1::TaskKind kind = taskKindOf(*task);
    if (result.ok() && (kind == v1::TASK_KIND_BAKE || kind == v1::TASK_KIND_TILE)) {
      hold(task->job(), task->frame());
    } else if (!result.ok() && kind == v1::TASK_KIND_TILE) {
      remoteTrees_.erase({task->job(), task->frame()});  // the frame baked again, say
    }
    // The frames held change only with a task; a worker that goes on asks for its next task
    // with this one's result.
    ask.clear_held();
    for (const HeldFrame& h : held_) {
      v1::HeldFrame* out = ask.add_held();
      out->set_job(h.job);
      out->set_frame(h.frame);
    }
    next = report(*task, result, std::chrono::duration<double>(Clock::now() - started).count(),
                  stop.load() ? nullptr : &ask);
  }
  if (next && next->has_task()) {
    // Stopped with a task leased and not started: its lease expires and it runs elsewhere.
    log::info("worker={}: leaving task={} to its lease's expiry", id_, next->task());
  }
  log::info("worker={} stopping", id_);
  return 0;
}

}  // namespace

int runWorker(const WorkerOptions& options, const std::atomic<bool>& stop) {
  if (options.coordinator.empty()) {
    log::error("the worker needs a coordinator address (--coordinator host:port)");
    return 1;
  }
  const std::string id =
      options.id.empty() ? fmt::format("{}:{}", hostName(), static_cast<long>(::getpid()))
                         : options.id;
  Worker worker(options, id);
  return worker.run(stop);
}

}  // namespace pbgi::farm
