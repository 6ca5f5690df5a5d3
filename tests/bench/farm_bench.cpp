// The farm's throughput, every figure from one process (these machines are noisy; compare within
// a run):
//   1. lease round trips per second (LeaseTask + CompleteTask over gRPC, every state change
//      committed) with 200 simulated workers: SQLite (group commit), PostgreSQL (a throwaway
//      cluster), and two coordinators on one PostgreSQL database; then the dispatch query's
//      time as the task table grows from 10 k to 1 M tasks, on each store;
//   2. 1 against 2 pbgi-worker processes on a 4-frame Cornell box job through `pbgi run`;
//   3. the page service: every page of a baked tree fetched over loopback, MB/s and pages/s.
//   4. locality-aware dispatch against plain: 2 workers streaming pages, bytes sent and time.
// Reports numbers; never fails on time. Run: build/bin/farm_bench [--workers-only|--leases-only|--sqlite-leases-only|
//   --scaling-only|--stream-only|--dispatch-only]

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "core/util/log.h"
#include "services/bake/frame_bake.h"
#include "services/coordinator/coordinator.h"
#include "services/farm/farm_client.h"
#include "services/farm/job_rules.h"
#include "services/job_store/job_store.h"
#include "tests/support/farm_fixtures.h"
#include "tests/support/postgres_cluster.h"

namespace pbgi::farm {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

double since(Clock::time_point t) { return std::chrono::duration<double>(Clock::now() - t).count(); }

std::unique_ptr<Coordinator> startCoordinator(const fs::path& dir, int tileSize,
                                              const std::string& store = {}) {
  CoordinatorOptions o;
  o.stateDir = (dir / "state").string();
  o.outputRoot = dir.string();
  o.token = "bench";
  o.tileSize = tileSize;
  o.leaseSeconds = 600;
  o.store = store;
  auto c = Coordinator::start(o);
  if (!c.ok()) {
    std::fprintf(stderr, "farm_bench: %s\n", std::string(c.status().message()).c_str());
    std::exit(1);
  }
  return *std::move(c);
}

v1::SubmitJobRequest jobRequest(const fs::path& shot) {
  v1::SubmitJobRequest r;
  r.set_shot_path(shot.string());
  r.set_shot_text(pbgi::testing::slurpFile(shot));
  return r;
}

// A fresh PostgreSQL database of the bench's throwaway cluster, or nullopt (said why) when no
// cluster can be started here.
std::optional<std::string> postgresDatabase() {
  auto cluster = pbgi::testing::PostgresCluster::shared();
  if (!cluster.ok()) {
    std::printf("PostgreSQL: skipped, no cluster: %s\n", cluster.status().ToString().c_str());
    return std::nullopt;
  }
  auto db = (*cluster)->createDatabase();
  if (!db.ok()) {
    std::printf("PostgreSQL: skipped: %s\n", db.status().ToString().c_str());
    return std::nullopt;
  }
  return (*cluster)->uri(*db);
}

// 200 simulated workers, each a thread of its own that leases a task and completes it over
// gRPC as fast as the coordinators answer, for 5 s; the workers take the coordinators in turn.
// Every state change is committed (SQLite: synchronous=FULL, grouped; PostgreSQL: fsync and
// synchronous_commit on, its defaults) before its call returns. `merged`: as pbgi-worker does, each completion
// asks for the next task in the same call (one RPC a task); otherwise LeaseTask and
// CompleteTask each (two, as v1 workers do).
void leaseRoundTrips(const std::string& label, const std::string& store, int coordinators,
                     bool merged) {
  const fs::path dir = pbgi::testing::makeTempDir("farm-bench-lease");
  pbgi::testing::SmallShot big;
  big.width = 2048;
  big.height = 2048;
  big.lastFrame = 16;  // more tiles than 5 s of round trips take
  const fs::path shot = pbgi::testing::writeSmallShot(dir, big);
  std::vector<std::unique_ptr<Coordinator>> farm;
  for (int c = 0; c < coordinators; ++c) farm.push_back(startCoordinator(dir, 32, store));
  FarmClient client(farm[0]->address(), "bench");  // 16 frames of 4096 tiles
  if (!client.submitJob(jobRequest(shot)).ok()) std::exit(1);
  constexpr int kWorkers = 200;
  constexpr double kSeconds = 5.0;
  std::atomic<uint64_t> trips{0};
  std::atomic<uint64_t> errors{0};
  std::atomic<bool> stop{false};
  std::vector<std::thread> threads;
  const auto t0 = Clock::now();
  for (int w = 0; w < kWorkers; ++w) {
    threads.emplace_back([&, w] {
      FarmClient own(farm[w % coordinators]->address(), "bench");
      v1::LeaseTaskRequest ask;
      ask.set_worker(fmt::format("sim-{}", w));
      std::optional<v1::LeaseTaskResponse> next;
      while (!stop.load()) {
        absl::StatusOr<v1::LeaseTaskResponse> lease =
            next ? *std::move(next) : own.leaseTask(ask);
        next.reset();
        if (!lease.ok() || !lease->has_task()) {
          errors.fetch_add(1);
          continue;
        }
        v1::CompleteTaskRequest done;
        done.set_worker(ask.worker());
        done.set_task(lease->task());
        done.set_attempt(lease->attempt());
        done.set_seconds(0.001);
        if (merged) *done.mutable_next() = ask;
        auto answer = own.completeTask(done);
        if (!answer.ok()) {
          errors.fetch_add(1);
          continue;
        }
        trips.fetch_add(1);
        if (answer->has_next()) next = std::move(*answer->mutable_next());
      }
    });
  }
  std::this_thread::sleep_for(std::chrono::duration<double>(kSeconds));
  stop.store(true);
  for (auto& th : threads) th.join();
  const double seconds = since(t0);
  std::printf("lease round trips, %s, %s: %d simulated workers, %d coordinator%s, %.1f s: %llu "
              "round trips (lease + complete), %.0f per second, %.1f ms each; %llu empty or "
              "failed\n",
              label.c_str(), merged ? "one call a task" : "two calls a task (v1 workers)",
              kWorkers, coordinators, coordinators > 1 ? "s" : "", seconds,
              static_cast<unsigned long long>(trips.load()), trips.load() / seconds,
              1000.0 * seconds * kWorkers / std::max<uint64_t>(trips.load(), 1),
              static_cast<unsigned long long>(errors.load()));
  farm.clear();
  fs::remove_all(dir);
}

// The store alone, without gRPC: `threads` threads lease and complete on one store for 3 s,
// so that the RPC round trip's share of the figure above can be read off.
void storeRoundTrips(const std::string& label, const std::string& store, int threads) {
  const fs::path dir = pbgi::testing::makeTempDir("farm-bench-store");
  auto opened = openJobStore(store.empty() ? (dir / "farm.sqlite").string() : store, RetryPolicy{});
  if (!opened.ok()) {
    std::fprintf(stderr, "farm_bench: %s\n", std::string(opened.status().message()).c_str());
    std::exit(1);
  }
  JobStore& jobs = **opened;
  JobSpec spec;
  spec.name = "bench";
  spec.shotPath = (dir / "bench.shot.toml").string();
  spec.shotText = "[camera]\n";
  spec.outputPattern = (dir / "bench.####.exr").string();
  for (int f = 1; f <= 16; ++f) spec.frames.push_back(f);
  spec.tileCount = 4096;
  if (!jobs.submit(spec, 0).ok()) std::exit(1);
  std::atomic<uint64_t> trips{0};
  std::atomic<bool> stop{false};
  std::vector<std::thread> pool;
  const auto t0 = Clock::now();
  for (int w = 0; w < threads; ++w) {
    pool.emplace_back([&, w] {
      const std::string worker = fmt::format("sim-{}", w);
      while (!stop.load()) {
        auto lease = jobs.lease(worker, 1, 600, {});
        if (!lease.ok() || !lease->has_value()) continue;
        if (jobs.complete((*lease)->task, (*lease)->attempt, 1, "").ok()) trips.fetch_add(1);
      }
    });
  }
  std::this_thread::sleep_for(std::chrono::seconds(3));
  stop.store(true);
  for (auto& th : pool) th.join();
  const double seconds = since(t0);
  std::printf("  the %s store alone, no RPC: %d threads, %.0f lease + complete per second\n",
              label.c_str(), threads, trips.load() / seconds);
  opened->reset();
  fs::remove_all(dir);
}

void leaseThroughput(bool sqliteOnly) {
  storeRoundTrips("SQLite", "", 200);
  leaseRoundTrips("SQLite", "", 1, /*merged=*/true);
  leaseRoundTrips("SQLite", "", 1, /*merged=*/false);
  if (sqliteOnly) return;
  if (const auto postgres = postgresDatabase()) storeRoundTrips("PostgreSQL", *postgres, 200);
  for (const int coordinators : {1, 2}) {
    for (const bool merged : {true, false}) {
      if (const auto postgres = postgresDatabase()) {
        leaseRoundTrips("PostgreSQL", *postgres, coordinators, merged);
      }
    }
  }
}

// The dispatch query as the task table grows (OpenCue's users see theirs slow down): a job of
// N tile tasks is submitted straight to the store, then 2,000 lease + complete pairs are timed
// on it, for N from 10 k to 1 M, on each store.
void dispatchScaling() {
  const fs::path dir = pbgi::testing::makeTempDir("farm-bench-scaling");
  for (const bool postgres : {false, true}) {
    for (const int frames : {10, 100, 1000}) {
      std::string spec = (dir / fmt::format("scale-{}.db", frames)).string();
      if (postgres) {
        const auto uri = postgresDatabase();
        if (!uri) return;
        spec = *uri;
      }
      auto store = openJobStore(spec, RetryPolicy{});
      if (!store.ok()) {
        std::fprintf(stderr, "farm_bench: %s\n", store.status().ToString().c_str());
        std::exit(1);
      }
      JobSpec job;
      job.name = "scale";
      job.shotPath = "/shots/scale.toml";
      job.shotText = "[camera]\n";
      job.outputPattern = "/renders/scale.####.exr";
      for (int f = 1; f <= frames; ++f) job.frames.push_back(f);
      job.tileCount = 1000;  // 10 k, 100 k, 1 M tile tasks (and one assemble a frame)
      auto t0 = Clock::now();
      if (auto id = (*store)->submit(job, 0.0); !id.ok()) {
        std::fprintf(stderr, "farm_bench: %s\n", id.status().ToString().c_str());
        std::exit(1);
      }
      const double submitSeconds = since(t0);
      constexpr int kPairs = 2000;
      t0 = Clock::now();
      for (int i = 0; i < kPairs; ++i) {
        auto lease = (*store)->lease("bench", 1.0, 600.0);
        if (!lease.ok() || !lease->has_value()) std::exit(1);
        if (!(*store)->complete((*lease)->task, (*lease)->attempt, 1.0).ok()) std::exit(1);
      }
      const double seconds = since(t0);
      std::printf("dispatch, %s, %7d tasks: %.3f ms a lease + complete (submitted in %.1f s)\n",
                  postgres ? "PostgreSQL" : "SQLite", frames * 1001, 1000.0 * seconds / kPairs,
                  submitSeconds);
    }
  }
  fs::remove_all(dir);
}

double timedRun(const fs::path& shot, const fs::path& state, int workers, int threads) {
  fs::remove_all(state);
  const std::string command = fmt::format(
      "{} -q run {} --workers {} --threads {} --tile-size 128 --state {} >/dev/null 2>&1",
      pbgi::testing::shellQuote(pbgi::testing::pbgiBinary().string()),
      pbgi::testing::shellQuote(shot.string()), workers, threads,
      pbgi::testing::shellQuote(state.string()));
  const auto t0 = Clock::now();
  const int status = std::system(command.c_str());
  const double seconds = since(t0);
  if (status != 0) {
    std::fprintf(stderr, "farm_bench: `%s` failed (%d)\n", command.c_str(), status);
    std::exit(1);
  }
  return seconds;
}

void workerScaling() {
  const fs::path dir = pbgi::testing::makeTempDir("farm-bench-workers");
  pbgi::testing::SmallShot cornell;
  cornell.width = 256;
  cornell.height = 256;
  cornell.lastFrame = 4;
  cornell.spp = 64;
  const fs::path shot = pbgi::testing::writeSmallShot(dir, cornell);
  const fs::path state = dir / "state";
  timedRun(shot, state, 1, 1);  // warm the file cache
  const double one = timedRun(shot, state, 1, 1);
  const double two = timedRun(shot, state, 2, 2);
  const double oneWide = timedRun(shot, state, 1, 2);
  std::printf("workers: 4-frame Cornell box, 256x256, 64 spp, 4 tiles a frame, pbgi run:\n"
              "  1 worker x 1 thread  %.2f s  (%.2f frames/s)\n"
              "  2 workers x 1 thread %.2f s  (%.2f frames/s)  throughput ratio 2:1 = %.2f\n"
              "  1 worker x 2 threads %.2f s  (%.2f frames/s)  2 processes vs 2 threads = %.2f\n",
              one, 4 / one, two, 4 / two, one / two, oneWide, 4 / oneWide, oneWide / two);
  fs::remove_all(dir);
}

void pageStream() {
  const fs::path dir = pbgi::testing::makeTempDir("farm-bench-stream");
  pbgi::testing::SmallShot cornell;
  cornell.integrator = "pbgi";
  cornell.lastFrame = 1;
  cornell.extraRender = "bake_points = 1000000\nbake_bounces = 0\n";
  const fs::path shot = pbgi::testing::writeSmallShot(dir, cornell);
  auto coordinator = startCoordinator(dir, 256);
  FarmClient client(coordinator->address(), "bench");
  auto job = client.submitJob(jobRequest(shot));
  if (!job.ok()) std::exit(1);
  // The bake task's work, done here: the tree lands where the page service looks.
  auto desc = jobShot(pbgi::testing::slurpFile(shot), shot.string(), {});
  auto bake = shotBakeRequest(*desc, 1);
  bake->outDir = jobBakeDir(jobWorkDir((dir / "state").string(), job->job()));
  auto baked = bakeShotFrame(*desc, *bake);
  if (!baked.ok()) {
    std::fprintf(stderr, "farm_bench: %s\n", std::string(baked.status().message()).c_str());
    std::exit(1);
  }
  // Every page of the tree, as a worker's traversals ask for them (one page a call), then in
  // calls of 64 pages.
  auto head = client.openTree(job->job(), 1);
  if (!head.ok()) std::exit(1);
  auto header = decodePageFileHeader(head->header, head->fileSize);
  if (!header.ok()) std::exit(1);
  const uint32_t pages = header->info.pageCount;
  for (const uint32_t batch : {1u, 64u}) {
    uint64_t bytes = head->bytes();
    const auto t0 = Clock::now();
    for (uint32_t first = 0; first < pages; first += batch) {
      std::vector<uint32_t> ids;
      for (uint32_t id = first; id < std::min(pages, first + batch); ++id) ids.push_back(id);
      auto got = client.fetchPages(job->job(), 1, head->treeId(), ids);
      if (!got.ok()) std::exit(1);
      for (const auto& page : *got) bytes += page.size();
    }
    const double seconds = since(t0);
    std::printf("page service: a %.1f MiB tree (1M surfels, %u pages) fetched over loopback %u "
                "page%s a call: %.1f MiB/s, %.0f pages/s\n",
                double(baked->treeFileBytes) / (1 << 20), pages, batch, batch > 1 ? "s" : "",
                double(bytes) / (1 << 20) / seconds, double(pages) / seconds);
  }
  coordinator.reset();
  fs::remove_all(dir);
}

// Locality-aware dispatch against plain dispatch: 2 pbgi-worker processes that see no shared
// tree (--tree-source stream, a disk cache each) render a 4-frame PBGI Cornell box; the page
// service's bytes sent (pages and heads) and the wall time, with each.
void localityDispatch() {
  const fs::path dir = pbgi::testing::makeTempDir("farm-bench-locality");
  pbgi::testing::SmallShot cornell;
  cornell.integrator = "pbgi";
  cornell.width = 256;
  cornell.height = 256;
  cornell.lastFrame = 4;
  cornell.spp = 1;
  cornell.extraRender = "bake_points = 200000\nbake_bounces = 1\n";
  const fs::path shot = pbgi::testing::writeSmallShot(dir, cornell);
  std::printf("dispatch: 2 workers streaming pages (no shared tree), 4-frame PBGI Cornell box, "
              "256x256, 200,000-surfel trees, 4 tiles a frame:\n");
  uint64_t plainBytes = 0;
  double plainSeconds = 0.0;
  for (const bool locality : {false, true}) {
    const fs::path run = dir / (locality ? "locality" : "plain");
    CoordinatorOptions o;
    o.stateDir = (run / "state").string();
    o.outputRoot = dir.string();
    o.token = "bench";
    o.tileSize = 128;
    o.leaseSeconds = 60;
    o.localityDispatch = locality;
    auto coordinator = Coordinator::start(o);
    if (!coordinator.ok()) std::exit(1);
    FarmClient client((*coordinator)->address(), o.token);
    const auto t0 = Clock::now();
    auto job = client.submitJob(jobRequest(shot));
    if (!job.ok()) std::exit(1);
    std::vector<pbgi::testing::Process> workers;
    for (int w = 0; w < 2; ++w) {
      const std::string id = fmt::format("w{}", w);
      workers.emplace_back(
          std::vector<std::string>{pbgi::testing::binary("pbgi-worker").string(), "--coordinator",
                                   (*coordinator)->address(), "--id", id, "--threads", "1",
                                   "--poll-seconds", "0.05", "--tree-source", "stream",
                                   "--cache-dir", (run / ("cache-" + id)).string()},
          run / (id + ".log"), std::vector<std::string>{"PBGI_TOKEN=bench"});
    }
    std::string state;
    const bool settled = pbgi::testing::waitFor(
        [&] {
          v1::GetStatusRequest r;
          r.set_job(job->job());
          auto st = client.getStatus(r);
          if (st.ok() && st->jobs_size() > 0) state = st->jobs(0).state();
          return state != "active" && !state.empty();
        },
        1800.0);
    const double seconds = since(t0);
    if (!settled || state != "done") {
      std::fprintf(stderr, "farm_bench: the locality run ended %s\n", state.c_str());
      std::exit(1);
    }
    const std::string metrics = (*coordinator)->metricsText();
    const auto value = [&](const std::string& name) -> uint64_t {
      const size_t at = metrics.find("\n" + name + " ");
      return at == std::string::npos ? 0 : std::stoull(metrics.substr(at + name.size() + 2));
    };
    const uint64_t bytes = value("pbgi_tree_bytes_served_total");
    const uint64_t pages = value("pbgi_tree_pages_served_total");
    if (!locality) {
      plainBytes = bytes;
      plainSeconds = seconds;
    }
    std::printf("  %-8s dispatch: %.2f s, %llu pages, %.2f MiB from the page service%s\n",
                locality ? "locality" : "plain", seconds, static_cast<unsigned long long>(pages),
                bytes / 1048576.0,
                locality ? fmt::format(" ({:.2f}x the bytes, {:.2f}x the time of plain)",
                                       double(bytes) / std::max<uint64_t>(plainBytes, 1),
                                       seconds / plainSeconds)
                               .c_str()
                         : "");
    for (auto& w : workers) w.signal(SIGTERM);
    for (auto& w : workers) w.wait(30.0);
  }
  fs::remove_all(dir);
}

}  // namespace
}  // namespace pbgi::farm

int main(int argc, char** argv) {
  const std::string only = argc > 1 ? argv[1] : "";
  // The bench's PostgreSQL commits durably, as SQLite's do (the tests' cluster does not).
  setenv("PBGI_POSTGRES_DURABLE", "1", 0);
  pbgi::log::setLevel(pbgi::log::Level::kError);
  if (only.empty() || only == "--leases-only" || only == "--sqlite-leases-only") {
    pbgi::farm::leaseThroughput(only == "--sqlite-leases-only");
  }
  if (only.empty() || only == "--scaling-only") pbgi::farm::dispatchScaling();
  if (only.empty() || only == "--workers-only") pbgi::farm::workerScaling();
  if (only.empty() || only == "--stream-only") pbgi::farm::pageStream();
  if (only.empty() || only == "--dispatch-only") pbgi::farm::localityDispatch();
  pbgi::testing::PostgresCluster::stopShared();
  return 0;
}
