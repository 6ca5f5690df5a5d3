#include "services/coordinator/page_service.h"

#include <sys/stat.h>

#include <fmt/format.h>

#include "core/util/status.h"
#include "services/farm/job_rules.h"

namespace pbgi::farm {

PageService::PageService(ParsedJobCache& jobs, CoordinatorMetrics& metrics)
    : jobs_(jobs), metrics_(metrics) {}

absl::StatusOr<std::shared_ptr<const PageFileReader>> PageService::tree(int64_t job, int frame) {
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const ParsedJob> view, jobs_.get(job));
  PBGI_ASSIGN_OR_RETURN(const std::string path, jobTreePath(view->shot, jobs_.workDir(job), frame));
  struct stat st {};
  if (::stat(path.c_str(), &st) != 0) {
    return absl::NotFoundError(fmt::format(
        "job {} frame {}: no tree at {} (has the frame's bake run?)", job, frame, path));
  }
  const FileKey key{path, static_cast<uint64_t>(st.st_ino),
                    static_cast<int64_t>(st.st_mtim.tv_sec) * 1000000000 + st.st_mtim.tv_nsec};
  {
    std::lock_guard lock(mutex_);
    for (const auto& [k, reader] : open_) {
      if (k == key) return reader;
    }
  }
  PBGI_ASSIGN_OR_RETURN(std::unique_ptr<PageFileReader> opened, PageFileReader::open(path));
  std::shared_ptr<const PageFileReader> reader = std::move(opened);
  std::lock_guard lock(mutex_);
  std::erase_if(open_, [&](const auto& t) { return t.first.path == path; });
  open_.emplace_back(key, reader);
  constexpr size_t kOpenTrees = 16;  // each holds its head and a descriptor
  if (open_.size() > kOpenTrees) open_.erase(open_.begin());
  return reader;
}

absl::Status PageService::openTree(const v1::OpenTreeRequest& request,
                                   v1::OpenTreeResponse* response) {
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const PageFileReader> reader,
                        tree(request.job(), request.frame()));
  const PageFileHead& head = reader->head();
  response->set_header(head.header.data(), head.header.size());
  response->set_tail_offset(head.tailOffset);
  response->set_tail(head.tail.data(), head.tail.size());
  response->set_file_size(head.fileSize);
  metrics_.treesOpened->add();
  metrics_.pageBytesServed->add(head.bytes());
  return absl::OkStatus();
}

absl::Status PageService::fetchPages(const v1::FetchPagesRequest& request,
                                     const std::function<bool(const v1::PageChunk&)>& write) {
  if (request.pages_size() == 0) {
    return absl::InvalidArgumentError("FetchPages: name the pages (whole trees are not served)");
  }
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const PageFileReader> reader,
                        tree(request.job(), request.frame()));
  if (reader->head().treeId() != request.tree_id()) {
    return absl::FailedPreconditionError(fmt::format(
        "job {} frame {}: the tree is {:016x} now, not {:016x} (baked again); open it again",
        request.job(), request.frame(), reader->head().treeId(), request.tree_id()));
  }
  v1::PageChunk chunk;
  for (const uint32_t id : request.pages()) {
    // Checked here too: a page damaged on this disk is named as such, not as the network's.
    auto bytes = reader->readStoredPage(id);
    if (!bytes.ok()) {
      return withContext(bytes.status(), fmt::format("page service of job {} frame {}",
                                                     request.job(), request.frame()));
    }
    chunk.set_page(id);
    chunk.set_offset(reader->directory()[id].offset);
    chunk.set_data(bytes->data(), bytes->size());
    if (!write(chunk)) break;  // the worker went away
    metrics_.pagesServed->add();
    metrics_.pageBytesServed->add(bytes->size());
  }
  return absl::OkStatus();
}

}  // namespace pbgi::farm
