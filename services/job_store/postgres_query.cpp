#include "services/job_store/postgres_query.h"

#include <chrono>
#include <string_view>
#include <thread>

#include <fmt/format.h>

#include "services/job_store/job_store.h"  // redactedUri, sqlSummary

namespace pbgi::farm {
namespace {

// The first line of the server's message, without libpq's "ERROR:  " in front.
std::string serverMessage(const std::exception& e) {
  std::string_view text = e.what();
  text = text.substr(0, text.find('\n'));
  for (std::string_view prefix : {"ERROR:  ", "FATAL:  "}) {
    if (text.starts_with(prefix)) text.remove_prefix(prefix.size());
  }
  return std::string(text);
}

// Unavailable for what the environment may fix (connections, resources, lock waits, an
// operator's cancel); InvalidArgument for values the database cannot store; Internal for the
// rest (a bug, or a schema changed behind our back).
absl::StatusCode codeOfSqlState(std::string_view state) {
  for (std::string_view prefix : {"08", "40", "53", "55P03", "57"}) {
    if (state.starts_with(prefix)) return absl::StatusCode::kUnavailable;
  }
  if (state.starts_with("22")) return absl::StatusCode::kInvalidArgument;
  return absl::StatusCode::kInternal;
}

}  // namespace

PgSession::PgSession(std::string uri)
    : uri_(std::move(uri)), shownUri_(redactedUri(uri_)), jitter_(std::random_device{}()) {}

const std::string& PgSession::prepared(const char* sql) {
  auto it = statementNames_.find(sql);
  if (it == statementNames_.end()) {
    std::string name = fmt::format("pbgi_{}", statementNames_.size());
    connection_->prepare(name, sql);
    it = statementNames_.emplace(sql, std::move(name)).first;
  }
  return it->second;
}

absl::Status PgSession::connectLocked() {
  if (connection_ != nullptr && connection_->is_open()) return absl::OkStatus();
  connection_.reset();
  statementNames_.clear();
  try {
    auto connection = std::make_unique<pqxx::connection>(uri_);
    // CREATE ... IF NOT EXISTS notices are not worth a line on stderr.
    connection->set_variable("client_min_messages", "warning");
    // An operator's session that holds a row for long fails the call rather than hanging it.
    connection->set_variable("lock_timeout", "'5s'");
    // Plans for each call's own values: a generic plan made once for `frame = $2 OR $2 IS
    // NULL` and the like cannot use the indexes, and the task table grows by millions.
    connection->set_variable("plan_cache_mode", "force_custom_plan");
    connection_ = std::move(connection);
    return absl::OkStatus();
  } catch (const std::exception& e) {
    return absl::UnavailableError(
        fmt::format("{}: connecting to the job store: {}", shownUri_, serverMessage(e)));
  }
}

PgSession::Failure PgSession::failed(const char* statement, int attempt) {
  const std::string what = fmt::format("{}: {}", shownUri_, sqlSummary(statement));
  try {
    throw;
  } catch (const pqxx::serialization_failure& e) {
    return {absl::UnavailableError(fmt::format("{}: {} (SQLSTATE 40001)", what, serverMessage(e))),
            true};
  } catch (const pqxx::deadlock_detected& e) {
    return {absl::UnavailableError(fmt::format("{}: {} (SQLSTATE 40P01)", what, serverMessage(e))),
            true};
  } catch (const pqxx::in_doubt_error& e) {
    connection_.reset();
    return {absl::UnavailableError(fmt::format(
                "{}: the connection broke; the call may or may not have been committed: {}", what,
                serverMessage(e))),
            false};
  } catch (const pqxx::broken_connection& e) {
    // Nothing was committed: one more try, on a new connection.
    connection_.reset();
    return {absl::UnavailableError(fmt::format("{}: {}", what, serverMessage(e))), attempt < 2};
  } catch (const pqxx::sql_error& e) {
    return {absl::Status(codeOfSqlState(e.sqlstate()),
                         fmt::format("{}: {} (SQLSTATE {})", what, serverMessage(e), e.sqlstate())),
            false};
  } catch (const std::exception& e) {
    // Conversions of what the database returned, and libpqxx's own complaints.
    return {absl::InternalError(fmt::format("{}: {}", what, e.what())), false};
  }
}

void PgSession::pause(int attempt) {
  // Apart, so that the two coordinators that collided do not collide again at once.
  std::uniform_int_distribution<int> ms(1, 5 * attempt);
  std::this_thread::sleep_for(std::chrono::milliseconds(ms(jitter_)));
}

}  // namespace pbgi::farm
