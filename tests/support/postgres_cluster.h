#pragma once
// A throwaway PostgreSQL cluster for tests: initdb into a temporary folder, a server that
// listens only on a Unix socket in that folder (no TCP), trust authentication for the user
// "pbgi", and a fresh database per test. One per test process, started on first use and
// stopped at the end by a gtest environment (pg_ctl -m immediate stop), so that a test binary
// that never asks for one never starts one.
//
// initdb refuses to run as root: as root, initdb and pg_ctl run as the `postgres` system user
// (runuser), which owns the folder. Without PostgreSQL's server binaries (Debian:
// postgresql-15) the tests that need a cluster skip, saying why, unless PBGI_REQUIRE_POSTGRES=1
// (CI) makes that a failure. PBGI_POSTGRES_BIN names another folder of server binaries.
//
// With PBGI_POSTGRES_SHARED_DIR set (ctest sets it for the services tests, which run a process
// per test), the cluster lives in that folder and is shared by every test process: the first
// starts it under a lock, the others connect, none stops it; a ctest cleanup fixture does
// (tests/support/postgres_stop.sh).
//
// The server runs without fsync and synchronous commits (durability is not what the tests are
// about) unless PBGI_POSTGRES_DURABLE=1 (farm_bench, which compares the stores' committed
// throughput). Databases are named by process, so none collide.
#include <filesystem>
#include <string>

#include <absl/status/status.h>
#include <absl/status/statusor.h>
#include <gtest/gtest.h>

namespace pbgi::testing {

class PostgresCluster {
 public:
  // The process's cluster, started on first use. NotFound when there are no server binaries;
  // other errors, with the server's log, when there are and the cluster does not start.
  static absl::StatusOr<PostgresCluster*> shared();
  // Stops the shared cluster if one started (the environment's TearDown).
  static void stopShared();

  PostgresCluster(const PostgresCluster&) = delete;
  PostgresCluster& operator=(const PostgresCluster&) = delete;
  ~PostgresCluster();  // stops the server

  // A new, empty database; returns its name.
  absl::StatusOr<std::string> createDatabase();
  // postgresql:///<database>?host=<folder>&port=<port>&user=pbgi
  std::string uri(const std::string& database) const;
  // Runs SQL statements in `database` outside the store under test (a test's sabotage).
  absl::Status execute(const std::string& database, const std::string& sql);

 private:
  PostgresCluster() = default;
  absl::Status start();
  absl::Status startServer();  // initdb and pg_ctl start in dir_
  absl::Status stop();

  std::filesystem::path bin_;
  std::filesystem::path dir_;
  std::string runAs_;  // the user initdb and pg_ctl run as; empty: this one
  int port_ = 0;
  bool running_ = false;
  bool stopsItself_ = true;  // false: a cluster shared between test processes (see shared())
  int databases_ = 0;
};

// Whether PBGI_REQUIRE_POSTGRES asks for missing server binaries to fail the tests.
bool postgresRequired();

// Whether a test without a cluster skips (missing binaries, not required) or fails.
inline bool skipWithoutPostgres(const absl::Status& status) {
  return absl::IsNotFound(status) && !postgresRequired();
}

}  // namespace pbgi::testing

// In a test or SetUp(): declares `PostgresCluster* var`, or skips the test (fails it under
// PBGI_REQUIRE_POSTGRES=1, or when the cluster does not start) saying why.
#define PBGI_POSTGRES_CLUSTER(var)                                                     \
  auto var##_or = ::pbgi::testing::PostgresCluster::shared();                          \
  if (!var##_or.ok()) {                                                                \
    if (::pbgi::testing::skipWithoutPostgres(var##_or.status())) {                     \
      GTEST_SKIP() << var##_or.status() << " (PBGI_REQUIRE_POSTGRES=1 fails instead)"; \
    }                                                                                  \
    FAIL() << var##_or.status();                                                       \
  }                                                                                    \
  ::pbgi::testing::PostgresCluster* const var = *var##_or
