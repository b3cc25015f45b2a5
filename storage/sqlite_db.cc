// SQLite connection, transaction and statement wrappers; contract in sqlite_db.h.
#include "storage/sqlite_db.h"

#include <fcntl.h>
#include <sqlite3.h>
#include <sys/file.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
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

// Why `path` cannot be written as far as access(2) can tell: "<file>: <errno text>" for the
// first of the database file, its -wal (and -shm unless `exclusive`) and its directory that
// exists and is not writable (immutable, read-only file system, permissions); empty if none.
// access(2) rather than open(2): closing any descriptor of the database file would drop this
// process's POSIX locks on it, which SQLite relies on.
std::string WriteBlocker(const std::string& path, bool exclusive) {
  std::vector<std::string> files = {path, path + "-wal"};
  if (!exclusive) files.push_back(path + "-shm");
  for (const std::string& file : files) {
    if (::access(file.c_str(), F_OK) == 0 && ::access(file.c_str(), W_OK) != 0) {
      return absl::StrCat(file, ": ", std::error_code(errno, std::generic_category()).message());
    }
  }
  std::string dir = std::filesystem::path(path).parent_path().string();
  if (dir.empty()) dir = ".";
  if (::access(dir.c_str(), W_OK) != 0) {
    return absl::StrCat("directory ", dir, ": ",
                        std::error_code(errno, std::generic_category()).message());
  }
  return std::string();
}

std::string ErrnoText(int error) {
  return std::error_code(error, std::generic_category()).message();
}

// The owner lock of sqlite_db.h ("Owner lock"): the descriptor of "<path>.lock" (symbolic links
// of the path resolved, so two names of one file share the lock) with flock(LOCK_EX) held and
// this process's id written into it. Unavailable naming the holder's pid if another descriptor
// holds the lock; FailedPrecondition if the lock file cannot be created.
absl::StatusOr<int> TakeOwnerLock(const std::string& path) {
  std::error_code ec;
  std::filesystem::path resolved = std::filesystem::weakly_canonical(path, ec);
  if (ec) resolved = path;
  const std::string lock_path = resolved.string() + ".lock";
  const int fd = ::open(lock_path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) {
    const int error = errno;
    const std::filesystem::path dir = std::filesystem::path(path).parent_path();
    if (error == ENOENT && !dir.empty() && !std::filesystem::is_directory(dir, ec)) {
      return absl::FailedPreconditionError(absl::StrCat(
          "db: ", path, " cannot be opened: directory ", dir.string(), " does not exist"));
    }
    const std::string blocker = WriteBlocker(path, /*exclusive=*/true);
    return absl::FailedPreconditionError(absl::StrCat(
        "db: ", path, " cannot be written: ",
        blocker.empty() ? absl::StrCat(lock_path, ": ", ErrnoText(error)) : blocker));
  }
  if (::flock(fd, LOCK_EX | LOCK_NB) != 0) {
    const int error = errno;
    std::string holder = "unknown";
    char buffer[32] = {};
    const ssize_t n = ::pread(fd, buffer, sizeof buffer - 1, 0);
    ::close(fd);
    if (n > 0) {
      const std::string text = std::string(absl::StripAsciiWhitespace(
          absl::string_view(buffer, static_cast<size_t>(n))));
      if (!text.empty() && text.find_first_not_of("0123456789") == std::string::npos) {
        holder = text;
      }
    }
    if (error != EWOULDBLOCK) {
      return absl::UnavailableError(absl::StrCat("db: ", path, ": cannot lock ", lock_path, ": ",
                                                 ErrnoText(error)));
    }
    return absl::UnavailableError(absl::StrCat("db: ", path,
                                               " is locked by another process (pid ", holder,
                                               " holds ", lock_path,
                                               "; is another server using this file?)"));
  }
  // The pid only serves the message of a refused Open(); the lock works without it, so a disk
  // that refuses these bytes (full) is left to the write probe to report.
  const std::string pid = absl::StrCat(::getpid(), "\n");
  if (::ftruncate(fd, 0) == 0) {
    [[maybe_unused]] const ssize_t written = ::pwrite(fd, pid.data(), pid.size(), 0);
  }
  return fd;
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

SqliteStatement::SqliteStatement(sqlite3* db, sqlite3_stmt* stmt, std::string sql)
    : Statement(std::move(sql)), db_(db), stmt_(stmt) {}

SqliteStatement::~SqliteStatement() { sqlite3_finalize(stmt_); }

void SqliteStatement::NoteBindResult(int rc, int index) {
  if (rc != SQLITE_OK && bind_status_.ok()) {
    bind_status_ = SqliteError(rc, db_, absl::StrCat("binding parameter ", index, " of ", sql()));
  }
}

SqliteStatement& SqliteStatement::BindInt64(int index, int64_t value) {
  NoteBindResult(sqlite3_bind_int64(stmt_, index, value), index);
  return *this;
}

SqliteStatement& SqliteStatement::BindDouble(int index, double value) {
  NoteBindResult(std::isnan(value) ? sqlite3_bind_null(stmt_, index)
                                   : sqlite3_bind_double(stmt_, index, value),
                 index);
  return *this;
}

SqliteStatement& SqliteStatement::BindText(int index, absl::string_view value) {
  NoteBindResult(sqlite3_bind_text64(stmt_, index, value.data(), value.size(), SQLITE_TRANSIENT,
                                     SQLITE_UTF8),
                 index);
  return *this;
}

SqliteStatement& SqliteStatement::BindBlob(int index, absl::string_view bytes) {
  // A zero-length blob needs a non-null pointer, or SQLite binds NULL.
  static const char kEmpty = 0;
  NoteBindResult(sqlite3_bind_blob64(stmt_, index, bytes.empty() ? &kEmpty : bytes.data(),
                                     bytes.size(), SQLITE_TRANSIENT),
                 index);
  return *this;
}

SqliteStatement& SqliteStatement::BindNull(int index) {
  NoteBindResult(sqlite3_bind_null(stmt_, index), index);
  return *this;
}

absl::StatusOr<bool> SqliteStatement::Step() {
  if (!bind_status_.ok()) return bind_status_;
  const int rc = sqlite3_step(stmt_);
  if (rc == SQLITE_ROW) return true;
  if (rc == SQLITE_DONE) return false;
  return SqliteError(rc, db_, sql());
}

void SqliteStatement::Reset() {
  // sqlite3_reset repeats the error of the last step, which has already been reported by Step().
  sqlite3_reset(stmt_);
  sqlite3_clear_bindings(stmt_);
  bind_status_ = absl::OkStatus();
}

int SqliteStatement::ColumnCount() const { return sqlite3_column_count(stmt_); }

bool SqliteStatement::ColumnIsNull(int column) const {
  return sqlite3_column_type(stmt_, column) == SQLITE_NULL;
}

int64_t SqliteStatement::ColumnInt64(int column) const { return sqlite3_column_int64(stmt_, column); }

double SqliteStatement::ColumnDouble(int column) const { return sqlite3_column_double(stmt_, column); }

std::string SqliteStatement::ColumnText(int column) const {
  const unsigned char* text = sqlite3_column_text(stmt_, column);
  const int size = sqlite3_column_bytes(stmt_, column);
  if (text == nullptr) return std::string();
  return std::string(reinterpret_cast<const char*>(text), static_cast<size_t>(size));
}

std::string SqliteStatement::ColumnBlob(int column) const {
  const void* blob = sqlite3_column_blob(stmt_, column);
  const int size = sqlite3_column_bytes(stmt_, column);
  if (blob == nullptr) return std::string();
  return std::string(static_cast<const char*>(blob), static_cast<size_t>(size));
}

// ---------------------------------------------------------------------------------------------
// Database

SqliteDatabase::SqliteDatabase(sqlite3* db, std::string path, const DatabaseOptions& options)
    : db_(db), path_(std::move(path)), options_(options) {}

SqliteDatabase::~SqliteDatabase() {
  WithLock([&] { cache_.clear(); });  // finalizes every statement before the connection closes
  sqlite3_close_v2(db_);
  if (owner_lock_fd_ >= 0) ::close(owner_lock_fd_);  // releases the owner lock
}

absl::StatusOr<std::unique_ptr<SqliteDatabase>> SqliteDatabase::Open(
    const std::string& path, const DatabaseOptions& options) {
  if (path.empty()) return absl::InvalidArgumentError("database path: empty");
  if (options.busy_timeout <= absl::ZeroDuration()) {
    return absl::InvalidArgumentError(absl::StrCat(
        "busy_timeout = ", absl::FormatDuration(options.busy_timeout), ": must be positive"));
  }
  if (!options.vfs.empty() && sqlite3_vfs_find(options.vfs.c_str()) == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat("vfs = '", options.vfs, "': no SQLite VFS of that name is registered"));
  }
  if (!options.create_if_missing) {
    std::error_code ec;
    if (!std::filesystem::exists(path, ec)) {
      return absl::NotFoundError(absl::StrCat("database file ", path, " does not exist"));
    }
  }
  int owner_lock_fd = -1;
  if (options.exclusive) {
    absl::StatusOr<int> fd = TakeOwnerLock(path);
    if (!fd.ok()) return fd.status();
    owner_lock_fd = *fd;
  }
  int flags = SQLITE_OPEN_READWRITE | SQLITE_OPEN_FULLMUTEX;
  if (options.create_if_missing) flags |= SQLITE_OPEN_CREATE;
  sqlite3* raw = nullptr;
  const int rc = sqlite3_open_v2(path.c_str(), &raw, flags,
                                 options.vfs.empty() ? nullptr : options.vfs.c_str());
  if (rc != SQLITE_OK) {
    absl::Status status = SqliteError(rc, raw, absl::StrCat("opening ", path));
    sqlite3_close_v2(raw);
    if (owner_lock_fd >= 0) ::close(owner_lock_fd);
    if ((rc & 0xff) == SQLITE_CANTOPEN) {
      const std::filesystem::path dir = std::filesystem::path(path).parent_path();
      std::error_code ec;
      if (!dir.empty() && !std::filesystem::is_directory(dir, ec)) {
        return absl::FailedPreconditionError(absl::StrCat(
            "db: ", path, " cannot be opened: directory ", dir.string(), " does not exist"));
      }
      const std::string blocker = WriteBlocker(path, options.exclusive);
      if (!blocker.empty()) {
        return absl::FailedPreconditionError(
            absl::StrCat("db: ", path, " cannot be written: ", blocker));
      }
    }
    return status;
  }
  std::unique_ptr<SqliteDatabase> db(new SqliteDatabase(raw, path, options));
  db->owner_lock_fd_ = owner_lock_fd;  // released by the destructor, also on the errors below
  sqlite3_extended_result_codes(raw, 1);
  const int64_t timeout_ms = absl::ToInt64Milliseconds(options.busy_timeout);
  sqlite3_busy_timeout(raw, static_cast<int>(
                                std::min<int64_t>(std::max<int64_t>(timeout_ms, 1),
                                                  std::numeric_limits<int>::max())));
  int failed_rc = SQLITE_OK;
  absl::Status status = db->WithLock([&] { return db->ConfigureAndProbeLocked(&failed_rc); });
  if (status.ok()) return db;
  switch (status.code()) {
    case absl::StatusCode::kUnavailable:
      if ((failed_rc & 0xff) == SQLITE_BUSY || (failed_rc & 0xff) == SQLITE_LOCKED) {
        return absl::UnavailableError(absl::StrCat(
            "db: ", path, " is locked by another process",
            options.exclusive ? "" : " or connection", " (waited busy_timeout ",
            absl::FormatDuration(options.busy_timeout),
            "; is another server using this file?): ", status.message()));
      }
      break;
    case absl::StatusCode::kDataLoss:
    case absl::StatusCode::kInvalidArgument:
      return status;
    default:
      break;
  }
  // Anything else (read-only, cannot open the -wal, I/O error, disk full) means the file cannot
  // be used for writing: say why, in operator's terms where the file system tells.
  const std::string blocker = WriteBlocker(path, options.exclusive);
  return absl::FailedPreconditionError(
      blocker.empty()
          ? absl::StrCat("db: ", path, " cannot be written: ", status.message())
          : absl::StrCat("db: ", path, " cannot be written: ", blocker, " (", status.message(),
                         ")"));
}

absl::Status SqliteDatabase::ConfigureAndProbeLocked(int* failed_rc) {
  // Keeps the SQLite result code of the failing step, which Open() needs to tell a lock held by
  // another process from an I/O error (both are Unavailable).
  auto note = [&](absl::Status status) {
    if (!status.ok() && *failed_rc == SQLITE_OK) *failed_rc = sqlite3_extended_errcode(db_);
    return status;
  };
  // Checked first: on a read-only connection PRAGMA journal_mode fails with misleading errors.
  if (sqlite3_db_readonly(db_, "main") == 1) {
    return absl::FailedPreconditionError("SQLite could open the file only read-only");
  }
  // Must precede the first access of a WAL database: in exclusive mode SQLite then never maps
  // the -shm file (sqlite_db.h, "Exclusive locking").
  if (options_.exclusive) {
    absl::Status status = note(ExecLocked("PRAGMA locking_mode=EXCLUSIVE"));
    if (!status.ok()) return status;
  }
  // The journal mode is persistent in the file; the PRAGMA answers with the mode in force.
  {
    // Preparing reads the schema, so a lock held by another process can show up here already.
    absl::StatusOr<Statement*> st = PrepareLocked("PRAGMA journal_mode=WAL");
    if (!st.ok()) return note(st.status());
    absl::StatusOr<bool> row = (*st)->Step();
    note(row.status()).IgnoreError();
    const std::string mode =
        row.ok() && *row ? absl::AsciiStrToLower((*st)->ColumnText(0)) : "";
    (*st)->Reset();
    if (!row.ok()) return row.status();
    if (mode != "wal") {
      return absl::FailedPreconditionError(
          absl::StrCat("database ", path_, ": journal_mode is '", mode, "', WAL required"));
    }
  }
  absl::Status status =
      note(ExecLocked(absl::StrCat("PRAGMA synchronous=", SynchronousName(options_.synchronous))));
  if (!status.ok()) return status;

  // The write probe: a real commit (one -wal frame, synced as configured) that changes nothing.
  status = note(ExecLocked("BEGIN IMMEDIATE"));
  if (!status.ok()) return status;
  int64_t version = 0;
  absl::StatusOr<Statement*> read = PrepareLocked("PRAGMA user_version");
  status = note(read.status());
  if (status.ok()) {
    absl::StatusOr<bool> row = (*read)->Step();
    status = note(row.status());
    if (status.ok() && *row) version = (*read)->ColumnInt64(0);
    (*read)->Reset();
  }
  if (status.ok()) status = note(ExecLocked(absl::StrCat("PRAGMA user_version=", version)));
  if (status.ok()) status = note(ExecLocked("COMMIT"));
  if (!status.ok() && !sqlite3_get_autocommit(db_)) ExecLocked("ROLLBACK").IgnoreError();
  return status;
}

absl::Status SqliteDatabase::BeginLocked(TransactionMode mode) {
  return ExecLocked(mode == TransactionMode::kImmediate ? "BEGIN IMMEDIATE" : "BEGIN DEFERRED");
}

absl::Status SqliteDatabase::QuickCheck() {
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

absl::Status SqliteDatabase::ExecLocked(absl::string_view sql) {
  // sqlite3_exec needs a NUL-terminated string.
  const std::string text(sql);
  const int rc = sqlite3_exec(db_, text.c_str(), nullptr, nullptr, nullptr);
  if (rc != SQLITE_OK) return SqliteError(rc, db_, text);
  return absl::OkStatus();
}

absl::StatusOr<Statement*> SqliteDatabase::PrepareLocked(absl::string_view sql) {
  absl::StatusOr<SqliteStatement*> st = PrepareSqliteLocked(sql);
  if (!st.ok()) return st.status();
  return *st;
}

absl::StatusOr<SqliteStatement*> SqliteDatabase::PrepareSqliteLocked(absl::string_view sql) {
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
  auto st = std::unique_ptr<SqliteStatement>(new SqliteStatement(db_, raw, std::string(sql)));
  SqliteStatement* result = st.get();
  cache_.emplace(std::string(sql), std::move(st));
  return result;
}

int64_t SqliteDatabase::ChangedRowsLocked() const { return sqlite3_changes64(db_); }

absl::Status SqliteDatabase::CommitLocked() {
  absl::Status status = ExecLocked("COMMIT");
  // A failed COMMIT may leave the transaction open (e.g. SQLITE_BUSY); end it so that the
  // contract "over either way" holds. SQLite may already have rolled back by itself.
  if (!status.ok() && !sqlite3_get_autocommit(db_)) ExecLocked("ROLLBACK").IgnoreError();
  return status;
}

absl::Status SqliteDatabase::RollbackLocked() {
  if (sqlite3_get_autocommit(db_)) return absl::OkStatus();
  return ExecLocked("ROLLBACK");
}

}  // namespace esg::storage
