// Throughput of the external surfel sort (Morton keys, then ExternalSurfelSorter) over 5 M
// surfels: in-core (1 GiB budget), and spilled with a 64 MiB budget; 1 thread and all.
// Reports surfels/s and memory: the sorter's own peak of buffered bytes and the process's
// peak RSS (VmHWM, reset before each benchmark through /proc/self/clear_refs, so each one
// reports its own peak). Reports numbers; never fails on time. Spill files go to $TMPDIR.
// Run: build/bin/external_sort_bench [--benchmark_filter=...]

#include <benchmark/benchmark.h>
#include <malloc.h>

#include <chrono>
#include <fstream>
#include <string>

#include "core/pbgi/external_sort.h"
#include "core/pbgi/morton.h"

namespace pbgi {
namespace {

constexpr uint64_t kSurfels = 5'000'000;

// Counter-based surfels (SplitMix64 of the index): nothing is stored, so the RSS measured is
// the sorter's, not the input's.
uint64_t splitMix64(uint64_t x) {
  x += 0x9e3779b97f4a7c15ull;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ull;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebull;
  return x ^ (x >> 31);
}
float unit(uint64_t bits) { return static_cast<float>(bits >> 40) * 0x1.0p-24f; }

Surfel makeSurfel(uint64_t i) {
  const uint64_t a = splitMix64(2 * i), b = splitMix64(2 * i + 1);
  Surfel s;
  s.position = Vec3f(unit(a), unit(a << 21), unit(b));
  s.normal = Vec3f(0.0f, 0.0f, 1.0f);
  s.radius = 0.001f;
  s.albedo = Rgb(0.5f);
  s.radiance = Rgb(unit(b << 21));
  s.triangle = static_cast<uint32_t>(b);
  return s;
}

// Memory lines of /proc/self/status, in KiB; -1 when absent.
double procStatusKiB(const std::string& field) {
  std::ifstream in("/proc/self/status");
  std::string line;
  while (std::getline(in, line)) {
    if (line.rfind(field + ":", 0) == 0) return std::stod(line.substr(field.size() + 1));
  }
  return -1.0;
}

// Gives freed heap back to the system first (glibc keeps it otherwise, and an earlier
// benchmark's buffers would count as this one's RSS), then resets VmHWM to VmRSS.
bool resetPeakRss() {
#ifdef __GLIBC__
  malloc_trim(0);
#endif
  std::ofstream out("/proc/self/clear_refs");
  out << "5";
  return static_cast<bool>(out.flush());
}

void sortSurfels(benchmark::State& state) {
  const size_t budget = static_cast<size_t>(state.range(0)) << 20;
  const int threads = static_cast<int>(state.range(1));
  Bounds3f bounds;
  bounds.extend(Vec3f(0.0f));
  bounds.extend(Vec3f(1.0f));
  const MortonCube cube(bounds);
  const bool rssReset = resetPeakRss();
  const double rssStart = procStatusKiB("VmRSS");
  SortStats stats;
  double addSeconds = 0.0, streamSeconds = 0.0;
  for (auto _ : state) {
    ExternalSortOptions options;
    options.memoryBudgetBytes = budget;
    options.threads = threads;
    ExternalSurfelSorter sorter(options);
    const auto t0 = std::chrono::steady_clock::now();
    for (uint64_t i = 0; i < kSurfels; ++i) {
      const Surfel s = makeSurfel(i);
      if (absl::Status st = sorter.add(mortonKey(s.position, cube), s); !st.ok()) {
        return state.SkipWithError(st.ToString().c_str());
      }
    }
    if (absl::Status st = sorter.finish(); !st.ok()) {
      return state.SkipWithError(st.ToString().c_str());
    }
    const auto t1 = std::chrono::steady_clock::now();
    SortedSurfel r;
    uint64_t n = 0, lastKey = 0;
    while (true) {
      absl::StatusOr<bool> more = sorter.next(&r);
      if (!more.ok()) return state.SkipWithError(more.status().ToString().c_str());
      if (!*more) break;
      if (r.key < lastKey) return state.SkipWithError("stream out of order");
      lastKey = r.key;
      ++n;
    }
    const auto t2 = std::chrono::steady_clock::now();
    if (n != kSurfels) return state.SkipWithError("records lost");
    benchmark::DoNotOptimize(lastKey);
    addSeconds += std::chrono::duration<double>(t1 - t0).count();
    streamSeconds += std::chrono::duration<double>(t2 - t1).count();
    stats = sorter.stats();
  }
  const double iterations = static_cast<double>(state.iterations());
  state.counters["surfels/s"] =
      benchmark::Counter(static_cast<double>(kSurfels) * iterations, benchmark::Counter::kIsRate);
  state.counters["add+finish_s"] = addSeconds / iterations;
  state.counters["stream_s"] = streamSeconds / iterations;
  state.counters["runs"] = static_cast<double>(stats.runsSpilled);
  state.counters["merges"] = static_cast<double>(stats.intermediateMerges);
  state.counters["spilled_MiB"] = static_cast<double>(stats.bytesWritten) / (1 << 20);
  state.counters["peak_buffered_MiB"] = static_cast<double>(stats.peakBufferedBytes) / (1 << 20);
  state.counters["rss_start_MiB"] = rssStart / 1024.0;
  // Without the reset, VmHWM is the process's peak so far (an earlier benchmark's, maybe).
  state.counters["peak_rss_MiB"] = procStatusKiB("VmHWM") / 1024.0;
  state.counters["peak_rss_reset"] = rssReset ? 1.0 : 0.0;
}

// The cost of making the input alone, to subtract from the sorts.
void generateOnly(benchmark::State& state) {
  Bounds3f bounds;
  bounds.extend(Vec3f(0.0f));
  bounds.extend(Vec3f(1.0f));
  const MortonCube cube(bounds);
  for (auto _ : state) {
    uint64_t sum = 0;
    for (uint64_t i = 0; i < kSurfels; ++i) sum += mortonKey(makeSurfel(i).position, cube);
    benchmark::DoNotOptimize(sum);
  }
  state.counters["surfels/s"] =
      benchmark::Counter(static_cast<double>(kSurfels) * static_cast<double>(state.iterations()),
                         benchmark::Counter::kIsRate);
}

BENCHMARK(generateOnly)->Unit(benchmark::kMillisecond)->UseRealTime();
// Arguments: budget in MiB, threads (0: all).
BENCHMARK(sortSurfels)
    ->ArgNames({"budget_MiB", "threads"})
    ->Args({1024, 1})
    ->Args({1024, 0})
    ->Args({64, 1})
    ->Args({64, 0})
    ->Iterations(2)
    ->Unit(benchmark::kMillisecond)
    ->UseRealTime();

}  // namespace
}  // namespace pbgi

BENCHMARK_MAIN();
