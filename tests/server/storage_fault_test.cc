// Storage faults as an operator meets them (docs/service.md "Storage faults"), against a real
// esgd whose SQLite database is opened through a VFS that fails writes on demand
// (tests/testing/fault_vfs.h): a commit that fails ends the senders' streams with UNAVAILABLE
// and the reason, no frame that is not stored is acknowledged, health is NOT_SERVING while
// storage cannot commit and SERVING again after, and senders that resume lose nothing.
#include <sqlite3.h>
#include <sys/statvfs.h>

#include <filesystem>
#include <fstream>

#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "grpc_health/health.grpc.pb.h"
#include "gtest/gtest.h"
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
