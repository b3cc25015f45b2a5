// The SQLite engine of database.h: SqliteDatabase (open, pragmas, the owner lock) and
// SqliteStatement. Every call returns absl::Status; nothing throws or logs.
//
// Durability contract (what an OK Transaction::Commit() guarantees)
// ------------------------------------------------------------------
// The connection always runs in WAL mode (journal_mode=WAL). Commit() returns OK only after
// SQLite has appended the transaction's pages and a commit record to the "-wal" file with
// write(2). What survives a failure then depends on DatabaseOptions::synchronous:
//
//   setting  | process crash (kill -9, abort) | OS crash or power loss
//   ---------+--------------------------------+-----------------------------------------------
//   kFull    | committed data survives        | committed data survives: the WAL is fsync'ed
//   (default)|                                | at every commit, before Commit() returns
//   kExtra   | same as kFull (in WAL mode EXTRA adds nothing over FULL for commits)
//   kNormal  | committed data survives        | the last transactions before the failure may
//            |                                | be rolled back (the WAL is fsync'ed only at
//            |                                | checkpoints); the file stays consistent
//   kOff     | committed data survives        | recent transactions may be lost and the file
//            |                                | may be corrupted (no fsync at all)
//
// A process crash never loses a committed transaction in any setting, because the bytes are in
// the OS page cache once write(2) returns. The default is kFull because the server acknowledges
// telemetry to the ground station only after Storage::ArchiveFrames() and the station then
// discards its copy: an acknowledged frame must also survive the host losing power, which only FULL
// (or EXTRA) guarantees in WAL mode. The price is one fsync per transaction, which is why the
// server commits frames in batches. "Survives" assumes the disk honours fsync (no lying write
// cache). An uncommitted transaction (no Commit(), a failed Commit(), or a crash before Commit()
// returned) is rolled back completely: readers never see part of a transaction.
//
// Storage faults (what a caller sees; tests/storage/storage_faults_test.cc)
// ---------------------------------------------------------------------------
//   fault during a transaction               | status of Commit() (or of the Statement step
//                                            | that wrote, if SQLite spilled pages early)
//   -----------------------------------------+-------------------------------------------------
//   disk full (write(2) fails with ENOSPC)   | ResourceExhausted
//   write(2) fails (EIO; EPERM on a -wal     | Unavailable
//     made immutable)                        |
//   fsync of the -wal fails at commit        | Unavailable
// Commit()'s message starts "db: <path>: commit failed and was rolled back: ". In every case
// nothing of the transaction is visible, the file stays consistent, and the same Database takes
// the next transaction as soon as the cause is gone: no reopen, no hang, no retry inside. A disk
// that stays full fails every commit the same way, quickly; reads keep working.
//
//   fault at Open()                          | status
//   -----------------------------------------+-------------------------------------------------
//   file, -wal, directory or file system not | FailedPrecondition "db: <path> cannot be written:
//     writable; SQLite opens it read-only;   |   <reason>" (<reason>: the file and errno text,
//     disk full at the write probe           |   e.g. "Read-only file system", and SQLite's)
//   another process or connection holds the  | Unavailable "db: <path> is locked by another
//     file (see "Exclusive locking")         |   process ..." at once for an exclusive Open()
//                                            |   while an exclusive Database holds the owner
//                                            |   lock ("Owner lock"), else after busy_timeout
//
// A checkpoint (SQLite copying -wal pages into the database file after a commit once the -wal
// holds 1000 pages, and when the last connection closes) that fails is not an error of any
// commit: the pages stay in the -wal, which keeps growing, and the next checkpoint retries. The
// database file must grow by up to the -wal's size at a checkpoint, so on a nearly full disk
// checkpoints fail first and commits later. A commit whose fsync failed was completely written
// to the -wal: this connection never shows it and overwrites it with its next commit, but if the
// process dies before that, the next Open() finds it complete in the -wal and recovers it as
// committed (all of it, never part of it).
//
// Exclusive locking (DatabaseOptions::exclusive, default true) sets PRAGMA locking_mode=EXCLUSIVE
// before the first access, so SQLite keeps the WAL index in heap memory instead of mapping the
// "-shm" file (https://www.sqlite.org/wal.html, "Use of WAL Without Shared-Memory"). A mapped
// -shm that is made immutable (chattr +i) or truncated kills the process with SIGBUS at the
// next store into the mapping (for an immutable one, once the kernel has written the page back);
// without the mapping, the same faults on the -wal or the database file are I/O errors returned
// as statuses (an immutable database file only makes checkpoints fail). The price: the
// connection holds an exclusive lock on the file from Open() until it is destroyed, so no other
// connection or process (a second server, the sqlite3 shell) can even read the file meanwhile.
//
// Owner lock. An exclusive Database also holds an exclusive advisory lock (flock(2)) on the file
// "<path>.lock" beside the database (symbolic links resolved) from Open() until it is destroyed,
// and writes its process id into it. A second exclusive Open() of the same file, from this or
// another process, is refused at once with Unavailable "db: <path> is locked by another process
// (pid <pid> holds <path>.lock; is another server using this file?)" instead of waiting
// busy_timeout for SQLite's lock. The lock file is left in place (its content names the last
// owner); the lock, not the file, is what counts, and the kernel drops it when the owner exits
// however it exits. A file other than the database is locked because closing any descriptor of
// the database file would drop this process's POSIX locks on it, which SQLite relies on.
//
// Thread safety
// -------------
// A Database is safe to share between threads. Access is serialized by an internal absl::Mutex:
// a Transaction holds it from Begin() until Commit()/Rollback()/destruction, so the statements
// of one transaction never interleave with another thread's. The connection is also opened with
// SQLITE_OPEN_FULLMUTEX. A thread must not call Begin() or Execute() on a Database while it holds
// a Transaction on it (FailedPrecondition). With exclusive = false, separate Database objects
// (other threads or processes) on the same file are isolated by SQLite's own locks; a writer
// waits up to busy_timeout for another connection's write lock and then gets Unavailable.
//
// Error codes (StatusCodeForSqliteResult): SQLITE_BUSY/LOCKED -> Unavailable (retry allowed),
// SQLITE_CORRUPT/NOTADB -> DataLoss, PRIMARY KEY/UNIQUE violation -> AlreadyExists, other
// constraint violations -> InvalidArgument, SQLITE_FULL/NOMEM -> ResourceExhausted, I/O error
// -> Unavailable, cannot open/read-only -> FailedPrecondition, SQL errors -> Internal.
#ifndef ESG_STORAGE_SQLITE_DB_H_
#define ESG_STORAGE_SQLITE_DB_H_

#include <cstdint>
#include <memory>
#include <string>

#include "absl/container/flat_hash_map.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/database.h"

struct sqlite3;
struct sqlite3_stmt;

namespace esg::storage {

// PRAGMA synchronous levels; see the durability table above.
enum class Synchronous { kOff = 0, kNormal = 1, kFull = 2, kExtra = 3 };

struct DatabaseOptions {
  // Durability of a commit; see the table in the file comment. kFull backs telemetry acks.
  Synchronous synchronous = Synchronous::kFull;
  // How long a statement waits for another connection's lock before returning Unavailable.
  absl::Duration busy_timeout = absl::Seconds(5);
  // If false, opening a path that does not exist returns NotFound. Parent directories are never
  // created: the caller creates them.
  bool create_if_missing = true;
  // PRAGMA locking_mode=EXCLUSIVE: one connection owns the file and no -shm file is mapped (see
  // "Exclusive locking" above). Set false only to share the file between connections.
  bool exclusive = true;
  // Name of a registered SQLite VFS to open the file through, e.g. the fault-injecting
  // "esg-fault" of tests/testing/fault_vfs.h; empty: SQLite's default VFS.
  std::string vfs;
};

// The absl::StatusCode for an SQLite (extended) result code other than SQLITE_OK/ROW/DONE.
absl::StatusCode StatusCodeForSqliteResult(int result_code);

class SqliteDatabase;

// A prepared SQLite statement (database.h Statement).
class SqliteStatement final : public Statement {
 public:
  ~SqliteStatement() override;

  SqliteStatement& BindInt64(int index, int64_t value) override;
  SqliteStatement& BindDouble(int index, double value) override;
  SqliteStatement& BindText(int index, absl::string_view value) override;
  SqliteStatement& BindBlob(int index, absl::string_view bytes) override;
  SqliteStatement& BindNull(int index) override;
  absl::StatusOr<bool> Step() override;
  void Reset() override;
  int ColumnCount() const override;
  bool ColumnIsNull(int column) const override;
  int64_t ColumnInt64(int column) const override;
  double ColumnDouble(int column) const override;
  std::string ColumnText(int column) const override;
  std::string ColumnBlob(int column) const override;

 private:
  friend class SqliteDatabase;
  SqliteStatement(sqlite3* db, sqlite3_stmt* stmt, std::string sql);
  void NoteBindResult(int rc, int index);

  sqlite3* db_;
  sqlite3_stmt* stmt_;
  absl::Status bind_status_;
};

// One SQLite connection in WAL mode with the options above (database.h Database). BEGIN
// DEFERRED takes SQLite's write lock at the first write (WAL readers never block and see a
// consistent snapshot); BEGIN IMMEDIATE takes it at Begin(), so lock contention shows up there
// (waiting up to busy_timeout) and never as a failed upgrade half-way through. The connection
// is also opened with SQLITE_OPEN_FULLMUTEX.
class SqliteDatabase final : public Database {
 public:
  // Opens (creating if allowed) the database file at `path`, takes the owner lock if
  // options.exclusive (see "Owner lock" above; refused at once with Unavailable naming the
  // holder's pid), applies busy_timeout,
  // locking_mode (exclusive), journal_mode=WAL and synchronous, and proves that the file can be
  // written by committing a transaction that rewrites PRAGMA user_version with its own value
  // (one -wal frame and, with kFull, one fsync). Errors: InvalidArgument (empty path, a
  // non-positive busy_timeout, an unknown vfs), NotFound (missing file and !create_if_missing),
  // DataLoss (the file is not an SQLite database or is corrupt), Unavailable ("db: <path> is
  // locked by another process": another connection kept the lock for longer than busy_timeout),
  // FailedPrecondition ("db: <path> cannot be opened: ..." for a missing parent directory;
  // "db: <path> cannot be written: <reason>" when SQLite could open the file only read-only or
  // the probe write failed: an immutable or read-only file, -wal or directory, a read-only
  // file system, a full disk; <reason> names the file and the errno text where access(2) finds
  // one, else SQLite's message).
  static absl::StatusOr<std::unique_ptr<SqliteDatabase>> Open(const std::string& path,
                                                              const DatabaseOptions& options = {});

  ~SqliteDatabase() override;

  // PRAGMA quick_check: OK, or DataLoss naming the first problem SQLite reports.
  absl::Status QuickCheck() override;
  const std::string& path() const override { return path_; }
  Dialect dialect() const override { return Dialect::kSqlite; }
  const DatabaseOptions& options() const { return options_; }

 protected:
  absl::Status BeginLocked(TransactionMode mode) override;
  absl::Status ExecLocked(absl::string_view sql) override;
  absl::StatusOr<Statement*> PrepareLocked(absl::string_view sql) override;
  int64_t ChangedRowsLocked() const override;
  absl::Status CommitLocked() override;
  absl::Status RollbackLocked() override;

 private:
  SqliteDatabase(sqlite3* db, std::string path, const DatabaseOptions& options);
  // Pragmas and the write probe of Open(); *failed_rc: the SQLite result code of the failure.
  absl::Status ConfigureAndProbeLocked(int* failed_rc);
  absl::StatusOr<SqliteStatement*> PrepareSqliteLocked(absl::string_view sql);

  sqlite3* const db_;
  const std::string path_;
  const DatabaseOptions options_;
  // The connection (db_'s statements, cache_) is used only with the base's mutex held.
  absl::flat_hash_map<std::string, std::unique_ptr<SqliteStatement>> cache_;  // by SQL text
  // Descriptor of "<path>.lock" holding the owner lock (exclusive mode), else -1; closed after
  // the connection.
  int owner_lock_fd_ = -1;
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_SQLITE_DB_H_
