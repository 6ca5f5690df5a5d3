// pbgi-coordinator [--config FILE] [--listen HOST:PORT] [--state DIR] [--store URI] ...

#include <cstdio>
#include <map>
#include <filesystem>

#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include "core/util/log.h"
#include "core/util/status.h"
#include "services/coordinator/coordinator.h"
#include "services/farm/job_rules.h"
#include "services/util/cli_checks.h"
#include "services/util/daemon.h"

namespace pbgi::farm {

int coordinatorDaemonMain(int argc, char** argv) {
  CLI::App app{"pbgi-coordinator: the render farm's coordinator daemon"};
  app.set_config("--config", "", "TOML file of these options (keys are the long flag names)");
  app.allow_config_extras(CLI::config_extras_mode::error);  // a misspelt key is an error
  CoordinatorOptions o;
  o.listen = kDefaultCoordinatorAddress;
  std::string stateDir = "pbgi-state";
  std::string tokenFile;
  std::string readAccess = "open";
  std::string addressFile;
  app.add_option("--listen", o.listen, "gRPC address (port 0 picks a free one)")
      ->capture_default_str();
  app.add_option("--http", o.httpListen, "HTTP address of the web dashboard, /metrics and /status (empty: none)");
  app.add_option("--state", stateDir, "State folder: jobs.db, job folders, token")
      ->capture_default_str();
  app.add_option("--store", o.store,
                 "Job store: a SQLite file, or a postgresql://user@host/db URI that several "
                 "coordinators may share (default: <state>/jobs.db)");
  app.add_option("--output-root", o.outputRoot,
                 "Every job's frames must lie under this folder (default: <state>/output)");
  app.add_option("--token-file", tokenFile,
                 "The farm token; created with a random token when missing (default: <state>/token)");
  app.add_option("--read-access", readAccess,
                 "Who may read jobs, logs and workers, over gRPC and on the HTTP dashboard, "
                 "/status and /metrics: open (anyone who reaches the ports) or token (the farm "
                 "token: Authorization: Bearer, or the page opened once at /?token=TOKEN)")
      ->check(CLI::IsMember({"open", "token"}))
      ->capture_default_str();
  app.add_option("--tls-cert", o.tls.cert,
                 "TLS: the coordinator's certificate (PEM; default: plaintext)");
  app.add_option("--tls-key", o.tls.key, "TLS: the key of --tls-cert");
  app.add_option("--tls-client-ca", o.tls.ca,
                 "TLS: every client must present a certificate signed by this CA");
  app.add_option("--address-file", addressFile,
                 "Where the bound address is written (default: <state>/coordinator.addr)");
  app.add_option("--lease-seconds", o.leaseSeconds, "Lease length; workers heartbeat within it")
      ->check(positiveNumber())
      ->capture_default_str();
  app.add_option("--expiry-interval", o.expiryIntervalSeconds, "Seconds between lease sweeps")
      ->check(positiveNumber())
      ->capture_default_str();
  app.add_option("--tile-size", o.tileSize, "Farm tile edge in pixels")
      ->check(CLI::Range(16, 8192))
      ->default_val(kDefaultFarmTileSize);
  app.add_option("--max-attempts", o.retry.maxAttempts, "Attempts before a task is dead")
      ->check(CLI::Range(1, 1000))
      ->capture_default_str();
  app.add_option("--backoff-base", o.retry.backoffBase, "First retry back-off in seconds (doubles)")
      ->check(nonNegativeNumber())
      ->capture_default_str();
  app.add_option("--backoff-max", o.retry.backoffMax, "Longest retry back-off in seconds")
      ->check(nonNegativeNumber())
      ->capture_default_str();
  app.add_option("--dispatch", o.localityDispatch,
                 "locality: a worker gets the tasks of frames it holds first (within the job it "
                 "would get anyway); plain: priority, job age, frame, kind, tile")
      ->transform(CLI::CheckedTransformer(
          std::map<std::string, bool>{{"locality", true}, {"plain", false}}, CLI::ignore_case))
      ->default_str("locality");
  app.add_option(
         "--blocklist-after", o.retry.blocklistAfter,
         "Failures of one job on one worker that blocklist the worker for the job (0: never)")
      ->check(nonNegativeNumber())
      ->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() != 0) {
      std::fprintf(stderr, "pbgi-coordinator: error: %s\n", e.what());
      return 2;
    }
    return app.exit(e);
  }
  log::setLevel(log::Level::kInfo);
  namespace fs = std::filesystem;
  o.stateDir = stateDir;
  if (o.outputRoot.empty()) o.outputRoot = (fs::path(stateDir) / "output").string();
  std::error_code ec;
  fs::create_directories(o.outputRoot, ec);
  auto token = loadOrCreateToken(tokenFile.empty() ? (fs::path(stateDir) / "token").string()
                                                   : tokenFile);
  if (!token.ok()) {
    std::fprintf(stderr, "pbgi-coordinator: error: %s\n", std::string(token.status().message()).c_str());
    return 2;
  }
  o.token = *token;
  o.readsNeedToken = readAccess == "token";
  blockStopSignals();
  auto coordinator = Coordinator::start(o);
  if (!coordinator.ok()) {
    std::fprintf(stderr, "pbgi-coordinator: error: %s\n",
                 std::string(coordinator.status().message()).c_str());
    // A bad option (TLS files that do not fit) as on the command line; anything else failed.
    return absl::IsInvalidArgument(coordinator.status()) ? 2 : 1;
  }
  const std::string addressPath =
      addressFile.empty() ? (fs::path(stateDir) / "coordinator.addr").string() : addressFile;
  if (absl::Status s = writeFileAtomic(addressPath, (*coordinator)->address() + "\n", 0644);
      !s.ok()) {
    log::warn("{}", s.message());
  }
  // The HTTP address beside it (either may have been port 0); the gRPC file stays one line,
  // as scripts read it.
  if (!(*coordinator)->httpAddress().empty()) {
    const std::string httpPath = (fs::path(addressPath).parent_path() / "coordinator.http").string();
    if (absl::Status s = writeFileAtomic(httpPath, (*coordinator)->httpAddress() + "\n", 0644);
        !s.ok()) {
      log::warn("{}", s.message());
    }
  }
  std::printf("pbgi-coordinator: listening on %s\n", (*coordinator)->address().c_str());
  std::fflush(stdout);
  const int signal = waitForStopSignal();
  log::info("signal {}: shutting down", signal);
  (*coordinator)->shutdown();
  return 0;
}

}  // namespace pbgi::farm
