// Several ground stations and the reorder window (docs/service.md "Several ground stations",
// docs/decisions.md D60-D62) against a real esgd on loopback over a real SQLite file: overlapping
// passes relayed by two stations are stored once, a conflict is refused, a late frame within the
// window is accepted and re-runs the filter from a window checkpoint (the history after it
// revised, ending equal to an offline run over the merged recording in time order), a frame
// beyond the window is refused naming it, window checkpoints stay bounded, and a restarted
// server re-runs from the checkpoints it kept.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/server/reorder_test_util.h"
#include "tests/server/server_test_util.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::InTimeOrder;
using ::esg::testing::LoopbackServer;
using ::esg::testing::OfflineCoefficientHistory;
using ::esg::testing::OfflineSessionValues;
using ::esg::testing::OfflineSnapshot;
using ::esg::testing::Session;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StationPass;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

// 4 h of 60 s frames.
const SimulatedRun& Run4h() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("REO-1", 4.0, 31));
  return *run;
}

void Configure(esg::v1::EstimationService::Stub& stub, const SimulatedRun& run) {
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub.ConfigureSpacecraft(&ctx, ConfigureRequestFor(run.config), &r).ok());
}

void ExpectAllStored(const esg::testing::StreamResult& result, size_t n) {
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), n);
  for (const esg::v1::TelemetryAck& ack : result.acks) {
    EXPECT_TRUE(ack.accepted()) << ack.rejection().reason();
  }
}

std::vector<storage::CoefficientRecord> History(LoopbackServer& server, const std::string& id,
                                                bool include_revised) {
  auto h = server.core().storage().coefficients().History(id, 0, absl::InfinitePast(),
                                                          absl::InfiniteFuture(), include_revised);
  EXPECT_TRUE(h.ok()) << h.status();
  return h.ok() ? *h : std::vector<storage::CoefficientRecord>{};
}

std::vector<double> StoredValues(LoopbackServer& server, const std::string& id) {
  auto record = server.core().storage().sessions().GetCheckpoint(id);
  EXPECT_TRUE(record.ok()) << record.status();
  if (!record.ok()) return {};
  auto checkpoint = DecodeCheckpoint(record->state_blob);
  EXPECT_TRUE(checkpoint.ok()) << checkpoint.status();
  if (!checkpoint.ok() || !checkpoint->session.has_value()) return {};
  return checkpoint->session->values;
}

// The current history equals the offline run's, estimate by estimate: the drift coefficients
// to 1e-12 deg/h, the misalignment to 1e-9 arcsec.
void ExpectHistoryEqualsOffline(const std::vector<storage::CoefficientRecord>& current,
                                const std::vector<OfflineSnapshot>& offline) {
  ASSERT_EQ(current.size(), offline.size());
  for (size_t k = 0; k < current.size(); ++k) {
    ASSERT_EQ(current[k].measurement_time, offline[k].time) << k;
    ASSERT_EQ(current[k].gyro_id, offline[k].gyro_id) << k;
    EXPECT_EQ(current[k].revised_time, absl::InfinitePast()) << k;
    for (int i = 0; i < storage::kNumCoefficientValues; ++i) {
      const double a = current[k].values[i];
      const double b = offline[k].values[i];
      if (std::isnan(a) || std::isnan(b)) {
        EXPECT_EQ(std::isnan(a), std::isnan(b)) << k << " " << i;
        continue;
      }
      const double tolerance = i < storage::kCoefficientMisalignment
                                   ? estimator::DegPerHourToRadPerSec(1e-12)
                                   : estimator::ArcsecToRad(1e-9);
      EXPECT_NEAR(a, b, tolerance) << "estimate " << k << " value " << i;
    }
  }
}

TEST(ReorderWindow, OverlappingPassesOfTwoStationsAreStoredOnceAndAConflictIsRefused) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run4h();
  const std::string id = run.config.spacecraft_id;
  Configure(*stub, run);
  // GS-1 relays minutes 0-79, GS-2 minutes 60-119, at the same time: 20 measurements twice.
  const auto a = StationPass(run, 0, 80, "GS-1", 1);
  const auto b = StationPass(run, 60, 120, "GS-2", 1);
  esg::testing::StreamResult ra, rb;
  std::thread ta([&] { ra = StreamFrames(*stub, a); });
  std::thread tb([&] { rb = StreamFrames(*stub, b); });
  ta.join();
  tb.join();
  ExpectAllStored(ra, a.size());
  ExpectAllStored(rb, b.size());
  int duplicates = 0;
  for (const auto* r : {&ra, &rb}) {
    for (const auto& ack : r->acks) duplicates += ack.duplicate() ? 1 : 0;
  }
  EXPECT_EQ(duplicates, 20);
  // A different frame at a stored time, under a new identity of GS-2.
  esg::v1::TelemetryFrame other = run.frames[100];
  other.set_station_id("GS-2");
  other.set_sequence(61);
  other.mutable_gyros(0)->set_h_k(0, other.gyros(0).h_k(0) + 1e-5);
  auto conflict = StreamFrames(*stub, {other});
  ASSERT_EQ(conflict.acks.size(), 1u);
  EXPECT_FALSE(conflict.acks[0].accepted());
  EXPECT_EQ(conflict.acks[0].rejection().code(), grpc::StatusCode::ALREADY_EXISTS);
  EXPECT_EQ(conflict.acks[0].rejection().field(), "time");
  ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(60)).ok());
  auto archived = server.core().storage().archive().ReadTimeRange(id, absl::InfinitePast(),
                                                                  absl::InfiniteFuture());
  ASSERT_TRUE(archived.ok());
  EXPECT_EQ(archived->size(), 120u);
  const esg::v1::SessionInfo info = Session(*stub, id);
  EXPECT_EQ(info.frames_conflicting(), 1);
  auto alerts = server.core().storage().alerts().Since(id, absl::InfinitePast(), 1000);
  ASSERT_TRUE(alerts.ok());
  int conflicts = 0;
  for (const auto& alert : *alerts) conflicts += alert.reason == "INGEST_CONFLICT" ? 1 : 0;
  EXPECT_EQ(conflicts, 1);
  // Whatever order the two streams interleaved in, the filter applied the merged recording in
  // time order (re-running over frames that arrived late).
  const std::vector<esg::v1::TelemetryFrame> merged(run.frames.begin(), run.frames.begin() + 120);
  EXPECT_EQ(StoredValues(server, id), OfflineSessionValues(run.config, "10+11", merged));
  ExpectHistoryEqualsOffline(History(server, id, false),
                             OfflineCoefficientHistory(run.config, "10+11", merged));
}

TEST(ReorderWindow, LateFramesWithinTheWindowReviseTheHistoryAndEndAsTheOfflineRunInTimeOrder) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run4h();
  const std::string id = run.config.spacecraft_id;
  Configure(*stub, run);
  // GS-1 sends minutes 0-199 but misses 150-159; GS-2 relays those 40 min after the last.
  std::vector<esg::v1::TelemetryFrame> first = StationPass(run, 0, 150, "GS-1", 1);
  for (const auto& f : StationPass(run, 160, 200, "GS-1", 151)) first.push_back(f);
  ExpectAllStored(StreamFrames(*stub, first), first.size());
  ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(60)).ok());
  auto kept = server.core().storage().reorder().CheckpointTimes(id);
  ASSERT_TRUE(kept.ok());
  ASSERT_FALSE(kept->empty());
  const size_t history_before = History(server, id, false).size();
  const double revisions_before = server.core().metrics().revisions.Value();
  EXPECT_EQ(revisions_before, 0);

  const auto late = StationPass(run, 150, 160, "GS-2", 1);
  const auto result = StreamFrames(*stub, late);
  ExpectAllStored(result, late.size());
  for (const auto& ack : result.acks) EXPECT_FALSE(ack.duplicate());
  ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(60)).ok());
  EXPECT_GE(server.core().metrics().revisions.Value(), 1);

  // Current history: what an offline run over the merged recording in time order stores.
  const std::vector<esg::v1::TelemetryFrame> merged(run.frames.begin(), run.frames.begin() + 200);
  const std::vector<storage::CoefficientRecord> current = History(server, id, false);
  EXPECT_GT(current.size(), history_before);
  ExpectHistoryEqualsOffline(current, OfflineCoefficientHistory(run.config, "10+11", merged));
  EXPECT_EQ(StoredValues(server, id), OfflineSessionValues(run.config, "10+11", merged));
  // Revised rows are kept: after the window checkpoint the re-run started from (before the late
  // frames), never before it.
  const std::vector<storage::CoefficientRecord> all = History(server, id, true);
  absl::Time first_revised = absl::InfiniteFuture();
  size_t revised = 0;
  for (const auto& r : all) {
    if (r.revised_time == absl::InfinitePast()) continue;
    ++revised;
    first_revised = std::min(first_revised, r.measurement_time);
  }
  EXPECT_EQ(all.size(), current.size() + revised);
  EXPECT_GT(revised, 0u);
  absl::Time late_time;
  ASSERT_TRUE(proto_convert::TimeFromProto(late.front().time()).ok());
  late_time = *proto_convert::TimeFromProto(late.front().time());
  absl::Time start_time = *proto_convert::TimeFromProto(run.frames.front().time());
  EXPECT_LT(first_revised, late_time);
  EXPECT_GT(first_revised, start_time + absl::Hours(1))
      << "the re-run started from the configuration";
  EXPECT_GE(first_revised, late_time - absl::Hours(1) - absl::Minutes(1));
  // The same over gRPC: current snapshots by default, the revised ones on request.
  grpc::ClientContext ctx;
  esg::v1::HistoryRequest request;
  request.set_spacecraft_id(id);
  esg::v1::HistoryResponse page;
  ASSERT_TRUE(stub->GetCoefficientHistory(&ctx, request, &page).ok());
  EXPECT_EQ(static_cast<size_t>(page.snapshots_size()), current.size());
  for (const auto& s : page.snapshots()) EXPECT_FALSE(s.has_revised_time());
  grpc::ClientContext ctx2;
  request.set_include_revised(true);
  ASSERT_TRUE(stub->GetCoefficientHistory(&ctx2, request, &page).ok());
  EXPECT_EQ(static_cast<size_t>(page.snapshots_size()), all.size());
  int with_revised_time = 0;
  for (const auto& s : page.snapshots()) with_revised_time += s.has_revised_time() ? 1 : 0;
  EXPECT_EQ(static_cast<size_t>(with_revised_time), revised);
}

TEST(ReorderWindow, FrameOlderThanTheWindowIsRefusedNamingTheWindow) {
  ServerOptions options;
  options.core.reorder_window = absl::Minutes(30);
  LoopbackServer server(options);
  auto stub = server.Stub();
  const SimulatedRun& run = Run4h();
  const std::string id = run.config.spacecraft_id;
  Configure(*stub, run);
  std::vector<esg::v1::TelemetryFrame> frames = StationPass(run, 0, 50, "GS-1", 1);
  for (const auto& f : StationPass(run, 51, 100, "GS-1", 52)) frames.push_back(f);
  ExpectAllStored(StreamFrames(*stub, frames), frames.size());
  // Minute 50 is 49 min before the last accepted frame (minute 99); minute 80 only 19 min.
  esg::v1::TelemetryFrame too_late = run.frames[50];
  too_late.set_station_id("GS-2");
  too_late.set_sequence(1);
  auto refused = StreamFrames(*stub, {too_late});
  ASSERT_EQ(refused.acks.size(), 1u);
  EXPECT_FALSE(refused.acks[0].accepted());
  EXPECT_EQ(refused.acks[0].rejection().code(), grpc::StatusCode::OUT_OF_RANGE);
  EXPECT_EQ(refused.acks[0].rejection().field(), "time");
  EXPECT_THAT(refused.acks[0].rejection().reason(), HasSubstr("reorder window (30m"));
  EXPECT_THAT(refused.acks[0].rejection().reason(), HasSubstr("--reorder-window"));
  // The station's own gap, sent under its never-used sequence 51 later than 30 min: refused
  // by its time too.
  esg::v1::TelemetryFrame own = run.frames[50];
  own.set_station_id("GS-1");
  own.set_sequence(51);
  auto own_refused = StreamFrames(*stub, {own});
  ASSERT_EQ(own_refused.acks.size(), 1u);
  EXPECT_EQ(own_refused.acks[0].rejection().field(), "time");
  EXPECT_EQ(Session(*stub, id).frames_rejected(), 2);
  auto archived = server.core().storage().archive().ReadTimeRange(id, absl::InfinitePast(),
                                                                  absl::InfiniteFuture());
  ASSERT_TRUE(archived.ok());
  EXPECT_EQ(archived->size(), 99u);
}

TEST(ReorderWindow, WindowCheckpointsAreHourlyAndBoundedByTheWindow) {
  LoopbackServer server;  // window 2 h, checkpoints every hour
  auto stub = server.Stub();
  const SimulatedRun& run = Run4h();
  const std::string id = run.config.spacecraft_id;
  Configure(*stub, run);
  const auto frames = StationPass(run, 0, 240, "GS-1", 1);
  ExpectAllStored(StreamFrames(*stub, frames), frames.size());
  ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(60)).ok());
  auto kept = server.core().storage().reorder().CheckpointTimes(id);
  ASSERT_TRUE(kept.ok());
  // 4 h of data cross 3 or 4 hour boundaries; the window needs the latest checkpoint before
  // (last - 2 h) and those after it: at most 2 h / 1 h + 1.
  ASSERT_GE(kept->size(), 2u);
  EXPECT_LE(kept->size(), 4u);
  const absl::Time last = *proto_convert::TimeFromProto(run.frames.back().time());
  EXPECT_LT(kept->front(), last - absl::Hours(2));
  for (size_t k = 1; k < kept->size(); ++k) {
    // Consecutive checkpoints lie in consecutive hours (each at the last frame of its hour).
    const int64_t h0 = absl::ToInt64Hours((*kept)[k - 1] - absl::UnixEpoch());
    const int64_t h1 = absl::ToInt64Hours((*kept)[k] - absl::UnixEpoch());
    EXPECT_EQ(h1, h0 + 1);
    EXPECT_GT((*kept)[k] + absl::Minutes(1), absl::FromUnixSeconds(h1 * 3600 + 3540));
  }
}

TEST(ReorderWindow, RestartedServerReRunsFromTheWindowCheckpointsItKept) {
  TempDir dir;
  const std::string db = dir.File("var/esg.db");
  const SimulatedRun& run = Run4h();
  const std::string id = run.config.spacecraft_id;
  std::vector<esg::v1::TelemetryFrame> first = StationPass(run, 0, 150, "GS-1", 1);
  for (const auto& f : StationPass(run, 160, 200, "GS-1", 151)) first.push_back(f);
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    Configure(*stub, run);
    ExpectAllStored(StreamFrames(*stub, first), first.size());
    ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(60)).ok());
  }
  LoopbackServer server({}, db);
  auto stub = server.Stub();
  const auto late = StationPass(run, 150, 160, "GS-2", 1);
  ExpectAllStored(StreamFrames(*stub, late), late.size());
  ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(60)).ok());
  EXPECT_GE(server.core().metrics().revisions.Value(), 1);
  const std::vector<esg::v1::TelemetryFrame> merged(run.frames.begin(), run.frames.begin() + 200);
  ExpectHistoryEqualsOffline(History(server, id, false),
                             OfflineCoefficientHistory(run.config, "10+11", merged));
  EXPECT_EQ(StoredValues(server, id), OfflineSessionValues(run.config, "10+11", merged));
  absl::Time first_revised = absl::InfiniteFuture();
  for (const auto& r : History(server, id, true)) {
    if (r.revised_time != absl::InfinitePast())
      first_revised = std::min(first_revised, r.measurement_time);
  }
  const absl::Time start_time = *proto_convert::TimeFromProto(run.frames.front().time());
  EXPECT_NE(first_revised, absl::InfiniteFuture());
  EXPECT_GT(first_revised, start_time + absl::Hours(1))
      << "the re-run started from the configuration";
}

}  // namespace
}  // namespace esg::server

namespace esg::server {
namespace {

// The replay of SubscribeAlerts up to its end marker.
std::vector<esg::v1::Alert> Replay(esg::v1::EstimationService::Stub& stub, const std::string& id,
                                   bool include_revised) {
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(10));
  esg::v1::AlertSubscription request;
  request.set_spacecraft_id(id);
  *request.mutable_since() = proto_convert::TimeToProto(absl::UnixEpoch());
  request.set_replay_marker(true);
  request.set_include_revised(include_revised);
  auto reader = stub.SubscribeAlerts(&ctx, request);
  std::vector<esg::v1::Alert> out;
  esg::v1::Alert a;
  while (reader->Read(&a) && !a.replay_complete()) out.push_back(a);
  ctx.TryCancel();
  return out;
}

TEST(ReorderWindow, CurrentAlertsAfterAReRunAreThoseOfTheFramesSentInTimeOrder) {
  // Star-tracker outliers raise alerts all along; the late frames fall among them.
  const SimulatedRun run = SimulateRun("REO-2", 4.0, 5, /*outlier_probability=*/0.08);
  const std::string id = run.config.spacecraft_id;
  std::vector<esg::v1::TelemetryFrame> first = StationPass(run, 0, 150, "GS-1", 1);
  for (const auto& f : StationPass(run, 160, 200, "GS-1", 151)) first.push_back(f);
  LoopbackServer reordered;
  auto stub = reordered.Stub();
  Configure(*stub, run);
  ExpectAllStored(StreamFrames(*stub, first), first.size());
  ASSERT_TRUE(reordered.core().WaitApplied(id, absl::Seconds(60)).ok());
  ExpectAllStored(StreamFrames(*stub, StationPass(run, 150, 160, "GS-2", 1)), 10);
  ASSERT_TRUE(reordered.core().WaitApplied(id, absl::Seconds(60)).ok());
  // The reference: the same frames, in time order, to a server of its own.
  LoopbackServer in_order;
  auto reference_stub = in_order.Stub();
  Configure(*reference_stub, run);
  ExpectAllStored(StreamFrames(*reference_stub, StationPass(run, 0, 200, "GS-1", 1)), 200);
  ASSERT_TRUE(in_order.core().WaitApplied(id, absl::Seconds(60)).ok());

  const std::vector<esg::v1::Alert> current = Replay(*stub, id, false);
  const std::vector<esg::v1::Alert> reference = Replay(*reference_stub, id, false);
  ASSERT_FALSE(reference.empty()) << "the outliers raised no alert: the test shows nothing";
  auto key = [](const esg::v1::Alert& a) {
    return std::make_tuple(a.reason(), a.subsystem(), a.first_time().seconds(),
                           a.measurement_time().seconds(), a.repeat_count(), a.cleared(),
                           a.cleared_time().seconds());
  };
  std::vector<decltype(key(reference[0]))> got, want;
  for (const auto& a : current) {
    EXPECT_FALSE(a.has_revised_time());
    got.push_back(key(a));
  }
  for (const auto& a : reference) want.push_back(key(a));
  std::sort(got.begin(), got.end());
  std::sort(want.begin(), want.end());
  EXPECT_EQ(got, want);
  // The superseded alerts are kept and replayed on request, marked.
  const std::vector<esg::v1::Alert> all = Replay(*stub, id, true);
  int revised = 0;
  for (const auto& a : all) revised += a.has_revised_time() ? 1 : 0;
  EXPECT_EQ(all.size(), current.size() + revised);
  EXPECT_GT(revised, 0);
}

}  // namespace
}  // namespace esg::server
