#pragma once
// The render worker: registers with a coordinator (cores, memory, cache size), then leases
// and runs tasks until it is told to stop:
//   bake      bakes the frame's tree into the job's bake folder;
//   tile      renders one farm tile of the frame to its EXR (written to a temporary, renamed);
//   assemble  checks every tile of the frame is there and writes the frame's EXR and preview.
// A worker keeps the scenes it loaded for later tasks of the same frame (a bake, then its
// tiles), within a memory budget. Tiles read the frame's tree from the shared job folder when
// this machine can see it, and otherwise fetch single pages of it from the coordinator's page
// service as their traversals reach them, each checked, through a bounded disk cache (of
// stored pages, kept between tasks and across restarts). While a
// task runs, a heartbeat thread extends its lease and reports progress. A coordinator that
// does not answer is waited for: the task's result is reported when it is back.
#include <atomic>
#include <cstddef>
#include <optional>
#include <string>

#include "services/farm/farm_tls.h"

namespace pbgi::farm {

enum class TreeSource {
  kAuto,    // the shared job folder when the tree is there, else the page service
  kShared,  // only the shared job folder
  kStream,  // only the page service
};

enum class FileSource {
  kAuto,  // the coordinator's job folder when it is visible here, else a local copy
  kShared,  // only the job folder (a task whose folder is not visible fails)
  kCopy,  // always a local copy: tasks read and write under <cache dir>/jobs/<job>, their
          // results are sent to the coordinator (PutFile) and their inputs fetched (GetFile)
};

struct WorkerOptions {
  std::string coordinator;   // host:port
  std::string token;
  std::optional<TlsPem> tls;  // readClientTls; nullopt: plaintext
  std::string id;            // empty: <host>:<pid>
  int threads = 0;           // 0: all cores
  size_t cacheBytes = 0;     // tree page cache budget; 0: the shot's cache_mb
  std::string cacheDir;      // streamed pages; empty: <temp>/pbgi-worker-<id>
  size_t diskCacheBytes = size_t{4} << 30;  // budget of the streamed pages kept on disk
  TreeSource treeSource = TreeSource::kAuto;
  FileSource fileSource = FileSource::kAuto;
  // Scenes (meshes, BVH, textures) kept between tasks, least recently used out first; each
  // scene counted at the resident memory its loading took.
  size_t sceneCacheBytes = size_t{2} << 30;
  double pollSeconds = 0.5;  // between lease requests while there is no work
};

// Runs until `stop` becomes true (the daemon sets it on SIGTERM). A task in progress is
// finished and reported first. Returns 0, or 1 when the coordinator refused the worker (a
// wrong token) or the options are unusable.
int runWorker(const WorkerOptions& options, const std::atomic<bool>& stop);

// pbgi-worker's command line (services/worker/worker_daemon.cpp).
int workerDaemonMain(int argc, char** argv);

}  // namespace pbgi::farm
