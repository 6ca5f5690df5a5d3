#pragma once
// What `pbgi run` and the farm client commands (submit, status, cancel, retry, logs, workers)
// share: the job flags that become a submission, the coordinator connection flags, and the
// text that shows a job's progress.
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include <absl/status/statusor.h>

#include "core/scene/shot.h"
#include "services/cli/cli.h"
#include "services/farm/farm_client.h"

namespace CLI {
class App;
}

namespace pbgi::cli {

// Flags that shape a job: which frames, and the overrides of the shot's [render] settings.
struct JobFlags {
  std::string frames;  // "1-3,7"; empty: every frame
  std::string integrator;
  int spp = 0;
  std::string gather;
  std::string quality;
  std::string cacheMb;
  std::vector<std::string> set;  // integrator parameters, KEY=VALUE
  int priority = 0;
  // The accuracy audit (farm.proto SubmitJobRequest): unset or 0, the coordinator's defaults.
  std::optional<int> auditTiles;
  int auditSpp = 0;
  double auditThreshold = 0;
  ImageFlags image;  // --resolution / --scale, --seed, --aovs, --exr-compression
};
void addJobFlags(CLI::App& cmd, JobFlags& flags);
// The job's state as users read it: the store's word, or "stalled" / "waiting" for an active
// job that cannot go on (JobStatus.stall); and ", no worker is live" or the blocklisted
// workers, for a one-line listing.
std::string jobStateWord(const farm::v1::JobStatus& job);
std::string stallSummary(const farm::v1::JobStatus& job);
// A job's audits, one line per frame ("  audit frame 1: relMSE 0.0041, bias -1.2 % ..."), and
// the summary "audited 3/4 frames, 1 flagged" (empty without audits).
std::string describeAudits(const farm::v1::JobStatus& job);
std::string auditSummary(const farm::v1::JobStatus& job);

// The submission of `shot` (the job renders the bytes it was parsed from) with `flags`.
// Errors name the shot file or the flag.
absl::StatusOr<farm::v1::SubmitJobRequest> submitRequest(const ShotDesc& shot,
                                                         const JobFlags& flags);

// --coordinator (default: $PBGI_COORDINATOR, else 127.0.0.1:7411), --token-file, and TLS:
// --tls-ca, --tls-cert, --tls-key (default: $PBGI_TLS_CA, $PBGI_TLS_CERT, $PBGI_TLS_KEY).
struct ConnectionFlags {
  std::string coordinator;
  std::string tokenFile;
  farm::TlsFiles tls;
};
void addConnectionFlags(CLI::App& cmd, ConnectionFlags& flags);
// `readsOnly` (status, logs, workers): no token is needed where none is given, for a
// coordinator whose reads are open (--read-access open, its default).
absl::StatusOr<std::unique_ptr<farm::FarmClient>> connect(const ConnectionFlags& flags,
                                                          bool readsOnly = false);

// Tasks done of all tasks, over the job's frames.
struct JobProgress {
  int done = 0;
  int total = 0;
};
JobProgress jobProgress(const farm::v1::JobStatus& job);

// One line per frame (bake, tiles done of all, assemble) and the dead tasks with their errors.
std::string describeJob(const farm::v1::JobStatus& job);

}  // namespace pbgi::cli
