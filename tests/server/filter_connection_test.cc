// The filter's commits on PostgreSQL run on a connection of their own (storage/storage.h
// "Connections"): a real esgd on 127.0.0.1 over a real PostgreSQL server (tests/testing/
// postgres_server.h), the filter's group commit on, a filter transaction held waiting for a row
// lock another connection holds, and a frame acknowledged meanwhile. Also on PostgreSQL with
// session leases: an operator's readmission of a gyro is fenced like every write of the session
// (docs/service.md "Several servers", Fencing).
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/postgres_db.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/example_config.h"
#include "tests/testing/postgres_server.h"
#include "tests/testing/status_matchers.h"

namespace esg::testing {
namespace {

using ::esg::storage::PostgresDatabase;
using ::esg::storage::Statement;
using ::esg::storage::Transaction;
using ::esg::storage::TransactionMode;

// A backend of the test's database waiting for a lock: its pid and the start of its
// transaction (microseconds since the epoch).
struct LockWaiter {
  int64_t pid = 0;
  int64_t xact_start_us = 0;
};

// The backends of `db`'s database waiting for a lock now (a new transaction per call, so
// pg_stat_activity is read afresh).
std::vector<LockWaiter> LockWaiters(PostgresDatabase& db) {
  std::vector<LockWaiter> waiters;
  absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kDeferred);
  EXPECT_THAT(txn, IsOk());
  if (!txn.ok()) return waiters;
  absl::StatusOr<Statement*> st = txn->Prepare(
      "SELECT pid, (extract(epoch FROM xact_start) * 1000000)::bigint FROM pg_stat_activity "
      "WHERE datname = current_database() AND wait_event_type = 'Lock'");
  EXPECT_THAT(st, IsOk());
  if (!st.ok()) return waiters;
  for (;;) {
    absl::StatusOr<bool> row = (*st)->Step();
    EXPECT_THAT(row, IsOk());
    if (!row.ok() || !*row) break;
    waiters.push_back({(*st)->ColumnInt64(0), (*st)->ColumnInt64(1)});
  }
  (*st)->Reset();
  EXPECT_THAT(txn->Commit(), IsOk());
  return waiters;
}

// A filter commit that cannot finish (its checkpoint row locked by another connection) does not
// hold up ingest: a frame sent while it waits is committed and acknowledged, and the filter's
// transaction is still the same one waiting when the ack arrives (on one connection the ack
// would have waited for that transaction to end, at lock_timeout). Released, the filter applies
// every frame.
TEST(FilterConnectionPostgres, AnAckIsSentWhileAFilterCommitWaitsForALock) {
  std::string error;
  PostgresServer* pg = PostgresServer::Shared(&error);
  ASSERT_NE(pg, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> uri = pg->CreateDatabase();
  ASSERT_THAT(uri, IsOk());

  server::ServerOptions options;
  options.core.worker_threads = 2;
  options.core.filter_commit_group = 8;
  LoopbackServer server(options, *uri);
  ASSERT_NE(server.get(), nullptr);
  auto stub = server.Stub();
  const SimulatedRun run = SimulateRun("FC-1", 1.0);
  ASSERT_GE(run.frames.size(), 10u);
  {
    grpc::ClientContext context;
    esg::v1::ConfigureResponse response;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &response)
                    .ok());
  }
  const size_t n = run.frames.size();
  std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(), run.frames.end() - 2);
  StreamResult sent = StreamFrames(*stub, first);
  ASSERT_TRUE(sent.status.ok()) << sent.status.error_message();
  ASSERT_THAT(server.core().WaitApplied("FC-1", absl::Minutes(2)), IsOk());

  // Another connection locks the spacecraft's checkpoint row; the next filter job's commit
  // waits for it.
  absl::StatusOr<std::unique_ptr<PostgresDatabase>> blocker = PostgresDatabase::Open(*uri);
  ASSERT_THAT(blocker, IsOk());
  absl::StatusOr<std::unique_ptr<PostgresDatabase>> observer = PostgresDatabase::Open(*uri);
  ASSERT_THAT(observer, IsOk());
  absl::StatusOr<Transaction> lock = (*blocker)->Begin(TransactionMode::kImmediate);
  ASSERT_THAT(lock, IsOk());
  {
    absl::StatusOr<Statement*> st = lock->Prepare(
        "SELECT spacecraft_id FROM checkpoints WHERE spacecraft_id = ?1 FOR UPDATE");
    ASSERT_THAT(st, IsOk());
    (*st)->BindText(1, "FC-1");
    absl::StatusOr<bool> row = (*st)->Step();
    ASSERT_THAT(row, IsOk());
    ASSERT_TRUE(*row) << "no checkpoint of FC-1";
    (*st)->Reset();
  }
  sent = StreamFrames(*stub, {run.frames[n - 2]});
  ASSERT_TRUE(sent.status.ok()) << sent.status.error_message();
  ASSERT_EQ(sent.acks.size(), 1u);
  ASSERT_TRUE(sent.acks[0].accepted());

  // The filter's commit of that frame waits for the lock.
  std::vector<LockWaiter> waiting;
  const absl::Time deadline = absl::Now() + absl::Minutes(1);
  while (waiting.empty() && absl::Now() < deadline) {
    waiting = LockWaiters(**observer);
    if (waiting.empty()) absl::SleepFor(absl::Milliseconds(20));
  }
  ASSERT_EQ(waiting.size(), 1u) << "no filter commit waits for the checkpoint row";

  // A frame sent now is acknowledged durable while that transaction still waits.
  sent = StreamFrames(*stub, {run.frames[n - 1]});
  ASSERT_TRUE(sent.status.ok()) << sent.status.error_message();
  ASSERT_EQ(sent.acks.size(), 1u);
  EXPECT_TRUE(sent.acks[0].accepted());
  EXPECT_EQ(sent.acks[0].highest_durable_sequence(), run.frames[n - 1].sequence());
  const std::vector<LockWaiter> still = LockWaiters(**observer);
  ASSERT_EQ(still.size(), 1u) << "the filter's transaction no longer waits";
  EXPECT_EQ(still[0].pid, waiting[0].pid);
  EXPECT_EQ(still[0].xact_start_us, waiting[0].xact_start_us);

  // Released, the filter commits and applies every frame once.
  ASSERT_THAT(lock->Rollback(), IsOk());
  ASSERT_THAT(server.core().WaitApplied("FC-1", absl::Minutes(2)), IsOk());
  const esg::v1::SessionInfo info = Session(*stub, "FC-1");
  EXPECT_EQ(info.frames_applied(), static_cast<int64_t>(n));
}

// A server that lost a session's lease (another node took it over: the lease row's owner and
// epoch changed, as a takeover after this server paused past its lease writes them) refuses an
// operator's readmission of the session's excluded gyro with ABORTED naming spacecraft_id, the
// node that took it over and that nothing is stored; the readmission is not in the database. The
// server drops the session: the call sent again is refused UNAVAILABLE while the other node
// holds the lease. (The lease renewal, every 20 s here, cannot notice the takeover first.)
TEST(ReadmitGyroPostgres, IsRefusedAndStoresNothingOnAServerThatLostTheSessionLease) {
  std::string error;
  PostgresServer* pg = PostgresServer::Shared(&error);
  ASSERT_NE(pg, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> uri = pg->CreateDatabase();
  ASSERT_THAT(uri, IsOk());
  server::ServerOptions options;
  options.core.node_id = "node-a";
  options.core.lease_duration = absl::Minutes(1);
  options.auto_diagnosis.span = absl::ZeroDuration();
  LoopbackServer server(options, *uri);
  ASSERT_NE(server.get(), nullptr);
  auto stub = server.Stub();

  // RDK-1, gyro 3's reading frozen for 15 min at 2 h while the spacecraft turns: excluded.
  const std::string id = "LEASE-1";
  estimator::SimulationSpec spec;
  spec.config = ExampleConfig("rdk1.json");
  spec.config.spacecraft_id = id;
  spec.duration = estimator::HoursToSeconds(3.0);
  spec.seed = 5;
  estimator::GyroFault frozen;
  frozen.time = estimator::HoursToSeconds(2.0);
  frozen.kind = estimator::GyroFault::Kind::kReadingFrozen;
  frozen.end = estimator::HoursToSeconds(2.25);
  spec.gyros[2].fault = frozen;
  const SimulatedRun run = SimulateCalibrationRun(id, spec);
  {
    grpc::ClientContext context;
    esg::v1::ConfigureResponse response;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &response)
                    .ok());
  }
  const StreamResult sent = StreamFrames(*stub, run.frames);
  ASSERT_TRUE(sent.status.ok()) << sent.status.error_message();
  ASSERT_THAT(server.core().WaitApplied(id, absl::Minutes(2)), IsOk());
  const esg::v1::SessionInfo info = Session(*stub, id);
  bool excluded = false;
  for (const esg::v1::ExcludedGyro& e : info.excluded_gyros()) excluded |= e.gyro_id() == 3;
  ASSERT_TRUE(excluded) << "gyro 3 was not excluded: " << info.DebugString();

  // Node B takes the session over.
  absl::StatusOr<std::unique_ptr<storage::Storage>> db = storage::Storage::Open(*uri);
  ASSERT_THAT(db, IsOk());
  absl::StatusOr<storage::SessionLease> held = (*db)->leases().Get(id);
  ASSERT_THAT(held, IsOk());
  ASSERT_EQ(held->owner, "node-a");
  ASSERT_THAT((*db)->database().Execute(
                  "UPDATE session_leases SET owner = 'node-b', epoch = epoch + 1 "
                  "WHERE spacecraft_id = 'LEASE-1'"),
              IsOk());

  const auto readmit = [&]() {
    grpc::ClientContext context;
    esg::v1::ReadmitGyroRequest request;
    request.set_spacecraft_id(id);
    request.set_gyro_id(3);
    request.set_operator_name("alice");
    esg::v1::ReadmitGyroResponse response;
    return stub->ReadmitGyro(&context, request, &response);
  };
  const grpc::Status refused = readmit();
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::ABORTED) << refused.error_message();
  EXPECT_THAT(refused.error_message(), ::testing::StartsWith("spacecraft_id: "));
  EXPECT_THAT(refused.error_message(),
              ::testing::HasSubstr(absl::StrCat("no longer holds its session (taken over by node "
                                                "node-b, epoch ",
                                                held->epoch + 1, ")")));
  EXPECT_THAT(refused.error_message(),
              ::testing::HasSubstr("the readmission of gyro 3 is not stored"));
  absl::StatusOr<std::vector<storage::ReadmissionRecord>> stored =
      (*db)->sessions().ListReadmissions(id);
  ASSERT_THAT(stored, IsOk());
  EXPECT_TRUE(stored->empty()) << stored->size() << " readmissions stored";

  const grpc::Status again = readmit();
  EXPECT_EQ(again.error_code(), grpc::StatusCode::UNAVAILABLE) << again.error_message();
  EXPECT_THAT(again.error_message(), ::testing::HasSubstr("is served by node node-b"));
}

}  // namespace
}  // namespace esg::testing
