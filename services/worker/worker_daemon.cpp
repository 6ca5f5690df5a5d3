// pbgi-worker --coordinator HOST:PORT [--config FILE] [--token-file FILE] ...

#include <cstdio>
#include <map>
#include <thread>

#include <CLI/CLI.hpp>

#include "core/util/log.h"
#include "services/farm/farm_client.h"
#include "services/util/cli_checks.h"
#include "services/util/daemon.h"
#include "services/worker/worker.h"

namespace pbgi::farm {

namespace {

// An option taking one of `words` (any case) for `target`, "auto" by default.
template <typename Choice>
void addChoice(CLI::App& app, const std::string& name, Choice& target, const std::string& help,
               std::map<std::string, Choice> words) {
  app.add_option(name, target, help)
      ->transform(CLI::CheckedTransformer(std::move(words), CLI::ignore_case))
      ->default_str("auto");
}

}  // namespace

int workerDaemonMain(int argc, char** argv) {
  CLI::App app{"pbgi-worker: a render farm worker daemon"};
  app.set_config("--config", "", "TOML file of these options (keys are the long flag names)");
  app.allow_config_extras(CLI::config_extras_mode::error);  // a misspelt key is an error
  WorkerOptions o;
  std::string tokenFile;
  int cacheMb = 0;
  int sceneCacheMb = 2048;
  app.add_option("--coordinator", o.coordinator, "The coordinator's host:port")->required();
  app.add_option("--token-file", tokenFile, "The farm token (default: $PBGI_TOKEN)");
  TlsFiles tls;
  app.add_option("--tls-ca", tls.ca,
                 "TLS: the CA that signed the coordinator's certificate (default: plaintext)");
  app.add_option("--tls-cert", tls.cert,
                 "TLS: this worker's certificate, for a coordinator that asks for one");
  app.add_option("--tls-key", tls.key, "TLS: the key of --tls-cert");
  app.add_option("--id", o.id, "Worker name (default: host:pid)");
  app.add_option("--threads", o.threads, "Render threads (default: all cores)")
      ->check(positiveNumber());
  app.add_option("--cache-mb", cacheMb, "Tree page cache in MiB (default: the shot's cache_mb)")
      ->check(positiveNumber());
  app.add_option("--scene-cache-mb", sceneCacheMb,
                 "Memory for the scenes kept between tasks, in MiB (0: keep none)")
      ->check(nonNegativeNumber())
      ->capture_default_str();
  int diskCacheMb = 4096;
  app.add_option("--cache-dir", o.cacheDir,
                 "Local disk cache of streamed tree pages (default: <temp>/pbgi-worker-<id>)");
  app.add_option("--disk-cache-mb", diskCacheMb,
                 "Disk the streamed pages may take in --cache-dir, in MiB (0: keep none)")
      ->check(nonNegativeNumber())
      ->capture_default_str();
  addChoice(app, "--tree-source", o.treeSource,
            "auto: the shared job folder when visible, else stream; shared; stream",
            {{"auto", TreeSource::kAuto},
             {"shared", TreeSource::kShared},
             {"stream", TreeSource::kStream}});
  addChoice(app, "--files", o.fileSource,
            "auto: the coordinator's job folder when visible here, else a local copy whose "
            "results are sent to the coordinator; shared; copy",
            {{"auto", FileSource::kAuto}, {"shared", FileSource::kShared}, {"copy", FileSource::kCopy}});
  app.add_option("--poll-seconds", o.pollSeconds, "Between lease requests while idle")
      ->check(positiveNumber())
      ->capture_default_str();
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    if (e.get_exit_code() != 0) {
      std::fprintf(stderr, "pbgi-worker: error: %s\n", e.what());
      return 2;
    }
    return app.exit(e);
  }
  log::setLevel(log::Level::kInfo);
  o.cacheBytes = static_cast<size_t>(cacheMb) << 20;
  o.sceneCacheBytes = static_cast<size_t>(sceneCacheMb) << 20;
  o.diskCacheBytes = static_cast<size_t>(diskCacheMb) << 20;
  auto token = loadClientToken(tokenFile);
  if (!token.ok()) {
    std::fprintf(stderr, "pbgi-worker: error: %s\n", std::string(token.status().message()).c_str());
    return 2;
  }
  o.token = *token;
  auto pem = readClientTls(tls);
  if (!pem.ok()) {
    std::fprintf(stderr, "pbgi-worker: error: %s\n", std::string(pem.status().message()).c_str());
    return 2;
  }
  o.tls = *std::move(pem);
  blockStopSignals();
  static std::atomic<bool> stop{false};
  // SIGTERM: finish the task in hand, report it, then exit.
  std::thread([] {
    waitForStopSignal();
    stop.store(true);
  }).detach();
  return runWorker(o, stop);
}

}  // namespace pbgi::farm
