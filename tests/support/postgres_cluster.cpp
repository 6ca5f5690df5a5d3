#include "tests/support/postgres_cluster.h"

#include <fcntl.h>
#include <netinet/in.h>
#include <pwd.h>
#include <spawn.h>
#include <sys/file.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <cstdlib>
#include <cctype>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <fstream>
#include <memory>
#include <mutex>
#include <sstream>
#include <vector>

#include <fmt/format.h>
#include <fmt/ranges.h>
#include <pqxx/pqxx>

#include "tests/support/test_paths.h"

extern char** environ;

namespace pbgi::testing {
namespace {

namespace fs = std::filesystem;

bool hasServer(const fs::path& dir) {
  return fs::is_regular_file(dir / "initdb") && fs::is_regular_file(dir / "pg_ctl");
}

// $PBGI_POSTGRES_BIN, else the newest /usr/lib/postgresql/<version>/bin (Debian's layout),
// else the folder of an initdb on PATH.
absl::StatusOr<fs::path> findServerBinaries() {
  if (const char* env = std::getenv("PBGI_POSTGRES_BIN"); env != nullptr && *env != '\0') {
    if (hasServer(env)) return fs::path(env);
    return absl::NotFoundError(
        fmt::format("PBGI_POSTGRES_BIN={}: no initdb and pg_ctl there", env));
  }
  std::vector<std::pair<int, fs::path>> versions;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator("/usr/lib/postgresql", ec)) {
    const std::string name = entry.path().filename().string();
    const auto digit = [](unsigned char c) { return std::isdigit(c) != 0; };
    if (!name.empty() && std::all_of(name.begin(), name.end(), digit) &&
        hasServer(entry.path() / "bin")) {
      versions.emplace_back(std::stoi(name), entry.path() / "bin");
    }
  }
  if (!versions.empty()) return std::max_element(versions.begin(), versions.end())->second;
  if (const char* path = std::getenv("PATH")) {
    std::stringstream dirs(path);
    for (std::string dir; std::getline(dirs, dir, ':');) {
      if (!dir.empty() && hasServer(dir)) return fs::path(dir);
    }
  }
  return absl::NotFoundError(
      "no PostgreSQL server binaries (initdb, pg_ctl) under /usr/lib/postgresql/*/bin or on "
      "PATH: install postgresql-15 (deploy/setup-debian.sh) or set PBGI_POSTGRES_BIN");
}

// The port only names the socket file (no TCP listener), but a free one keeps it unique.
int freePort() {
  const int fd = socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  socklen_t size = sizeof(addr);
  int port = 5432;
  if (fd >= 0 && bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)) == 0 &&
      getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &size) == 0) {
    port = ntohs(addr.sin_port);
  }
  if (fd >= 0) close(fd);
  return port;
}

std::string tail(const fs::path& log) {
  std::ifstream in(log);
  std::string text((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
  constexpr size_t kMaxChars = 2000;
  return text.size() > kMaxChars ? "..." + text.substr(text.size() - kMaxChars) : text;
}

// Runs argv (prefixed with runuser when runAs is set) in `cwd`, its output into `log`.
absl::Status run(std::vector<std::string> argv, const std::string& runAs, const fs::path& cwd,
                 const fs::path& log) {
  if (!runAs.empty()) argv.insert(argv.begin(), {"runuser", "-u", runAs, "--"});
  std::vector<char*> args;
  for (std::string& a : argv) args.push_back(a.data());
  args.push_back(nullptr);
  posix_spawn_file_actions_t actions;
  posix_spawn_file_actions_init(&actions);
  posix_spawn_file_actions_addopen(&actions, 0, "/dev/null", O_RDONLY, 0);
  // Not the test's own stdout: a server that kept ctest's pipe open would hang ctest.
  posix_spawn_file_actions_addopen(&actions, 1, log.c_str(), O_WRONLY | O_CREAT | O_TRUNC, 0644);
  posix_spawn_file_actions_adddup2(&actions, 1, 2);
  posix_spawn_file_actions_addchdir_np(&actions, cwd.c_str());
  pid_t pid = 0;
  const int rc = posix_spawnp(&pid, args[0], &actions, nullptr, args.data(), environ);
  posix_spawn_file_actions_destroy(&actions);
  const std::string command = fmt::format("{}", fmt::join(argv, " "));
  if (rc != 0) return absl::InternalError(fmt::format("{}: {}", command, std::strerror(rc)));
  int status = 0;
  while (waitpid(pid, &status, 0) < 0 && errno == EINTR) {
  }
  if (WIFEXITED(status) && WEXITSTATUS(status) == 0) return absl::OkStatus();
  return absl::InternalError(
      fmt::format("{}: exit status {}; its log:\n{}", command, status, tail(log)));
}

std::mutex sharedMutex;
std::unique_ptr<PostgresCluster> sharedCluster;

class PostgresClusterEnvironment : public ::testing::Environment {
 public:
  void TearDown() override { PostgresCluster::stopShared(); }
};
::testing::Environment* const kEnvironment =
    ::testing::AddGlobalTestEnvironment(new PostgresClusterEnvironment);

}  // namespace

bool postgresRequired() {
  const char* env = std::getenv("PBGI_REQUIRE_POSTGRES");
  return env != nullptr && *env != '\0' && std::string(env) != "0";
}

absl::StatusOr<PostgresCluster*> PostgresCluster::shared() {
  std::lock_guard lock(sharedMutex);
  if (sharedCluster == nullptr) {
    std::unique_ptr<PostgresCluster> cluster(new PostgresCluster());
    if (absl::Status s = cluster->start(); !s.ok()) return s;
    sharedCluster = std::move(cluster);
  }
  return sharedCluster.get();
}

void PostgresCluster::stopShared() {
  std::lock_guard lock(sharedMutex);
  sharedCluster.reset();
}

PostgresCluster::~PostgresCluster() {
  if (absl::Status s = stop(); !s.ok()) std::fprintf(stderr, "%s\n", s.ToString().c_str());
}

absl::Status PostgresCluster::start() {
  auto bin = findServerBinaries();
  if (!bin.ok()) return bin.status();
  bin_ = *bin;
  const char* sharedDir = std::getenv("PBGI_POSTGRES_SHARED_DIR");
  int lock = -1;
  if (sharedDir != nullptr && *sharedDir != '\0') {
    // One cluster for every test process: the first starts it, under the folder's lock.
    dir_ = sharedDir;
    std::error_code ec;
    fs::create_directories(dir_, ec);
    lock = ::open((dir_ / "lock").c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);  // not the server's
    if (lock < 0 || ::flock(lock, LOCK_EX) != 0) {
      return absl::InternalError(fmt::format("locking {}: {}", dir_.string(), std::strerror(errno)));
    }
    stopsItself_ = false;
    std::ifstream portFile(dir_ / "port");
    if (portFile >> port_ && fs::exists(dir_ / "data" / "postmaster.pid")) {
      const passwd* user = geteuid() == 0 ? getpwnam("postgres") : nullptr;
      if (user != nullptr) runAs_ = "postgres";
      if (run({(bin_ / "pg_ctl").string(), "-D", (dir_ / "data").string(), "status"}, runAs_,
              dir_, dir_ / "status.log")
              .ok()) {
        running_ = true;
        ::close(lock);  // its descriptor's lock goes with it
        return absl::OkStatus();
      }
    }
    fs::remove_all(dir_ / "data", ec);
  } else {
    dir_ = makeTempDir("postgres");
  }
  const auto unlock = [&] {
    if (lock >= 0) ::close(lock);
  };
  absl::Status started = startServer();
  if (started.ok() && !stopsItself_) std::ofstream(dir_ / "port") << port_;
  unlock();
  return started;
}

absl::Status PostgresCluster::startServer() {
  if (geteuid() == 0) {
    const passwd* user = getpwnam("postgres");
    if (user == nullptr) {
      return absl::FailedPreconditionError(
          "running as root, which initdb refuses, and there is no `postgres` user to run it as");
    }
    if (chown(dir_.c_str(), user->pw_uid, user->pw_gid) != 0) {
      return absl::InternalError(fmt::format("chown {}: {}", dir_.string(), std::strerror(errno)));
    }
    runAs_ = "postgres";
  }
  port_ = freePort();
  const fs::path data = dir_ / "data";
  absl::Status initdb = run({(bin_ / "initdb").string(), "-D", data.string(), "-U", "pbgi",
                             "--auth=trust", "--no-sync", "--encoding=UTF8", "--locale=C"},
                            runAs_, dir_, dir_ / "initdb.log");
  if (!initdb.ok()) return initdb;
  // Durability is not what the tests are about; a benchmark comparing stores asks for it.
  const char* durableEnv = std::getenv("PBGI_POSTGRES_DURABLE");
  const bool durable = durableEnv != nullptr && *durableEnv != '\0' && std::string(durableEnv) != "0";
  const std::string options = fmt::format(
      "-k {} -p {} -c listen_addresses=''{}", dir_.string(), port_,
      durable ? "" : " -c fsync=off -c synchronous_commit=off -c full_page_writes=off");
  absl::Status started = run({(bin_ / "pg_ctl").string(), "-D", data.string(), "-l",
                              (dir_ / "server.log").string(), "-o", options, "-w", "start"},
                             runAs_, dir_, dir_ / "pg_ctl.log");
  if (!started.ok()) {
    return absl::InternalError(fmt::format("{}\nserver log:\n{}", std::string(started.message()),
                                           tail(dir_ / "server.log")));
  }
  running_ = true;
  return absl::OkStatus();
}

absl::Status PostgresCluster::stop() {
  if (!running_ || !stopsItself_) return absl::OkStatus();
  running_ = false;
  return run(
      {(bin_ / "pg_ctl").string(), "-D", (dir_ / "data").string(), "-m", "immediate", "-w", "stop"},
      runAs_, dir_, dir_ / "stop.log");
}

std::string PostgresCluster::uri(const std::string& database) const {
  return fmt::format("postgresql:///{}?host={}&port={}&user=pbgi", database, dir_.string(), port_);
}

absl::Status PostgresCluster::execute(const std::string& database, const std::string& sql) {
  try {
    pqxx::connection connection(uri(database));
    pqxx::nontransaction(connection).exec(sql);
    return absl::OkStatus();
  } catch (const std::exception& e) {
    return absl::InternalError(fmt::format("{}: {}: {}", uri(database), sql, e.what()));
  }
}

absl::StatusOr<std::string> PostgresCluster::createDatabase() {
  const std::string name = fmt::format("pbgi_test_{}_{}", ::getpid(), ++databases_);
  if (absl::Status s = execute("postgres", "CREATE DATABASE " + name); !s.ok()) return s;
  return name;
}

}  // namespace pbgi::testing
