// The filter's group commit on PostgreSQL (docs/decisions.md D109, docs/deploy.md "Capacity"): a
// real esgd on 127.0.0.1 over a real PostgreSQL server (tests/testing/postgres_server.h) with
// session leases. Three spacecraft's jobs are held at their start (CoreOptions::before_apply_job)
// until every frame of the three is acknowledged durable, then released together: their effects
// are committed in ONE transaction (the group fills with every thread of the pool; the window is
// a minute, so nothing here depends on how fast the jobs run). With one of the three leases taken
// over by another node while its job was held, that job is refused alone and the other two
// spacecraft's effects are committed.
#include <memory>
#include <set>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/postgres_server.h"
#include "tests/testing/status_matchers.h"

namespace esg::testing {
namespace {

const std::vector<std::string> kIds = {"GC-A", "GC-B", "GC-C"};

// Holds each spacecraft's job at its start while armed, until Release(); counts the spacecraft
// held.
class JobGate {
 public:
  void Enter(const std::string& id) {
    absl::MutexLock lock(&mu_);
    if (!armed_) return;
    held_.insert(id);
    mu_.Await(absl::Condition(+[](bool* armed) { return !*armed; }, &armed_));
  }
  // True once `n` spacecraft's jobs wait (at most a minute).
  bool WaitHeld(size_t n) {
    absl::MutexLock lock(&mu_);
    struct Arg {
      std::set<std::string>* held;
      size_t n;
    } arg{&held_, n};
    return mu_.AwaitWithTimeout(
        absl::Condition(+[](Arg* a) { return a->held->size() >= a->n; }, &arg),
        absl::Minutes(1));
  }
  void Release() {
    absl::MutexLock lock(&mu_);
    armed_ = false;
  }

 private:
  absl::Mutex mu_;
  bool armed_ ABSL_GUARDED_BY(mu_) = true;
  std::set<std::string> held_ ABSL_GUARDED_BY(mu_);
};

struct Fleet {
  std::string uri;
  std::vector<SimulatedRun> runs;
};

// Runs the scenario: three spacecraft configured on a server with leases (node "a"), a group of
// at most 3 jobs (worker_threads 2), every frame sent and acknowledged while the jobs are held,
// `take_over` (if not empty) taken by node "b", the jobs released. Returns the filter's commit
// counts between the release and the end of the applied spacecraft's jobs.
server::EstimationCore::FilterCommitCounts RunHeldGroup(Fleet& fleet,
                                                        const std::string& take_over) {
  server::EstimationCore::FilterCommitCounts counts;
  std::string error;
  PostgresServer* pg = PostgresServer::Shared(&error);
  EXPECT_NE(pg, nullptr) << "the PostgreSQL test server cannot start: " << error;
  if (pg == nullptr) return counts;
  absl::StatusOr<std::string> uri = pg->CreateDatabase();
  EXPECT_THAT(uri, IsOk());
  if (!uri.ok()) return counts;
  fleet.uri = *uri;

  JobGate gate;
  server::ServerOptions options;
  options.core.node_id = "a";
  options.core.lease_duration = absl::Minutes(10);  // no renewal round during the test
  options.core.worker_threads = 2;
  options.core.filter_commit_group = 3;
  options.core.filter_commit_window = absl::Minutes(1);
  options.core.reorder_window = absl::ZeroDuration();  // no window checkpoint splits a job
  options.core.before_apply_job = [&gate](const std::string& id) { gate.Enter(id); };
  LoopbackServer server(options, *uri);
  EXPECT_NE(server.get(), nullptr);
  if (server.get() == nullptr) {
    gate.Release();
    return counts;
  }
  auto stub = server.Stub();
  std::vector<esg::v1::TelemetryFrame> all;
  for (size_t i = 0; i < kIds.size(); ++i) {
    fleet.runs.push_back(SimulateRun(kIds[i], 0.3, 7 + i));  // 18 frames: one job each
    grpc::ClientContext context;
    esg::v1::ConfigureResponse response;
    EXPECT_TRUE(stub->ConfigureSpacecraft(&context, ConfigureRequestFor(fleet.runs[i].config),
                                          &response)
                    .ok());
    all.insert(all.end(), fleet.runs[i].frames.begin(), fleet.runs[i].frames.end());
  }
  const StreamResult sent = StreamFrames(*stub, all);
  EXPECT_TRUE(sent.status.ok()) << sent.status.error_message();
  EXPECT_EQ(sent.acks.size(), all.size());
  for (const esg::v1::TelemetryAck& ack : sent.acks) EXPECT_TRUE(ack.accepted());
  EXPECT_TRUE(gate.WaitHeld(kIds.size())) << "not every spacecraft's job started";

  if (!take_over.empty()) {
    absl::StatusOr<std::unique_ptr<storage::Storage>> other = storage::Storage::Open(*uri);
    EXPECT_THAT(other, IsOk());
    if (other.ok()) {
      // b finds a's lease expired: its clock an hour ahead.
      EXPECT_THAT((*other)->leases().Acquire(take_over, "b", absl::Now() + absl::Hours(1),
                                             absl::Hours(1)),
                  IsOk());
    }
  }
  const server::EstimationCore::FilterCommitCounts before = server.core().filter_commit_counts();
  gate.Release();
  for (const std::string& id : kIds) {
    if (id == take_over) continue;
    EXPECT_THAT(server.core().WaitApplied(id, absl::Minutes(2)), IsOk()) << id;
  }
  const server::EstimationCore::FilterCommitCounts after = server.core().filter_commit_counts();
  counts.transactions = after.transactions - before.transactions;
  counts.jobs = after.jobs - before.jobs;
  return counts;
}

// What the database holds of spacecraft `id` (index i of the fleet): its checkpoint's cursor and
// its stored estimates.
struct Stored {
  int64_t last_sequence = -1;
  int64_t estimates = -1;
};
Stored StoredOf(const std::string& uri, const std::string& id) {
  Stored s;
  absl::StatusOr<std::unique_ptr<storage::Storage>> storage = storage::Storage::Open(uri);
  EXPECT_THAT(storage, IsOk());
  if (!storage.ok()) return s;
  absl::StatusOr<storage::CheckpointRecord> cp = (*storage)->sessions().GetCheckpoint(id);
  if (cp.ok()) s.last_sequence = cp->last_sequence;
  absl::StatusOr<int64_t> n = (*storage)->estimates().Count(id);
  EXPECT_THAT(n, IsOk());
  if (n.ok()) s.estimates = *n;
  return s;
}

TEST(FilterGroupCommitPostgres, JobsThatFinishTogetherCommitInOneTransaction) {
  Fleet fleet;
  const server::EstimationCore::FilterCommitCounts counts = RunHeldGroup(fleet, "");
  ASSERT_EQ(fleet.runs.size(), kIds.size());
  EXPECT_EQ(counts.jobs, 3);
  EXPECT_EQ(counts.transactions, 1);
  for (size_t i = 0; i < kIds.size(); ++i) {
    const Stored s = StoredOf(fleet.uri, kIds[i]);
    EXPECT_EQ(s.last_sequence, fleet.runs[i].frames.back().sequence()) << kIds[i];
    EXPECT_GT(s.estimates, 0) << kIds[i];
  }
}

TEST(FilterGroupCommitPostgres, ALostLeaseInAGroupLeavesTheOthersCommitted) {
  Fleet fleet;
  const server::EstimationCore::FilterCommitCounts counts = RunHeldGroup(fleet, "GC-B");
  ASSERT_EQ(fleet.runs.size(), kIds.size());
  // GC-B's job was in the same transaction as the others' and rolled back to its savepoint.
  EXPECT_EQ(counts.jobs, 3);
  EXPECT_EQ(counts.transactions, 1);
  for (size_t i = 0; i < kIds.size(); ++i) {
    const Stored s = StoredOf(fleet.uri, kIds[i]);
    if (kIds[i] == "GC-B") {
      EXPECT_NE(s.last_sequence, fleet.runs[i].frames.back().sequence()) << kIds[i];
      EXPECT_EQ(s.estimates, 0) << kIds[i];
    } else {
      EXPECT_EQ(s.last_sequence, fleet.runs[i].frames.back().sequence()) << kIds[i];
      EXPECT_GT(s.estimates, 0) << kIds[i];
    }
  }
}

}  // namespace
}  // namespace esg::testing
