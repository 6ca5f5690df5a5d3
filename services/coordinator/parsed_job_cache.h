#pragma once
// The coordinator's view of a job's shot: its spec parsed (the shot text with its overrides)
// once and kept, since a spec never changes after submission; and where the job's files go.
// Shared by the RPCs, the status report and the page service.
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <unordered_map>
#include <vector>

#include <absl/status/statusor.h>

#include "core/scene/shot.h"
#include "services/job_store/job_store.h"
#include "services/render/frame_assembly.h"

namespace pbgi::farm {

struct ParsedJob {
  JobSpec spec;
  ShotDesc shot;
  // The frame's farm tiles (farmTiles of the shot at the coordinator's tile size), computed
  // once: a lease of tile t sends tiles[t]'s rectangles, and sorting 4,096 tiles into Morton
  // order on every lease was a tenth of the coordinator's time.
  std::vector<FarmTile> tiles;
};

class ParsedJobCache {
 public:
  // `stateDir` absolute; tileSize > 0.
  ParsedJobCache(JobStore& store, std::string stateDir, int tileSize);

  // The job's view, read from the store and parsed at the first call.
  absl::StatusOr<std::shared_ptr<const ParsedJob>> get(int64_t job);

  int tileSize() const { return tileSize_; }
  // <state>/jobs/<job>: its bakes and tiles.
  std::string workDir(int64_t job) const;
  // The frame's EXR under the output root.
  static std::string frameOutput(const ParsedJob& view, int frame);

 private:
  JobStore& store_;
  const std::string stateDir_;
  const int tileSize_;
  std::mutex mutex_;
  std::unordered_map<int64_t, std::shared_ptr<const ParsedJob>> views_;
};

}  // namespace pbgi::farm
