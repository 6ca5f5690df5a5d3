#pragma once
// The coordinator's page service, for workers that cannot see the job folder: a frame's tree
// opened (its header, directory and sections sent once), then single pages as stored, in the
// order asked (farm.proto: OpenTree, FetchPages). Each page is checked here before it is sent,
// so a page damaged on this disk is named as such; pages of a tree the frame no longer has
// (baked again) are refused.
#include <cstdint>
#include <functional>
#include <memory>
#include <mutex>
#include <string>
#include <utility>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "formats/pbgi/page_file.h"
#include "pbgi/farm/v1/farm.pb.h"
#include "services/coordinator/coordinator_metrics.h"
#include "services/coordinator/parsed_job_cache.h"

namespace pbgi::farm {

class PageService {
 public:
  PageService(ParsedJobCache& jobs, CoordinatorMetrics& metrics);

  absl::Status openTree(const v1::OpenTreeRequest& request, v1::OpenTreeResponse* response);
  // `write` sends a chunk; false when the worker went away (the rest is not read).
  absl::Status fetchPages(const v1::FetchPagesRequest& request,
                          const std::function<bool(const v1::PageChunk&)>& write);

 private:
  // The frame's tree, opened (its head read and checked) once and kept while its file is the
  // same one: a worker asks for a page at a time.
  absl::StatusOr<std::shared_ptr<const PageFileReader>> tree(int64_t job, int frame);

  // A file is known by path, inode and modification time, so a frame baked again is opened
  // again.
  struct FileKey {
    std::string path;
    uint64_t inode = 0;
    int64_t mtimeNs = 0;
    bool operator==(const FileKey&) const = default;
  };

  ParsedJobCache& jobs_;
  CoordinatorMetrics& metrics_;
  std::mutex mutex_;
  std::vector<std::pair<FileKey, std::shared_ptr<const PageFileReader>>> open_;  // oldest first
};

}  // namespace pbgi::farm
