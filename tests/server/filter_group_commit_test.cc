// The filter's group commit on PostgreSQL (docs/decisions.md D109, docs/deploy.md "Capacity"): a
// real esgd on 127.0.0.1 over a real PostgreSQL server (tests/testing/postgres_server.h) with
// session leases. Three spacecraft's jobs are held at their start (CoreOptions::before_apply_job)
// until every frame of the three is acknowledged durable, then released together: their effects
// are committed in ONE transaction (the group fills with every thread of the pool; the window is
// a minute, so nothing here depends on how fast the jobs run). With one of the three leases taken
// over by another node while its job was held, that job is refused alone and the other two
// spacecraft's effects are committed. And the real esgd (tests/testing/daemon.h) with
// --filter-commit-group, killed with SIGKILL while it streams and commits groups: every frame
// acknowledged before the kill is in the archive after the restart, and every frame is applied
// exactly once (the acknowledgement invariant, docs/service.md).
#include <signal.h>

#include <algorithm>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/clock.h"
#include "absl/time/time.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
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

// The frames of `runs` interleaved in time order (frame k of every spacecraft, then k + 1).
std::vector<esg::v1::TelemetryFrame> Interleaved(const std::vector<SimulatedRun>& runs) {
  std::vector<esg::v1::TelemetryFrame> all;
  for (size_t k = 0;; ++k) {
    bool any = false;
    for (const SimulatedRun& r : runs) {
      if (k < r.frames.size()) {
        all.push_back(r.frames[k]);
        any = true;
      }
    }
    if (!any) return all;
  }
}

TEST(FilterGroupCommitPostgres, AKillNineWhileGroupsCommitLosesNoAckedFrameAndAppliesEachOnce) {
  std::string error;
  PostgresServer* pg = PostgresServer::Shared(&error);
  ASSERT_NE(pg, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> uri = pg->CreateDatabase();
  ASSERT_THAT(uri, IsOk());
  TempDir dir;
  const std::vector<std::string> args = {"--node-id",          "k",  "--lease-duration",
                                         "2s",                 "--filter-commit-group",
                                         "16",                 "--filter-commit-window",
                                         "25ms"};
  std::vector<SimulatedRun> runs;
  for (int i = 0; i < 6; ++i) {
    runs.push_back(SimulateRun(absl::StrCat("GK-", i), 6.0, 40 + i));  // 360 frames each
  }
  const std::vector<esg::v1::TelemetryFrame> all = Interleaved(runs);

  std::map<std::string, int64_t> acked;  // the highest sequence acknowledged, per spacecraft
  {
    Daemon first(*uri, dir.File("first.log"), DaemonLimits{}, args);
    ASSERT_GT(first.port(), 0);
    auto stub = first.Stub();
    for (const SimulatedRun& r : runs) {
      grpc::ClientContext context;
      esg::v1::ConfigureResponse response;
      ASSERT_TRUE(
          stub->ConfigureSpacecraft(&context, ConfigureRequestFor(r.config), &response).ok());
    }
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(120));
    auto stream = stub->StreamTelemetry(&context);
    std::thread writer([&] {
      for (const esg::v1::TelemetryFrame& f : all) {
        if (!stream->Write(f)) break;
      }
      stream->WritesDone();
    });
    // Killed once a third of the frames are acknowledged: the filter's groups are committing
    // behind ingest then.
    esg::v1::TelemetryAck ack;
    size_t n = 0;
    while (stream->Read(&ack)) {
      EXPECT_TRUE(ack.accepted()) << ack.ShortDebugString();
      int64_t& highest = acked[ack.spacecraft_id()];
      highest = std::max(highest, ack.sequence());
      if (++n == all.size() / 3) first.Stop(SIGKILL);
    }
    writer.join();
    stream->Finish();
    EXPECT_GE(n, all.size() / 3);
  }

  Daemon second(*uri, dir.File("second.log"), DaemonLimits{}, args);
  ASSERT_GT(second.port(), 0);
  auto stub = second.Stub();
  for (const SimulatedRun& r : runs) {
    const std::string& id = r.config.spacecraft_id;
    const esg::v1::SessionInfo info = Session(*stub, id);
    EXPECT_GE(info.highest_durable_sequence(), acked[id]) << id << ": an acked frame is lost";
  }
  // Every frame again: the stored ones come back as duplicates.
  const StreamResult resent = StreamFrames(*stub, all);
  ASSERT_TRUE(resent.status.ok()) << resent.status.error_message();
  ASSERT_EQ(resent.acks.size(), all.size());
  for (const esg::v1::TelemetryAck& a : resent.acks) EXPECT_TRUE(a.accepted());
  for (const SimulatedRun& r : runs) {
    const std::string& id = r.config.spacecraft_id;
    const int64_t n = static_cast<int64_t>(r.frames.size());
    esg::v1::SessionInfo info;
    for (const absl::Time deadline = absl::Now() + absl::Minutes(3); absl::Now() < deadline;) {
      info = Session(*stub, id);
      if (info.frames_applied() >= n) break;
      absl::SleepFor(absl::Milliseconds(100));
    }
    EXPECT_EQ(info.frames_applied(), n) << id << ": every frame applied exactly once";
    EXPECT_EQ(info.highest_durable_sequence(), r.frames.back().sequence()) << id;
  }
}

}  // namespace
}  // namespace esg::testing
