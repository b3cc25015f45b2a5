// Storage faults as an operator meets them (docs/service.md "Storage faults"), against a real
// esgd whose SQLite database is opened through a VFS that fails writes on demand
// (tests/testing/fault_vfs.h): a commit that fails ends the senders' streams with UNAVAILABLE
// and the reason, no frame that is not stored is acknowledged, health is NOT_SERVING while
// storage cannot commit and SERVING again after, and senders that resume lose nothing.
#include <sqlite3.h>
#include <sys/statvfs.h>

#include <algorithm>
#include <filesystem>
#include <fstream>

#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "grpc_health/health.grpc.pb.h"
#include "gtest/gtest.h"
#include "storage/service_queries.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/fault_vfs.h"
#include "tests/testing/tmpfs.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::FaultOp;
using ::esg::testing::FaultPersistence;
using ::esg::testing::FaultVfs;
using ::esg::testing::LoopbackServer;
using ::esg::testing::OfflineSessionValues;
using ::esg::testing::SimulateRun;
using ::esg::testing::SimulatedRun;
using ::esg::testing::StoredSessionValues;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::esg::testing::Tmpfs;
using ::testing::HasSubstr;

grpc::health::v1::HealthCheckResponse::ServingStatus Health(const LoopbackServer& server) {
  auto stub = grpc::health::v1::Health::NewStub(
      grpc::CreateChannel(server.address(), grpc::InsecureChannelCredentials()));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  grpc::health::v1::HealthCheckRequest request;
  request.set_service("esg.v1.EstimationService");
  grpc::health::v1::HealthCheckResponse response;
  EXPECT_TRUE(stub->Check(&ctx, request, &response).ok());
  return response.status();
}

// Waits (bounded) until health reports `status`.
bool AwaitHealth(const LoopbackServer& server,
                 grpc::health::v1::HealthCheckResponse::ServingStatus status) {
  for (int i = 0; i < 500; ++i) {
    if (Health(server) == status) return true;
    absl::SleepFor(absl::Milliseconds(10));
  }
  return false;
}

class StorageFault : public ::testing::Test {
 protected:
  void TearDown() override { FaultVfs::Instance().Disarm(); }
};

TEST_F(StorageFault, FullDiskFailsTheStreamNotTheAckAndIngestResumesWhenSpaceReturns) {
  for (const int error : {SQLITE_FULL, SQLITE_IOERR_WRITE}) {
    SCOPED_TRACE(error == SQLITE_FULL ? "disk full" : "I/O error");
    TempDir dir;
    const std::string db = dir.File("esg.db");
    const SimulatedRun run = SimulateRun("FULL-1", 1.0, 51);
    FaultVfs& vfs = FaultVfs::Instance();
    {
      ServerOptions options;
      options.db_vfs = FaultVfs::kName;
      options.core.storage_probe_period = absl::Milliseconds(50);
      LoopbackServer server(options, db);
      auto stub = server.Stub();
      grpc::ClientContext ctx;
      esg::v1::ConfigureResponse r;
      ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
      const std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(),
                                                       run.frames.begin() + 20);
      ASSERT_EQ(StreamFrames(*stub, first).acks.size(), 20u);
      EXPECT_EQ(Health(server), grpc::health::v1::HealthCheckResponse::SERVING);

      // The disk fills up: every write fails until space returns.
      vfs.Arm(FaultOp::kWrite, 1, error, FaultPersistence::kUntilDisarmed);
      const std::vector<esg::v1::TelemetryFrame> second(run.frames.begin() + 20,
                                                        run.frames.begin() + 40);
      auto failed = StreamFrames(*stub, second);
      EXPECT_EQ(failed.status.error_code(), grpc::StatusCode::UNAVAILABLE);
      EXPECT_THAT(failed.status.error_message(), HasSubstr("storage"));
      EXPECT_THAT(failed.status.error_message(),
                  HasSubstr(error == SQLITE_FULL ? "full" : "I/O error"));
      EXPECT_TRUE(failed.acks.empty()) << "an ack for a frame that is not stored";
      EXPECT_TRUE(AwaitHealth(server, grpc::health::v1::HealthCheckResponse::NOT_SERVING));
      // New frames are refused the same way while storage cannot commit.
      auto refused = StreamFrames(*stub, second);
      EXPECT_EQ(refused.status.error_code(), grpc::StatusCode::UNAVAILABLE);
      EXPECT_TRUE(refused.acks.empty());
      // Queries still answer, and say what is durable.
      grpc::ClientContext get_ctx;
      esg::v1::GetSessionRequest get;
      get.set_spacecraft_id("FULL-1");
      esg::v1::SessionInfo info;
      ASSERT_TRUE(stub->GetSession(&get_ctx, get, &info).ok());
      EXPECT_EQ(info.highest_durable_sequence(), 20);

      // Space returns: the probe commits, health is SERVING, the sender resumes from
      // highest_durable_sequence + 1 and nothing is lost or stored twice.
      vfs.Disarm();
      EXPECT_TRUE(AwaitHealth(server, grpc::health::v1::HealthCheckResponse::SERVING));
      const std::vector<esg::v1::TelemetryFrame> rest(run.frames.begin() + 20, run.frames.end());
      auto resumed = StreamFrames(*stub, rest);
      ASSERT_TRUE(resumed.status.ok()) << resumed.status.error_message();
      ASSERT_EQ(resumed.acks.size(), rest.size());
      for (const auto& ack : resumed.acks) {
        EXPECT_TRUE(ack.accepted());
        EXPECT_FALSE(ack.duplicate());
      }
      ASSERT_TRUE(server.core().WaitApplied("FULL-1", absl::Seconds(60)).ok());
    }
    // The archive holds every frame once, and the filter's state is that of an offline run.
    EXPECT_EQ(StoredSessionValues(db, "FULL-1"),
              OfflineSessionValues(run.config, "10+11", run.frames));
  }
}

TEST_F(StorageFault, FailingFsyncIsNeverAcknowledged) {
  TempDir dir;
  const SimulatedRun run = SimulateRun("SYNC-1", 0.5, 52);
  FaultVfs& vfs = FaultVfs::Instance();
  ServerOptions options;
  options.db_vfs = FaultVfs::kName;
  options.core.storage_probe_period = absl::Milliseconds(50);
  LoopbackServer server(options, dir.File("esg.db"));
  auto stub = server.Stub();
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
  vfs.Arm(FaultOp::kSync, 1, SQLITE_IOERR_FSYNC, FaultPersistence::kUntilDisarmed);
  auto failed = StreamFrames(*stub, run.frames);
  EXPECT_EQ(failed.status.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_TRUE(failed.acks.empty());
  vfs.Disarm();
  EXPECT_TRUE(AwaitHealth(server, grpc::health::v1::HealthCheckResponse::SERVING));
  // A commit whose fsync failed was written whole to the WAL: after the fault the resent frames
  // come back as stored or as duplicates, every one accepted, none lost.
  auto resumed = StreamFrames(*stub, run.frames);
  ASSERT_TRUE(resumed.status.ok()) << resumed.status.error_message();
  ASSERT_EQ(resumed.acks.size(), run.frames.size());
  for (const auto& ack : resumed.acks) EXPECT_TRUE(ack.accepted());
  EXPECT_EQ(resumed.acks.back().highest_durable_sequence(),
            static_cast<int64_t>(run.frames.size()));
}

// Writes (xWrite calls) one probe write (storage::ProbeWrite, what the committer tries while
// storage cannot commit) takes through the fault VFS: the most of a few, on a database of its own.
int64_t ProbeWrites(const std::string& path) {
  FaultVfs& vfs = FaultVfs::Instance();
  storage::DatabaseOptions options;
  options.vfs = FaultVfs::kName;
  absl::StatusOr<std::unique_ptr<storage::Storage>> opened = storage::Storage::Open(path, options);
  EXPECT_TRUE(opened.ok()) << opened.status();
  if (!opened.ok()) return 0;
  int64_t most = 0;
  for (int i = 0; i < 3; ++i) {
    vfs.ResetCounters();
    EXPECT_TRUE(storage::ProbeWrite((*opened)->database(), absl::Now()).ok());
    most = std::max(most, vfs.Calls(FaultOp::kWrite));
  }
  return most;
}

int Occurrences(const std::string& text, const std::string& what) {
  int n = 0;
  for (size_t at = text.find(what); at != std::string::npos; at = text.find(what, at + 1)) ++n;
  return n;
}

// Issue 33: on a full disk a probe write fitted, "storage commits again: ingest resumed" was
// logged, and the next commit of frames failed 7 ms later. A probe that succeeds lets frames in
// (health SERVING) but only a commit of frames that succeeds is "ingest resumed".
TEST_F(StorageFault, IngestResumedIsLoggedOnlyAfterACommitOfFramesSucceeds) {
  TempDir dir;
  const int64_t probe_writes = ProbeWrites(dir.File("probe.db"));
  ASSERT_GT(probe_writes, 0);
  const SimulatedRun run = SimulateRun("RESUME-1", 1.0, 54);
  FaultVfs& vfs = FaultVfs::Instance();
  ServerOptions options;
  options.db_vfs = FaultVfs::kName;
  options.core.storage_probe_period = absl::Milliseconds(50);
  LoopbackServer server(options, dir.File("esg.db"));
  auto stub = server.Stub();
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
  const std::vector<esg::v1::TelemetryFrame> first(run.frames.begin(), run.frames.begin() + 20);
  ASSERT_EQ(StreamFrames(*stub, first).acks.size(), first.size());
  ASSERT_TRUE(server.core().WaitApplied("RESUME-1", absl::Seconds(30)).ok());

  ::testing::internal::CaptureStderr();
  // The disk fills up.
  vfs.Arm(FaultOp::kWrite, 1, SQLITE_FULL, FaultPersistence::kUntilDisarmed);
  const std::vector<esg::v1::TelemetryFrame> second(run.frames.begin() + 20,
                                                    run.frames.begin() + 40);
  EXPECT_EQ(StreamFrames(*stub, second).status.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_TRUE(AwaitHealth(server, grpc::health::v1::HealthCheckResponse::NOT_SERVING));
  // Room for a probe, not for a commit of frames: the probe succeeds and frames are taken again,
  // then their commit fails.
  vfs.Arm(FaultOp::kWrite, probe_writes + 1, SQLITE_FULL, FaultPersistence::kUntilDisarmed);
  EXPECT_TRUE(AwaitHealth(server, grpc::health::v1::HealthCheckResponse::SERVING));
  const auto failed = StreamFrames(*stub, second);
  EXPECT_EQ(failed.status.error_code(), grpc::StatusCode::UNAVAILABLE);
  EXPECT_TRUE(failed.acks.empty());
  EXPECT_TRUE(AwaitHealth(server, grpc::health::v1::HealthCheckResponse::NOT_SERVING));
  // Space returns: the next commit of frames succeeds, and only then is ingest resumed.
  vfs.Disarm();
  EXPECT_TRUE(AwaitHealth(server, grpc::health::v1::HealthCheckResponse::SERVING));
  const std::string before_commit = ::testing::internal::GetCapturedStderr();
  EXPECT_EQ(Occurrences(before_commit, "ingest resumed"), 0) << before_commit;
  // The same fault again is not logged again (a reason worded differently is).
  EXPECT_GE(Occurrences(before_commit, "storage cannot commit"), 1) << before_commit;
  EXPECT_LE(Occurrences(before_commit, "storage cannot commit"), 2) << before_commit;
  ::testing::internal::CaptureStderr();
  const std::vector<esg::v1::TelemetryFrame> rest(run.frames.begin() + 20, run.frames.end());
  const auto resumed = StreamFrames(*stub, rest);
  const std::string after_commit = ::testing::internal::GetCapturedStderr();
  ASSERT_TRUE(resumed.status.ok()) << resumed.status.error_message();
  ASSERT_EQ(resumed.acks.size(), rest.size());
  EXPECT_EQ(Occurrences(after_commit, "storage commits again: ingest resumed (2 commits"), 1)
      << after_commit;
}

TEST_F(StorageFault, ShutdownFinishesWhileStorageCannotCommit) {
  TempDir dir;
  const SimulatedRun run = SimulateRun("STOP-1", 0.5, 53);
  FaultVfs& vfs = FaultVfs::Instance();
  ServerOptions options;
  options.db_vfs = FaultVfs::kName;
  auto server = std::make_unique<LoopbackServer>(options, dir.File("esg.db"));
  auto stub = server->Stub();
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
  vfs.Arm(FaultOp::kWrite, 1, SQLITE_FULL, FaultPersistence::kUntilDisarmed);
  auto failed = StreamFrames(*stub, run.frames);
  EXPECT_EQ(failed.status.error_code(), grpc::StatusCode::UNAVAILABLE);
  // The disk stays full: the stop (1 s for calls, 1 s for the filter) still returns.
  const absl::Time start = absl::Now();
  server.reset();
  EXPECT_LT(absl::Now() - start, absl::Seconds(20));
}

// The same on a real file system that fills up: a small tmpfs holding the database, with ballast
// leaving about 150 KiB free (a day of frames alone needs about 500 KiB, with the coefficient
// history several MiB).
TEST_F(StorageFault, RealFullFileSystemFailsStreamsUntilSpaceIsFreedAndLosesNothing) {
  TempDir dir;
  Tmpfs tmpfs(dir, "16m");
  if (!tmpfs.ok()) GTEST_SKIP() << tmpfs.error();
  const std::string db = tmpfs.File("esg.db");
  const std::string ballast = tmpfs.File("ballast");
  const SimulatedRun run = SimulateRun("DISK-1", 24.0, 54);
  {
    ServerOptions options;
    options.core.storage_probe_period = absl::Milliseconds(50);
    LoopbackServer server(options, db);
    auto stub = server.Stub();
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
    struct statvfs fs {};
    ASSERT_EQ(statvfs(tmpfs.File("").c_str(), &fs), 0);
    const int64_t free_bytes = static_cast<int64_t>(fs.f_bavail) * fs.f_frsize;
    {
      std::ofstream out(ballast, std::ios::binary);
      out << std::string(static_cast<size_t>(free_bytes - 150 * 1024), 'b');
    }
    // Stream the day, resuming after every failure until the disk is full.
    auto failed = StreamFrames(*stub, run.frames);
    EXPECT_EQ(failed.status.error_code(), grpc::StatusCode::UNAVAILABLE)
        << "the disk never filled up";
    EXPECT_THAT(failed.status.error_message(), HasSubstr("full"));
    EXPECT_LT(failed.acks.size(), run.frames.size());
    for (const auto& ack : failed.acks) EXPECT_TRUE(ack.accepted());
    EXPECT_TRUE(AwaitHealth(server, grpc::health::v1::HealthCheckResponse::NOT_SERVING));
    // Space is freed: SERVING again, and the sender resumes from its highest durable sequence.
    std::filesystem::remove(ballast);
    EXPECT_TRUE(AwaitHealth(server, grpc::health::v1::HealthCheckResponse::SERVING));
    const int64_t durable = failed.acks.empty() ? 0 : failed.acks.back().highest_durable_sequence();
    const std::vector<esg::v1::TelemetryFrame> rest(run.frames.begin() + durable,
                                                    run.frames.end());
    auto resumed = StreamFrames(*stub, rest);
    ASSERT_TRUE(resumed.status.ok()) << resumed.status.error_message();
    ASSERT_EQ(resumed.acks.size(), rest.size());
    for (const auto& ack : resumed.acks) EXPECT_TRUE(ack.accepted());
    ASSERT_TRUE(server.core().WaitApplied("DISK-1", absl::Seconds(120)).ok());
  }
  EXPECT_EQ(StoredSessionValues(db, "DISK-1"),
            OfflineSessionValues(run.config, "10+11", run.frames));
}

}  // namespace
}  // namespace esg::server
