// Tests of storage/postgres_db.h, the PostgreSQL engine's own promises beyond the conformance
// suite (the TEST_P tests of the store tests, tests/storage/backend.h): passwords kept out of
// names and messages, the status codes of a bad URI, an unreachable server and SQLSTATEs, exact
// round trips of doubles, integers and blobs, NaN as NULL, text with a NUL refused, a statement
// error that makes Commit() fail, reconnection after the server is killed and restarted, and two
// Storage::Open() racing on a fresh database. Runs against the shared test server
// (tests/testing/postgres_server.h); a server that cannot start fails the tests.
#include "storage/postgres_db.h"

#include <netinet/in.h>
#include <sys/socket.h>
#include <unistd.h>

#include <bit>
#include <cfloat>
#include <cmath>
#include <cstdint>
#include <functional>
#include <latch>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/postgres_schema.h"
#include "storage/schema.h"
#include "storage/storage.h"
#include "tests/storage/storage_test_util.h"
#include "tests/testing/postgres_server.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::storage::testing::IsOkAndHolds;
using ::esg::storage::testing::QueryInt;
using ::esg::storage::testing::T;
using ::esg::testing::IsOk;
using ::esg::testing::PostgresServer;
using ::esg::testing::StatusIs;
using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::Not;

TEST(RedactPostgresUri, RemovesTheUserInfoPasswordAndPasswordParameters) {
  EXPECT_EQ(RedactPostgresUri("postgresql://esg:s3cret@db.example:5432/esg"),
            "postgresql://esg@db.example:5432/esg");
  // A password may itself hold '@' and ':'; everything up to the last '@' of the authority goes.
  EXPECT_EQ(RedactPostgresUri("postgres://esg:p@ss:w0rd@db.example/esg?sslmode=require"),
            "postgres://esg@db.example/esg?sslmode=require");
  const std::string query =
      RedactPostgresUri("postgresql://db.example/esg?user=esg&password=s3cret&sslmode=require");
  EXPECT_THAT(query, Not(HasSubstr("s3cret")));
  EXPECT_THAT(query, AllOf(HasSubstr("user=esg"), HasSubstr("sslmode=require")));
  EXPECT_THAT(RedactPostgresUri("postgresql://esg:a@db/esg?password=b&password=c"),
              AllOf(Not(HasSubstr(":a@")), Not(HasSubstr("=b")), Not(HasSubstr("=c"))));
  // Nothing to remove: unchanged.
  EXPECT_EQ(RedactPostgresUri("postgresql://esg@127.0.0.1:5432/esg"),
            "postgresql://esg@127.0.0.1:5432/esg");
  EXPECT_EQ(RedactPostgresUri("postgresql://127.0.0.1:5432/esg"),
            "postgresql://127.0.0.1:5432/esg");
}

TEST(PostgresDatabase, AnUnparsableUriIsInvalidArgumentWithoutThePassword) {
  // An unterminated IPv6 host, and a bad percent-escape in the user info itself (libpq quotes
  // the token it could not decode).
  for (const char* uri :
       {"postgresql://esg:s3cret@[::1/esg", "postgresql://esg:s3cret%zz@127.0.0.1/esg",
        "postgresql://127.0.0.1/esg?password=s3cret&no_such_option=1"}) {
    absl::StatusOr<std::unique_ptr<PostgresDatabase>> db = PostgresDatabase::Open(uri);
    EXPECT_THAT(db, StatusIs(absl::StatusCode::kInvalidArgument,
                             AllOf(HasSubstr("URI"), Not(HasSubstr("s3cret")))))
        << uri;
  }
}

TEST(PostgresDatabase, AnUnreachablePortIsUnavailableCannotConnect) {
  // A port bound on loopback but not listening: the connection is refused at once.
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  ASSERT_GE(fd, 0);
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  addr.sin_port = 0;
  ASSERT_EQ(::bind(fd, reinterpret_cast<sockaddr*>(&addr), sizeof(addr)), 0);
  socklen_t len = sizeof(addr);
  ASSERT_EQ(::getsockname(fd, reinterpret_cast<sockaddr*>(&addr), &len), 0);
  const int port = ntohs(addr.sin_port);
  absl::StatusOr<std::unique_ptr<PostgresDatabase>> db =
      PostgresDatabase::Open(absl::StrCat("postgresql://esg:s3cret@127.0.0.1:", port, "/esg"));
  ::close(fd);
  EXPECT_THAT(db, StatusIs(absl::StatusCode::kUnavailable,
                           AllOf(HasSubstr("cannot connect"), HasSubstr(absl::StrCat(port)),
                                 Not(HasSubstr("s3cret")))));
}

TEST(StatusCodeForSqlState, MapsTheClassesDatabaseHPromises) {
  EXPECT_EQ(StatusCodeForSqlState("23505"), absl::StatusCode::kAlreadyExists);      // unique
  EXPECT_EQ(StatusCodeForSqlState("23514"), absl::StatusCode::kInvalidArgument);    // check
  EXPECT_EQ(StatusCodeForSqlState("53100"), absl::StatusCode::kResourceExhausted);  // disk full
  EXPECT_EQ(StatusCodeForSqlState("08006"), absl::StatusCode::kUnavailable);        // connection
  EXPECT_EQ(StatusCodeForSqlState("40001"), absl::StatusCode::kUnavailable);        // serialization
  EXPECT_EQ(StatusCodeForSqlState("55P03"), absl::StatusCode::kUnavailable);        // lock timeout
  EXPECT_EQ(StatusCodeForSqlState("42P01"), absl::StatusCode::kInternal);           // SQL error
}

// A fresh database of the shared server, opened with PostgresDatabase::Open().
class PostgresDatabaseTest : public ::testing::Test {
 protected:
  // The server of the fixture's database: the one shared with other tests.
  virtual PostgresServer* Server(std::string* error) { return PostgresServer::Shared(error); }

  void SetUp() override {
    std::string error;
    server_ = Server(&error);
    ASSERT_NE(server_, nullptr) << "the PostgreSQL test server cannot start: " << error;
    absl::StatusOr<std::string> uri = server_->CreateDatabase();
    ASSERT_THAT(uri, IsOk());
    uri_ = *uri;
    absl::StatusOr<std::unique_ptr<PostgresDatabase>> db = PostgresDatabase::Open(uri_);
    ASSERT_THAT(db, IsOk());
    db_ = std::move(*db);
    ASSERT_THAT(db_->Execute("CREATE TABLE t (k BIGINT PRIMARY KEY, d DOUBLE PRECISION, "
                             "i BIGINT, b BYTEA, s TEXT)"),
                IsOk());
  }

  // Inserts row k in a transaction of its own, `bind` applied to the statement of
  // (?1 k, ?2 d, ?3 i, ?4 b, ?5 s) after ?1; the first error, or that of Commit().
  absl::Status Insert(int64_t k, const std::function<void(Statement&)>& bind) {
    absl::StatusOr<Transaction> txn = db_->Begin();
    if (!txn.ok()) return txn.status();
    absl::StatusOr<Statement*> st =
        txn->Prepare("INSERT INTO t (k, d, i, b, s) VALUES (?1, ?2, ?3, ?4, ?5)");
    if (!st.ok()) return st.status();
    (*st)->BindInt64(1, k);
    bind(**st);
    if (absl::Status s = (*st)->Run(); !s.ok()) return s;
    return txn->Commit();
  }

  PostgresServer* server_ = nullptr;
  std::string uri_;
  std::unique_ptr<PostgresDatabase> db_;
};

TEST_F(PostgresDatabaseTest, DoublesIntegersAndBlobsRoundTripBitExactly) {
  const std::vector<double> doubles = {1.0 / 3.0,
                                       1e-310,  // subnormal
                                       std::numeric_limits<double>::denorm_min(),
                                       DBL_MIN,
                                       DBL_MAX,
                                       -DBL_MAX,
                                       0.1,
                                       -0.0,
                                       std::numeric_limits<double>::infinity(),
                                       -std::numeric_limits<double>::infinity()};
  const std::vector<int64_t> integers = {std::numeric_limits<int64_t>::min(),
                                         std::numeric_limits<int64_t>::max(), -1, 0};
  std::string all_bytes;
  for (int c = 0; c < 256; ++c) all_bytes.push_back(static_cast<char>(c));
  const std::vector<std::string> blobs = {std::string("a\0b\xff", 4), std::string(3, '\0'),
                                          "\xff\xfe", all_bytes, ""};
  int64_t k = 0;
  for (double d : doubles) {
    ASSERT_THAT(Insert(++k, [&](Statement& st) { st.BindDouble(2, d); }), IsOk()) << d;
  }
  for (int64_t i : integers) {
    ASSERT_THAT(Insert(++k, [&](Statement& st) { st.BindInt64(3, i); }), IsOk()) << i;
  }
  for (const std::string& b : blobs) {
    ASSERT_THAT(Insert(++k, [&](Statement& st) { st.BindBlob(4, b); }), IsOk());
  }

  absl::StatusOr<Transaction> txn = db_->Begin(TransactionMode::kDeferred);
  ASSERT_THAT(txn, IsOk());
  absl::StatusOr<Statement*> st = txn->Prepare("SELECT d, i, b FROM t WHERE k = ?1");
  ASSERT_THAT(st, IsOk());
  k = 0;
  for (double d : doubles) {
    (*st)->Reset();
    (*st)->BindInt64(1, ++k);
    ASSERT_THAT((*st)->Step(), IsOkAndHolds(true));
    // Bit patterns: -0.0 keeps its sign, a subnormal its last bit.
    EXPECT_EQ(std::bit_cast<uint64_t>((*st)->ColumnDouble(0)), std::bit_cast<uint64_t>(d))
        << "wrote " << d << ", read " << (*st)->ColumnDouble(0);
  }
  for (int64_t i : integers) {
    (*st)->Reset();
    (*st)->BindInt64(1, ++k);
    ASSERT_THAT((*st)->Step(), IsOkAndHolds(true));
    EXPECT_EQ((*st)->ColumnInt64(1), i);
  }
  for (const std::string& b : blobs) {
    (*st)->Reset();
    (*st)->BindInt64(1, ++k);
    ASSERT_THAT((*st)->Step(), IsOkAndHolds(true));
    EXPECT_FALSE((*st)->ColumnIsNull(2)) << "an empty blob is not NULL";
    EXPECT_EQ((*st)->ColumnBlob(2), b) << b.size() << " bytes";
  }
  EXPECT_THAT(txn->Commit(), IsOk());
}

TEST_F(PostgresDatabaseTest, NaNIsStoredAsNullAndReadsBackAsNaN) {
  ASSERT_THAT(Insert(1, [](Statement& st) { st.BindDouble(2, std::nan("")); }), IsOk());
  EXPECT_THAT(QueryInt(*db_, "SELECT COUNT(*) FROM t WHERE k = 1 AND d IS NULL"), IsOkAndHolds(1));
  absl::StatusOr<Transaction> txn = db_->Begin(TransactionMode::kDeferred);
  ASSERT_THAT(txn, IsOk());
  absl::StatusOr<Statement*> st = txn->Prepare("SELECT d FROM t WHERE k = 1");
  ASSERT_THAT(st, IsOk());
  ASSERT_THAT((*st)->Step(), IsOkAndHolds(true));
  EXPECT_TRUE((*st)->ColumnIsNull(0));
  EXPECT_TRUE(std::isnan((*st)->ColumnDoubleOrNaN(0)));
}

TEST_F(PostgresDatabaseTest, TextWithANulByteIsInvalidArgumentAndStoresNothing) {
  EXPECT_THAT(Insert(1, [](Statement& st) { st.BindText(5, std::string("a\0b", 3)); }),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("NUL")));
  EXPECT_THAT(QueryInt(*db_, "SELECT COUNT(*) FROM t"), IsOkAndHolds(0));
  // Text without one is stored as given (UTF-8).
  ASSERT_THAT(Insert(2, [](Statement& st) { st.BindText(5, "ü \xe2\x9c\x93 'q'"); }), IsOk());
  EXPECT_THAT(testing::QueryText(*db_, "SELECT s FROM t WHERE k = 2"),
              IsOkAndHolds(std::string("ü \xe2\x9c\x93 'q'")));
}

TEST_F(PostgresDatabaseTest, AStatementErrorMakesCommitFailAndNothingIsVisible) {
  {
    absl::StatusOr<Transaction> txn = db_->Begin();
    ASSERT_THAT(txn, IsOk());
    absl::StatusOr<Statement*> insert = txn->Prepare("INSERT INTO t (k) VALUES (?1)");
    ASSERT_THAT(insert, IsOk());
    (*insert)->BindInt64(1, 1);
    ASSERT_THAT((*insert)->Run(), IsOk());
    (*insert)->Reset();
    (*insert)->BindInt64(1, 1);  // the same key again
    EXPECT_THAT((*insert)->Run(), StatusIs(absl::StatusCode::kAlreadyExists, HasSubstr("23505")));
    // The server aborted the transaction; committing it must not report success.
    const absl::Status commit = txn->Commit();
    EXPECT_THAT(commit, Not(IsOk()));
    EXPECT_THAT(std::string(commit.message()), HasSubstr("commit failed and was rolled back"));
    EXPECT_FALSE(txn->active());
  }
  EXPECT_THAT(QueryInt(*db_, "SELECT COUNT(*) FROM t"), IsOkAndHolds(0));
  // The connection takes the next transaction.
  ASSERT_THAT(Insert(2, [](Statement&) {}), IsOk());
  EXPECT_THAT(QueryInt(*db_, "SELECT COUNT(*) FROM t"), IsOkAndHolds(1));
}

// The durability and reconnection contract of postgres_db.h: after kill -9 of the server and
// its restart, the PostgresDatabase opened before takes transactions again (its first Begin()
// may report the lost connection) and sees what was committed.
// On a server of this process's own: killing the shared one would break the tests using it.
class PostgresDatabaseCrashTest : public PostgresDatabaseTest {
 protected:
  PostgresServer* Server(std::string* error) override { return PostgresServer::Own(error); }
};

TEST_F(PostgresDatabaseCrashTest, AfterTheServerIsKilledAndRestartedTheConnectionRecovers) {
  ASSERT_THAT(Insert(7, [](Statement& st) { st.BindText(5, "committed before the crash"); }),
              IsOk());
  ASSERT_THAT(server_->Kill(), IsOk());
  ASSERT_THAT(server_->Restart(), IsOk());

  {
    absl::StatusOr<Transaction> first = db_->Begin();
    if (!first.ok()) {
      EXPECT_THAT(first, StatusIs(absl::StatusCode::kUnavailable, ::testing::_));
    } else {
      EXPECT_THAT(first->Rollback(), IsOk());
    }
  }
  absl::StatusOr<Transaction> txn = db_->Begin();
  ASSERT_THAT(txn, IsOk());
  absl::StatusOr<Statement*> st = txn->Prepare("SELECT s FROM t WHERE k = 7");
  ASSERT_THAT(st, IsOk());
  ASSERT_THAT((*st)->Step(), IsOkAndHolds(true));
  EXPECT_EQ((*st)->ColumnText(0), "committed before the crash");
  absl::StatusOr<Statement*> insert = txn->Prepare("INSERT INTO t (k) VALUES (8)");
  ASSERT_THAT(insert, IsOk());
  ASSERT_THAT((*insert)->Run(), IsOk());
  ASSERT_THAT(txn->Commit(), IsOk());
  EXPECT_THAT(QueryInt(*db_, "SELECT COUNT(*) FROM t"), IsOkAndHolds(2));
}

// Two servers starting at once on a fresh database (docs/service.md "Storage backends"): both
// opens succeed and the schema is created once. Repeated on fresh databases, as the race may
// need a few tries to happen.
TEST(PostgresStorage, TwoOpensOfAFreshDatabaseAtOnceBothSucceed) {
  std::string error;
  PostgresServer* server = PostgresServer::Shared(&error);
  ASSERT_NE(server, nullptr) << "the PostgreSQL test server cannot start: " << error;
  for (int round = 0; round < 3; ++round) {
    absl::StatusOr<std::string> uri = server->CreateDatabase();
    ASSERT_THAT(uri, IsOk());
    std::latch start(2);
    absl::StatusOr<std::unique_ptr<Storage>> opened[2];
    std::vector<std::thread> threads;
    for (int t = 0; t < 2; ++t) {
      threads.emplace_back([&, t] {
        start.arrive_and_wait();
        opened[t] = Storage::Open(*uri);
      });
    }
    for (std::thread& th : threads) th.join();
    ASSERT_THAT(opened[0], IsOk()) << "round " << round;
    ASSERT_THAT(opened[1], IsOk()) << "round " << round;
    EXPECT_THAT(QueryInt((*opened[0])->database(), "SELECT COUNT(*) FROM esg_schema"),
                IsOkAndHolds(1));
    EXPECT_THAT(QueryInt((*opened[1])->database(), "SELECT MAX(version) FROM esg_schema"),
                IsOkAndHolds(kCurrentSchemaVersion));
  }
}

// Takes a database at version 9 back to before version 9 (schema.h).
constexpr char kDropAttitudeErrorColumns[] =
    "ALTER TABLE estimates DROP COLUMN attitude_error_x_arcsec, "
    "DROP COLUMN attitude_error_y_arcsec, DROP COLUMN attitude_error_z_arcsec, "
    "DROP COLUMN attitude_error_sigma_x_arcsec, DROP COLUMN attitude_error_sigma_y_arcsec, "
    "DROP COLUMN attitude_error_sigma_z_arcsec; ";

// A new database of the shared test server as an earlier program left it: created at version 9,
// where `count_sql` reads `current`, then taken back by `downgrade` (SQL), after which it reads
// 0. Its URI in *uri, the connection closed again.
void MakeDatabaseTakenBack(const std::string& count_sql, int64_t current,
                           const std::string& downgrade, std::string* uri) {
  std::string error;
  PostgresServer* server = PostgresServer::Shared(&error);
  ASSERT_NE(server, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> made = server->CreateDatabase();
  ASSERT_THAT(made, IsOk());
  *uri = *made;
  // Version 9, from which the downgrades go back (the keyed coefficient values of version 10
  // are not undone by them).
  absl::StatusOr<std::unique_ptr<PostgresDatabase>> db = PostgresDatabase::Open(*uri);
  ASSERT_THAT(db, IsOk());
  ASSERT_THAT(MigrateTo(**db, 9), IsOk());
  EXPECT_THAT(QueryInt(**db, count_sql), IsOkAndHolds(current));
  ASSERT_THAT((*db)->Execute(downgrade), IsOk());
  EXPECT_THAT(QueryInt(**db, count_sql), IsOkAndHolds(0));
}

// A database created at version 7 by an earlier program is upgraded when a server opens it: the
// coefficients gain their basis terms (schema.h version 8), the estimates their attitude error
// estimate (version 9).
TEST(PostgresStorage, AVersion7DatabaseIsUpgradedWhenOpened) {
  const std::string column_sql =
      "SELECT COUNT(*) FROM information_schema.columns WHERE table_name = 'coefficients' AND "
      "column_name = 'basis_terms_json'";
  std::string uri;
  ASSERT_NO_FATAL_FAILURE(MakeDatabaseTakenBack(
      column_sql, 1,
      absl::StrCat("ALTER TABLE coefficients DROP COLUMN basis_terms_json; ",
                   kDropAttitudeErrorColumns, "UPDATE esg_schema SET version = 7"),
      &uri));
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(uri);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(QueryInt((*storage)->database(), column_sql), IsOkAndHolds(1));
  EXPECT_THAT(QueryInt((*storage)->database(), "SELECT MAX(version) FROM esg_schema"),
              IsOkAndHolds(kCurrentSchemaVersion));
  EXPECT_THAT(QueryInt((*storage)->database(), "SELECT COUNT(*) FROM esg_schema"),
              IsOkAndHolds(1));
}

// A database at version 8 is upgraded when a server opens it: the estimates gain the six
// columns of the attitude error estimate in double precision; a row stored before reads back
// without one, a new row with its values.
TEST(PostgresStorage, AVersion8DatabaseGainsTheAttitudeErrorColumnsWhenOpened) {
  const std::string column_sql =
      "SELECT COUNT(*) FROM information_schema.columns WHERE table_name = 'estimates' AND "
      "column_name LIKE 'attitude_error_%' AND data_type = 'double precision'";
  std::string uri;
  ASSERT_NO_FATAL_FAILURE(MakeDatabaseTakenBack(
      column_sql, 6,
      absl::StrCat(kDropAttitudeErrorColumns, "UPDATE esg_schema SET version = 8; ",
                   "INSERT INTO estimates (spacecraft_id, measurement_time_unix_ns, "
                   "compute_time_unix_ns, state, attitude_valid, "
                   "attitude_invalid_reason, star_tracker_used) VALUES ('PG-8', ",
                   TimeToUnixNanos(T(60)), ", ", TimeToUnixNanos(T(61)),
                   ", 'CALIBRATING', 0, 'no pair', 0)"),
      &uri));
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(uri);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(QueryInt((*storage)->database(), column_sql), IsOkAndHolds(6));
  EXPECT_THAT(QueryInt((*storage)->database(), "SELECT MAX(version) FROM esg_schema"),
              IsOkAndHolds(kCurrentSchemaVersion));
  EstimateRecord added;
  added.spacecraft_id = "PG-8";
  added.measurement_time = T(120);
  added.compute_time = T(121);
  added.state = "CONVERGED";
  added.has_attitude_error = true;
  added.attitude_error_b = {estimator::ArcsecToRad(0.1), estimator::ArcsecToRad(-0.2),
                            estimator::ArcsecToRad(1.0 / 3.0)};
  added.attitude_error_sigma_b = {estimator::ArcsecToRad(1.0), estimator::ArcsecToRad(2.0),
                                  estimator::ArcsecToRad(9.0)};
  ASSERT_THAT((*storage)->estimates().Put(added), IsOk());
  absl::StatusOr<EstimatePage> page = (*storage)->estimates().Page(
      "PG-8", absl::InfinitePast(), absl::InfiniteFuture(), std::nullopt, 10);
  ASSERT_THAT(page, IsOk());
  ASSERT_EQ(page->records.size(), 2u);
  EXPECT_FALSE(page->records[0].has_attitude_error);
  ASSERT_TRUE(page->records[1].has_attitude_error);
  for (int k = 0; k < 3; ++k) {
    EXPECT_DOUBLE_EQ(page->records[1].attitude_error_b[k], added.attitude_error_b[k]) << k;
    EXPECT_DOUBLE_EQ(page->records[1].attitude_error_sigma_b[k], added.attitude_error_sigma_b[k])
        << k;
  }
}

// The estimates trigger (postgres_schema.h kEstimatesChannel): a stored estimate is notified to a
// listener of Storage::ListenForChanges with its measurement time and spacecraft, and a database
// created at version 7 before the trigger existed gets it when a server opens it.
TEST(PostgresStorage, AStoredEstimateIsNotifiedAndAMissingTriggerIsAddedAtOpen) {
  const std::string count_sql = "SELECT COUNT(*) FROM pg_trigger WHERE tgname = 'estimates_notify'";
  std::string uri;
  ASSERT_NO_FATAL_FAILURE(MakeDatabaseTakenBack(
      count_sql, 1,
      "DROP TRIGGER estimates_notify ON estimates; DROP FUNCTION esg_estimates_notify()", &uri));
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(uri);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(QueryInt((*storage)->database(), count_sql), IsOkAndHolds(1));

  absl::StatusOr<std::unique_ptr<PostgresListener>> listener = (*storage)->ListenForChanges();
  ASSERT_THAT(listener, IsOk());
  EstimateRecord estimate;
  estimate.spacecraft_id = "N-1";
  estimate.measurement_time = absl::FromUnixSeconds(1700000000);
  estimate.compute_time = absl::FromUnixSeconds(1700000001);
  estimate.state = "CALIBRATING";
  ASSERT_THAT((*storage)->estimates().Put(estimate), IsOk());
  std::vector<PostgresListener::Notification> got;
  for (int i = 0; i < 20 && got.empty(); ++i) {
    absl::StatusOr<std::vector<PostgresListener::Notification>> n =
        (*listener)->Wait(absl::Milliseconds(250));
    ASSERT_THAT(n, IsOk());
    got = *n;
  }
  ASSERT_EQ(got.size(), 1u);
  EXPECT_EQ(got[0].channel, kEstimatesChannel);
  EXPECT_EQ(got[0].payload, "1700000000000000000 N-1");
  EXPECT_EQ(got[0].sender_pid, (*storage)->ConnectionPid());
}

// A database at version 10 is upgraded when a server opens it (schema.h version 11): its
// diagnoses gain the configuration version (bigint) and model they ran on, read back as 0 and
// empty for the rows stored before; readmissions of excluded gyros are stored and listed.
TEST(PostgresStorage, AVersion10DatabaseGainsTheDiagnosisConfigurationAndReadmissions) {
  std::string error;
  PostgresServer* server = PostgresServer::Shared(&error);
  ASSERT_NE(server, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> uri = server->CreateDatabase();
  ASSERT_THAT(uri, IsOk());
  {
    absl::StatusOr<std::unique_ptr<PostgresDatabase>> db = PostgresDatabase::Open(*uri);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(MigrateTo(**db, 10), IsOk());
    ASSERT_THAT((*db)->Execute(absl::StrCat(
                    "INSERT INTO diagnoses (spacecraft_id, from_time_unix_ns, to_time_unix_ns, "
                    "compute_time_unix_ns, verdict, report_json, frames) VALUES ('PG-10', ",
                    TimeToUnixNanos(T(60)), ", ", TimeToUnixNanos(T(600)), ", ",
                    TimeToUnixNanos(T(900)), ", 'none', '{}', 10)")),
                IsOk());
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(*uri);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(QueryInt((*storage)->database(), "SELECT MAX(version) FROM esg_schema"),
              IsOkAndHolds(kCurrentSchemaVersion));
  EXPECT_THAT(QueryInt((*storage)->database(),
                       "SELECT COUNT(*) FROM information_schema.columns WHERE table_name = "
                       "'diagnoses' AND column_name = 'config_version' AND data_type = 'bigint'"),
              IsOkAndHolds(1));
  absl::StatusOr<std::vector<DiagnosisRecord>> old = (*storage)->diagnoses().List("PG-10");
  ASSERT_THAT(old, IsOk());
  ASSERT_EQ(old->size(), 1u);
  EXPECT_EQ((*old)[0].config_version, 0);
  DiagnosisRecord fresh = (*old)[0];
  fresh.config_version = 2;
  fresh.model_name = "10+11";
  absl::StatusOr<int64_t> id = (*storage)->diagnoses().Put(fresh);
  ASSERT_THAT(id, IsOk());
  absl::StatusOr<DiagnosisRecord> read = (*storage)->diagnoses().Get(*id);
  ASSERT_THAT(read, IsOk());
  EXPECT_EQ(read->config_version, 2);
  EXPECT_EQ(read->model_name, "10+11");
  const ReadmissionRecord readmission{"PG-10", 3, T(7200), T(9000), "alice"};
  ASSERT_THAT((*storage)->sessions().PutReadmission(readmission), IsOk());
  EXPECT_THAT((*storage)->sessions().PutReadmission(readmission),
              StatusIs(absl::StatusCode::kAlreadyExists, HasSubstr("gyro_id")));
  absl::StatusOr<std::vector<ReadmissionRecord>> listed =
      (*storage)->sessions().ListReadmissions("PG-10");
  ASSERT_THAT(listed, IsOk());
  ASSERT_EQ(listed->size(), 1u);
  EXPECT_EQ((*listed)[0].gyro_id, 3);
  EXPECT_EQ((*listed)[0].after_time, T(7200));
  EXPECT_EQ((*listed)[0].operator_name, "alice");
}

// A version-12 database gains auto_diagnosis_cancels (config_version bigint) at its open; an
// operator's cancel is stored and read back per spacecraft and configuration version.
TEST(PostgresStorage, AVersion12DatabaseGainsTheAutoDiagnosisCancels) {
  std::string error;
  PostgresServer* server = PostgresServer::Shared(&error);
  ASSERT_NE(server, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> uri = server->CreateDatabase();
  ASSERT_THAT(uri, IsOk());
  {
    absl::StatusOr<std::unique_ptr<PostgresDatabase>> db = PostgresDatabase::Open(*uri);
    ASSERT_THAT(db, IsOk());
    ASSERT_THAT(MigrateTo(**db, 12), IsOk());
    EXPECT_THAT(QueryInt(**db, "SELECT COUNT(*) FROM information_schema.tables WHERE table_name = "
                               "'auto_diagnosis_cancels'"),
                IsOkAndHolds(0));
  }
  absl::StatusOr<std::unique_ptr<Storage>> storage = Storage::Open(*uri);
  ASSERT_THAT(storage, IsOk());
  EXPECT_THAT(QueryInt((*storage)->database(), "SELECT MAX(version) FROM esg_schema"),
              IsOkAndHolds(kCurrentSchemaVersion));
  EXPECT_THAT(QueryInt((*storage)->database(),
                       "SELECT COUNT(*) FROM information_schema.columns WHERE table_name = "
                       "'auto_diagnosis_cancels' AND column_name = 'config_version' AND "
                       "data_type = 'bigint'"),
              IsOkAndHolds(1));
  DiagnosisStore& diagnoses = (*storage)->diagnoses();
  EXPECT_THAT(diagnoses.AutoCancelled("PG-12", 1), IsOkAndHolds(false));
  ASSERT_THAT(diagnoses.PutAutoCancel({"PG-12", 1, 4, T(100)}), IsOk());
  ASSERT_THAT(diagnoses.PutAutoCancel({"PG-12", 1, 5, T(200)}), IsOk());
  EXPECT_THAT(diagnoses.AutoCancelled("PG-12", 1), IsOkAndHolds(true));
  EXPECT_THAT(diagnoses.AutoCancelled("PG-12", 2), IsOkAndHolds(false));
}

}  // namespace
}  // namespace esg::storage
