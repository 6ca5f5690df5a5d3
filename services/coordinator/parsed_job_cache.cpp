#include "services/coordinator/parsed_job_cache.h"

#include "core/util/status.h"
#include "services/farm/job_rules.h"

namespace pbgi::farm {

ParsedJobCache::ParsedJobCache(JobStore& store, std::string stateDir, int tileSize)
    : store_(store), stateDir_(std::move(stateDir)), tileSize_(tileSize) {}

absl::StatusOr<std::shared_ptr<const ParsedJob>> ParsedJobCache::get(int64_t job) {
  {
    std::lock_guard lock(mutex_);
    if (auto it = views_.find(job); it != views_.end()) return it->second;
  }
  PBGI_ASSIGN_OR_RETURN(JobInfo info, store_.job(job));
  auto view = std::make_shared<ParsedJob>();
  view->spec = std::move(info.spec);
  PBGI_ASSIGN_OR_RETURN(view->shot,
                        jobShot(view->spec.shotText, view->spec.shotPath, view->spec.overrides));
  view->tiles = farmTiles(view->shot, tileSize_);
  std::lock_guard lock(mutex_);
  return views_.emplace(job, std::move(view)).first->second;
}

std::string ParsedJobCache::workDir(int64_t job) const { return jobWorkDir(stateDir_, job); }

std::string ParsedJobCache::frameOutput(const ParsedJob& view, int frame) {
  return outputPathForFrame(view.spec.outputPattern, frame,
                            view.shot.lastFrame > view.shot.firstFrame);
}

}  // namespace pbgi::farm
