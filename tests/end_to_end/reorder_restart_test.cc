// The reorder window across kill -9 (docs/service.md "Several ground stations"): the real esgd
// keeps its window checkpoints and the records of late frames in SQLite, so a daemon killed
// after applying a pass, and again right after acknowledging late frames of another station,
// still re-runs the filter over them from a kept checkpoint (not from the configuration) and
// ends with the coefficient history of an offline run over the merged recording in time order
// (drift coefficients to 1e-12 deg/h) and the same filter state bit for bit. `esg history`
// shows the current snapshots, and with --include-revised also the superseded ones, marked.
#include <csignal>
#include <iostream>
#include <string>
#include <vector>

#include "absl/strings/str_split.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/server/reorder_test_util.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/daemon.h"
#include "tests/testing/run_process.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Daemon;
using ::esg::testing::ExpectDriftCoefficientsEqualOffline;
using ::esg::testing::OfflineCoefficientHistory;
using ::esg::testing::OfflineSessionValues;
using ::esg::testing::RunBinary;
using ::esg::testing::RunResult;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StationPass;
using ::esg::testing::StoredSessionValues;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;

// Polls GetSession until `frames_applied` reaches `n` (30 s at most).
bool WaitFramesApplied(Daemon& daemon, const std::string& id, int64_t n) {
  const absl::Time deadline = absl::Now() + absl::Seconds(30);
  while (absl::Now() < deadline) {
    auto stub = daemon.Stub();
    grpc::ClientContext ctx;
    esg::v1::GetSessionRequest get;
    get.set_spacecraft_id(id);
    esg::v1::SessionInfo info;
    if (stub->GetSession(&ctx, get, &info).ok() && info.frames_applied() >= n) return true;
    absl::SleepFor(absl::Milliseconds(20));
  }
  return false;
}

TEST(ReorderRestart, LateFramesAcknowledgedBeforeAKillNineAreReRunFromAKeptCheckpoint) {
  const SimulatedRun run = SimulateRun("RRK-1", 4.0, 17);
  const std::string id = run.config.spacecraft_id;
  TempDir dir;
  const std::string db = dir.File("var/esg.db");
  const std::string log = dir.File("esgd.log");
  // GS-1 relays minutes 0-199 without 150-159; GS-2 relays those afterwards.
  std::vector<esg::v1::TelemetryFrame> first = StationPass(run, 0, 150, "GS-1", 1);
  for (const auto& f : StationPass(run, 160, 200, "GS-1", 151)) first.push_back(f);
  const std::vector<esg::v1::TelemetryFrame> late = StationPass(run, 150, 160, "GS-2", 1);
  {
    Daemon daemon(db, log);
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(daemon.Stub()->ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
    auto result = StreamFrames(*daemon.Stub(), first);
    ASSERT_TRUE(result.status.ok()) << result.status.error_message();
    ASSERT_EQ(result.acks.size(), first.size());
    ASSERT_TRUE(WaitFramesApplied(daemon, id, static_cast<int64_t>(first.size())));
    daemon.Stop(SIGKILL);
  }
  int64_t kept_checkpoints = 0;
  {
    auto storage = storage::Storage::Open(db);
    ASSERT_TRUE(storage.ok()) << storage.status();
    auto kept = (*storage)->reorder().CheckpointTimes(id);
    ASSERT_TRUE(kept.ok());
    kept_checkpoints = static_cast<int64_t>(kept->size());
  }
  EXPECT_GE(kept_checkpoints, 2) << "no window checkpoint survived the kill";
  {
    Daemon daemon(db, log);
    auto result = StreamFrames(*daemon.Stub(), late);
    ASSERT_TRUE(result.status.ok()) << result.status.error_message();
    ASSERT_EQ(result.acks.size(), late.size());
    for (const auto& ack : result.acks) {
      EXPECT_TRUE(ack.accepted() && !ack.duplicate()) << ack.rejection().reason();
    }
    daemon.Stop(SIGKILL);  // right after the acks: the re-run may not have run yet
  }
  {
    auto storage = storage::Storage::Open(db);
    ASSERT_TRUE(storage.ok()) << storage.status();
    auto pending = (*storage)->reorder().LateFrames(id);
    ASSERT_TRUE(pending.ok());
    std::cout << "late frames still to re-run after the second kill -9: " << pending->size()
              << " of " << late.size() << "\n";
  }
  RunResult cli_current, cli_all;
  {
    Daemon daemon(db, log);
    ASSERT_TRUE(WaitFramesApplied(daemon, id, 200));
    const std::string args = "--server " + daemon.address() + " history --spacecraft " + id;
    cli_current = RunBinary(dir, ESG_BINARY, args + " --csv");
    cli_all = RunBinary(dir, ESG_BINARY, args + " --csv --include-revised");
    daemon.Stop(SIGTERM);
  }

  const std::vector<esg::v1::TelemetryFrame> merged(run.frames.begin(), run.frames.begin() + 200);
  EXPECT_EQ(StoredSessionValues(db, id), OfflineSessionValues(run.config, "10+11", merged));
  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  auto pending = (*storage)->reorder().LateFrames(id);
  ASSERT_TRUE(pending.ok());
  EXPECT_TRUE(pending->empty());
  auto current =
      (*storage)->coefficients().History(id, 0, absl::InfinitePast(), absl::InfiniteFuture());
  auto all = (*storage)->coefficients().History(id, 0, absl::InfinitePast(), absl::InfiniteFuture(),
                                                /*include_revised=*/true);
  ASSERT_TRUE(current.ok() && all.ok());
  ASSERT_NO_FATAL_FAILURE(ExpectDriftCoefficientsEqualOffline(
      *current, OfflineCoefficientHistory(run.config, "10+11", merged)));
  // The re-run started from a kept checkpoint: what came before it is still current.
  absl::Time first_revised = absl::InfiniteFuture();
  for (const auto& r : *all) {
    if (r.revised_time != absl::InfinitePast()) {
      first_revised = std::min(first_revised, r.measurement_time);
    }
  }
  ASSERT_NE(first_revised, absl::InfiniteFuture()) << "nothing was revised";
  const absl::Time start = *proto_convert::TimeFromProto(run.frames.front().time());
  const absl::Time late_time = *proto_convert::TimeFromProto(late.front().time());
  EXPECT_GT(first_revised, start + absl::Hours(1));
  EXPECT_LT(first_revised, late_time);

  // The CLI: a row per current snapshot; with --include-revised a row per stored snapshot and a
  // last column revised_time_utc, filled exactly on the superseded ones.
  ASSERT_EQ(cli_current.exit_code, 0) << cli_current.err;
  ASSERT_EQ(cli_all.exit_code, 0) << cli_all.err;
  const std::vector<std::string> current_rows =
      absl::StrSplit(cli_current.out, '\n', absl::SkipEmpty());
  const std::vector<std::string> all_rows = absl::StrSplit(cli_all.out, '\n', absl::SkipEmpty());
  ASSERT_EQ(current_rows.size(), current->size() + 1);
  ASSERT_EQ(all_rows.size(), all->size() + 1);
  EXPECT_EQ(all_rows[0], current_rows[0] + ",revised_time_utc");
  size_t revised_rows = 0, revised_stored = 0;
  for (size_t k = 1; k < all_rows.size(); ++k) {
    if (all_rows[k].back() != ',') ++revised_rows;
  }
  for (const auto& r : *all) revised_stored += r.revised_time != absl::InfinitePast();
  EXPECT_GT(revised_stored, 0u);
  EXPECT_EQ(revised_rows, revised_stored);
}

}  // namespace
}  // namespace esg::server
