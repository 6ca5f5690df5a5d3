#pragma once
// How a coordinator runs: its listeners, state, store, token, TLS, leases and retries
// (coordinator.h starts one; farm_service.h's handlers read it too).
#include <string>

#include "services/farm/farm_tls.h"
#include "services/job_store/job_store.h"

namespace pbgi::farm {

struct CoordinatorOptions {
  std::string listen = "127.0.0.1:0";  // host:port; port 0 picks a free one
  std::string httpListen;              // host:port for /metrics and /status; empty: none
  std::string stateDir;                // jobs.db and jobs/<job>/ (bakes, tiles)
  // The job store: a SQLite file or a postgresql:// URI (openJobStore); empty: <stateDir>/jobs.db.
  std::string store;
  std::string outputRoot;              // every job's frames must lie under it
  std::string token;                   // required on every RPC that changes or works (not empty)
  // Reads (GetStatus, GetLogs, ListWorkers over gRPC; the dashboard, /status and /metrics over
  // HTTP) are one policy: open to whoever reaches the ports, or only with the token.
  bool readsNeedToken = false;
  // TLS: cert and key, the coordinator's certificate; ca, the CA that must have signed every
  // client's certificate (empty: none asked). All empty: plaintext.
  TlsFiles tls;
  double leaseSeconds = 30.0;          // a worker heartbeats well within this
  double expiryIntervalSeconds = 1.0;  // how often expired leases are reclaimed
  int tileSize = 0;                    // farm tile edge; 0: kDefaultFarmTileSize
  RetryPolicy retry;
  // Lease a worker the tasks of frames it holds first (within the job it would get anyway);
  // false: plain order (priority, job age, frame, kind, tile).
  bool localityDispatch = true;
};

}  // namespace pbgi::farm
