// PostgreSQL connection and statement wrappers over libpq; contract in postgres_db.h.
#include "storage/postgres_db.h"

#include <libpq-fe.h>
#include <poll.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <limits>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_replace.h"
#include "absl/strings/strip.h"

namespace esg::storage {
namespace {

// PostgreSQL type OIDs (server/catalog/pg_type.dat), stable across versions.
constexpr unsigned int kBytea = 17;
constexpr unsigned int kInt8 = 20;
constexpr unsigned int kText = 25;
constexpr unsigned int kFloat8 = 701;

// Rewrites SQLite's numbered parameters "?N" as "$N" outside string literals and quoted
// identifiers; (*used)[N - 1]: whether ?N occurs, up to the largest N. InvalidArgument for an
// unnumbered "?".
absl::StatusOr<std::string> TranslateParameters(absl::string_view sql, std::vector<bool>* used) {
  std::string out;
  out.reserve(sql.size());
  used->clear();
  char quote = 0;
  for (size_t i = 0; i < sql.size(); ++i) {
    const char c = sql[i];
    if (quote != 0) {
      out.push_back(c);
      if (c == quote) quote = 0;
      continue;
    }
    if (c == '\'' || c == '"') {
      quote = c;
      out.push_back(c);
      continue;
    }
    if (c != '?') {
      out.push_back(c);
      continue;
    }
    size_t j = i + 1;
    while (j < sql.size() && absl::ascii_isdigit(static_cast<unsigned char>(sql[j]))) ++j;
    int n = 0;
    if (j == i + 1 || !absl::SimpleAtoi(sql.substr(i + 1, j - i - 1), &n) || n < 1) {
      return absl::InvalidArgumentError(
          absl::StrCat("parameters must be numbered (?1, ?2, ...): ", sql));
    }
    if (static_cast<int>(used->size()) < n) used->resize(static_cast<size_t>(n), false);
    (*used)[static_cast<size_t>(n - 1)] = true;
    absl::StrAppend(&out, "$", n);
    i = j - 1;
  }
  return out;
}

std::string ConnectionError(pg_conn* conn) {
  if (conn == nullptr) return "out of memory";
  return std::string(absl::StripTrailingAsciiWhitespace(PQerrorMessage(conn)));
}

void IgnoreNotice(void*, const char*) {}

// A new connection to `uri` (notices dropped); Unavailable "db: <uri without password>: cannot
// connect: <reason>".
absl::StatusOr<pg_conn*> Connect(const std::string& uri, const PostgresOptions& options,
                                 const char* application_name) {
  const std::string timeout =
      absl::StrCat(std::max<int64_t>(1, absl::ToInt64Seconds(options.connect_timeout)));
  const char* keywords[] = {"dbname", "connect_timeout", "application_name", nullptr};
  const char* values[] = {uri.c_str(), timeout.c_str(), application_name, nullptr};
  // expand_dbname = 1: the URI's own settings win over the defaults above where it gives them.
  pg_conn* conn = PQconnectdbParams(keywords, values, /*expand_dbname=*/1);
  if (conn == nullptr || PQstatus(conn) != CONNECTION_OK) {
    const std::string reason = ConnectionError(conn);
    PQfinish(conn);
    return absl::UnavailableError(
        absl::StrCat("db: ", RedactPostgresUri(uri), ": cannot connect: ", reason));
  }
  PQsetNoticeProcessor(conn, IgnoreNotice, nullptr);
  return conn;
}

// RedactPostgresUri, also collecting the password texts it removed (as written in `uri`, still
// percent-encoded) in *removed.
std::string RedactUri(absl::string_view uri, std::vector<std::string>* removed) {
  std::string out(uri);
  const size_t scheme = out.find("://");
  if (scheme != std::string::npos) {
    const size_t authority = scheme + 3;
    const size_t end = out.find_first_of("/?", authority);
    const size_t at = out.rfind('@', end == std::string::npos ? out.size() : end);
    if (at != std::string::npos && at > authority) {
      const size_t colon = out.find(':', authority);
      if (colon != std::string::npos && colon < at) {
        removed->push_back(out.substr(colon + 1, at - colon - 1));
        out.erase(colon, at - colon);
      }
    }
  }
  // password=... among the query parameters
  size_t p = out.find("password=");
  while (p != std::string::npos) {
    const size_t value = p + 9;
    const size_t end = std::min(out.find('&', p), out.size());
    removed->push_back(out.substr(value, end - value));
    out.replace(p, end - p, "password=***");
    p = out.find("password=", p + 12);
  }
  return out;
}

}  // namespace

bool IsPostgresUri(absl::string_view db) {
  return absl::StartsWith(db, "postgresql://") || absl::StartsWith(db, "postgres://");
}

std::string RedactPostgresUri(absl::string_view uri) {
  std::vector<std::string> removed;
  return RedactUri(uri, &removed);
}

absl::StatusCode StatusCodeForSqlState(absl::string_view sqlstate) {
  if (sqlstate.size() != 5) return absl::StatusCode::kUnavailable;  // no server answer
  if (sqlstate == "23505") return absl::StatusCode::kAlreadyExists;
  if (sqlstate == "23503") return absl::StatusCode::kFailedPrecondition;  // foreign key
  if (sqlstate == "XX001" || sqlstate == "XX002") return absl::StatusCode::kDataLoss;
  if (sqlstate == "57014") return absl::StatusCode::kCancelled;
  if (sqlstate == "25P02") return absl::StatusCode::kAborted;  // earlier error in transaction
  const absl::string_view cls = sqlstate.substr(0, 2);
  if (cls == "23" || cls == "22") return absl::StatusCode::kInvalidArgument;
  if (cls == "08" || cls == "40" || cls == "55" || cls == "57" || cls == "58") {
    return absl::StatusCode::kUnavailable;  // connection, rollback, lock, shutdown, system I/O
  }
  if (cls == "53") return absl::StatusCode::kResourceExhausted;
  if (cls == "28") return absl::StatusCode::kPermissionDenied;
  return absl::StatusCode::kInternal;  // SQL errors (class 42) are program errors, and the rest
}

// ---------------------------------------------------------------------------------------------
// PostgresStatement

PostgresStatement::PostgresStatement(PostgresDatabase* db, std::string sql, std::string pg_sql,
                                     std::vector<bool> used)
    : Statement(std::move(sql)),
      db_(db),
      pg_sql_(std::move(pg_sql)),
      used_(std::move(used)),
      params_(used_.size()) {}

PostgresStatement::~PostgresStatement() { PQclear(result_); }

PostgresStatement::Param* PostgresStatement::At(int index) {
  if (index < 1 || index > static_cast<int>(params_.size())) {
    if (bind_status_.ok()) {
      bind_status_ = absl::InternalError(absl::StrCat("binding parameter ", index, " of ", sql(),
                                                      ": the statement has ", params_.size()));
    }
    return nullptr;
  }
  return &params_[static_cast<size_t>(index - 1)];
}

PostgresStatement& PostgresStatement::BindInt64(int index, int64_t value) {
  if (Param* p = At(index)) *p = Param{kInt8, false, false, absl::StrCat(value)};
  return *this;
}

PostgresStatement& PostgresStatement::BindDouble(int index, double value) {
  Param* p = At(index);
  if (p == nullptr) return *this;
  if (std::isnan(value)) {
    *p = Param{kFloat8, true, false, ""};
  } else if (std::isinf(value)) {
    *p = Param{kFloat8, false, false, value > 0 ? "Infinity" : "-Infinity"};
  } else {
    *p = Param{kFloat8, false, false, absl::StrFormat("%.17g", value)};
  }
  return *this;
}

PostgresStatement& PostgresStatement::BindText(int index, absl::string_view value) {
  if (Param* p = At(index)) {
    if (value.find('\0') != absl::string_view::npos && bind_status_.ok()) {
      bind_status_ = absl::InvalidArgumentError(absl::StrCat(
          "parameter ", index, " of ", sql(), ": text with a NUL byte cannot be stored"));
    }
    *p = Param{kText, false, false, std::string(value)};
  }
  return *this;
}

PostgresStatement& PostgresStatement::BindBlob(int index, absl::string_view bytes) {
  if (Param* p = At(index)) *p = Param{kBytea, false, true, std::string(bytes)};
  return *this;
}

PostgresStatement& PostgresStatement::BindNull(int index) {
  if (Param* p = At(index)) *p = Param{};
  return *this;
}

absl::StatusOr<bool> PostgresStatement::Step() {
  if (result_ == nullptr) {
    if (!bind_status_.ok()) return bind_status_;
    const size_t n = params_.size();
    std::vector<unsigned int> types(n);
    std::vector<const char*> values(n);
    std::vector<int> lengths(n);
    std::vector<int> formats(n);
    for (size_t i = 0; i < n; ++i) {
      const Param& p = params_[i];
      // A parameter the SQL does not use still needs a type: PostgreSQL cannot infer one.
      types[i] = p.type == 0 && !used_[i] ? kText : p.type;
      values[i] = p.null ? nullptr : p.value.data();
      lengths[i] = static_cast<int>(p.value.size());
      formats[i] = p.binary ? 1 : 0;
    }
    pg_result* result = PQexecParams(db_->conn_, pg_sql_.c_str(), static_cast<int>(n),
                                     types.data(), values.data(), lengths.data(), formats.data(),
                                     /*resultFormat=*/0);
    absl::Status status = db_->CheckResult(result, sql());
    if (!status.ok()) {
      PQclear(result);
      return status;
    }
    result_ = result;
    row_ = -1;
  }
  if (row_ + 1 >= PQntuples(result_)) {
    row_ = PQntuples(result_);
    return false;
  }
  ++row_;
  return true;
}

void PostgresStatement::Reset() {
  PQclear(result_);
  result_ = nullptr;
  row_ = -1;
  for (Param& p : params_) p = Param{};
  bind_status_ = absl::OkStatus();
}

int PostgresStatement::ColumnCount() const {
  return result_ == nullptr ? 0 : PQnfields(result_);
}

bool PostgresStatement::ColumnIsNull(int column) const {
  if (result_ == nullptr || row_ < 0 || row_ >= PQntuples(result_)) return true;
  if (column < 0 || column >= PQnfields(result_)) return true;
  return PQgetisnull(result_, row_, column) == 1;
}

int64_t PostgresStatement::ColumnInt64(int column) const {
  if (ColumnIsNull(column)) return 0;
  const char* text = PQgetvalue(result_, row_, column);
  int64_t value = 0;
  if (absl::SimpleAtoi(text, &value)) return value;
  // SUM() of BIGINT is NUMERIC ("12" or "12.0"); booleans read as 0/1.
  if (text[0] == 't') return 1;
  if (text[0] == 'f') return 0;
  return static_cast<int64_t>(std::strtod(text, nullptr));
}

double PostgresStatement::ColumnDouble(int column) const {
  if (ColumnIsNull(column)) return 0.0;
  // float8 output: shortest exact form, or "NaN", "Infinity", "-Infinity" (strtod reads all).
  return std::strtod(PQgetvalue(result_, row_, column), nullptr);
}

std::string PostgresStatement::ColumnText(int column) const {
  if (ColumnIsNull(column)) return std::string();
  return std::string(PQgetvalue(result_, row_, column),
                     static_cast<size_t>(PQgetlength(result_, row_, column)));
}

std::string PostgresStatement::ColumnBlob(int column) const {
  if (ColumnIsNull(column)) return std::string();
  size_t size = 0;
  unsigned char* bytes = PQunescapeBytea(
      reinterpret_cast<const unsigned char*>(PQgetvalue(result_, row_, column)), &size);
  if (bytes == nullptr) return std::string();
  std::string out(reinterpret_cast<const char*>(bytes), size);
  PQfreemem(bytes);
  return out;
}

// ---------------------------------------------------------------------------------------------
// PostgresDatabase

PostgresDatabase::PostgresDatabase(pg_conn* conn, std::string uri, const PostgresOptions& options)
    : conn_(conn), uri_(std::move(uri)), name_(RedactPostgresUri(uri_)), options_(options) {}

PostgresDatabase::~PostgresDatabase() {
  WithLock([&] { cache_.clear(); });
  PQfinish(conn_);
}

absl::StatusOr<std::unique_ptr<PostgresDatabase>> PostgresDatabase::Open(
    const std::string& uri, const PostgresOptions& options) {
  const std::string name = RedactPostgresUri(uri);
  if (options.connect_timeout < absl::Seconds(1) || options.lock_timeout <= absl::ZeroDuration()) {
    return absl::InvalidArgumentError(
        "connect_timeout must be >= 1s and lock_timeout positive");
  }
  char* parse_error = nullptr;
  PQconninfoOption* parsed = PQconninfoParse(uri.c_str(), &parse_error);
  if (parsed == nullptr) {
    std::string reason = parse_error != nullptr
                             ? std::string(absl::StripTrailingAsciiWhitespace(parse_error))
                             : "out of memory";
    PQfreemem(parse_error);
    // libpq quotes the URI, or the token it could not decode, which may be the password.
    std::vector<std::string> passwords;
    RedactUri(uri, &passwords);
    reason = absl::StrReplaceAll(reason, {{uri, name}});
    for (const std::string& password : passwords) {
      if (!password.empty()) reason = absl::StrReplaceAll(reason, {{password, "***"}});
    }
    return absl::InvalidArgumentError(absl::StrCat("db: ", name, ": not a PostgreSQL connection "
                                                   "URI libpq accepts: ", reason));
  }
  PQconninfoFree(parsed);
  absl::StatusOr<pg_conn*> conn = Connect(uri, options, "esgd");
  if (!conn.ok()) return conn.status();
  std::unique_ptr<PostgresDatabase> db(new PostgresDatabase(*conn, uri, options));
  absl::Status status = db->WithLock([&] { return db->ConfigureSessionLocked(); });
  if (!status.ok()) return status;
  absl::StatusOr<Transaction> txn = db->Begin(TransactionMode::kDeferred);
  if (!txn.ok()) return txn.status();
  absl::StatusOr<Statement*> fsync = txn->Prepare("SELECT current_setting('fsync')");
  if (!fsync.ok()) return fsync.status();
  absl::StatusOr<bool> row = (*fsync)->Step();
  if (!row.ok()) return row.status();
  if (!*row || (*fsync)->ColumnText(0) != "on") {
    return absl::FailedPreconditionError(
        absl::StrCat("db: ", name, ": the server runs with fsync=off, so a committed (and "
                     "acknowledged) frame would not survive a crash of its host; set fsync=on"));
  }
  status = txn->Commit();
  if (!status.ok()) return status;
  return db;
}

absl::Status PostgresDatabase::ConfigureSessionLocked() {
  return ExecLocked(absl::StrCat(
      "SET synchronous_commit = on; SET TIME ZONE 'UTC'; SET extra_float_digits = 3; "
      "SET client_encoding = 'UTF8'; SET lock_timeout = ",
      std::max<int64_t>(1, absl::ToInt64Milliseconds(options_.lock_timeout))));
}

absl::Status PostgresDatabase::EnsureConnectedLocked() {
  if (PQstatus(conn_) == CONNECTION_OK) return absl::OkStatus();
  PQreset(conn_);
  if (PQstatus(conn_) != CONNECTION_OK) {
    return absl::UnavailableError(
        absl::StrCat("db: ", name_, ": connection lost: ", ConnectionError(conn_)));
  }
  PQsetNoticeProcessor(conn_, IgnoreNotice, nullptr);
  return ConfigureSessionLocked();
}

absl::Status PostgresDatabase::CheckResult(pg_result* result, absl::string_view context) {
  const ExecStatusType status = result == nullptr ? PGRES_FATAL_ERROR : PQresultStatus(result);
  if (status == PGRES_COMMAND_OK || status == PGRES_TUPLES_OK) {
    int64_t rows = 0;
    changed_rows_ = absl::SimpleAtoi(PQcmdTuples(result), &rows) ? rows : 0;
    return absl::OkStatus();
  }
  const char* sqlstate = result == nullptr ? nullptr : PQresultErrorField(result, PG_DIAG_SQLSTATE);
  std::string message = result != nullptr && PQresultErrorMessage(result)[0] != '\0'
                            ? PQresultErrorMessage(result)
                            : PQerrorMessage(conn_);
  message = std::string(absl::StripTrailingAsciiWhitespace(message));
  if (PQstatus(conn_) != CONNECTION_OK) {
    return absl::UnavailableError(
        absl::StrCat("postgresql: ", context, ": connection lost: ", message));
  }
  return absl::Status(StatusCodeForSqlState(sqlstate == nullptr ? "" : sqlstate),
                      absl::StrCat("postgresql: ", context, ": ", message,
                                   sqlstate == nullptr ? "" : absl::StrCat(" (SQLSTATE ", sqlstate, ")")));
}

absl::Status PostgresDatabase::BeginLocked(TransactionMode mode) {
  absl::Status status = EnsureConnectedLocked();
  if (!status.ok()) return status;
  // A connection left inside a transaction (a failed ROLLBACK) is ended first.
  if (PQtransactionStatus(conn_) != PQTRANS_IDLE) ExecLocked("ROLLBACK").IgnoreError();
  // READ COMMITTED in both modes: every row a server writes belongs to a spacecraft it owns
  // (docs/service.md "Storage backends"), and the keys back every insert.
  (void)mode;
  return ExecLocked("BEGIN");
}

absl::Status PostgresDatabase::ExecLocked(absl::string_view sql) {
  const std::string text(sql);
  pg_result* result = PQexec(conn_, text.c_str());
  absl::Status status = CheckResult(result, text);
  PQclear(result);
  return status;
}

absl::StatusOr<Statement*> PostgresDatabase::PrepareLocked(absl::string_view sql) {
  auto it = cache_.find(sql);
  if (it != cache_.end()) {
    it->second->Reset();
    return it->second.get();
  }
  std::vector<bool> used;
  absl::StatusOr<std::string> pg_sql = TranslateParameters(sql, &used);
  if (!pg_sql.ok()) return pg_sql.status();
  auto st = std::unique_ptr<PostgresStatement>(
      new PostgresStatement(this, std::string(sql), *std::move(pg_sql), std::move(used)));
  PostgresStatement* result = st.get();
  cache_.emplace(std::string(sql), std::move(st));
  return result;
}

absl::Status PostgresDatabase::CommitLocked() {
  pg_result* result = PQexec(conn_, "COMMIT");
  absl::Status status = CheckResult(result, "COMMIT");
  // COMMIT of a transaction an earlier error aborted "succeeds" with the tag ROLLBACK.
  if (status.ok() && std::string(PQcmdStatus(result)) != "COMMIT") {
    status = absl::AbortedError("the transaction was aborted by an earlier error");
  }
  PQclear(result);
  if (!status.ok() && PQstatus(conn_) == CONNECTION_OK &&
      PQtransactionStatus(conn_) != PQTRANS_IDLE) {
    ExecLocked("ROLLBACK").IgnoreError();
  }
  return status;
}

absl::Status PostgresDatabase::RollbackLocked() {
  if (PQstatus(conn_) != CONNECTION_OK) return absl::OkStatus();  // the server rolls back
  if (PQtransactionStatus(conn_) == PQTRANS_IDLE) return absl::OkStatus();
  return ExecLocked("ROLLBACK");
}

absl::StatusOr<std::unique_ptr<PostgresListener>> PostgresDatabase::Listen(
    const std::vector<std::string>& channels) const {
  return PostgresListener::Open(uri_, channels, options_);
}

int PostgresDatabase::BackendPid() {
  return WithLock([&] { return PQbackendPID(conn_); });
}

// ---------------------------------------------------------------------------------------------
// PostgresListener

PostgresListener::PostgresListener(pg_conn* conn, std::string uri,
                                   std::vector<std::string> channels, PostgresOptions options)
    : conn_(conn), uri_(std::move(uri)), channels_(std::move(channels)), options_(options) {}

PostgresListener::~PostgresListener() { PQfinish(conn_); }

absl::StatusOr<std::unique_ptr<PostgresListener>> PostgresListener::Open(
    const std::string& uri, const std::vector<std::string>& channels,
    const PostgresOptions& options) {
  if (channels.empty()) return absl::InvalidArgumentError("channels: none");
  for (const std::string& channel : channels) {
    if (channel.empty() ||
        channel.find_first_not_of("abcdefghijklmnopqrstuvwxyz0123456789_") != std::string::npos) {
      return absl::InvalidArgumentError(absl::StrCat("channel '", channel, "': not a plain name"));
    }
  }
  absl::StatusOr<pg_conn*> conn = Connect(uri, options, "esgd-listener");
  if (!conn.ok()) return conn.status();
  std::unique_ptr<PostgresListener> listener(new PostgresListener(*conn, uri, channels, options));
  absl::Status status = listener->ListenLocked();
  if (!status.ok()) return status;
  return listener;
}

absl::Status PostgresListener::ListenLocked() {
  for (const std::string& channel : channels_) {
    pg_result* result = PQexec(conn_, absl::StrCat("LISTEN ", channel).c_str());
    const bool ok = result != nullptr && PQresultStatus(result) == PGRES_COMMAND_OK;
    PQclear(result);
    if (!ok) {
      return absl::UnavailableError(absl::StrCat("db: ", RedactPostgresUri(uri_), ": LISTEN ",
                                                 channel, ": ", ConnectionError(conn_)));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<PostgresListener::Notification>> PostgresListener::Wait(
    absl::Duration timeout) {
  if (PQstatus(conn_) != CONNECTION_OK) {
    PQreset(conn_);
    if (PQstatus(conn_) != CONNECTION_OK) {
      return absl::UnavailableError(absl::StrCat("db: ", RedactPostgresUri(uri_),
                                                 ": connection lost: ", ConnectionError(conn_)));
    }
    PQsetNoticeProcessor(conn_, IgnoreNotice, nullptr);
    absl::Status listened = ListenLocked();
    if (!listened.ok()) return listened;
    // Whatever was notified while the connection was down is lost: say so once.
    return absl::UnavailableError("reconnected: notifications in between were lost");
  }
  std::vector<Notification> out;
  auto drain = [&] {
    while (PGnotify* n = PQnotifies(conn_)) {
      out.push_back({n->relname != nullptr ? n->relname : "", n->extra != nullptr ? n->extra : "",
                     n->be_pid});
      PQfreemem(n);
    }
  };
  drain();
  if (!out.empty()) return out;
  pollfd p{PQsocket(conn_), POLLIN, 0};
  const int ms = static_cast<int>(std::clamp<int64_t>(absl::ToInt64Milliseconds(timeout), 0,
                                                      std::numeric_limits<int>::max()));
  const int ready = ::poll(&p, 1, ms);
  if (ready < 0 && errno != EINTR) {
    return absl::UnavailableError(absl::StrCat("poll: ", std::strerror(errno)));
  }
  if (ready > 0 && PQconsumeInput(conn_) == 0) {
    return absl::UnavailableError(absl::StrCat("db: ", RedactPostgresUri(uri_),
                                               ": connection lost: ", ConnectionError(conn_)));
  }
  drain();
  return out;
}

absl::Status PostgresDatabase::QuickCheck() {
  absl::StatusOr<Transaction> txn = Begin(TransactionMode::kDeferred);
  if (!txn.ok()) return txn.status();
  absl::StatusOr<Statement*> tables = txn->Prepare(
      "SELECT tablename FROM pg_catalog.pg_tables WHERE schemaname = current_schema() "
      "ORDER BY tablename");
  if (!tables.ok()) return tables.status();
  std::vector<std::string> names;
  while (true) {
    absl::StatusOr<bool> row = (*tables)->Step();
    if (!row.ok()) return row.status();
    if (!*row) break;
    names.push_back((*tables)->ColumnText(0));
  }
  for (const std::string& table : names) {
    // Reads every row (a sequential scan touches each page, whose checksum the server checks).
    absl::StatusOr<Statement*> count =
        txn->Prepare(absl::StrCat("SELECT COUNT(*) FROM \"", table, "\""));
    if (!count.ok()) return count.status();
    absl::StatusOr<bool> row = (*count)->Step();
    if (!row.ok()) {
      return absl::DataLossError(absl::StrCat("database ", name_, ": table ", table,
                                              " cannot be read: ", row.status().message()));
    }
  }
  return txn->Commit();
}

}  // namespace esg::storage
