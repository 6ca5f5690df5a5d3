#pragma once
// PostgreSQL plumbing for the job store, private to services/coordinator: connections with
// their prepared statements (a pool of them), transactions retried when the server asks for it (serialization
// failures, deadlocks), and errors that name the database, without its password, and the
// statement. libpqxx's exceptions stop here; callers see absl::Status.
#include <condition_variable>
#include <cstdint>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <random>
#include <string>
#include <unordered_map>
#include <utility>
#include <vector>

#include <absl/status/status.h>
#include <absl/status/statusor.h>
#include <pqxx/pqxx>

#include "core/util/status.h"

namespace pbgi::farm {

// An integer parameter that may be NULL (no frame, no tile). Not std::optional: GCC 12 warns
// that libpqxx's inlined parameter code reads an empty optional's value.
struct NullableInt {
  bool null = true;
  int value = 0;
};
inline NullableInt nullable(std::optional<int> value) {
  return value ? NullableInt{false, *value} : NullableInt{};
}

}  // namespace pbgi::farm

template <>
struct pqxx::string_traits<pbgi::farm::NullableInt> {
  using T = pbgi::farm::NullableInt;
  static constexpr const char* name() noexcept { return "NullableInt"; }
  static constexpr bool has_null() noexcept { return true; }
  static bool is_null(const T& v) { return v.null; }
  static T null() { return {}; }
  static void from_string(const char text[], T& v) {
    v.null = false;
    string_traits<int>::from_string(text, v.value);
  }
  static std::string to_string(const T& v) { return string_traits<int>::to_string(v.value); }
};

namespace pbgi::farm {

// A BYTEA column's bytes.
inline std::string pgBytes(const pqxx::field& field) { return pqxx::binarystring(field).str(); }

// A row read by column number, as job_store.h's row readers take it.
struct PgRow {
  const pqxx::row& row;
  int64_t int64(int column) const { return row[column].as<int64_t>(); }
  int integer(int column) const { return row[column].as<int>(); }
  double real(int column) const { return row[column].as<double>(); }
  bool boolean(int column) const { return row[column].as<bool>(); }
  std::string text(int column) const { return row[column].as<std::string>(); }
  std::string bytes(int column) const { return pgBytes(row[column]); }
  // A result column: NULL only if a row was written otherwise than by completeAudit().
  double realOrNan(int column) const {
    return row[column].is_null() ? std::numeric_limits<double>::quiet_NaN() : real(column);
  }
};

class PgSession;

// One transaction as a store method sees it. Statements are prepared once per connection;
// the one running is remembered for the error message.
class PgTx {
 public:
  PgTx(pqxx::transaction_base& txn, PgSession& session, const char*& statement)
      : txn_(txn), session_(session), statement_(statement) {}

  template <typename... Args>
  pqxx::result exec(const char* sql, Args&&... args);
  // Several statements in one string, unprepared (the schema).
  pqxx::result script(const char* sql) {
    statement_ = sql;
    return txn_.exec(sql);
  }

 private:
  pqxx::transaction_base& txn_;
  PgSession& session_;
  const char*& statement_;
};

enum class PgAccess { kRead, kWrite };

// A connection to one database behind a mutex, (re)opened on demand.
class PgSession {
 public:
  explicit PgSession(std::string uri);

  // The URI as errors show it: without its password.
  const std::string& shownUri() const { return shownUri_; }

  // Runs body(PgTx&), which returns absl::Status or absl::StatusOr<T>, as one transaction:
  // committed when the body succeeds, rolled back when it returns an error or throws.
  // Serialization failures and deadlocks run it again (at most kMaxTries times in all), and
  // so does a connection that broke before the commit (once). Writes run at READ COMMITTED;
  // reads in a read-only REPEATABLE READ transaction, one snapshot for the whole answer.
  template <typename Body>
  auto transaction(PgAccess access, Body&& body) -> decltype(body(std::declval<PgTx&>()));

  // The name `sql` is prepared under on the current connection.
  const std::string& prepared(const char* sql);

  static constexpr int kMaxTries = 8;

 private:
  struct Failure {
    absl::Status status;
    bool retry = false;
  };
  absl::Status connectLocked();
  // Turns the exception in flight into a status, and says whether the call may run again.
  Failure failed(const char* statement, int attempt);
  void pause(int attempt);

  const std::string uri_;
  const std::string shownUri_;
  std::mutex mutex_;
  std::unique_ptr<pqxx::connection> connection_;
  std::unordered_map<std::string, std::string> statementNames_;  // of connection_
  std::minstd_rand jitter_;
};

// Connections to one database, each used by one transaction at a time: concurrent calls run
// on different connections, so the server overlaps them and flushes their commits together
// (one connection would serialize every call behind one WAL flush). Connections open on first
// use; a call waits when all are busy.
class PgPool {
 public:
  PgPool(const std::string& uri, int size) {
    for (int i = 0; i < size; ++i) {
      all_.push_back(std::make_unique<PgSession>(uri));
      idle_.push_back(all_.back().get());
    }
  }
  const std::string& shownUri() const { return all_.front()->shownUri(); }

  template <typename Body>
  auto transaction(PgAccess access, Body&& body) -> decltype(body(std::declval<PgTx&>())) {
    PgSession* session = nullptr;
    {
      std::unique_lock lock(mutex_);
      freed_.wait(lock, [&] { return !idle_.empty(); });
      session = idle_.back();
      idle_.pop_back();
    }
    auto result = session->transaction(access, std::forward<Body>(body));
    {
      std::lock_guard lock(mutex_);
      idle_.push_back(session);
    }
    freed_.notify_one();
    return result;
  }

 private:
  std::mutex mutex_;
  std::condition_variable freed_;
  std::vector<std::unique_ptr<PgSession>> all_;
  std::vector<PgSession*> idle_;
};

template <typename... Args>
pqxx::result PgTx::exec(const char* sql, Args&&... args) {
  statement_ = sql;
  return txn_.exec_prepared(session_.prepared(sql), std::forward<Args>(args)...);
}

template <typename Body>
auto PgSession::transaction(PgAccess access, Body&& body) -> decltype(body(std::declval<PgTx&>())) {
  using Result = decltype(body(std::declval<PgTx&>()));
  std::lock_guard lock(mutex_);
  absl::Status last;
  for (int attempt = 1; attempt <= kMaxTries; ++attempt) {
    const char* statement = "BEGIN";
    const auto run = [&](pqxx::transaction_base& txn) -> Result {
      PgTx tx(txn, *this, statement);
      Result result = body(tx);
      if (!result.ok()) return result;  // the transaction rolls back as it goes
      statement = "COMMIT";
      txn.commit();
      return result;
    };
    try {
      PBGI_RETURN_IF_ERROR(connectLocked());
      if (access == PgAccess::kRead) {
        pqxx::transaction<pqxx::repeatable_read, pqxx::read_only> txn(*connection_);
        return run(txn);
      }
      pqxx::work txn(*connection_);
      return run(txn);
    } catch (...) {
      Failure f = failed(statement, attempt);
      if (!f.retry) return f.status;
      last = std::move(f.status);
    }
    pause(attempt);
  }
  return withContext(last, fmt::format("gave up after {} tries", kMaxTries));
}

}  // namespace pbgi::farm
