#pragma once
// The embedded farm: a coordinator in this process (its SQLite file in the state folder) and N
// pbgi-worker processes beside this executable, talking the same gRPC, tasks and files as a
// farm of many machines. `pbgi run` composes it with a progress bar.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include <absl/status/statusor.h>
#include <sys/types.h>

#include "pbgi/farm/v1/farm.pb.h"

namespace pbgi::farm {

class Coordinator;

struct LocalFarmOptions {
  std::string stateDir;    // the job database, bakes, tiles and worker logs
  std::string outputRoot;  // every job's frames must lie under it (created when missing)
  std::string token;       // the coordinator's and its workers' shared secret
  int tileSize = 0;        // farm tile edge; 0: the coordinator's default
  double leaseSeconds = 30.0;
};

class LocalFarm {
 public:
  // Starts the coordinator on a free local port.
  static absl::StatusOr<std::unique_ptr<LocalFarm>> start(const LocalFarmOptions& options);
  ~LocalFarm();

  const std::string& address() const;
  const std::string& token() const { return options_.token; }

  // The job a run continues: an unfinished one of the same shot bytes, overrides, frames and
  // output (a run that was interrupted), else a new submission. `resumed` says which.
  absl::StatusOr<int64_t> findOrSubmit(const v1::SubmitJobRequest& request, bool* resumed);

  // Starts `count` workers of `threads` render threads each, their output appended to
  // worker-<i>.log in the job's folder (logDir()). A worker is told to stop when this process
  // dies, however it dies.
  absl::Status startWorkers(int64_t job, int count, int threads);
  const std::string& logDir() const { return logDir_; }
  // Starts again a worker that died (a crash, the OOM killer), at most kMaxRestarts times
  // each, warning on stderr. False once every worker has exited for good.
  static constexpr int kMaxRestarts = 3;
  bool superviseWorkers();
  // SIGTERM to every worker (each finishes the task in hand, reports it and exits), then waits
  // for them.
  void stopWorkers();
  // Stops the coordinator (the workers first, when still running).
  void shutdown();

 private:
  struct Worker {
    pid_t pid = -1;
    int index = 0;
    int restarts = 0;
  };
  LocalFarm(LocalFarmOptions options, std::unique_ptr<Coordinator> coordinator);
  absl::StatusOr<pid_t> spawn(int index) const;

  LocalFarmOptions options_;
  std::unique_ptr<Coordinator> coordinator_;
  std::vector<Worker> workers_;
  std::string logDir_;
  int threads_ = 1;
};

}  // namespace pbgi::farm
