// SQLite connection, transaction and statement wrappers; contract in sqlite_db.h.
#include "storage/sqlite_db.h"

#include <sqlite3.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <limits>
#include <system_error>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace esg::storage {
namespace {

// "sqlite: <context>: <message> (<code name>)" with the code chosen by StatusCodeForSqliteResult.
absl::Status SqliteError(int rc, sqlite3* db, absl::string_view context) {
  // sqlite3_errmsg describes the most recent failure on the connection; fall back to the generic
  // text of the code when the connection is gone or the message belongs to another call.
  const char* message = db != nullptr ? sqlite3_errmsg(db) : sqlite3_errstr(rc);
  return absl::Status(StatusCodeForSqliteResult(rc),
                      absl::StrFormat("sqlite: %s: %s (%s, code %d)", context, message,
                                      sqlite3_errstr(rc), rc));
}

const char* SynchronousName(Synchronous s) {
  switch (s) {
    case Synchronous::kOff:
      return "OFF";
    case Synchronous::kNormal:
      return "NORMAL";
    case Synchronous::kFull:
      return "FULL";
    case Synchronous::kExtra:
      return "EXTRA";
  }
  return "FULL";
}

}  // namespace

absl::StatusCode StatusCodeForSqliteResult(int result_code) {
  switch (result_code) {
    case SQLITE_CONSTRAINT_PRIMARYKEY:
    case SQLITE_CONSTRAINT_UNIQUE:
      return absl::StatusCode::kAlreadyExists;
    case SQLITE_CONSTRAINT_FOREIGNKEY:
      return absl::StatusCode::kFailedPrecondition;
    case SQLITE_IOERR_CORRUPTFS:
      return absl::StatusCode::kDataLoss;
    default:
      break;
  }
  switch (result_code & 0xff) {
    case SQLITE_BUSY:
    case SQLITE_LOCKED:
    case SQLITE_IOERR:
    case SQLITE_PROTOCOL:
      return absl::StatusCode::kUnavailable;
    case SQLITE_CORRUPT:
    case SQLITE_NOTADB:
      return absl::StatusCode::kDataLoss;
    case SQLITE_CONSTRAINT:
    case SQLITE_TOOBIG:
    case SQLITE_MISMATCH:
      return absl::StatusCode::kInvalidArgument;
    case SQLITE_FULL:
    case SQLITE_NOMEM:
      return absl::StatusCode::kResourceExhausted;
    case SQLITE_PERM:
    case SQLITE_AUTH:
      return absl::StatusCode::kPermissionDenied;
    case SQLITE_CANTOPEN:
    case SQLITE_READONLY:
      return absl::StatusCode::kFailedPrecondition;
    case SQLITE_INTERRUPT:
      return absl::StatusCode::kCancelled;
    case SQLITE_ABORT:
    case SQLITE_SCHEMA:
      return absl::StatusCode::kAborted;
    default:
      return absl::StatusCode::kInternal;
  }
}

// ---------------------------------------------------------------------------------------------
// Statement

Statement::Statement(sqlite3* db, sqlite3_stmt* stmt, std::string sql)
    : db_(db), stmt_(stmt), sql_(std::move(sql)) {}

Statement::~Statement() { sqlite3_finalize(stmt_); }

void Statement::NoteBindResult(int rc, int index) {
  if (rc != SQLITE_OK && bind_status_.ok()) {
    bind_status_ = SqliteError(rc, db_, absl::StrCat("binding parameter ", index, " of ", sql_));
  }
}

Statement& Statement::BindInt64(int index, int64_t value) {
  NoteBindResult(sqlite3_bind_int64(stmt_, index, value), index);
  return *this;
}

Statement& Statement::BindDouble(int index, double value) {
  NoteBindResult(std::isnan(value) ? sqlite3_bind_null(stmt_, index)
                                   : sqlite3_bind_double(stmt_, index, value),
                 index);
  return *this;
}

Statement& Statement::BindText(int index, absl::string_view value) {
  NoteBindResult(sqlite3_bind_text64(stmt_, index, value.data(), value.size(), SQLITE_TRANSIENT,
                                     SQLITE_UTF8),
                 index);
  return *this;
}

Statement& Statement::BindBlob(int index, absl::string_view bytes) {
  // A zero-length blob needs a non-null pointer, or SQLite binds NULL.
  static const char kEmpty = 0;
  NoteBindResult(sqlite3_bind_blob64(stmt_, index, bytes.empty() ? &kEmpty : bytes.data(),
                                     bytes.size(), SQLITE_TRANSIENT),
                 index);
  return *this;
}

Statement& Statement::BindNull(int index) {
  NoteBindResult(sqlite3_bind_null(stmt_, index), index);
  return *this;
}

absl::StatusOr<bool> Statement::Step() {
  if (!bind_status_.ok()) return bind_status_;
  const int rc = sqlite3_step(stmt_);
  if (rc == SQLITE_ROW) return true;
  if (rc == SQLITE_DONE) return false;
  return SqliteError(rc, db_, sql_);
}

absl::Status Statement::Run() {
  absl::StatusOr<bool> row = Step();
  if (!row.ok()) return row.status();
  if (*row) return absl::InternalError(absl::StrCat("statement returned a row: ", sql_));
  return absl::OkStatus();
}

void Statement::Reset() {
  // sqlite3_reset repeats the error of the last step, which has already been reported by Step().
  sqlite3_reset(stmt_);
  sqlite3_clear_bindings(stmt_);
  bind_status_ = absl::OkStatus();
}

int Statement::ColumnCount() const { return sqlite3_column_count(stmt_); }

bool Statement::ColumnIsNull(int column) const {
  return sqlite3_column_type(stmt_, column) == SQLITE_NULL;
}

int64_t Statement::ColumnInt64(int column) const { return sqlite3_column_int64(stmt_, column); }

double Statement::ColumnDouble(int column) const { return sqlite3_column_double(stmt_, column); }

double Statement::ColumnDoubleOrNaN(int column) const {
  return ColumnIsNull(column) ? std::numeric_limits<double>::quiet_NaN()
                              : sqlite3_column_double(stmt_, column);
}

std::string Statement::ColumnText(int column) const {
  const unsigned char* text = sqlite3_column_text(stmt_, column);
  const int size = sqlite3_column_bytes(stmt_, column);
  if (text == nullptr) return std::string();
  return std::string(reinterpret_cast<const char*>(text), static_cast<size_t>(size));
}

std::string Statement::ColumnBlob(int column) const {
  const void* blob = sqlite3_column_blob(stmt_, column);
  const int size = sqlite3_column_bytes(stmt_, column);
  if (blob == nullptr) return std::string();
  return std::string(static_cast<const char*>(blob), static_cast<size_t>(size));
}

// ---------------------------------------------------------------------------------------------
// Transaction

Transaction::Transaction(Transaction&& other) noexcept
    : db_(std::exchange(other.db_, nullptr)), used_(std::move(other.used_)) {}

Transaction::~Transaction() {
  // Nothing can be reported from a destructor; a failed ROLLBACK leaves SQLite to roll the
  // transaction back when the connection closes or the next BEGIN fails loudly.
  Rollback().IgnoreError();
}

void Transaction::ResetUsedStatements() {
  // A statement left mid-iteration would keep its read open and block COMMIT of writes.
  for (Statement* st : used_) st->Reset();
  used_.clear();
}

void Transaction::Release() {
  Database* db = std::exchange(db_, nullptr);
  if (db != nullptr) db->ReleaseLock();
}

absl::Status Transaction::Execute(absl::string_view sql) {
  if (db_ == nullptr) return absl::FailedPreconditionError("transaction already ended");
  return db_->ExecLocked(sql);
}

absl::StatusOr<Statement*> Transaction::Prepare(absl::string_view sql) {
  if (db_ == nullptr) return absl::FailedPreconditionError("transaction already ended");
  absl::StatusOr<Statement*> st = db_->PrepareLocked(sql);
  if (st.ok()) used_.push_back(*st);
  return st;
}

int64_t Transaction::ChangedRows() const {
  return db_ == nullptr ? 0 : sqlite3_changes64(db_->db_);
}

int64_t Transaction::LastInsertRowId() const {
  return db_ == nullptr ? 0 : sqlite3_last_insert_rowid(db_->db_);
}

absl::Status Transaction::Commit() {
  if (db_ == nullptr) return absl::FailedPreconditionError("transaction already ended");
  ResetUsedStatements();
  absl::Status status = db_->ExecLocked("COMMIT");
  if (!status.ok()) {
    // A failed COMMIT may leave the transaction open (e.g. SQLITE_BUSY); end it so that the
    // contract "over either way" holds. SQLite may already have rolled back by itself.
    if (!sqlite3_get_autocommit(db_->db_)) db_->ExecLocked("ROLLBACK").IgnoreError();
  }
  Release();
  return status;
}

absl::Status Transaction::Rollback() {
  if (db_ == nullptr) return absl::OkStatus();
  ResetUsedStatements();
  absl::Status status;
  if (!sqlite3_get_autocommit(db_->db_)) status = db_->ExecLocked("ROLLBACK");
  Release();
  return status;
}

// ---------------------------------------------------------------------------------------------
// Database

Database::Database(sqlite3* db, std::string path, const DatabaseOptions& options)
    : db_(db), path_(std::move(path)), options_(options) {}

Database::~Database() {
  {
    absl::MutexLock lock(&mu_);
    cache_.clear();  // finalizes every statement before the connection closes
  }
  sqlite3_close_v2(db_);
}

absl::StatusOr<std::unique_ptr<Database>> Database::Open(const std::string& path,
                                                         const DatabaseOptions& options) {
  if (path.empty()) return absl::InvalidArgumentError("database path: empty");
  if (options.busy_timeout <= absl::ZeroDuration()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "busy_timeout = ", absl::FormatDuration(options.busy_timeout), ": must be positive"));
  }
  if (!options.create_if_missing) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
      return absl::NotFoundError(absl::StrCat("database file ", path, " does not exist"));
    }
  }
  int flags = SQLITE_OPEN_READWRITE | SQLITE_OPEN_FULLMUTEX;
  if (options.create_if_missing) flags |= SQLITE_OPEN_CREATE;
  sqlite3* raw = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &raw, flags, nullptr);
  if (rc != SQLITE_OK) {
    absl::Status status = SqliteError(rc, raw, absl::StrCat("opening ", path));
    sqlite3_close_v2(raw);
    return status;
  }
  std::unique_ptr<Database> db(new Database(raw, path, options));
  sqlite3_extended_result_codes(raw, 1);
  const int64_t timeout_ms = absl::ToInt64Milliseconds(options.busy_timeout);
  sqlite3_busy_timeout(raw, static_cast<int>(
                                std::min<int64_t>(std::max<int64_t>(timeout_ms, 1),
                                                  std::numeric_limits<int>::max())));

  absl::MutexLock lock(&db->mu_);
  // The journal mode is persistent in the file; the PRAGMA answers with the mode in force.
  {
    absl::StatusOr<Statement*> st = db->PrepareLocked("PRAGMA journal_mode=WAL");
    if (!st.ok()) return st.status();
    absl::StatusOr<bool> row = (*st)->Step();
    if (!row.ok()) return row.status();
    const std::string mode = *row ? absl::AsciiStrToLower((*st)->ColumnText(0)) : "";
    (*st)->Reset();
    if (mode != "wal") {
      return absl::FailedPreconditionError(
          absl::StrCat("database ", path, ": journal_mode is '", mode, "', WAL required"));
    }
  }
  absl::Status status =
      db->ExecLocked(absl::StrCat("PRAGMA synchronous=", SynchronousName(options.synchronous)));
  if (!status.ok()) return status;
  return db;
}

absl::Status Database::Acquire() {
  if (owner_.load(std::memory_order_relaxed) == std::this_thread::get_id()) {
    return absl::FailedPreconditionError(
        "this thread already holds a transaction on this database (nested use would deadlock)");
  }
  mu_.Lock();
  owner_.store(std::this_thread::get_id(), std::memory_order_relaxed);
  return absl::OkStatus();
}

void Database::ReleaseLock() {
  owner_.store(std::thread::id(), std::memory_order_relaxed);
  mu_.Unlock();
}

absl::StatusOr<Transaction> Database::Begin(TransactionMode mode) {
  absl::Status status = Acquire();
  if (!status.ok()) return status;
  status =
      ExecLocked(mode == TransactionMode::kImmediate ? "BEGIN IMMEDIATE" : "BEGIN DEFERRED");
  if (!status.ok()) {
    ReleaseLock();
    return status;
  }
  return Transaction(this);
}

absl::Status Database::Execute(absl::string_view sql) {
  absl::Status status = Acquire();
  if (!status.ok()) return status;
  status = ExecLocked(sql);
  ReleaseLock();
  return status;
}

absl::Status Database::QuickCheck() {
  absl::StatusOr<Transaction> txn = Begin(TransactionMode::kDeferred);
  if (!txn.ok()) return txn.status();
  absl::StatusOr<Statement*> st = txn->Prepare("PRAGMA quick_check(1)");
  if (!st.ok()) return st.status();
  absl::StatusOr<bool> row = (*st)->Step();
  if (!row.ok()) return row.status();
  const std::string result = *row ? (*st)->ColumnText(0) : "no result";
  if (result != "ok") {
    return absl::DataLossError(absl::StrCat("database ", path_, ": quick_check: ", result));
  }
  return absl::OkStatus();
}

absl::Status Database::ExecLocked(absl::string_view sql) {
  // sqlite3_exec needs a NUL-terminated string.
  const std::string text(sql);
  const int rc = sqlite3_exec(db_, text.c_str(), nullptr, nullptr, nullptr);
  if (rc != SQLITE_OK) return SqliteError(rc, db_, text);
  return absl::OkStatus();
}

absl::StatusOr<Statement*> Database::PrepareLocked(absl::string_view sql) {
  auto it = cache_.find(sql);
  if (it != cache_.end()) {
    it->second->Reset();
    return it->second.get();
  }
  sqlite3_stmt* raw = nullptr;
  const char* tail = nullptr;
  const int rc = sqlite3_prepare_v3(db_, sql.data(), static_cast<int>(sql.size()),
                                    SQLITE_PREPARE_PERSISTENT, &raw, &tail);
  if (rc != SQLITE_OK) return SqliteError(rc, db_, absl::StrCat("preparing ", sql));
  if (raw == nullptr) return absl::InvalidArgumentError(absl::StrCat("no SQL statement in: ", sql));
  const absl::string_view rest(tail, static_cast<size_t>(sql.data() + sql.size() - tail));
  if (!absl::StripAsciiWhitespace(rest).empty()) {
    sqlite3_finalize(raw);
    return absl::InvalidArgumentError(
        absl::StrCat("Prepare takes exactly one SQL statement; extra text: ", rest));
  }
  auto st = std::unique_ptr<Statement>(new Statement(db_, raw, std::string(sql)));
  Statement* result = st.get();
  cache_.emplace(std::string(sql), std::move(st));
  return result;
}

}  // namespace esg::storage
