#pragma once
// The coordinator: the farm's gRPC service (pbgi.farm.v1) over the durable job store, and an
// HTTP endpoint with Prometheus metrics and a JSON status. The `pbgi-coordinator` daemon runs
// one; `pbgi run` runs one in-process. Its parts, each in its own file:
//   coordinator.cpp        the RPCs (requests into store calls), start and shutdown
//   farm_auth.h            the token check on every call, before any RPC runs
//   farm_tls.h             TLS: the certificates, the clients' trust, handshake failures
//   parsed_job_cache.h     each job's parsed shot, kept
//   status_report.h        a job's status for GetStatus and /status
//   page_service.h         trees a page at a time for workers that cannot see the job folder
//   lease_reaper.h         expired leases reclaimed
//   coordinator_metrics.h  every metric, declared once (metrics.h writes Prometheus text)
//
// Every RPC must carry "authorization: Bearer <token>"; others are refused (and counted).
// With TLS files the gRPC port speaks TLS only (and may require client certificates);
// without them, plaintext. A job's frames are written only under the output root. The
// coordinator keeps running through any bad job: a shot that does not parse is refused at
// submission with the reader's message, and a task that fails on a worker is retried, then
// dead, by the store's policy.
#include <cstdint>
#include <memory>
#include <string>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "services/coordinator/coordinator_options.h"
#include "services/job_store/job_store.h"

namespace pbgi::farm {

class Coordinator {
 public:
  // Opens (or creates) the job store (<stateDir>/jobs.db by default), binds both listeners
  // and starts serving. After a
  // restart, leases already in the database get one lease period to be heartbeated before
  // they are reclaimed: their workers may only have lost sight of the coordinator.
  static absl::StatusOr<std::unique_ptr<Coordinator>> start(const CoordinatorOptions& options);
  ~Coordinator();

  // The bound addresses ("127.0.0.1:41234"); httpAddress is empty without an HTTP listener.
  const std::string& address() const;
  const std::string& httpAddress() const;

  // The store, for an in-process caller (pbgi run) that watches its job.
  JobStore& store();

  // Stops accepting calls, lets calls in flight finish, and stops the expiry loop.
  void shutdown();

  // The Prometheus text the HTTP endpoint serves at /metrics.
  std::string metricsText();

  struct Impl;

 private:
  explicit Coordinator(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// pbgi-coordinator's command line (services/coordinator/coordinator_daemon.cpp).
int coordinatorDaemonMain(int argc, char** argv);

}  // namespace pbgi::farm
