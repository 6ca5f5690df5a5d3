#pragma once
// SQLite plumbing for the job store, private to services/coordinator: owners for the connection
// and its statements, one use of a prepared statement, and errors that name the file.
#include <sqlite3.h>

#include <cstdint>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <type_traits>
#include <utility>

#include <absl/status/status.h>
#include <absl/status/statusor.h>

#include "core/util/status.h"
#include "services/job_store/job_store.h"  // sqlSummary

namespace pbgi::farm {

struct DatabaseCloser {
  void operator()(sqlite3* db) const { sqlite3_close_v2(db); }
};
using DatabasePtr = std::unique_ptr<sqlite3, DatabaseCloser>;

struct StatementFinalizer {
  void operator()(sqlite3_stmt* stmt) const { sqlite3_finalize(stmt); }
};
using StatementPtr = std::unique_ptr<sqlite3_stmt, StatementFinalizer>;

// "path: what: sqlite's message". Unavailable for busy, locked, full and cannot-open (the
// environment's doing, which may pass); Internal for the rest (a bug or a damaged file).
absl::Status sqliteStatus(int rc, std::string_view message, std::string_view path,
                          std::string_view what);

// One use of a cached prepared statement. It resets the statement when it goes, because a
// statement left in the middle of its rows would hold its snapshot past the COMMIT. A failed
// prepare or bind is kept and returned by the first step(), so call sites bind unconditionally.
class Query {
 public:
  // stmt is null exactly when `prepared` is an error.
  Query(sqlite3* db, sqlite3_stmt* stmt, absl::Status prepared, const std::string& path)
      : db_(db), stmt_(stmt), status_(std::move(prepared)), path_(path) {}
  Query(const Query&) = delete;
  Query& operator=(const Query&) = delete;
  ~Query();

  Query& bind(int index, int64_t value);
  Query& bind(int index, int value) { return bind(index, static_cast<int64_t>(value)); }
  Query& bind(int index, double value);
  Query& bind(int index, std::string_view value);
  Query& bindBlob(int index, std::string_view value);
  Query& bind(int index, std::nullopt_t);
  template <typename E>
  requires std::is_enum_v<E> Query& bind(int index, E value) {
    return bind(index, static_cast<int>(value));
  }
  template <typename T>
  Query& bind(int index, const std::optional<T>& value) {
    return value ? bind(index, *value) : bind(index, std::nullopt);
  }

  // True while a row is available.
  absl::StatusOr<bool> step();
  // For statements whose rows nobody reads.
  absl::Status run();

  int64_t int64(int column) const { return sqlite3_column_int64(stmt_, column); }
  int integer(int column) const { return sqlite3_column_int(stmt_, column); }
  double real(int column) const { return sqlite3_column_double(stmt_, column); }
  int columns() const { return sqlite3_column_count(stmt_); }
  bool isNull(int column) const { return sqlite3_column_type(stmt_, column) == SQLITE_NULL; }
  // Text or blob, byte for byte.
  std::string text(int column) const;
  std::string bytes(int column) const { return text(column); }
  bool boolean(int column) const { return integer(column) != 0; }
  // NULL is how SQLite stores a NaN.
  double realOrNan(int column) const {
    return isNull(column) ? std::numeric_limits<double>::quiet_NaN() : real(column);
  }

 private:
  Query& note(int rc);

  sqlite3* db_;
  sqlite3_stmt* stmt_;
  absl::Status status_;
  const std::string& path_;
};

}  // namespace pbgi::farm
