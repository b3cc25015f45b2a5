// Tests of proto_mapping.h SessionInfoToProto: GetSession's message from a SessionSummary, as a
// pure function (no server, no threads, no SQLite).
#include <string>

#include "gtest/gtest.h"
#include "server/proto_mapping.h"
#include "server/session_summary.h"
#include "tests/server/server_test_util.h"

namespace esg::server {
namespace {

// A session of the paper configuration that has taken `hours` of simulated frames.
estimator::EstimationSession SessionAfter(double hours) {
  const testing::SimulatedRun run = testing::SimulateRun("SC-1", hours);
  auto spec = estimator::ParseModel("10");
  EXPECT_TRUE(spec.ok()) << spec.status();
  auto session = estimator::EstimationSession::Create(run.config, estimator::SessionOptions{*spec});
  EXPECT_TRUE(session.ok()) << session.status();
  for (const esg::v1::TelemetryFrame& proto : run.frames) {
    auto frame = proto_convert::FrameFromProto(proto);
    EXPECT_TRUE(frame.ok()) << frame.status();
    EXPECT_TRUE(session->AddFrame(*frame).ok());
  }
  return *std::move(session);
}

TEST(SessionSummary, ACountedSummaryWithoutASessionMapsFieldForField) {
  SessionSummary s;
  s.spacecraft_id = "SC-1";
  s.served_by = "node-b";
  s.frames_rejected = 3;
  s.frames_duplicate = 4;
  s.frames_conflicting = 5;
  s.frames_accepted = 60;
  s.frames_applied = 58;
  s.frames_apply_failed = 1;
  s.star_tracker_rejections = 2;
  s.highest_applied_sequence = 57;
  s.last_frame_time = absl::FromUnixSeconds(1'700'000'000);
  s.highest_durable = {{"goldstone", 12}, {storage::kDefaultStation, 40}, {"canberra", 9}};
  s.alerts = storage::AlertCounts{7, 2};
  const esg::v1::SessionInfo info = SessionInfoToProto(s);
  EXPECT_EQ(info.spacecraft_id(), "SC-1");
  EXPECT_EQ(info.served_by(), "node-b");
  EXPECT_EQ(info.frames_rejected(), 3);
  EXPECT_EQ(info.frames_duplicate(), 4);
  EXPECT_EQ(info.frames_conflicting(), 5);
  EXPECT_EQ(info.frames_accepted(), 60);
  EXPECT_EQ(info.frames_applied(), 58);
  EXPECT_EQ(info.frames_apply_failed(), 1);
  EXPECT_EQ(info.star_tracker_rejections(), 2);
  EXPECT_EQ(info.highest_applied_sequence(), 57);
  EXPECT_EQ(info.last_frame_time().seconds(), 1'700'000'000);
  // The single-station fields are the default station's; every station is listed, by name.
  EXPECT_EQ(info.highest_durable_sequence(), 40);
  EXPECT_EQ(info.last_sequence(), 40);
  ASSERT_EQ(info.stations_size(), 3);
  EXPECT_EQ(info.stations(0).station_id(), "canberra");
  EXPECT_EQ(info.stations(0).highest_durable_sequence(), 9);
  EXPECT_EQ(info.stations(2).station_id(), "goldstone");
  EXPECT_EQ(info.active_alerts(), 7);
  EXPECT_EQ(info.unacknowledged_alerts(), 2);
  // Nothing configured, no session, never computed: those parts are absent.
  EXPECT_TRUE(info.model().empty());
  EXPECT_FALSE(info.has_config());
  EXPECT_EQ(info.reserve_pair_size(), 0);
  EXPECT_FALSE(info.has_last_compute_time());
  EXPECT_EQ(info.state(), esg::v1::SESSION_STATE_UNSPECIFIED);
  EXPECT_FALSE(info.has_latest_attitude());
  EXPECT_FALSE(info.has_star_tracker_latency());
}

TEST(SessionSummary, WithoutTheDefaultStationItsSequencesAreZero) {
  SessionSummary s;
  s.highest_durable = {{"goldstone", 12}};
  const esg::v1::SessionInfo info = SessionInfoToProto(s);
  EXPECT_EQ(info.highest_durable_sequence(), 0);
  EXPECT_EQ(info.last_sequence(), 0);
  ASSERT_EQ(info.stations_size(), 1);
  EXPECT_EQ(info.stations(0).highest_durable_sequence(), 12);
}

TEST(SessionSummary, ARunningSessionGivesItsStateAttitudeAndLatencyAndAQuarantineOverridesState) {
  SessionSummary s;
  s.spacecraft_id = "SC-1";
  s.configured = SessionSummary::Configured{"model10", esg::v1::SpacecraftConfig(), {1, 3}};
  s.configured->config.set_spacecraft_id("SC-1");
  s.session = SessionAfter(2.0);
  ASSERT_TRUE(s.session->initialized());
  esg::v1::SessionInfo info = SessionInfoToProto(s);
  EXPECT_EQ(info.model(), "model10");
  EXPECT_EQ(info.config().spacecraft_id(), "SC-1");
  ASSERT_EQ(info.reserve_pair_size(), 2);
  EXPECT_EQ(info.reserve_pair(1), 3);
  EXPECT_EQ(info.state(), StateToProto(s.session->state()));
  EXPECT_NE(info.state(), esg::v1::SESSION_STATE_QUARANTINED);
  ASSERT_EQ(info.working_pair_size(), 2);
  EXPECT_EQ(info.working_pair(0), s.session->working_pair()[0]);
  ASSERT_TRUE(info.has_latest_attitude());
  // Canonical sign (q0 >= 0) and a 1-sigma per body axis.
  EXPECT_GE(info.latest_attitude().q_in_b(0), 0.0);
  EXPECT_EQ(info.latest_attitude().sigma_arcsec_size(), 3);
  EXPECT_TRUE(info.has_star_tracker_latency());

  s.quarantine_reason = "archived frame 12 unreadable";
  info = SessionInfoToProto(s);
  EXPECT_EQ(info.state(), esg::v1::SESSION_STATE_QUARANTINED);
  EXPECT_EQ(info.quarantine_reason(), "archived frame 12 unreadable");
  // The rest of the session is still reported.
  EXPECT_TRUE(info.has_latest_attitude());
}

}  // namespace
}  // namespace esg::server
