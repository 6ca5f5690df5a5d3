#include "services/farm/job_rules.h"

#include <algorithm>
#include <filesystem>
#include <iterator>
#include <numeric>

#include <absl/strings/numbers.h>
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <xxhash.h>

#include "core/render/integrators.h"
#include "core/util/status.h"
#include "formats/shot/shot_file.h"
#include "services/bake/frame_bake.h"
#include "services/render/frame_render.h"

namespace pbgi::farm {

namespace fs = std::filesystem;

std::string jobWorkDir(const std::string& stateDir, int64_t job) {
  return (fs::path(stateDir) / "jobs" / std::to_string(job)).string();
}

std::string jobBakeDir(const std::string& workDir) { return (fs::path(workDir) / "bake").string(); }

std::string farmTilePath(const std::string& workDir, int frame, int tile) {
  return (fs::path(workDir) / fmt::format("frame.{:04d}", frame) / fmt::format("tile.{:04d}.exr", tile))
      .string();
}

absl::StatusOr<std::string> jobTreePath(const ShotDesc& shot, const std::string& workDir,
                                        int frame) {
  PBGI_ASSIGN_OR_RETURN(FrameBakeRequest bake, shotBakeRequest(shot, frame));
  bake.outDir = jobBakeDir(workDir);
  return bakeTreePath(shot, bake);
}

absl::StatusOr<RenderOverrides> parseOverrideLines(const std::vector<std::string>& lines) {
  RenderOverrides overrides;
  for (const std::string& line : lines) {
    const size_t eq = line.find('=');
    if (eq == std::string::npos) {
      return absl::InvalidArgumentError(fmt::format("override '{}': expected key=value", line));
    }
    const std::string key = line.substr(0, eq);
    const std::string value = line.substr(eq + 1);
    const SourceLocation where{fmt::format("override {}", line)};
    if (key == "integrator") {
      overrides.integrator = value;
      overrides.integratorWhere = where;
    } else if (key == "spp") {
      if (!absl::SimpleAtoi(value, &overrides.spp) || overrides.spp < 1 ||
          overrides.spp > kMaxOverrideSpp) {
        return absl::InvalidArgumentError(
            fmt::format("override {}: expected a whole number in [1, {}]", line, kMaxOverrideSpp));
      }
    } else if (findParam(key) != nullptr) {
      PBGI_RETURN_IF_ERROR(setParamText(overrides.params, key, value, where));
    } else {
      return absl::InvalidArgumentError(fmt::format(
          "override '{}': unknown key '{}' (expected integrator, spp or an integrator parameter: "
          "{})",
          line, key, fmt::join(allParamKeys(), ", ")));
    }
  }
  return overrides;
}

std::vector<std::string> overrideLines(const RenderOverrides& overrides) {
  std::vector<std::string> lines;
  if (!overrides.integrator.empty()) lines.push_back("integrator=" + overrides.integrator);
  if (overrides.spp > 0) lines.push_back(fmt::format("spp={}", overrides.spp));
  for (const auto& [key, value] : overrides.params.values()) {
    lines.push_back(fmt::format("{}={}", key, value.toString()));
  }
  return lines;
}

absl::StatusOr<ShotDesc> jobShot(std::string_view shotText, const std::string& shotPath,
                                 const RenderOverrides& overrides) {
  PBGI_ASSIGN_OR_RETURN(ShotDesc shot, parseShot(shotText, shotPath));
  PBGI_RETURN_IF_ERROR(applyShotOverrides(shot, overrides));
  return shot;
}

absl::StatusOr<std::string> confineToRoot(const std::string& path, const std::string& root) {
  std::error_code ec;
  const fs::path rootPath = fs::weakly_canonical(fs::absolute(root), ec);
  if (ec) {
    return absl::InvalidArgumentError(
        fmt::format("output root {}: {}", root, ec.message()));
  }
  const fs::path full = fs::weakly_canonical(fs::absolute(path), ec);
  if (ec) return absl::InvalidArgumentError(fmt::format("output {}: {}", path, ec.message()));
  const auto [rootEnd, fullIt] = std::mismatch(rootPath.begin(), rootPath.end(), full.begin(),
                                               full.end());
  // Inside means strictly below: every component of the root, then at least one more (the
  // root's own trailing empty component, when it has one, does not count).
  const bool rootConsumed =
      rootEnd == rootPath.end() || (std::next(rootEnd) == rootPath.end() && rootEnd->empty());
  if (!rootConsumed || fullIt == full.end()) {
    return absl::PermissionDeniedError(fmt::format(
        "output {} lies outside the coordinator's output root {}: submit with --output-dir "
        "DIR (a folder under the root, or relative to it), or start the coordinator with "
        "--output-root set to a folder that holds the shot's output",
        full.string(), rootPath.string()));
  }
  return full.string();
}

}  // namespace pbgi::farm

namespace pbgi::farm {

std::vector<int> chooseAuditTiles(std::string_view shotName, int frame, int tileCount, int count) {
  std::vector<int> all(static_cast<size_t>(std::max(tileCount, 0)));
  std::iota(all.begin(), all.end(), 0);
  if (count >= tileCount) return all;
  // A partial Fisher-Yates shuffle driven by a hash chain: the first `count` are the choice.
  const std::string seed = fmt::format("{}#{}", shotName, frame);
  uint64_t h = XXH3_64bits(seed.data(), seed.size());
  for (int i = 0; i < count; ++i) {
    h = XXH3_64bits_withSeed(&h, sizeof h, static_cast<uint64_t>(i));
    const int j = i + static_cast<int>(h % static_cast<uint64_t>(tileCount - i));
    std::swap(all[static_cast<size_t>(i)], all[static_cast<size_t>(j)]);
  }
  all.resize(static_cast<size_t>(std::max(count, 0)));
  std::sort(all.begin(), all.end());
  return all;
}

std::vector<TileRect> auditWindows(const std::vector<TileRect>& tile) {
  std::vector<TileRect> windows;
  for (const TileRect& r : tile) {
    const int w = std::min(r.width(), kAuditWindow);
    const int h = std::min(r.height(), kAuditWindow);
    const int x0 = r.x0 + (r.width() - w) / 2;
    const int y0 = r.y0 + (r.height() - h) / 2;
    windows.push_back({x0, y0, x0 + w, y0 + h});
  }
  return windows;
}

}  // namespace pbgi::farm
