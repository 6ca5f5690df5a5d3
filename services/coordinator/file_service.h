#pragma once
// The coordinator's side of farm.proto's PutFile and GetFile: files of a job's folder (and
// its frames under the output root) for workers on hosts that do not see them. The
// coordinator names each file from (job, kind, frame, tile); an upload is taken only from the
// current attempt of the leased task that makes that file (a tile task its tile, a bake its
// frame's tree, an assemble its frame and preview), whole, and committed by rename.
#include <functional>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "pbgi/farm/v1/farm.pb.h"
#include "services/coordinator/parsed_job_cache.h"
#include "services/job_store/job_store.h"

namespace pbgi::farm {

class FileService {
 public:
  FileService(JobStore& store, ParsedJobCache& jobs) : store_(store), jobs_(jobs) {}

  // `next` reads the upload's next chunk (false: no more). Returns the file's path.
  absl::StatusOr<std::string> put(const std::function<bool(v1::PutFileChunk*)>& next);
  // `write` sends a chunk; false when the worker went away.
  absl::Status get(const v1::GetFileRequest& request,
                   const std::function<bool(const v1::FileChunk&)>& write);

  // Where the coordinator keeps the file.
  absl::StatusOr<std::string> pathOf(int64_t job, v1::FileKind kind, int frame, int tile);

 private:
  JobStore& store_;
  ParsedJobCache& jobs_;
};

}  // namespace pbgi::farm
