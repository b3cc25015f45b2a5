// Two promises of docs/service.md checked against the real esgd as a child process over a real
// SQLite file (issue 33):
//  - Shutdown ("Running it"): SIGTERM first stops ingest on every open stream, each stream gets
//    the acks of what it queued and ends UNAVAILABLE with a retry delay, and the daemon exits well
//    inside --shutdown-deadline while a station streams continuously; every acknowledged frame
//    is in the archive after the restart.
//  - The ingest contract's clock lead: a frame tagged ahead of the server's clock (+3 days, +1 h)
//    is refused OUT_OF_RANGE, and the correct frames after it are stored.
#include <signal.h>

#include <atomic>
#include <chrono>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/clock.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/run_process.h"

namespace esg {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::SimulateRun;
using ::esg::testing::SimulatedRun;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

void Configure(esg::v1::EstimationService::Stub& stub, const SimulatedRun& run) {
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  const grpc::Status status = stub.ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r);
  ASSERT_TRUE(status.ok()) << status.error_message();
}

// `frames` moved in time so that the last one is measured one minute before now.
std::vector<esg::v1::TelemetryFrame> EndingNow(std::vector<esg::v1::TelemetryFrame> frames) {
  const int64_t shift = absl::ToUnixSeconds(absl::Now()) - 60 - frames.back().time().seconds();
  for (esg::v1::TelemetryFrame& f : frames) {
    f.mutable_time()->set_seconds(f.time().seconds() + shift);
  }
  return frames;
}

TEST(Shutdown, SigtermUnderContinuousIngestStopsTheStreamAndExitsWellInsideTheDeadline) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  const std::string log = dir.File("esgd.log");
  // 48 h at 60 s: 2881 frames, sent one every 5 ms (14 s, longer than the deadline).
  const SimulatedRun run = SimulateRun("STOP-1", 48.0, 61);
  constexpr int kDeadlineSeconds = 10;
  auto daemon = std::make_unique<Daemon>(
      db, log, testing::DaemonLimits{},
      std::vector<std::string>{"--shutdown-deadline", absl::StrCat(kDeadlineSeconds)});
  ASSERT_GT(daemon->port(), 0) << testing::ReadFile(log);
  auto stub = daemon->Stub();
  Configure(*stub, run);

  std::atomic<int64_t> acknowledged{0};
  std::atomic<int64_t> highest_acked{0};
  grpc::Status status;
  std::string pushback;
  std::thread station([&] {
    grpc::ClientContext ctx;
    ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(60));
    auto stream = stub->StreamTelemetry(&ctx);
    std::thread reader([&] {
      esg::v1::TelemetryAck ack;
      while (stream->Read(&ack)) {
        if (!ack.accepted()) continue;
        ++acknowledged;
        highest_acked = std::max(highest_acked.load(), ack.sequence());
      }
    });
    for (const esg::v1::TelemetryFrame& f : run.frames) {
      if (!stream->Write(f)) break;
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    stream->WritesDone();
    reader.join();
    status = stream->Finish();
    const auto& trailers = ctx.GetServerTrailingMetadata();
    if (auto it = trailers.find("grpc-retry-pushback-ms"); it != trailers.end()) {
      pushback = std::string(it->second.data(), it->second.size());
    }
  });
  // Streaming for a second before the SIGTERM.
  while (acknowledged < 100) std::this_thread::sleep_for(std::chrono::milliseconds(10));
  std::this_thread::sleep_for(std::chrono::seconds(1));
  const auto stopping = std::chrono::steady_clock::now();
  daemon->Stop(SIGTERM);  // returns once the process exited
  const double shutdown_s =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - stopping).count();
  station.join();
  RecordProperty("shutdown_ms", static_cast<int>(shutdown_s * 1000));
  std::printf("shutdown under ingest: %.3f s (deadline %d s), %lld frames acknowledged\n",
              shutdown_s, kDeadlineSeconds, static_cast<long long>(acknowledged.load()));
  // Before issue 33 the stream was served for the whole deadline.
  EXPECT_LT(shutdown_s, kDeadlineSeconds / 2.0) << testing::ReadFile(log);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::UNAVAILABLE) << status.error_message();
  EXPECT_THAT(status.error_message(), HasSubstr("shutting down"));
  EXPECT_THAT(status.error_message(), HasSubstr("highest_durable_sequence + 1"));
  EXPECT_EQ(pushback, "1000");
  ASSERT_LT(acknowledged.load(), static_cast<int64_t>(run.frames.size()));

  // Every acknowledged frame is stored (acks follow commits), in order from sequence 1.
  Daemon restarted(db, log);
  ASSERT_GT(restarted.port(), 0) << testing::ReadFile(log);
  const esg::v1::SessionInfo info = testing::Session(*restarted.Stub(), "STOP-1");
  EXPECT_GE(info.highest_durable_sequence(), highest_acked.load());
  EXPECT_GE(info.frames_accepted(), acknowledged.load());
  EXPECT_EQ(info.frames_accepted(), info.highest_durable_sequence());
}

TEST(ClockLead, AFrameAheadOfTheServersClockIsRefusedAndTheCorrectFramesAfterItAreStored) {
  for (const absl::Duration ahead : {absl::Hours(72), absl::Hours(1)}) {
    SCOPED_TRACE(absl::FormatDuration(ahead));
    TempDir dir;
    const std::string log = dir.File("esgd.log");
    Daemon daemon(dir.File("esg.db"), log);
    ASSERT_GT(daemon.port(), 0) << testing::ReadFile(log);
    auto stub = daemon.Stub();
    SimulatedRun run = SimulateRun("LEAD-1", 2.0, 62);
    run.frames = EndingNow(run.frames);
    Configure(*stub, run);
    // Half the frames, the mistagged one (the next frame's readings, tagged `ahead` of the
    // present), the rest.
    const size_t half = run.frames.size() / 2;
    esg::v1::TelemetryFrame wrong = run.frames[half];
    wrong.mutable_time()->set_seconds(absl::ToUnixSeconds(absl::Now() + ahead));
    std::vector<esg::v1::TelemetryFrame> sent(run.frames.begin(), run.frames.begin() + half);
    sent.push_back(wrong);
    sent.insert(sent.end(), run.frames.begin() + half, run.frames.end());
    const auto result = StreamFrames(*stub, sent);
    ASSERT_TRUE(result.status.ok()) << result.status.error_message();
    ASSERT_EQ(result.acks.size(), sent.size());
    for (size_t i = 0; i < sent.size(); ++i) {
      if (i == half) {
        EXPECT_FALSE(result.acks[i].accepted());
        EXPECT_EQ(result.acks[i].rejection().code(), grpc::StatusCode::OUT_OF_RANGE);
        EXPECT_EQ(result.acks[i].rejection().field(), "time");
        EXPECT_THAT(result.acks[i].rejection().reason(), HasSubstr("ahead of the server's clock"));
      } else {
        EXPECT_TRUE(result.acks[i].accepted())
            << "frame " << i << ": " << result.acks[i].rejection().reason();
        EXPECT_FALSE(result.acks[i].duplicate()) << "frame " << i;
      }
    }
    const esg::v1::SessionInfo info = testing::Session(*stub, "LEAD-1");
    EXPECT_EQ(info.frames_accepted(), static_cast<int64_t>(run.frames.size()));
    EXPECT_EQ(info.highest_durable_sequence(), run.frames.back().sequence());
  }
}

}  // namespace
}  // namespace esg
