// Tests of server/alert_collapse.h: alert collapsing as a pure function of the occurrences (no
// server, no threads, no SQLite): repeats within the window, clearing by each reason's rule, the
// catalog's severity and subsystem form.
#include "server/alert_collapse.h"

#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace esg::server {
namespace {

AlertOccurrence Occurrence(const std::string& reason, const std::string& subsystem, absl::Time t) {
  return {reason, "INFO", subsystem, t, 1.0, 0.5, "arcsec", "test"};
}

TEST(AlertCollapse, EachReasonIsClearedByItsRule) {
  const absl::Time t0 = absl::FromUnixSeconds(1'700'000'000);
  const absl::Duration window = absl::Minutes(30);
  // Stored tracks (sequences 1..4) of a quiet, a star-tracker, a never and a quarantine reason.
  std::vector<AlertTrack> tracks = {
      {"GYRO_DATA_REJECTED", "gyro_pair[1,2]", 1, 1, t0},
      {"STAR_TRACKER_FAULT", "star_tracker", 2, 1, t0},
      {"WORKING_PAIR_FAULT", "gyro_3", 3, 1, t0},
      {"SESSION_QUARANTINED", "session", 4, 1, t0},
  };
  AlertCollapser c("SC", tracks, window, t0);
  c.Advance(t0 + absl::Hours(5));  // only the quiet one ends, at its occurrence + the window
  ASSERT_EQ(c.clears().size(), 1u);
  EXPECT_EQ(c.clears()[0].sequence, 1);
  EXPECT_EQ(c.clears()[0].time, t0 + window);
  c.StarTrackerAccepted(t0 + absl::Hours(6));
  ASSERT_EQ(c.clears().size(), 2u);
  EXPECT_EQ(c.clears()[1].sequence, 2);
  EXPECT_EQ(c.clears()[1].time, t0 + absl::Hours(6));
  c.End("SESSION_QUARANTINED", "session", t0 + absl::Hours(7));
  ASSERT_EQ(c.clears().size(), 3u);
  EXPECT_EQ(c.clears()[2].sequence, 4);
  // The pair fault stays live whatever happens.
  ASSERT_EQ(c.Tracks({}).size(), 1u);
  EXPECT_EQ(c.Tracks({})[0].reason, "WORKING_PAIR_FAULT");
}

TEST(AlertCollapse, SeverityAndSubsystemFormComeFromTheCatalog) {
  const absl::Time t0 = absl::FromUnixSeconds(1'700'000'000);
  AlertCollapser c("SC", {}, absl::Minutes(30), t0);
  c.Add(Occurrence("WORKING_PAIR_FAULT", "gyro 2", t0));
  c.Add(Occurrence("GYRO_DATA_REJECTED", "gyros 1,3", t0));
  c.Add(Occurrence("GYRO_DATA_REJECTED", "gyro_pair[1,3]", t0 + absl::Minutes(1)));  // a repeat
  c.Add(Occurrence("STAR_TRACKER_FAULT", "star_tracker", t0));
  c.StarTrackerAccepted(t0 + absl::Minutes(2));  // created and cleared in one job
  ASSERT_EQ(c.new_alerts().size(), 3u);
  EXPECT_EQ(c.new_alerts()[0].severity, "DISTRESS");  // the output stays on a clean pair (D94)
  EXPECT_EQ(c.new_alerts()[0].subsystem, "gyro_2");
  EXPECT_EQ(c.new_alerts()[1].severity, "WARNING");
  EXPECT_EQ(c.new_alerts()[1].subsystem, "gyro_pair[1,3]");
  EXPECT_EQ(c.new_alerts()[1].repeat_count, 2);
  EXPECT_EQ(c.new_alerts()[2].severity, "DISTRESS");
  EXPECT_TRUE(c.new_alerts()[2].cleared);
  EXPECT_EQ(c.new_alerts()[2].cleared_time, t0 + absl::Minutes(2));
  EXPECT_FALSE(c.new_alerts()[0].cleared);
}

TEST(AlertCollapse, RepeatsWithinTheWindowCollapseIntoTheStoredAlertAndLaterOnesStartANewOne) {
  const absl::Time t0 = absl::FromUnixSeconds(1'700'000'000);
  const absl::Duration window = absl::Minutes(30);
  // A stored, live track (sequence 7) of a quiet reason, last seen at t0.
  AlertCollapser c("SC", {{"GYRO_DATA_REJECTED", "gyro_pair[1,2]", 7, 1, t0}}, window, t0);
  for (int k = 1; k <= 3; ++k) {
    const absl::Time t = t0 + absl::Minutes(10 * k);
    c.Advance(t);
    c.Add(Occurrence("GYRO_DATA_REJECTED", "gyro_pair[1,2]", t));
  }
  EXPECT_TRUE(c.new_alerts().empty());
  ASSERT_EQ(c.repeats().count(7), 1u);
  EXPECT_EQ(c.repeats().at(7).repeat_count, 4);
  EXPECT_EQ(c.repeats().at(7).last_time, t0 + absl::Minutes(30));
  // Quiet for longer than the window: cleared at its last occurrence + the window; the next
  // occurrence is a new alert.
  const absl::Time later = t0 + absl::Minutes(30) + window + absl::Minutes(1);
  c.Advance(later);
  c.Add(Occurrence("GYRO_DATA_REJECTED", "gyro_pair[1,2]", later));
  ASSERT_EQ(c.clears().size(), 1u);
  EXPECT_EQ(c.clears()[0].sequence, 7);
  EXPECT_EQ(c.clears()[0].time, t0 + absl::Minutes(30) + window);
  ASSERT_EQ(c.new_alerts().size(), 1u);
  EXPECT_EQ(c.new_alerts()[0].first_time, later);
  EXPECT_EQ(c.new_alerts()[0].spacecraft_id, "SC");
  // The live track after the job carries the sequence the store assigns.
  const std::vector<AlertTrack> tracks = c.Tracks({8});
  ASSERT_EQ(tracks.size(), 1u);
  EXPECT_EQ(tracks[0].sequence, 8);
}

}  // namespace
}  // namespace esg::server
