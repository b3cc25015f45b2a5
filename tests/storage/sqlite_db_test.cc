// Tests of storage/sqlite_db.h on real SQLite files: pragmas in force, transactions, statement
// cache, error-code mapping (busy, corrupt, constraints) and serialized multi-thread use.
#include "storage/sqlite_db.h"

#include <sqlite3.h>

#include <cmath>
#include <fstream>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::QueryInt;
using ::esg::storage::testing::QueryText;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

std::unique_ptr<Database> OpenOrDie(const std::string& path, const DatabaseOptions& options = {}) {
  absl::StatusOr<std::unique_ptr<Database>> db = SqliteDatabase::Open(path, options);
  EXPECT_THAT(db, IsOk());
  return db.ok() ? std::move(*db) : nullptr;
}

std::unique_ptr<Database> OpenWithTable(const std::string& path,
                                        const DatabaseOptions& options = {}) {
  std::unique_ptr<Database> db = OpenOrDie(path, options);
  if (db != nullptr) {
    EXPECT_THAT(db->Execute("CREATE TABLE IF NOT EXISTS t (k INTEGER PRIMARY KEY, v TEXT)"),
                IsOk());
  }
  return db;
}

absl::Status Insert(Transaction& txn, int64_t k, const std::string& v) {
  absl::StatusOr<Statement*> st = txn.Prepare("INSERT INTO t (k, v) VALUES (?1, ?2)");
  if (!st.ok()) return st.status();
  (*st)->BindInt64(1, k).BindText(2, v);
  return (*st)->Run();
}

TEST(Database, DefaultsPutWalAndSynchronousFullInForce) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenOrDie(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  EXPECT_THAT(QueryText(*db, "PRAGMA journal_mode"), IsOkAndHolds(std::string("wal")));
  // PRAGMA synchronous answers 0 OFF, 1 NORMAL, 2 FULL, 3 EXTRA.
  EXPECT_THAT(QueryInt(*db, "PRAGMA synchronous"), IsOkAndHolds(int64_t{2}));
  EXPECT_THAT(QueryInt(*db, "PRAGMA busy_timeout"), IsOkAndHolds(int64_t{5000}));
}

TEST(Database, SynchronousAndBusyTimeoutAreConfigurable) {
  TempDir dir;
  DatabaseOptions options;
  options.synchronous = Synchronous::kNormal;
  options.busy_timeout = absl::Milliseconds(250);
  std::unique_ptr<Database> db = OpenOrDie(dir.File("a.db"), options);
  ASSERT_NE(db, nullptr);
  EXPECT_THAT(QueryInt(*db, "PRAGMA synchronous"), IsOkAndHolds(int64_t{1}));
  EXPECT_THAT(QueryInt(*db, "PRAGMA busy_timeout"), IsOkAndHolds(int64_t{250}));
  EXPECT_THAT(QueryText(*db, "PRAGMA journal_mode"), IsOkAndHolds(std::string("wal")));
}

TEST(Database, OpenRejectsBadArgumentsAndMissingFiles) {
  TempDir dir;
  EXPECT_THAT(SqliteDatabase::Open(""), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("path")));
  DatabaseOptions zero_timeout;
  zero_timeout.busy_timeout = absl::ZeroDuration();
  EXPECT_THAT(SqliteDatabase::Open(dir.File("a.db"), zero_timeout),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("busy_timeout")));
  DatabaseOptions no_create;
  no_create.create_if_missing = false;
  EXPECT_THAT(SqliteDatabase::Open(dir.File("missing.db"), no_create),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("missing.db")));
  // Parent directories are the caller's job.
  EXPECT_THAT(SqliteDatabase::Open(dir.File("no/such/dir/a.db")),
              StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("no/such/dir")));
}

TEST(Transaction, CommitMakesChangesVisibleAndDestructionRollsBack) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenWithTable(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  {
    absl::StatusOr<Transaction> txn = db->Begin();
    ASSERT_THAT(txn, IsOk());
    ASSERT_THAT(Insert(*txn, 1, "kept"), IsOk());
    ASSERT_THAT(txn->Commit(), IsOk());
    EXPECT_FALSE(txn->active());
    EXPECT_THAT(txn->Commit(), StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("ended")));
  }
  {
    absl::StatusOr<Transaction> txn = db->Begin();
    ASSERT_THAT(txn, IsOk());
    ASSERT_THAT(Insert(*txn, 2, "dropped"), IsOk());
    // Inside the transaction the row is visible ...
    absl::StatusOr<Statement*> count = txn->Prepare("SELECT COUNT(*) FROM t");
    ASSERT_THAT(count, IsOk());
    ASSERT_THAT((*count)->Step(), IsOkAndHolds(true));
    EXPECT_EQ((*count)->ColumnInt64(0), 2);
  }  // ... and gone after destruction without Commit().
  EXPECT_THAT(QueryInt(*db, "SELECT COUNT(*) FROM t"), IsOkAndHolds(int64_t{1}));
  EXPECT_THAT(QueryText(*db, "SELECT v FROM t"), IsOkAndHolds(std::string("kept")));
}

TEST(Transaction, ConstraintViolationLeavesNothingOfTheTransaction) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenWithTable(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  absl::Status failed = [&]() -> absl::Status {
    absl::StatusOr<Transaction> txn = db->Begin();
    if (!txn.ok()) return txn.status();
    for (int64_t k : {10, 11, 10}) {  // the third insert violates the primary key
      absl::Status s = Insert(*txn, k, "x");
      if (!s.ok()) return s;
    }
    return txn->Commit();
  }();
  EXPECT_THAT(failed, StatusIs(absl::StatusCode::kAlreadyExists, HasSubstr("UNIQUE")));
  EXPECT_THAT(QueryInt(*db, "SELECT COUNT(*) FROM t"), IsOkAndHolds(int64_t{0}));
}

TEST(Transaction, ExplicitRollbackAndSecondRollbackIsNoOp) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenWithTable(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  absl::StatusOr<Transaction> txn = db->Begin();
  ASSERT_THAT(txn, IsOk());
  ASSERT_THAT(Insert(*txn, 1, "x"), IsOk());
  EXPECT_THAT(txn->Rollback(), IsOk());
  EXPECT_THAT(txn->Rollback(), IsOk());
  EXPECT_THAT(QueryInt(*db, "SELECT COUNT(*) FROM t"), IsOkAndHolds(int64_t{0}));
}

TEST(Transaction, PreparedStatementsAreCachedAndReset) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenWithTable(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  Statement* first = nullptr;
  {
    absl::StatusOr<Transaction> txn = db->Begin();
    ASSERT_THAT(txn, IsOk());
    absl::StatusOr<Statement*> st = txn->Prepare("SELECT ?1 + 1");
    ASSERT_THAT(st, IsOk());
    first = *st;
    first->BindInt64(1, 41);
    ASSERT_THAT(first->Step(), IsOkAndHolds(true));
    EXPECT_EQ(first->ColumnInt64(0), 42);
    ASSERT_THAT(txn->Commit(), IsOk());
  }
  absl::StatusOr<Transaction> txn = db->Begin(TransactionMode::kDeferred);
  ASSERT_THAT(txn, IsOk());
  absl::StatusOr<Statement*> again = txn->Prepare("SELECT ?1 + 1");
  ASSERT_THAT(again, IsOk());
  EXPECT_EQ(*again, first);  // compiled once, reused
  // Bindings were cleared: an unbound parameter is NULL.
  ASSERT_THAT((*again)->Step(), IsOkAndHolds(true));
  EXPECT_TRUE((*again)->ColumnIsNull(0));
}

TEST(Transaction, PrepareRejectsMultipleStatementsAndBadSql) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenWithTable(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  absl::StatusOr<Transaction> txn = db->Begin();
  ASSERT_THAT(txn, IsOk());
  EXPECT_THAT(txn->Prepare("SELECT 1; SELECT 2"),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("exactly one")));
  EXPECT_THAT(txn->Prepare("SELEKT 1"),
              StatusIs(absl::StatusCode::kInternal, HasSubstr("syntax error")));
  EXPECT_THAT(txn->Prepare("SELECT * FROM no_such_table"),
              StatusIs(absl::StatusCode::kInternal, HasSubstr("no_such_table")));
}

TEST(Statement, BindErrorIsReportedByStep) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenWithTable(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  absl::StatusOr<Transaction> txn = db->Begin();
  ASSERT_THAT(txn, IsOk());
  absl::StatusOr<Statement*> st = txn->Prepare("SELECT ?1");
  ASSERT_THAT(st, IsOk());
  (*st)->BindInt64(1, 5).BindInt64(7, 6);  // there is no parameter 7
  EXPECT_THAT((*st)->Step(), StatusIs(absl::StatusCode::kInternal, HasSubstr("parameter 7")));
  (*st)->Reset();  // forgets the bind error
  (*st)->BindInt64(1, 5);
  EXPECT_THAT((*st)->Step(), IsOkAndHolds(true));
}

TEST(Statement, RoundTripsValueTypesIncludingNaNAndBinaryBlobs) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenOrDie(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  ASSERT_THAT(db->Execute("CREATE TABLE v (i INTEGER, d REAL, n REAL, s TEXT, b BLOB, e BLOB, z)"),
              IsOk());
  const std::string blob("a\0b\xff", 4);
  absl::StatusOr<Transaction> txn = db->Begin();
  ASSERT_THAT(txn, IsOk());
  absl::StatusOr<Statement*> insert =
      txn->Prepare("INSERT INTO v VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7)");
  ASSERT_THAT(insert, IsOk());
  (*insert)
      ->BindInt64(1, int64_t{-9007199254740993})
      .BindDouble(2, 0.1)
      .BindDouble(3, std::nan(""))
      .BindText(4, "ünïcode")
      .BindBlob(5, blob)
      .BindBlob(6, "")
      .BindNull(7);
  ASSERT_THAT((*insert)->Run(), IsOk());
  EXPECT_EQ(txn->ChangedRows(), 1);
  absl::StatusOr<Statement*> select = txn->Prepare("SELECT i, d, n, s, b, e, z FROM v");
  ASSERT_THAT(select, IsOk());
  ASSERT_THAT((*select)->Step(), IsOkAndHolds(true));
  const Statement& row = **select;
  EXPECT_EQ(row.ColumnCount(), 7);
  EXPECT_EQ(row.ColumnInt64(0), int64_t{-9007199254740993});
  EXPECT_EQ(row.ColumnDouble(1), 0.1);
  EXPECT_TRUE(row.ColumnIsNull(2));  // SQLite stores NaN as NULL
  EXPECT_TRUE(std::isnan(row.ColumnDoubleOrNaN(2)));
  EXPECT_EQ(row.ColumnText(3), "ünïcode");
  EXPECT_EQ(row.ColumnBlob(4), blob);
  EXPECT_FALSE(row.ColumnIsNull(5));  // an empty blob is not NULL
  EXPECT_EQ(row.ColumnBlob(5), "");
  EXPECT_TRUE(row.ColumnIsNull(6));
  EXPECT_THAT((*select)->Step(), IsOkAndHolds(false));
}

TEST(Database, NestedUseOnOneThreadIsRefusedInsteadOfDeadlocking) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenWithTable(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  absl::StatusOr<Transaction> txn = db->Begin();
  ASSERT_THAT(txn, IsOk());
  EXPECT_THAT(db->Begin(), StatusIs(absl::StatusCode::kFailedPrecondition, HasSubstr("already")));
  EXPECT_THAT(db->Execute("SELECT 1"), StatusIs(absl::StatusCode::kFailedPrecondition, ::testing::_));
  ASSERT_THAT(txn->Commit(), IsOk());
  EXPECT_THAT(db->Execute("SELECT 1"), IsOk());  // released after Commit()
}

TEST(Database, WriterBlockedByAnotherConnectionGetsUnavailable) {
  TempDir dir;
  DatabaseOptions shared;
  shared.exclusive = false;  // the default locks out every other connection
  std::unique_ptr<Database> holder = OpenWithTable(dir.File("a.db"), shared);
  ASSERT_NE(holder, nullptr);
  DatabaseOptions impatient = shared;
  impatient.busy_timeout = absl::Milliseconds(30);
  std::unique_ptr<Database> waiter = OpenOrDie(dir.File("a.db"), impatient);
  ASSERT_NE(waiter, nullptr);

  absl::StatusOr<Transaction> lock = holder->Begin(TransactionMode::kImmediate);
  ASSERT_THAT(lock, IsOk());
  ASSERT_THAT(Insert(*lock, 1, "holder"), IsOk());
  EXPECT_THAT(waiter->Begin(TransactionMode::kImmediate),
              StatusIs(absl::StatusCode::kUnavailable, HasSubstr("locked")));
  EXPECT_THAT(waiter->Execute("INSERT INTO t (k, v) VALUES (2, 'waiter')"),
              StatusIs(absl::StatusCode::kUnavailable, ::testing::_));
  // WAL readers are not blocked by the writer and see the last committed state.
  EXPECT_THAT(QueryInt(*waiter, "SELECT COUNT(*) FROM t"), IsOkAndHolds(int64_t{0}));

  ASSERT_THAT(lock->Commit(), IsOk());
  EXPECT_THAT(waiter->Execute("INSERT INTO t (k, v) VALUES (2, 'waiter')"), IsOk());
  EXPECT_THAT(QueryInt(*holder, "SELECT COUNT(*) FROM t"), IsOkAndHolds(int64_t{2}));
}

TEST(Database, GarbageFileIsDataLossNotACrash) {
  TempDir dir;
  const std::string path = dir.File("garbage.db");
  {
    std::ofstream out(path, std::ios::binary);
    for (int i = 0; i < 8192; ++i) out.put(static_cast<char>((i * 131 + 7) & 0xff));
  }
  EXPECT_THAT(SqliteDatabase::Open(path),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("not a database")));
}

TEST(Database, QuickCheckPassesOnAHealthyFile) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenWithTable(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  EXPECT_THAT(db->QuickCheck(), IsOk());
}

TEST(Database, ThreadsSharingOneDatabaseNeverInterleaveTransactions) {
  TempDir dir;
  std::unique_ptr<Database> db = OpenOrDie(dir.File("a.db"));
  ASSERT_NE(db, nullptr);
  ASSERT_THAT(db->Execute("CREATE TABLE counter (n INTEGER); INSERT INTO counter VALUES (0)"),
              IsOk());
  constexpr int kThreads = 4;
  constexpr int kIncrementsPerThread = 50;
  std::vector<absl::Status> failures(kThreads);
  std::vector<std::thread> threads;
  for (int t = 0; t < kThreads; ++t) {
    threads.emplace_back([&, t] {
      for (int i = 0; i < kIncrementsPerThread; ++i) {
        // Read-modify-write: loses increments if two transactions ever interleave.
        absl::Status s = [&]() -> absl::Status {
          absl::StatusOr<Transaction> txn = db->Begin(TransactionMode::kDeferred);
          if (!txn.ok()) return txn.status();
          absl::StatusOr<Statement*> read = txn->Prepare("SELECT n FROM counter");
          if (!read.ok()) return read.status();
          absl::StatusOr<bool> row = (*read)->Step();
          if (!row.ok()) return row.status();
          const int64_t n = (*read)->ColumnInt64(0);
          (*read)->Reset();
          std::this_thread::yield();
          absl::StatusOr<Statement*> write = txn->Prepare("UPDATE counter SET n = ?1");
          if (!write.ok()) return write.status();
          (*write)->BindInt64(1, n + 1);
          absl::Status run = (*write)->Run();
          if (!run.ok()) return run;
          return txn->Commit();
        }();
        if (!s.ok()) {
          failures[t] = s;
          return;
        }
      }
    });
  }
  for (std::thread& th : threads) th.join();
  for (const absl::Status& s : failures) EXPECT_THAT(s, IsOk());
  EXPECT_THAT(QueryInt(*db, "SELECT n FROM counter"),
              IsOkAndHolds(int64_t{kThreads * kIncrementsPerThread}));
}

TEST(StatusCodeForSqliteResult, FollowsTheProjectPolicy) {
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_BUSY), absl::StatusCode::kUnavailable);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_BUSY_SNAPSHOT), absl::StatusCode::kUnavailable);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_LOCKED), absl::StatusCode::kUnavailable);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_CORRUPT), absl::StatusCode::kDataLoss);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_NOTADB), absl::StatusCode::kDataLoss);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_CONSTRAINT_PRIMARYKEY),
            absl::StatusCode::kAlreadyExists);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_CONSTRAINT_UNIQUE), absl::StatusCode::kAlreadyExists);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_CONSTRAINT_CHECK),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_CONSTRAINT_NOTNULL),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_FULL), absl::StatusCode::kResourceExhausted);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_IOERR_FSYNC), absl::StatusCode::kUnavailable);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_CANTOPEN), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(StatusCodeForSqliteResult(SQLITE_ERROR), absl::StatusCode::kInternal);
}

}  // namespace
}  // namespace esg::storage
