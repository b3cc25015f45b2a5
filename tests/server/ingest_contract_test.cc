// The ingest contract of docs/service.md ("Ingest contract") against a real esgd on loopback:
// what identifies a frame, the outcome of every case (new, exact duplicate, conflict, late,
// unstorable), per-station sequences, and that one bad frame never stops ingest.
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::Session;
using ::esg::testing::LoopbackServer;
using ::esg::testing::OfflineSessionValues;
using ::esg::testing::SimulateRun;
using ::esg::testing::SimulatedRun;
using ::esg::testing::StoredSessionValues;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

const SimulatedRun& Run2h() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("ING-1", 2.0, 23));
  return *run;
}

void Configure(esg::v1::EstimationService::Stub& stub, const estimator::SpacecraftConfig& config,
               const std::string& model = "") {
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub.ConfigureSpacecraft(&ctx, ConfigureRequestFor(config, model), &r).ok());
}

std::vector<storage::ArchivedFrame> Archived(LoopbackServer& server, const std::string& id) {
  auto frames = server.core().storage().archive().ReadTimeRange(id, absl::InfinitePast(),
                                                                absl::InfiniteFuture());
  EXPECT_TRUE(frames.ok()) << frames.status();
  return frames.ok() ? *frames : std::vector<storage::ArchivedFrame>{};
}

TEST(IngestContract, LateFrameNeverSentIsAcceptedWithinTheReorderWindowAndStoredOnce) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run2h();
  Configure(*stub, run.config);
  // Frames 1-5 and 10, then 7 (never sent before; 3 min late, within the 2 h window): the
  // station's sequence 7 is below its highest (10) but was never used, so it is a new frame.
  std::vector<esg::v1::TelemetryFrame> frames(run.frames.begin(), run.frames.begin() + 5);
  frames.push_back(run.frames[9]);
  frames.push_back(run.frames[6]);
  auto result = StreamFrames(*stub, frames);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), 7u);
  for (int i = 0; i < 7; ++i) EXPECT_TRUE(result.acks[i].accepted()) << i;
  const esg::v1::TelemetryAck& late = result.acks[6];
  EXPECT_FALSE(late.duplicate());
  EXPECT_EQ(late.highest_durable_sequence(), 10);
  const std::vector<storage::ArchivedFrame> archived = Archived(server, run.config.spacecraft_id);
  ASSERT_EQ(archived.size(), 7u);
  // The same measurement relayed late by another station: a duplicate, stored once.
  esg::v1::TelemetryFrame other = run.frames[6];
  other.set_station_id("GS-2");
  other.set_sequence(1);
  auto second = StreamFrames(*stub, {other});
  ASSERT_EQ(second.acks.size(), 1u);
  EXPECT_TRUE(second.acks[0].accepted());
  EXPECT_TRUE(second.acks[0].duplicate());
  EXPECT_EQ(Archived(server, run.config.spacecraft_id).size(), 7u);
  // Applied in time order: the filter ends where an offline run over frames 1-5, 7 and 10 does.
  ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(30)).ok());
  std::vector<esg::v1::TelemetryFrame> in_order(run.frames.begin(), run.frames.begin() + 5);
  in_order.push_back(run.frames[6]);
  in_order.push_back(run.frames[9]);
  auto record = server.core().storage().sessions().GetCheckpoint(run.config.spacecraft_id);
  ASSERT_TRUE(record.ok());
  auto checkpoint = DecodeCheckpoint(record->state_blob);
  ASSERT_TRUE(checkpoint.ok() && checkpoint->session.has_value());
  const std::vector<double> offline = OfflineSessionValues(run.config, "10+11", in_order);
  EXPECT_EQ(checkpoint->frames_applied, 7);
  EXPECT_EQ(checkpoint->session->values, offline);
}

TEST(IngestContract, ExactDuplicateIsAcknowledgedAsDuplicateAndStoredOnce) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run2h();
  Configure(*stub, run.config);
  // Frame 3 twice in the same stream (the original may still be committing), then again after
  // it is durable, with the station named explicitly ("default" is what an empty one means).
  std::vector<esg::v1::TelemetryFrame> frames(run.frames.begin(), run.frames.begin() + 5);
  frames.push_back(run.frames[2]);
  auto result = StreamFrames(*stub, frames);
  ASSERT_EQ(result.acks.size(), 6u);
  EXPECT_TRUE(result.acks[5].accepted());
  EXPECT_TRUE(result.acks[5].duplicate());
  EXPECT_GE(result.acks[5].highest_durable_sequence(), 3);
  esg::v1::TelemetryFrame again = run.frames[2];
  again.set_station_id("default");
  auto later = StreamFrames(*stub, {again});
  ASSERT_EQ(later.acks.size(), 1u);
  EXPECT_TRUE(later.acks[0].accepted());
  EXPECT_TRUE(later.acks[0].duplicate());
  EXPECT_EQ(later.acks[0].station_id(), "default");
  EXPECT_EQ(Archived(server, run.config.spacecraft_id).size(), 5u);
  EXPECT_EQ(Session(*stub, run.config.spacecraft_id).frames_duplicate(), 2);
}

TEST(IngestContract, SameIdentityWithOtherContentIsRefusedAlreadyExistsAndAlerted) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run2h();
  Configure(*stub, run.config);
  std::vector<esg::v1::TelemetryFrame> frames(run.frames.begin(), run.frames.begin() + 5);
  ASSERT_EQ(StreamFrames(*stub, frames).acks.size(), 5u);
  const std::string stored_before = Archived(server, run.config.spacecraft_id)[2].payload;
  // Sequence 3 again with another reading; then the time of frame 4 under a new sequence with
  // other content.
  esg::v1::TelemetryFrame reused = run.frames[2];
  reused.mutable_gyros(0)->set_h_k(0, reused.gyros(0).h_k(0) + 1e-5);
  esg::v1::TelemetryFrame same_time = run.frames[3];
  same_time.set_sequence(50);
  same_time.mutable_star_tracker()->set_valid(false);
  auto result = StreamFrames(*stub, {reused, same_time, run.frames[5]});
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), 3u);
  for (int i : {0, 1}) {
    SCOPED_TRACE(i);
    EXPECT_FALSE(result.acks[i].accepted());
    EXPECT_FALSE(result.acks[i].duplicate());
    EXPECT_EQ(result.acks[i].rejection().code(), grpc::StatusCode::ALREADY_EXISTS);
    // The message names both frames.
    EXPECT_THAT(result.acks[i].rejection().reason(), HasSubstr("conflicts with the stored frame"));
  }
  EXPECT_EQ(result.acks[0].rejection().field(), "sequence");
  EXPECT_THAT(result.acks[0].rejection().reason(), HasSubstr("sequence 3"));
  EXPECT_EQ(result.acks[1].rejection().field(), "time");
  EXPECT_THAT(result.acks[1].rejection().reason(), HasSubstr("sequence 50"));
  EXPECT_THAT(result.acks[1].rejection().reason(), HasSubstr("sequence 4"));
  EXPECT_TRUE(result.acks[2].accepted());  // the stream goes on
  // The stored frame is untouched; the conflicts are counted and alerted.
  EXPECT_EQ(Archived(server, run.config.spacecraft_id)[2].payload, stored_before);
  EXPECT_EQ(Session(*stub, run.config.spacecraft_id).frames_conflicting(), 2);
  ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(30)).ok());
  auto alerts = server.core().storage().alerts().Since(run.config.spacecraft_id,
                                                       absl::InfinitePast(), 100);
  ASSERT_TRUE(alerts.ok());
  int conflicts = 0;
  for (const storage::AlertRecord& a : *alerts) {
    if (a.reason == "INGEST_CONFLICT") conflicts += static_cast<int>(a.repeat_count);
  }
  EXPECT_EQ(conflicts, 2);
}

TEST(IngestContract, EachStationCountsItsOwnSequencesAndTheSameMeasurementIsStoredOnce) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun& run = Run2h();
  Configure(*stub, run.config);
  // Station A (the default) sends frames 1-10; station GS-B relays frames 8-20 of the same pass
  // under its own sequences 1-13: its 8-10 are the same measurements (stored once), the rest new.
  std::vector<esg::v1::TelemetryFrame> a(run.frames.begin(), run.frames.begin() + 10);
  ASSERT_EQ(StreamFrames(*stub, a).acks.size(), 10u);
  std::vector<esg::v1::TelemetryFrame> b;
  for (int i = 7; i < 20; ++i) {
    b.push_back(run.frames[i]);
    b.back().set_station_id("GS-B");
    b.back().set_sequence(i - 6);
  }
  auto result = StreamFrames(*stub, b);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), 13u);
  for (int i = 0; i < 13; ++i) {
    SCOPED_TRACE(i);
    EXPECT_TRUE(result.acks[i].accepted());
    EXPECT_EQ(result.acks[i].duplicate(), i < 3);
    EXPECT_EQ(result.acks[i].station_id(), "GS-B");
  }
  EXPECT_EQ(result.acks.back().highest_durable_sequence(), 13);
  const std::vector<storage::ArchivedFrame> archived = Archived(server, run.config.spacecraft_id);
  ASSERT_EQ(archived.size(), 20u);
  for (size_t i = 0; i < archived.size(); ++i) {
    EXPECT_EQ(archived[i].station_id, i < 10 ? "default" : "GS-B");
  }
  const esg::v1::SessionInfo info = Session(*stub, run.config.spacecraft_id);
  ASSERT_EQ(info.stations_size(), 2);
  EXPECT_EQ(info.stations(0).station_id(), "GS-B");
  EXPECT_EQ(info.stations(0).highest_durable_sequence(), 13);
  EXPECT_EQ(info.stations(1).station_id(), "default");
  EXPECT_EQ(info.stations(1).highest_durable_sequence(), 10);
  // The filter applied the 20 measurements in time order, as one stream would.
  ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(30)).ok());
  EXPECT_EQ(Session(*stub, run.config.spacecraft_id).frames_applied(), 20);
}

TEST(IngestContract, AFrameStorageCannotHoldIsRefusedAtOnceAndIngestGoesOn) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  const SimulatedRun& run = Run2h();
  SimulatedRun other = SimulateRun("ING-2", 0.5, 5);
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    Configure(*stub, run.config);
    Configure(*stub, other.config);
    esg::v1::TelemetryFrame y2300 = run.frames[1];
    y2300.mutable_time()->set_seconds(10413792000);  // 2300-01-01
    esg::v1::TelemetryFrame y1600 = run.frames[1];
    y1600.mutable_time()->set_seconds(-11676096000);  // 1600-01-01
    auto result = StreamFrames(*stub, {run.frames[0], y2300, y1600, run.frames[1]});
    ASSERT_TRUE(result.status.ok()) << result.status.error_message();
    ASSERT_EQ(result.acks.size(), 4u);
    EXPECT_TRUE(result.acks[0].accepted());
    for (int i : {1, 2}) {
      EXPECT_FALSE(result.acks[i].accepted());
      EXPECT_EQ(result.acks[i].rejection().code(), grpc::StatusCode::OUT_OF_RANGE);
      EXPECT_EQ(result.acks[i].rejection().field(), "time");
    }
    EXPECT_TRUE(result.acks[3].accepted());
    EXPECT_EQ(result.acks[3].highest_durable_sequence(), 2);
    // Other spacecraft still get acknowledgements.
    auto others = StreamFrames(*stub, other.frames);
    ASSERT_TRUE(others.status.ok());
    ASSERT_EQ(others.acks.size(), other.frames.size());
    EXPECT_TRUE(others.acks.back().accepted());
    // Shutdown (the LoopbackServer's destructor) returns: nothing is retried for ever.
  }
  LoopbackServer restarted({}, db);
  EXPECT_EQ(Session(*restarted.Stub(), run.config.spacecraft_id).frames_accepted(), 2);
}

TEST(IngestContract, ReconfigurationReappliesTheArchiveUnderTheNewModel) {
  TempDir dir;
  const std::string db = dir.File("esg.db");
  const SimulatedRun& run = Run2h();
  absl::Time reconfigured;
  {
    LoopbackServer server({}, db);
    auto stub = server.Stub();
    Configure(*stub, run.config, "10+11");
    ASSERT_EQ(StreamFrames(*stub, run.frames).acks.size(), run.frames.size());
    ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(60)).ok());
    reconfigured = absl::Now();
    auto changed = ConfigureRequestFor(run.config, "1+11");
    changed.set_replace(true);
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, changed, &r).ok());
    ASSERT_TRUE(server.core().WaitApplied(run.config.spacecraft_id, absl::Seconds(60)).ok());
  }
  // The state equals an offline run of the new model over the archive, bit for bit.
  const std::vector<double> stored = StoredSessionValues(db, run.config.spacecraft_id);
  EXPECT_EQ(stored, OfflineSessionValues(run.config, "1+11", run.frames));
  EXPECT_NE(stored, OfflineSessionValues(run.config, "10+11", run.frames));

  // The current coefficient history is the new session's alone (one snapshot per step and gyro,
  // model 1); the old session's is kept, every snapshot of it revised, and only those.
  auto storage = storage::Storage::Open(db);
  ASSERT_TRUE(storage.ok()) << storage.status();
  const std::string& id = run.config.spacecraft_id;
  auto current =
      (*storage)->coefficients().History(id, 0, absl::InfinitePast(), absl::InfiniteFuture());
  auto all = (*storage)->coefficients().History(id, 0, absl::InfinitePast(), absl::InfiniteFuture(),
                                                /*include_revised=*/true);
  ASSERT_TRUE(current.ok() && all.ok());
  const size_t steps =
      ::esg::testing::OfflineCoefficientHistory(run.config, "1+11", run.frames).size();
  ASSERT_GT(steps, 0u);
  EXPECT_EQ(current->size(), steps);
  EXPECT_EQ(all->size(), 2 * steps);  // the same steps under both models
  size_t revised = 0;
  for (const auto& r : *all) {
    if (r.revised_time == absl::InfinitePast()) {
      EXPECT_EQ(r.model_name, "model1+11");
    } else {
      ++revised;
      EXPECT_EQ(r.model_name, "model10+11");
    }
  }
  EXPECT_EQ(revised, steps);
  // No alert the old session's filter raised is current any more: a current one was raised by
  // the new session, a revised one was raised before and revised by the reconfiguration.
  auto alerts = (*storage)->alerts().Since(id, absl::InfinitePast(), 10000, true);
  ASSERT_TRUE(alerts.ok());
  for (const auto& a : *alerts) {
    if (a.revised_time == absl::InfinitePast()) {
      EXPECT_GE(a.compute_time, reconfigured) << a.sequence << " " << a.reason;
    } else {
      EXPECT_LT(a.compute_time, reconfigured) << a.sequence << " " << a.reason;
      EXPECT_GE(a.revised_time, reconfigured) << a.sequence << " " << a.reason;
    }
  }
}

}  // namespace
}  // namespace esg::server
