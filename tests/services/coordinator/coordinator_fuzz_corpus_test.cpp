// The coordinator's fuzz corpus (tests/data/coordinator/fuzz_corpus): written here (with
// PBGI_REGENERATE_TEST_DATA=1), and replayed through the fuzz target's body, so that builds
// without libFuzzer (CI's gcc) run every seed too. Each seed is a job's life, or a worker's
// and a user's mistakes, as a sequence of RPC records (tests/fuzz/coordinator_fuzz_input.h).
#include <gtest/gtest.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <span>
#include <sstream>
#include <string>
#include <vector>

#include "core/util/log.h"
#include "formats/pbgi/page_file.h"
#include "tests/fuzz/coordinator_fuzz_input.h"
#include "tests/support/test_paths.h"

namespace pbgi::fuzz {
namespace {

namespace fs = std::filesystem;

fs::path corpusDir() { return testing::testDataDir() / "coordinator" / "fuzz_corpus"; }
fs::path bakedTree() { return testing::testDataDir() / "pbgi" / "valid.pbgi"; }

// Two frames of 64 x 48 pixels: 4 farm tiles of 32 (the fuzz coordinator's tile size).
std::string shotText(const std::string& integrator) {
  return "version = 1\n"
         "[shot]\n"
         "name = \"fuzz\"\n"
         "frames = [1, 2]\n"
         "resolution = [64, 48]\n"
         "output = \"fuzz.####.exr\"\n"
         "[camera]\n"
         "position = [0, 1, -5]\n"
         "look_at = [0, 1, 0]\n"
         "up = [0, 1, 0]\n"
         "fov_y_deg = 45\n"
         "[[geometry]]\n"
         "file = \"tri.obj\"\n"
         "[render]\n"
         "integrator = \"" +
         integrator + "\"\n";
}

// Seeds are built with the generated messages' setters, record by record.
class Sequence {
 public:
  Sequence& submit(const std::string& integrator, std::vector<int> frames = {},
                   std::vector<std::string> overrides = {}, const std::string& text = {},
                   int auditTiles = -1) {
    v1::SubmitJobRequest r;
    if (auditTiles >= 0) {
      r.set_audit_tiles(auditTiles);
      r.set_audit_spp(4);
      r.set_audit_threshold(0.05);
    }
    r.set_shot_path("shots/fuzz.shot.toml");
    r.set_shot_text(text.empty() ? shotText(integrator) : text);
    r.set_output_dir("frames");
    for (int f : frames) r.add_frames(f);
    for (const std::string& o : overrides) r.add_overrides(o);
    return add(FarmRpc::kSubmitJob, r);
  }
  Sequence& registerWorker(const std::string& worker) {
    v1::RegisterWorkerRequest r;
    r.set_worker(worker);
    r.set_host("fuzzhost");
    r.set_cores(8);
    r.set_memory_bytes(uint64_t{16} << 30);
    r.set_cache_bytes(uint64_t{1} << 30);
    return add(FarmRpc::kRegisterWorker, r);
  }
  Sequence& lease(const std::string& worker, int64_t heldJob = 0, int heldFrame = 0,
                  bool runsAudits = false) {
    v1::LeaseTaskRequest r;
    r.set_worker(worker);
    r.set_runs_audits(runsAudits);
    if (heldJob != 0) {
      v1::HeldFrame* h = r.add_held();
      h->set_job(heldJob);
      h->set_frame(heldFrame);
    }
    return add(FarmRpc::kLeaseTask, r);
  }
  Sequence& heartbeat(int64_t task, int attempt, double progress, bool audit = false) {
    v1::HeartbeatRequest r;
    r.set_audit(audit);
    r.set_task(task);
    r.set_attempt(attempt);
    r.set_progress(progress);
    r.set_worker("w1");
    return add(FarmRpc::kHeartbeat, r);
  }
  Sequence& complete(int64_t task, int attempt, bool audit = false) {
    v1::CompleteTaskRequest r;
    if (audit) {
      r.set_audit(true);
      r.set_audit_rel_mse(0.01);
      r.set_audit_bias(-0.002);
    }
    r.set_task(task);
    r.set_attempt(attempt);
    r.set_worker("w1");
    r.set_log("rendered");
    r.set_seconds(1.5);
    r.set_cache_hits(10);
    r.set_cache_misses(2);
    return add(FarmRpc::kCompleteTask, r);
  }
  Sequence& fail(int64_t task, int attempt, const std::string& error, bool audit = false) {
    v1::FailTaskRequest r;
    r.set_audit(audit);
    r.set_task(task);
    r.set_attempt(attempt);
    r.set_worker("w1");
    r.set_error(error);
    return add(FarmRpc::kFailTask, r);
  }
  Sequence& status(int64_t job, bool withTasks) {
    v1::GetStatusRequest r;
    r.set_job(job);
    r.set_with_tasks(withTasks);
    return add(FarmRpc::kGetStatus, r);
  }
  Sequence& logs(int64_t job, std::optional<int> frame = {}, std::optional<int> tile = {}) {
    v1::GetLogsRequest r;
    r.set_job(job);
    if (frame) r.set_frame(*frame);
    if (tile) r.set_tile(*tile);
    return add(FarmRpc::kGetLogs, r);
  }
  Sequence& retry(int64_t job, std::optional<int> frame = {}, std::optional<int> tile = {}) {
    v1::RetryJobRequest r;
    r.set_job(job);
    if (frame) r.set_frame(*frame);
    if (tile) r.set_tile(*tile);
    return add(FarmRpc::kRetryJob, r);
  }
  Sequence& cancel(int64_t job) {
    v1::CancelJobRequest r;
    r.set_job(job);
    return add(FarmRpc::kCancelJob, r);
  }
  Sequence& workers() { return add(FarmRpc::kListWorkers, v1::ListWorkersRequest()); }
  Sequence& openTree(int64_t job, int frame) {
    v1::OpenTreeRequest r;
    r.set_job(job);
    r.set_frame(frame);
    return add(FarmRpc::kOpenTree, r);
  }
  Sequence& fetchPages(int64_t job, int frame, std::vector<uint32_t> pages, uint64_t treeId) {
    v1::FetchPagesRequest r;
    r.set_job(job);
    r.set_frame(frame);
    for (uint32_t p : pages) r.add_pages(p);
    r.set_tree_id(treeId);
    return add(FarmRpc::kFetchPages, r);
  }
  Sequence& expireLeases() {
    bytes_ += farmRecord(FarmRpc::kExpireLeases, v1::ListWorkersRequest());
    return *this;
  }
  const std::string& bytes() const { return bytes_; }

 private:
  Sequence& add(FarmRpc rpc, const google::protobuf::Message& r) {
    bytes_ += farmRecord(rpc, r);
    return *this;
  }
  std::string bytes_;
};

std::map<std::string, std::string> seeds() {
  std::map<std::string, std::string> out;
  // A path-traced job from submission to its assembled frames: tasks 1-4 are frame 1's tiles,
  // 5 its assemble, 6-10 frame 2's.
  Sequence path;
  path.registerWorker("w1").submit("path").workers();
  for (int64_t task = 1; task <= 10; ++task) {
    path.lease("w1", 1, 1).heartbeat(task, 1, 0.5).complete(task, 1);
  }
  path.status(1, true).logs(1).logs(1, 1).logs(1, 2, 3);
  out["path_job_done"] = path.bytes();

  // A PBGI job: a bake per frame (tasks 1 and 7), whose tree the page service serves.
  auto tree = PageFileReader::open(bakedTree().string());
  const uint64_t treeId = tree.ok() ? (*tree)->head().treeId() : 0;
  Sequence pbgi;
  pbgi.registerWorker("w1")
      .submit("pbgi", {2}, {"quality=draft", "spp=2"})
      .lease("w1")
      .openTree(1, 2)
      .fetchPages(1, 2, {0, 1}, treeId)
      .fetchPages(1, 2, {0}, treeId + 1)
      .complete(1, 1)
      .lease("w1", 1, 2)
      .fail(2, 1, "out of memory")
      .lease("w1", 1, 2)
      .status(1, true);
  out["pbgi_job_pages"] = pbgi.bytes();

  // A PBGI job's accuracy audit (2 tiles), leased once its frame is assembled to a worker that
  // runs audits: task 1 is the bake, 2-5 the tiles, 6 the assemble; audit 1 fails once.
  Sequence audit;
  audit.registerWorker("w1").submit("pbgi", {1}, {}, {}, 2);
  for (int64_t task = 1; task <= 6; ++task) audit.lease("w1", 1, 1, true).complete(task, 1);
  audit.lease("w1", 0, 0, true)
      .heartbeat(1, 1, 0.5, true)
      .fail(1, 1, "out of memory", true)
      .lease("w1", 0, 0, false)
      .lease("w1", 0, 0, true)
      .complete(1, 2, true)
      .status(1, true)
      .logs(1);
  out["pbgi_job_audit"] = audit.bytes();

  // A lease lost, failures up to the cap (2 attempts) that kill a tile and blocklist its
  // worker, a stale completion, then retries and a cancel. Task 1 is frame 1's tile 0, 2 its
  // tile 1.
  Sequence expiry;
  expiry.registerWorker("w1")
      .registerWorker("w2")
      .submit("path", {1})
      .lease("w1")
      .expireLeases()
      .lease("w2")
      .heartbeat(2, 1, 0.1)
      .complete(1, 1)
      .fail(2, 1, "crashed")
      .lease("w2")
      .fail(2, 2, "crashed again")
      .status(0, false)
      .retry(1, 1, 1)
      .lease("w2")
      .lease("w1")
      .complete(2, 3)
      .retry(1)
      .cancel(1)
      .retry(1, 1)
      .status(1, true)
      .logs(1);
  out["expiry_dead_retry"] = expiry.bytes();

  // Requests a coordinator must refuse: shots that do not parse, frames the shot lacks,
  // overrides it does not know, an output outside the root, tasks and jobs that do not exist.
  Sequence refusals;
  refusals.submit("path", {}, {}, "version = 1\n[shot]\nname = \"x\"\n")
      .submit("path", {7})
      .submit("path", {}, {"spp=0"})
      .submit("path", {}, {"nonsense"})
      .submit("bidirectional")
      .heartbeat(99, 1, 0.5)
      .complete(99, 1)
      .fail(99, 1, "?")
      .retry(5, 1, 2)
      .cancel(5)
      .logs(5, 1)
      .openTree(5, 1)
      .fetchPages(5, 1, {}, 0)
      .status(5, true)
      .lease("nobody");
  v1::SubmitJobRequest outside;
  outside.set_shot_path("shots/fuzz.shot.toml");
  outside.set_shot_text(shotText("path"));
  outside.set_output_dir("/etc");
  out["refusals"] = refusals.bytes() + farmRecord(FarmRpc::kSubmitJob, outside);
  return out;
}

std::string readBytes(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::ostringstream bytes;
  bytes << in.rdbuf();
  return bytes.str();
}

TEST(CoordinatorFuzzCorpusTest, EverySeedKeepsTheCoordinatorsPromises) {
  log::setLevel(log::Level::kWarn);
  if (std::getenv("PBGI_REGENERATE_TEST_DATA")) {
    fs::create_directories(corpusDir());
    for (const auto& [name, bytes] : seeds()) {
      std::ofstream(corpusDir() / name, std::ios::binary) << bytes;
    }
  }
  int replayed = 0;
  for (const auto& entry : fs::directory_iterator(corpusDir())) {
    const std::string input = readBytes(entry.path());
    const std::string broken = runFarmInput(
        std::span(reinterpret_cast<const uint8_t*>(input.data()), input.size()), bakedTree());
    EXPECT_EQ(broken, "") << entry.path().filename();
    ++replayed;
  }
  EXPECT_GE(replayed, 4);
}

// Applies every record of a seed, none of which may break a promise.
void replay(FarmFuzzCoordinator& c, const std::string& bytes) {
  std::span input(reinterpret_cast<const uint8_t*>(bytes.data()), bytes.size());
  while (input.size() >= 3) {
    const size_t size = input[1] | size_t{input[2]} << 8;
    ASSERT_LE(3 + size, input.size());
    EXPECT_EQ(c.apply(static_cast<FarmRpc>(input[0]), input.subspan(3, size)), "");
    input = input.subspan(3 + size);
  }
  EXPECT_EQ(c.checkJobs(), "");
}

// The seeds get where they are meant to: a job done, pages served, tasks dead and retried.
TEST(CoordinatorFuzzCorpusTest, SeedsReachTheirJobsEnd) {
  log::setLevel(log::Level::kWarn);
  const std::map<std::string, std::string> all = seeds();
  {
    FarmFuzzCoordinator c(bakedTree());
    replay(c, all.at("path_job_done"));
    const auto job = c.store().job(1);
    ASSERT_TRUE(job.ok()) << job.status();
    EXPECT_EQ(job->state, farm::JobState::kDone);
  }
  {
    FarmFuzzCoordinator c(bakedTree());
    replay(c, all.at("pbgi_job_pages"));
    EXPECT_EQ(c.metrics().treesOpened->value(), 1u);
    EXPECT_EQ(c.metrics().pagesServed->value(), 2u);
  }
  {
    FarmFuzzCoordinator c(bakedTree());
    replay(c, all.at("pbgi_job_audit"));
    const auto audits = c.store().audits(1);
    ASSERT_TRUE(audits.ok()) << audits.status();
    ASSERT_EQ(audits->size(), 1u);
    EXPECT_EQ((*audits)[0].state, farm::AuditState::kDone);
    EXPECT_EQ((*audits)[0].attempt, 2);
  }
  {
    FarmFuzzCoordinator c(bakedTree());
    replay(c, all.at("expiry_dead_retry"));
    const auto events = c.store().events(1, std::nullopt, std::nullopt);
    ASSERT_TRUE(events.ok()) << events.status();
    std::multiset<std::string> kinds;
    for (const farm::TaskEvent& e : *events) kinds.insert(e.event);
    EXPECT_EQ(kinds.count("expired"), 1u);
    EXPECT_EQ(kinds.count("failed"), 2u);
    EXPECT_EQ(kinds.count("done"), 1u);
    // w2, blocklisted after its two failures, takes the retried tile again: the retry lifted
    // its blocklist (w1 then takes another tile).
    EXPECT_EQ(kinds.count("leased"), 5u);
  }
  {
    FarmFuzzCoordinator c(bakedTree());
    replay(c, all.at("refusals"));
    const auto jobs = c.store().jobs();
    ASSERT_TRUE(jobs.ok()) << jobs.status();
    EXPECT_TRUE(jobs->empty());
  }
}

}  // namespace
}  // namespace pbgi::fuzz
