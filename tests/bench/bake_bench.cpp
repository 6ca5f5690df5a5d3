// What `pbgi bake` costs a user: the real binary run as a child process, as a farm's bake task
// runs it, so that the numbers include everything the process holds (the scene, Embree's BVH,
// OpenVDB, the allocator's slack), not only the buffers the bake accounts for.
//
//  1. Sponza (../shared/scenes, skipped when absent) at 1 M and 10 M surfels, quantized, and at
//     1 M as float: sample+shade and sort+build throughput, peak RSS, the tree's size, nodes,
//     pages and bytes per node (file bytes / nodes), and float over quantized bytes per node.
//  2. Bounded memory (architecture invariant 4): a procedural terrain (about 2 M triangles,
//     written here into a temporary folder) baked with --mem-budget 256M at 10 M and 50 M
//     surfels, and at 100 k as the floor (the scene's own memory); peak RSS over the budget
//     should stay flat as the point count grows.
//
// Peak RSS is wait4()'s ru_maxrss of the child. The child's VmRSS is also polled from /proc
// every 20 ms and laid over the stage times the bake prints, which says which stage the peak
// belongs to. Reports numbers; never fails on time (exit 1 only when a bake itself fails).
//
// Run: build/bin/bake_bench [--quick] [--skip-50m] [--threads N] [--csv FILE] [--trace DIR]
//   --quick: only 1 M Sponza and 100 k and 10 M terrain. --trace: each run's polled VmRSS over
//   time, DIR/<run>.rss.csv, to see the shape behind a peak. Temporary files go to $TMPDIR (or
//   /tmp) and each run's outputs are deleted as soon as it has been measured.

#include <fcntl.h>
#include <spawn.h>
#include <sys/resource.h>
#include <sys/wait.h>
#include <unistd.h>

#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <optional>
#include <regex>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include <fmt/format.h>

#include "tests/support/test_paths.h"

extern char** environ;

namespace pbgi {
namespace {

namespace fs = std::filesystem;
using Clock = std::chrono::steady_clock;

constexpr uint64_t kMiB = uint64_t{1} << 20;
// The budget of the memory runs: small enough that 10 M surfels (about 800 MiB of sort
// records) must spill, so the flat-RSS claim is actually exercised.
constexpr uint64_t kSmallBudget = 256 * kMiB;
constexpr uint64_t kDefaultBudget = 1024 * kMiB;
constexpr auto kPollInterval = std::chrono::milliseconds(20);
// Disk a bake needs per surfel, with room to spare: an 81-byte spilled sort record and the
// tree's share (about 16 bytes a surfel quantized, more as float).
constexpr uint64_t kDiskBytesPerSurfel = 160;

struct BenchOptions {
  bool quick = false;
  bool skip50m = false;
  int threads = 0;
  std::string csvPath;
  std::string traceDir;  // per run, the polled VmRSS over time: <label>.rss.csv
  int terrainQuads = 1000;  // per side; the scene's own memory grows with it
  bool skipSponza = false;
};

struct BakeSpec {
  std::string label;
  std::string scene;
  fs::path shot;
  uint64_t points = 0;
  std::string encoding = "quantized";
  uint64_t memBudget = kDefaultBudget;
  int lightSamples = 16;
  std::string pointCloud = "auto";
};

struct StageResult {
  std::string name;
  double start = 0.0;  // seconds after the child was spawned, estimated from the durations
  double seconds = 0.0;
  uint64_t peakRssKiB = 0;  // highest polled VmRSS inside the stage's window
};

struct BakeResult {
  BakeSpec spec;
  bool ok = false;
  std::string failure;
  uint64_t surfels = 0, nodes = 0, leaves = 0, pages = 0, fileBytes = 0;
  uint64_t runsSpilled = 0, spillBytes = 0;
  bool wroteCloud = false;
  std::vector<StageResult> stages;
  double bakeWallSeconds = 0.0;  // as the bake reports it
  double childSeconds = 0.0;     // spawn to reap, as seen from here
  uint64_t peakRssKiB = 0;       // ru_maxrss
  uint64_t polledPeakKiB = 0;
  std::string peakStage;  // the stage holding the highest polled sample
  // The highest sample after the scene load: the loaded scene plus the bake's own buffers,
  // without the importer's transient peak. How it grows with the point count is what the
  // budget governs; the scene's share cannot be told apart by RSS (the allocator keeps or
  // returns the importer's freed memory depending on heap layout).
  uint64_t afterLoadPeakKiB = 0;

  double stageSeconds(const std::string& name) const {
    for (const StageResult& s : stages) {
      if (s.name == name) return s.seconds;
    }
    return 0.0;
  }
  uint64_t stagePeakKiB(const std::string& name) const {
    for (const StageResult& s : stages) {
      if (s.name == name) return s.peakRssKiB;
    }
    return 0;
  }
  double shadeRate() const {
    const double s = stageSeconds("sample+shade");
    return s > 0.0 ? double(surfels) / s : 0.0;
  }
  double buildRate() const {
    const double s = stageSeconds("sort") + stageSeconds("merge+build");
    return s > 0.0 ? double(surfels) / s : 0.0;
  }
  double bytesPerNode() const { return nodes > 0 ? double(fileBytes) / double(nodes) : 0.0; }
  double bytesPerSurfel() const { return surfels > 0 ? double(fileBytes) / double(surfels) : 0.0; }
  double overBudget(uint64_t kib) const { return double(kib) * 1024.0 / double(spec.memBudget); }
};

std::string budgetArg(uint64_t bytes) {
  return bytes % (1024 * kMiB) == 0 ? fmt::format("{}G", bytes / (1024 * kMiB))
                                    : fmt::format("{}M", bytes / kMiB);
}

std::string countLabel(uint64_t n) {
  return n % 1'000'000 == 0 ? fmt::format("{}M", n / 1'000'000) : fmt::format("{}k", n / 1000);
}

std::string slurp(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

std::string lastLines(const std::string& text, int count) {
  size_t pos = text.size();
  while (count-- > 0 && pos > 0) {
    const size_t nl = text.rfind('\n', pos - 1);
    if (nl == std::string::npos) return text;
    pos = nl;
  }
  return text.substr(pos == 0 ? 0 : pos + 1);
}

// VmRSS of a live process in KiB; nullopt once it is gone (or is a zombie, whose status has
// no memory lines).
std::optional<uint64_t> vmRssKiB(pid_t pid) {
  std::ifstream in(fmt::format("/proc/{}/status", pid));
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind("VmRSS:", 0) == 0) return std::stoull(line.substr(6));
  }
  return std::nullopt;
}

struct RssSample {
  double t = 0.0;
  uint64_t kib = 0;
};

struct ChildOutcome {
  int waitStatus = 0;
  struct rusage usage {};
  std::vector<RssSample> samples;
  double seconds = 0.0;
};

// posix_spawn rather than system(): wait4() then gives the bake's own rusage, not a shell's.
// The bench itself stays a few MiB (the scene is streamed to disk), which matters because
// Linux folds the pre-exec image's high-water mark into the child's ru_maxrss.
std::optional<ChildOutcome> spawnAndMeasure(const std::vector<std::string>& args,
                                            const fs::path& outFile, const fs::path& errFile,
                                            std::string* error) {
  std::vector<char*> argv;
  for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
  argv.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  posix_spawn_file_actions_addopen(&actions, 1, outFile.c_str(), O_WRONLY | O_CREAT | O_TRUNC,
                                   0644);
  posix_spawn_file_actions_addopen(&actions, 2, errFile.c_str(), O_WRONLY | O_CREAT | O_TRUNC,
                                   0644);
  pid_t pid = -1;
  const auto t0 = Clock::now();
  const int rc = posix_spawn(&pid, argv[0], &actions, nullptr, argv.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  if (rc != 0) {
    *error = fmt::format("cannot start {}: {}", args[0], std::strerror(rc));
    return std::nullopt;
  }
  ChildOutcome outcome;
  while (true) {
    const pid_t r = wait4(pid, &outcome.waitStatus, WNOHANG, &outcome.usage);
    if (r == pid) break;
    if (r < 0 && errno != EINTR) {
      *error = fmt::format("wait4({}): {}", pid, std::strerror(errno));
      return std::nullopt;
    }
    if (auto kib = vmRssKiB(pid)) {
      outcome.samples.push_back({std::chrono::duration<double>(Clock::now() - t0).count(), *kib});
    }
    std::this_thread::sleep_for(kPollInterval);
  }
  outcome.seconds = std::chrono::duration<double>(Clock::now() - t0).count();
  return outcome;
}

// Reads what `pbgi bake` prints (services/cli/bake_command.cpp); a line it no longer prints
// leaves its numbers at zero, which the table shows rather than hides.
void parseBakeOutput(const std::string& text, BakeResult* r) {
  static const std::regex stageLine(R"(^  (\S.*?)\s+([0-9.]+) s$)");
  static const std::regex keyValue(R"((\w+)=(\d+))");
  std::istringstream in(text);
  std::string line;
  while (std::getline(in, line)) {
    unsigned long long a = 0, b = 0, c = 0;
    double x = 0.0;
    std::smatch m;
    if (std::sscanf(line.c_str(), "  surfels %llu", &a) == 1) {
      r->surfels = a;
    } else if (std::sscanf(line.c_str(), "  tree: %llu nodes, %llu leaves, %llu pages", &a, &b,
                           &c) == 3) {
      r->nodes = a, r->leaves = b, r->pages = c;
    } else if (line.rfind("  sort: ", 0) == 0) {
      for (auto it = std::sregex_iterator(line.begin(), line.end(), keyValue);
           it != std::sregex_iterator(); ++it) {
        if ((*it)[1] == "runs_spilled") r->runsSpilled = std::stoull((*it)[2]);
        if ((*it)[1] == "bytes_written") r->spillBytes = std::stoull((*it)[2]);
      }
    } else if (std::sscanf(line.c_str(), "wall time %lf s", &x) == 1) {
      r->bakeWallSeconds = x;
    } else if (line.rfind("wrote ", 0) == 0 && line.find(".vdb") != std::string::npos) {
      r->wroteCloud = true;
    } else if (std::regex_match(line, m, stageLine)) {
      r->stages.push_back({m[1], 0.0, std::stod(m[2]), 0});
    }
  }
}

// Which stage a moment of the child's life falls in, by the estimated windows.
std::string stageAt(const BakeResult& r, double t) {
  for (const StageResult& s : r.stages) {
    if (t >= s.start && t < s.start + s.seconds) return s.name;
  }
  return t < 0.5 ? "start" : "exit";
}

void writeRssTrace(const fs::path& path, const std::vector<RssSample>& samples,
                   const BakeResult& r) {
  std::ofstream out(path);
  out << "t_s,vm_rss_kib,stage\n";
  for (const RssSample& s : samples) {
    out << fmt::format("{:.3f},{},{}\n", s.t, s.kib, stageAt(r, s.t));
  }
}

// The stages run back to back and end where the bake's wall clock does. Before them the
// process loads its shared libraries and the shot file (0.3 s on a loaded two-core machine,
// far over the poll interval), while tearing down after them is quick; so the stages are
// laid out backwards from the child's exit. Samples outside them count for the peak only.
void attributeRss(const std::vector<RssSample>& samples, BakeResult* r) {
  double t = std::max(0.0, r->childSeconds - r->bakeWallSeconds);
  for (StageResult& s : r->stages) {
    s.start = t;
    t += s.seconds;
  }
  double peakT = 0.0;
  for (const RssSample& sample : samples) {
    if (sample.kib > r->polledPeakKiB) r->polledPeakKiB = sample.kib, peakT = sample.t;
    for (StageResult& s : r->stages) {
      if (sample.t >= s.start && sample.t < s.start + s.seconds) {
        s.peakRssKiB = std::max(s.peakRssKiB, sample.kib);
        if (s.name != "load") r->afterLoadPeakKiB = std::max(r->afterLoadPeakKiB, sample.kib);
      }
    }
  }
  r->peakStage = stageAt(*r, peakT);
}

BakeResult runBake(const BakeSpec& spec, const fs::path& workRoot, const BenchOptions& options) {
  BakeResult r;
  r.spec = spec;
  const fs::path dir = workRoot / spec.label;
  const fs::path out = dir / "out", spill = dir / "spill";
  fs::create_directories(out);
  fs::create_directories(spill);
  const uint64_t needed = spec.points * kDiskBytesPerSurfel;
  std::error_code ec;
  const fs::space_info space = fs::space(workRoot, ec);
  if (!ec && space.available < needed) {
    r.failure = fmt::format("skipped: {} has {} MiB free, the run needs about {} MiB",
                            workRoot.string(), space.available / kMiB, needed / kMiB);
    fs::remove_all(dir, ec);
    return r;
  }
  std::vector<std::string> args = {testing::pbgiBinary().string(), "bake", spec.shot.string()};
  const auto flag = [&](const char* name, std::string value) {
    args.push_back(name);
    args.push_back(std::move(value));
  };
  flag("--frame", "1");
  flag("--out", out.string());
  flag("--points", std::to_string(spec.points));
  flag("--mem-budget", budgetArg(spec.memBudget));
  flag("--threads", std::to_string(options.threads));
  flag("--light-samples", std::to_string(spec.lightSamples));
  flag("--encoding", spec.encoding);
  flag("--point-cloud", spec.pointCloud);
  flag("--temp-dir", spill.string());
  std::string error;
  const auto outcome = spawnAndMeasure(args, dir / "stdout.txt", dir / "stderr.txt", &error);
  if (!outcome) {
    r.failure = error;
  } else if (!WIFEXITED(outcome->waitStatus) || WEXITSTATUS(outcome->waitStatus) != 0) {
    r.failure = fmt::format("{} {}: {}", WIFEXITED(outcome->waitStatus) ? "exit" : "signal",
                            WIFEXITED(outcome->waitStatus) ? WEXITSTATUS(outcome->waitStatus)
                                                           : WTERMSIG(outcome->waitStatus),
                            lastLines(slurp(dir / "stderr.txt"), 3));
  } else {
    r.ok = true;
    parseBakeOutput(slurp(dir / "stdout.txt"), &r);
    r.childSeconds = outcome->seconds;
    r.peakRssKiB = static_cast<uint64_t>(outcome->usage.ru_maxrss);  // KiB on Linux
    attributeRss(outcome->samples, &r);
    if (!options.traceDir.empty()) {
      writeRssTrace(fs::path(options.traceDir) / (spec.label + ".rss.csv"), outcome->samples, r);
    }
    for (const auto& e : fs::directory_iterator(out, ec)) {
      if (e.path().extension() == ".pbgi") r.fileBytes = e.file_size();
    }
  }
  // At 50 M surfels the tree and the spilled runs are gigabytes; the next run needs the room.
  fs::remove_all(dir, ec);
  return r;
}

// ---- The procedural scene ------------------------------------------------------------------

// Rolling hills with detail down to the grid spacing, so that surfels land on many slopes and
// the octree is not a flat sheet.
double terrainHeight(double x, double z) {
  return 3.0 * std::sin(0.13 * x) * std::cos(0.11 * z) + 0.7 * std::sin(0.71 * x + 0.3 * z) +
         0.15 * std::sin(3.1 * x) * std::sin(2.7 * z);
}

// A quads x quads displaced grid over [-50, 50]^2 (2 quads^2 triangles) and a few boxes on it,
// lit by a sun. Streamed with stdio: the bench must stay small (see spawnAndMeasure).
fs::path writeTerrainShot(const fs::path& dir, int quads) {
  {
    std::FILE* mtl = std::fopen((dir / "terrain.mtl").c_str(), "w");
    std::fprintf(mtl, "newmtl ground\nKd 0.45 0.4 0.3\n\nnewmtl box\nKd 0.7 0.7 0.7\n");
    std::fclose(mtl);
  }
  std::FILE* obj = std::fopen((dir / "terrain.obj").c_str(), "w");
  std::vector<char> buffer(1 << 20);
  std::setvbuf(obj, buffer.data(), _IOFBF, buffer.size());
  std::fprintf(obj, "# bake_bench terrain: %d x %d quads\nmtllib terrain.mtl\no ground\n", quads,
               quads);
  const double extent = 100.0, step = extent / quads;
  for (int j = 0; j <= quads; ++j) {
    for (int i = 0; i <= quads; ++i) {
      const double x = -extent / 2 + i * step, z = -extent / 2 + j * step;
      std::fprintf(obj, "v %.5f %.5f %.5f\n", x, terrainHeight(x, z), z);
    }
  }
  std::fprintf(obj, "usemtl ground\n");
  const int row = quads + 1;
  for (int j = 0; j < quads; ++j) {
    for (int i = 0; i < quads; ++i) {
      const int v = j * row + i + 1;  // OBJ indices start at 1
      std::fprintf(obj, "f %d %d %d\nf %d %d %d\n", v, v + row, v + 1, v + 1, v + row, v + row + 1);
    }
  }
  int base = row * row;
  const double boxes[][4] = {{-20, -10, 4, 8}, {5, 15, 3, 12}, {25, -20, 6, 5}, {-8, 25, 2, 9}};
  for (const auto& b : boxes) {
    const double cx = b[0], cz = b[1], half = b[2], height = b[3];
    const double y0 = terrainHeight(cx, cz) - 2.0;  // sunk in, so no gap under a slope
    std::fprintf(obj, "o box\nusemtl box\n");
    for (int k = 0; k < 8; ++k) {
      std::fprintf(obj, "v %.5f %.5f %.5f\n", cx + ((k & 1) ? half : -half),
                   (k & 2) ? y0 + height : y0, cz + ((k & 4) ? half : -half));
    }
    // Corners: bit 0 = +x, bit 1 = +y, bit 2 = +z; two triangles per face.
    const int faces[6][4] = {{0, 1, 3, 2}, {4, 6, 7, 5}, {0, 2, 6, 4},
                             {1, 5, 7, 3}, {0, 4, 5, 1}, {2, 3, 7, 6}};
    for (const auto& f : faces) {
      std::fprintf(obj, "f %d %d %d\nf %d %d %d\n", base + f[0] + 1, base + f[1] + 1,
                   base + f[2] + 1, base + f[0] + 1, base + f[2] + 1, base + f[3] + 1);
    }
    base += 8;
  }
  std::fclose(obj);

  const fs::path shot = dir / "terrain.shot.toml";
  std::FILE* toml = std::fopen(shot.c_str(), "w");
  std::fprintf(toml, R"(# Written by bake_bench: a displaced terrain for the bounded-memory runs.
version = 1

[shot]
name = "terrain"
frames = [1, 1]
resolution = [320, 180]
output = "terrain.####.exr"

[camera]
position = [0.0, 40.0, -80.0]
look_at = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov_y_deg = 50.0

[[geometry]]
file = "terrain.obj"

[[light]]
type = "directional"
direction = [0.3, -1.0, 0.2]
irradiance = [5.0, 4.8, 4.5]

[render]
integrator = "pbgi"
spp = 1
seed = 0
)");
  std::fclose(toml);
  return shot;
}

// ---- Reporting -----------------------------------------------------------------------------

std::string mib(uint64_t bytes) { return fmt::format("{:.1f}", double(bytes) / double(kMiB)); }
std::string mibKiB(uint64_t kib) { return kib > 0 ? mib(kib * 1024) : std::string("-"); }

void printThroughputTable(const std::vector<BakeResult>& results) {
  std::printf(
      "\nThroughput and tree (Msurf/s: millions of surfels a second; build = sort+build)\n");
  const std::string header = fmt::format(
      "{:<22} {:>5} {:>10} {:>7} {:>7} {:>8} {:>7} {:>7} {:>8} {:>7} {:>9} {:>9} {:>10} {:>6} "
      "{:>6} {:>7}",
      "run", "light", "surfels", "shade s", "Msurf/s", "sort+bld", "Msurf/s", "vdb s", "peakRSS",
      "file", "nodes", "leaves", "pages", "B/node", "B/surf", "wall s");
  std::printf("%s\n%s\n", header.c_str(), std::string(header.size(), '-').c_str());
  for (const BakeResult& r : results) {
    if (!r.ok) {
      std::printf("%-22s %s\n", r.spec.label.c_str(), r.failure.c_str());
      continue;
    }
    std::printf("%s\n",
                fmt::format("{:<22} {:>5} {:>10} {:>7.2f} {:>7.3f} {:>8.2f} {:>7.3f} {:>7} "
                            "{:>8} {:>7} {:>9} {:>9} {:>10} {:>6.1f} {:>6.1f} {:>7.1f}",
                            r.spec.label, r.spec.lightSamples, r.surfels,
                            r.stageSeconds("sample+shade"), r.shadeRate() / 1e6,
                            r.stageSeconds("sort") + r.stageSeconds("merge+build"), r.buildRate() / 1e6,
                            r.wroteCloud ? fmt::format("{:.2f}", r.stageSeconds("point cloud"))
                                         : std::string("-"),
                            mibKiB(r.peakRssKiB), mib(r.fileBytes), r.nodes, r.leaves, r.pages,
                            r.bytesPerNode(), r.bytesPerSurfel(), r.childSeconds)
                    .c_str());
  }
  std::printf(
      "(peakRSS and file in MiB; B/node, B/surf: file bytes over nodes, over surfels; "
      "vdb s '-': no point cloud written)\n");
}

void printMemoryTable(const std::vector<BakeResult>& results) {
  std::printf(
      "\nMemory (MiB). load..vdb: highest VmRSS polled every 20 ms in each stage; after load: "
      "highest\nin any stage after the load; x bud: over the --mem-budget\n");
  const std::string header = fmt::format(
      "{:<22} {:>6} {:>8} {:>6} {:>8} {:>10} {:>6} {:>7} {:>7} {:>7} {:>7} {:>12} {:>5} {:>9}",
      "run", "budget", "peakRSS", "x bud", "load", "after load", "x bud", "shade", "sort", "build",
      "vdb", "peak stage", "runs", "spill MiB");
  std::printf("%s\n%s\n", header.c_str(), std::string(header.size(), '-').c_str());
  for (const BakeResult& r : results) {
    if (!r.ok) continue;
    std::printf(
        "%s\n",
        fmt::format("{:<22} {:>6} {:>8} {:>6.2f} {:>8} {:>10} {:>6.2f} {:>7} {:>7} {:>7} {:>7} "
                    "{:>12} {:>5} {:>9}",
                    r.spec.label, budgetArg(r.spec.memBudget), mibKiB(r.peakRssKiB),
                    r.overBudget(r.peakRssKiB), mibKiB(r.stagePeakKiB("load")),
                    mibKiB(r.afterLoadPeakKiB), r.overBudget(r.afterLoadPeakKiB),
                    mibKiB(r.stagePeakKiB("sample+shade")), mibKiB(r.stagePeakKiB("sort")),
                    mibKiB(r.stagePeakKiB("merge+build")), mibKiB(r.stagePeakKiB("point cloud")),
                    r.peakStage, r.runsSpilled, mib(r.spillBytes))
            .c_str());
  }
}

const BakeResult* findRun(const std::vector<BakeResult>& results, const std::string& label) {
  for (const BakeResult& r : results) {
    if (r.spec.label == label && r.ok) return &r;
  }
  return nullptr;
}

void printSummary(const std::vector<BakeResult>& results) {
  std::printf("\n");
  const BakeResult* q = findRun(results, "sponza-1M-quantized");
  const BakeResult* f = findRun(results, "sponza-1M-float");
  if (q && f && q->bytesPerNode() > 0.0) {
    std::printf("sponza 1M bytes/node: float %.1f / quantized %.1f = %.2fx (file %.2fx)\n",
                f->bytesPerNode(), q->bytesPerNode(), f->bytesPerNode() / q->bytesPerNode(),
                double(f->fileBytes) / double(q->fileBytes));
  }
  std::vector<const BakeResult*> small;
  for (const BakeResult& r : results) {
    if (r.ok && r.spec.memBudget == kSmallBudget) small.push_back(&r);
  }
  for (const BakeResult* r : small) {
    const double ratio = r->overBudget(r->peakRssKiB);
    std::printf(
        "%s: peak RSS %s MiB = %.2fx the %s budget (target under 1.5x)%s; after the "
        "load %s MiB = %.2fx\n",
        r->spec.label.c_str(), mibKiB(r->peakRssKiB).c_str(), ratio,
        budgetArg(r->spec.memBudget).c_str(),
        ratio > 1.5 ? fmt::format(", OVER, peak in stage '{}'", r->peakStage).c_str() : "",
        mibKiB(r->afterLoadPeakKiB).c_str(), r->overBudget(r->afterLoadPeakKiB));
  }
  for (size_t i = 1; i < small.size(); ++i) {
    const BakeResult& a = *small.front();
    const BakeResult& b = *small[i];
    std::printf(
        "%s -> %s surfels (%.2fx the points): peak RSS %+.1f MiB, after the load "
        "%+.1f MiB\n",
        countLabel(a.spec.points).c_str(), countLabel(b.spec.points).c_str(),
        double(b.surfels) / double(std::max<uint64_t>(a.surfels, 1)),
        (double(b.peakRssKiB) - double(a.peakRssKiB)) / 1024.0,
        (double(b.afterLoadPeakKiB) - double(a.afterLoadPeakKiB)) / 1024.0);
  }
}

bool writeCsv(const std::string& path, const std::vector<BakeResult>& results) {
  std::ofstream out(path);
  out << "run,scene,points,encoding,mem_budget_bytes,light_samples,point_cloud,status,surfels,"
         "load_s,shade_s,sort_s,build_s,point_cloud_s,bake_wall_s,child_s,shade_surfels_per_s,"
         "build_surfels_per_s,peak_rss_kib,polled_peak_rss_kib,rss_load_kib,rss_shade_kib,"
         "rss_sort_kib,rss_build_kib,rss_point_cloud_kib,rss_after_load_kib,peak_stage,file_bytes,"
         "nodes,leaves,"
         "pages,bytes_per_node,runs_spilled,spill_bytes\n";
  for (const BakeResult& r : results) {
    std::string status = r.ok ? "ok" : r.failure;
    for (char& c : status) {
      if (c == ',' || c == '\n' || c == '"') c = ' ';
    }
    out << fmt::format(
        "{},{},{},{},{},{},{},{},{},{:.3f},{:.3f},{:.3f},{:.3f},{:.3f},{:.3f},{:.3f},{:.0f},"
        "{:.0f},{},{},{},{},{},{},{},{},{},{},{},{},{},{:.2f},{},{}\n",
        r.spec.label, r.spec.scene, r.spec.points, r.spec.encoding, r.spec.memBudget,
        r.spec.lightSamples, r.spec.pointCloud, status, r.surfels, r.stageSeconds("load"),
        r.stageSeconds("sample+shade"), r.stageSeconds("sort"), r.stageSeconds("merge+build"),
        r.stageSeconds("point cloud"), r.bakeWallSeconds, r.childSeconds, r.shadeRate(),
        r.buildRate(), r.peakRssKiB, r.polledPeakKiB, r.stagePeakKiB("load"),
        r.stagePeakKiB("sample+shade"), r.stagePeakKiB("sort"), r.stagePeakKiB("merge+build"),
        r.stagePeakKiB("point cloud"), r.afterLoadPeakKiB, r.peakStage, r.fileBytes, r.nodes,
        r.leaves, r.pages, r.bytesPerNode(), r.runsSpilled, r.spillBytes);
  }
  return static_cast<bool>(out.flush());
}

// ---- main ----------------------------------------------------------------------------------

std::optional<BenchOptions> parseOptions(int argc, char** argv) {
  BenchOptions o;
  o.threads = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == "--quick") {
      o.quick = true;
    } else if (a == "--skip-50m") {
      o.skip50m = true;
    } else if (a == "--skip-sponza") {
      o.skipSponza = true;
    } else if (a == "--terrain-quads" && i + 1 < argc) {
      o.terrainQuads = std::max(2, std::atoi(argv[++i]));
    } else if (a == "--csv" && i + 1 < argc) {
      o.csvPath = argv[++i];
    } else if (a == "--trace" && i + 1 < argc) {
      o.traceDir = argv[++i];
    } else if (a == "--threads" && i + 1 < argc) {
      o.threads = std::max(1, std::atoi(argv[++i]));
    } else {
      std::fprintf(
          stderr,
          "bake_bench: unknown argument '%s'\n"
          "usage: bake_bench [--quick] [--skip-50m] [--skip-sponza] [--terrain-quads N] [--threads N]\n"
          "                  [--csv FILE] [--trace DIR]\n",
          a.c_str());
      return std::nullopt;
    }
  }
  return o;
}

std::vector<BakeSpec> plannedRuns(const BenchOptions& o, const fs::path& terrainShot) {
  std::vector<BakeSpec> runs;
  if (const auto shared = testing::sharedScenesDir();
      !o.skipSponza && shared && fs::exists(*shared / "sponza/sponza.shot.toml")) {
    const fs::path sponza = *shared / "sponza/sponza.shot.toml";
    runs.push_back({"sponza-1M-quantized", "sponza", sponza, 1'000'000});
    if (!o.quick) {
      runs.push_back({"sponza-1M-float", "sponza", sponza, 1'000'000, "float"});
      runs.push_back({"sponza-10M-quantized", "sponza", sponza, 10'000'000});
    }
  } else {
    std::printf("sponza: skipped, ../shared/scenes/sponza is absent (set PBGI_SHARED_SCENES)\n");
  }
  // One light sample and no point cloud: these runs measure memory, and 50 M fully shaded
  // surfels would take most of an hour on a two-core machine.
  const BakeSpec terrain{"", "terrain", terrainShot, 0, "quantized", kSmallBudget, 1, "never"};
  // 100 k first: nearly all of its memory is the scene's, the floor the others are read against.
  for (uint64_t points : {uint64_t{100'000}, uint64_t{10'000'000}, uint64_t{50'000'000}}) {
    if (points > 10'000'000 && (o.quick || o.skip50m)) continue;
    BakeSpec s = terrain;
    s.points = points;
    s.label = fmt::format("terrain-{}-256M", countLabel(points));
    runs.push_back(s);
  }
  return runs;
}

int benchMain(int argc, char** argv) {
  const auto options = parseOptions(argc, argv);
  if (!options) return 2;
  if (!fs::exists(testing::pbgiBinary())) {
    std::fprintf(stderr, "bake_bench: %s is missing (build the pbgi target)\n",
                 testing::pbgiBinary().c_str());
    return 2;
  }
  const fs::path root = testing::makeTempDir("bake-bench");
  std::error_code ec;
  const fs::space_info space = fs::space(root, ec);
  std::printf("bake_bench: %s, %d threads, temporary files in %s (%llu MiB free)\n",
              testing::pbgiBinary().c_str(), options->threads, root.c_str(),
              static_cast<unsigned long long>(ec ? 0 : space.available / kMiB));
  const fs::path sceneDir = root / "terrain-scene";
  fs::create_directories(sceneDir);
  const auto t0 = Clock::now();
  const int quads = options->terrainQuads;
  const fs::path terrainShot = writeTerrainShot(sceneDir, quads);
  std::printf(
      "terrain: %d x %d quads + 4 boxes (%llu triangles), %s MiB OBJ, written in "
      "%.1f s\n",
      quads, quads, 2ull * quads * quads + 4 * 12,
      mib(fs::file_size(sceneDir / "terrain.obj")).c_str(),
      std::chrono::duration<double>(Clock::now() - t0).count());

  std::vector<BakeResult> results;
  for (const BakeSpec& spec : plannedRuns(*options, terrainShot)) {
    std::printf("running %s: %llu points, %s, budget %s, %d light samples, point cloud %s ...\n",
                spec.label.c_str(), static_cast<unsigned long long>(spec.points),
                spec.encoding.c_str(), budgetArg(spec.memBudget).c_str(), spec.lightSamples,
                spec.pointCloud.c_str());
    std::fflush(stdout);
    results.push_back(runBake(spec, root, *options));
    const BakeResult& r = results.back();
    if (r.ok) {
      std::printf("  done in %.1f s, peak RSS %s MiB, tree %s MiB\n", r.childSeconds,
                  mibKiB(r.peakRssKiB).c_str(), mib(r.fileBytes).c_str());
    } else {
      std::printf("  FAILED: %s\n", r.failure.c_str());
    }
    std::fflush(stdout);
  }
  fs::remove_all(root, ec);

  printThroughputTable(results);
  printMemoryTable(results);
  printSummary(results);
  if (!options->csvPath.empty()) {
    if (!writeCsv(options->csvPath, results)) {
      std::fprintf(stderr, "bake_bench: cannot write %s\n", options->csvPath.c_str());
      return 1;
    }
    std::printf("wrote %s\n", options->csvPath.c_str());
  }
  for (const BakeResult& r : results) {
    if (!r.ok && r.failure.rfind("skipped", 0) != 0) return 1;
  }
  return 0;
}

}  // namespace
}  // namespace pbgi

int main(int argc, char** argv) { return pbgi::benchMain(argc, argv); }
