#include "services/job_store/sqlite_query.h"

#include <fmt/format.h>

namespace pbgi::farm {

absl::Status sqliteStatus(int rc, std::string_view message, std::string_view path,
                          std::string_view what) {
  std::string text = fmt::format("{}: {}: {} (sqlite error {})", path, what, message, rc);
  switch (rc & 0xff) {
    case SQLITE_BUSY:
    case SQLITE_LOCKED:
    case SQLITE_FULL:
    case SQLITE_CANTOPEN:
      return absl::UnavailableError(std::move(text));
    default:
      return absl::InternalError(std::move(text));
  }
}

Query::~Query() {
  if (stmt_ != nullptr) {
    sqlite3_reset(stmt_);
    sqlite3_clear_bindings(stmt_);
  }
}

Query& Query::bind(int index, int64_t value) {
  return note(stmt_ ? sqlite3_bind_int64(stmt_, index, value) : SQLITE_OK);
}

Query& Query::bind(int index, double value) {
  return note(stmt_ ? sqlite3_bind_double(stmt_, index, value) : SQLITE_OK);
}

Query& Query::bind(int index, std::string_view value) {
  return note(stmt_ ? sqlite3_bind_text(stmt_, index, value.data(), static_cast<int>(value.size()),
                                        SQLITE_TRANSIENT)
                    : SQLITE_OK);
}

Query& Query::bindBlob(int index, std::string_view value) {
  return note(stmt_ ? sqlite3_bind_blob(stmt_, index, value.data(), static_cast<int>(value.size()),
                                        SQLITE_TRANSIENT)
                    : SQLITE_OK);
}

Query& Query::bind(int index, std::nullopt_t) {
  return note(stmt_ ? sqlite3_bind_null(stmt_, index) : SQLITE_OK);
}

absl::StatusOr<bool> Query::step() {
  if (!status_.ok()) return status_;
  const int rc = sqlite3_step(stmt_);
  if (rc == SQLITE_ROW) return true;
  if (rc == SQLITE_DONE) return false;
  status_ = sqliteStatus(rc, sqlite3_errmsg(db_), path_, sqlSummary(sqlite3_sql(stmt_)));
  return status_;
}

absl::Status Query::run() {
  absl::StatusOr<bool> row = step();
  while (row.ok() && *row) row = step();
  return row.status();
}

std::string Query::text(int column) const {
  // Blob first, then its size: the order sqlite3 documents for reading bytes unconverted.
  const auto* data = static_cast<const char*>(sqlite3_column_blob(stmt_, column));
  if (data == nullptr) return {};
  return std::string(data, static_cast<size_t>(sqlite3_column_bytes(stmt_, column)));
}

Query& Query::note(int rc) {
  if (rc != SQLITE_OK && status_.ok()) {
    status_ =
        sqliteStatus(rc, sqlite3_errmsg(db_), path_, "binding " + sqlSummary(sqlite3_sql(stmt_)));
  }
  return *this;
}

}  // namespace pbgi::farm
