#include "services/coordinator/file_service.h"

#include <algorithm>
#include <filesystem>

#include <fmt/format.h>

#include "core/util/status.h"
#include "services/coordinator/lease_reaper.h"
#include "services/farm/file_transfer.h"
#include "services/farm/job_rules.h"

namespace pbgi::farm {

namespace fs = std::filesystem;

absl::StatusOr<std::string> FileService::pathOf(int64_t job, v1::FileKind kind, int frame,
                                                int tile) {
  PBGI_ASSIGN_OR_RETURN(const std::shared_ptr<const ParsedJob> view, jobs_.get(job));
  if (std::find(view->spec.frames.begin(), view->spec.frames.end(), frame) ==
      view->spec.frames.end()) {
    return absl::NotFoundError(fmt::format("job {} has no frame {}", job, frame));
  }
  const std::string workDir = jobs_.workDir(job);
  switch (kind) {
    case v1::FILE_KIND_TILE:
      if (tile < 0 || tile >= view->spec.tileCount) {
        return absl::NotFoundError(
            fmt::format("job {} frame {} has tiles 0..{}, not {}", job, frame,
                        view->spec.tileCount - 1, tile));
      }
      return farmTilePath(workDir, frame, tile);
    case v1::FILE_KIND_TREE:
      return jobTreePath(view->shot, workDir, frame);
    case v1::FILE_KIND_FRAME:
      return ParsedJobCache::frameOutput(*view, frame);
    case v1::FILE_KIND_PREVIEW:
      return fs::path(ParsedJobCache::frameOutput(*view, frame)).replace_extension(".png").string();
    default:
      return absl::InvalidArgumentError(fmt::format("file kind {}: not one this coordinator "
                                                    "keeps", static_cast<int>(kind)));
  }
}

absl::StatusOr<std::string> FileService::put(
    const std::function<bool(v1::PutFileChunk*)>& next) {
  v1::PutFileChunk chunk;
  if (!next(&chunk)) return absl::InvalidArgumentError("an upload without a first chunk");
  PBGI_ASSIGN_OR_RETURN(const TaskInfo task, store_.task(chunk.task()));
  PBGI_RETURN_IF_ERROR(checkCurrentLease(task, chunk.attempt()));
  // The files each kind of task makes, and nothing else.
  const v1::FileKind kind = chunk.kind();
  const bool allowed =
      (task.ref.kind == TaskKind::kTile && kind == v1::FILE_KIND_TILE &&
       chunk.tile() == task.ref.tile) ||
      (task.ref.kind == TaskKind::kBake && kind == v1::FILE_KIND_TREE) ||
      (task.ref.kind == TaskKind::kAssemble &&
       (kind == v1::FILE_KIND_FRAME || kind == v1::FILE_KIND_PREVIEW));
  if (!allowed) {
    return absl::PermissionDeniedError(
        fmt::format("{} (attempt {}) makes no {} file{}", task.ref.toString(), chunk.attempt(),
                    v1::FileKind_Name(kind),
                    kind == v1::FILE_KIND_TILE ? fmt::format(" of tile {}", chunk.tile()) : ""));
  }
  PBGI_ASSIGN_OR_RETURN(const std::string path,
                        pathOf(task.ref.job, kind, task.ref.frame, task.ref.tile));
  PBGI_RETURN_IF_ERROR(receiveChunks(path, chunk, next));
  return path;
}

absl::Status FileService::get(const v1::GetFileRequest& request,
                              const std::function<bool(const v1::FileChunk&)>& write) {
  if (request.kind() != v1::FILE_KIND_TILE && request.kind() != v1::FILE_KIND_FRAME) {
    return absl::InvalidArgumentError(fmt::format(
        "file kind {}: GetFile sends tiles and frames (trees go a page at a time)",
        v1::FileKind_Name(request.kind())));
  }
  PBGI_ASSIGN_OR_RETURN(const std::string path, pathOf(request.job(), request.kind(),
                                                       request.frame(), request.tile()));
  return sendChunks(path, v1::FileChunk(), write);
}

}  // namespace pbgi::farm
