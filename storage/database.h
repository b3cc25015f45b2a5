// The service database seen by the stores: one connection (Database), its transactions
// (Transaction, the only way to run statements) and cached prepared statements (Statement).
// Two implementations: SQLite (sqlite_db.h, the embedded default) and PostgreSQL
// (postgres_db.h, for several servers sharing one database). The stores write their SQL once,
// in the subset both engines run the same way (docs/service.md "Storage backends"):
//   * parameters are numbered, "?1", "?2", ... (the PostgreSQL implementation sends them as
//     $1, $2, ...); a parameter used as a truth value is compared ("?9 <> 0");
//   * instants, counters and booleans are 64-bit integers, booleans 0/1;
//   * an upsert is "INSERT ... ON CONFLICT (key) DO UPDATE SET c = excluded.c" or
//     "ON CONFLICT DO NOTHING"; a generated key is read with "RETURNING id";
//   * a subquery in FROM has an alias; SUM() is taken over integers, never over a comparison.
// Every call returns absl::Status; nothing throws or logs.
//
// Error codes, both engines: a PRIMARY KEY/UNIQUE violation is AlreadyExists, other constraint
// violations InvalidArgument, a lost connection, a lock or serialization conflict Unavailable
// (retry allowed), a full disk ResourceExhausted, a corrupt database DataLoss, an SQL error
// Internal. An error inside a transaction leaves it usable for Rollback() only (PostgreSQL
// aborts the transaction at the first error; the stores never go on after one).
#ifndef ESG_STORAGE_DATABASE_H_
#define ESG_STORAGE_DATABASE_H_

#include <atomic>
#include <cstdint>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"

namespace esg::storage {

// The engine behind a Database, for the few places that must differ (schema DDL and
// migrations, checks of the file).
enum class Dialect { kSqlite, kPostgres };

// A prepared statement owned by the Database's cache and lent out by Transaction::Prepare().
// Parameter indexes are 1-based ("?1"), column indexes 0-based. Bind* never fails
// immediately: the first bind error is remembered and returned by the next Step()/Run(), so
// binds can be chained:
//   st->BindText(1, id).BindInt64(2, sequence);
class Statement {
 public:
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;
  virtual ~Statement() = default;

  virtual Statement& BindInt64(int index, int64_t value) = 0;
  // A NaN binds as NULL (neither engine is asked to store NaN); read it back with
  // ColumnDoubleOrNaN(). Other doubles round-trip exactly.
  virtual Statement& BindDouble(int index, double value) = 0;
  virtual Statement& BindText(int index, absl::string_view value) = 0;
  virtual Statement& BindBlob(int index, absl::string_view bytes) = 0;
  virtual Statement& BindNull(int index) = 0;

  // Advances the statement: true if a row is available through the Column* getters, false when
  // the statement has finished. Errors as in the file comment.
  virtual absl::StatusOr<bool> Step() = 0;
  // Runs a statement that returns no rows to completion (INSERT/UPDATE/DELETE/DDL). Returns
  // Internal if it produces a row.
  absl::Status Run();
  // Rewinds the statement and clears all bindings and any remembered bind error.
  virtual void Reset() = 0;

  // Column getters for the current row (valid after Step() returned true). A NULL reads as 0,
  // 0.0 or "" except in ColumnDoubleOrNaN().
  virtual int ColumnCount() const = 0;
  virtual bool ColumnIsNull(int column) const = 0;
  virtual int64_t ColumnInt64(int column) const = 0;
  virtual double ColumnDouble(int column) const = 0;
  double ColumnDoubleOrNaN(int column) const;
  virtual std::string ColumnText(int column) const = 0;
  virtual std::string ColumnBlob(int column) const = 0;

  const std::string& sql() const { return sql_; }

 protected:
  explicit Statement(std::string sql) : sql_(std::move(sql)) {}

 private:
  std::string sql_;
};

// kDeferred: for reads (and writes that need no lock up front); kImmediate: the transaction
// writes, and lock contention shows up at Begin() rather than half-way through. SQLite takes
// its write lock at BEGIN IMMEDIATE; PostgreSQL locks rows as they are written either way.
enum class TransactionMode { kDeferred, kImmediate };

class Database;

// An open SQL transaction holding exclusive use of its Database. Destroying it without a
// successful Commit() rolls back everything it did. Movable, so Begin() can return it.
class Transaction {
 public:
  Transaction(Transaction&& other) noexcept;
  Transaction& operator=(Transaction&&) = delete;
  Transaction(const Transaction&) = delete;
  Transaction& operator=(const Transaction&) = delete;
  ~Transaction();

  // Runs one or more SQL statements that return no rows (DDL, PRAGMA assignments); not cached.
  absl::Status Execute(absl::string_view sql);

  // Returns the cached prepared statement for exactly one SQL statement `sql`, reset and with
  // bindings cleared. The statement is compiled once per Database and reused; the pointer is
  // valid while this transaction is open. Preparing the same SQL text again in the same
  // transaction returns the same (reset) statement. InvalidArgument if `sql` holds more than one
  // statement (SQLite); Internal for SQL errors.
  absl::StatusOr<Statement*> Prepare(absl::string_view sql);

  // Rows inserted, updated or deleted by the most recently completed statement.
  int64_t ChangedRows() const;

  // Makes the transaction durable (the engine's durability contract: sqlite_db.h,
  // postgres_db.h). After Commit() returns the transaction is over either way: on error it has
  // been rolled back and nothing is visible. The message of an error starts
  // "db: <name>: commit failed and was rolled back: ".
  absl::Status Commit();
  // Undoes the transaction. Calling it after the transaction ended is a no-op returning OK.
  absl::Status Rollback();

  bool active() const { return db_ != nullptr; }

 private:
  friend class Database;
  explicit Transaction(Database* db) : db_(db) {}
  void ResetUsedStatements();
  void Release();

  Database* db_;  // null once committed, rolled back or moved from
  std::vector<Statement*> used_;
};

// One connection to the service database. Safe to share between threads: access is serialized
// by an internal mutex, which a Transaction holds from Begin() until Commit()/Rollback()/
// destruction, so the statements of one transaction never interleave with another thread's. A
// thread must not call Begin() or Execute() while it holds a Transaction on the same Database
// (FailedPrecondition). Closing (destruction) requires that no Transaction on it is alive.
class Database {
 public:
  Database(const Database&) = delete;
  Database& operator=(const Database&) = delete;
  virtual ~Database() = default;

  // Starts a transaction (see TransactionMode), waiting for other threads' transactions on this
  // Database first. Unavailable if the engine's lock is held elsewhere beyond its timeout or the
  // connection is lost (the next Begin() reconnects); FailedPrecondition if the calling thread
  // already holds a Transaction on this Database.
  absl::StatusOr<Transaction> Begin(TransactionMode mode = TransactionMode::kImmediate);

  // Runs SQL that returns no rows outside any explicit transaction. Same locking and errors as
  // Begin().
  absl::Status Execute(absl::string_view sql);

  // A structural check of the stored data: OK, or DataLoss naming the first problem.
  virtual absl::Status QuickCheck() = 0;

  // The file path (SQLite) or the connection URI without its password (PostgreSQL): the name
  // messages use.
  virtual const std::string& path() const = 0;
  virtual Dialect dialect() const = 0;

 protected:
  Database() = default;

  // The engine's side of the calls above, each made with the mutex held (Locked) by this
  // class or by a Transaction of it.
  virtual absl::Status BeginLocked(TransactionMode mode) = 0;
  virtual absl::Status ExecLocked(absl::string_view sql) = 0;
  virtual absl::StatusOr<Statement*> PrepareLocked(absl::string_view sql) = 0;
  virtual int64_t ChangedRowsLocked() const = 0;
  // COMMIT; on failure the engine must leave no transaction open.
  virtual absl::Status CommitLocked() = 0;
  // ROLLBACK if a transaction is open.
  virtual absl::Status RollbackLocked() = 0;

  // For an engine's Open(): runs `fn` with the mutex held.
  template <typename Fn>
  auto WithLock(Fn fn) {
    absl::MutexLock lock(&mu_);
    return fn();
  }

 private:
  friend class Transaction;
  absl::Status Acquire();
  void ReleaseLock();

  // mu_ is held by a Transaction for its whole life (Begin() .. Release()), which the static
  // thread-safety analysis cannot follow; hence no ABSL_GUARDED_BY in the engines.
  absl::Mutex mu_;
  std::atomic<std::thread::id> owner_{};  // thread holding mu_ through a Transaction
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_DATABASE_H_
