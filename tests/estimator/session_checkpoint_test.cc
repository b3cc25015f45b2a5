// The session checkpoint (session_checkpoint.cc, version 6): a session restored from
// ExportCheckpoint at any point continues bit for bit as the uninterrupted one (every field of
// every StepReport, the consistency monitor, the final state and covariance), in each phase that
// carries state beyond the filter's x and P: before initialisation, in a star-tracker outage
// (AUTONOMOUS), in the middle of a star-tracker rejection streak, right after a pair switch, in
// FAULTED, before the star tracker is anchored (docs/decisions.md D19) and with the consistency
// monitor's windows part full. Each test first asserts that the phase was reached at the cut.
// A corrupt or truncated checkpoint is restored or refused with DataLoss, never a crash.
#include <bit>
#include <cmath>
#include <cstdint>
#include <cstdio>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/basis_term.h"
#include "estimator/calibration_model.h"
#include "estimator/consistency_monitor.h"
#include "estimator/session.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/checkpoint_versions.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::PaperFlight;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;
using Channel = ConsistencyMonitor::Channel;

constexpr int kNoStarTrackerFrames = 5;  // the first frames carry no star-tracker sample

// One flight through every phase, 60 s frames: no star tracker in frames 0-4 (NO_DATA), an
// outage at 1.5-2 h (AUTONOMOUS), a burst of 14 cross-boresight outliers of 5 arcmin at 3 h (a
// rejection streak longer than kResetAfterRejections), a 5 arcmin readout jump of gyro 2 at
// 6 h - 30 s (isolated, output moved to [1,3], FAULTED). The consistency monitor tests from
// about 3 h on, every 15 steps.
struct Scenario {
  SimulationSpec spec;
  std::vector<TelemetryFrame> frames;
};

Scenario AllPhases() {
  Scenario s;
  s.spec = PaperFlight(23, 8.0);
  s.spec.star_tracker.outages = {{HoursToSeconds(1.5), HoursToSeconds(2.0)}};
  s.spec.star_tracker.outlier_burst =
      StarTrackerOutlierBurst{HoursToSeconds(3.0), 14, ArcminToRad(5)};
  GyroFault fault;
  fault.time = HoursToSeconds(6.0) - 30.0;
  fault.kind = GyroFault::Kind::kReadoutJump;
  fault.value = Eigen::Vector3d(ArcminToRad(5), 0, 0);
  s.spec.gyros[1].fault = fault;
  auto sim = Simulate(s.spec);
  EXPECT_THAT(sim, IsOk());
  if (sim.ok()) s.frames = sim->recording.frames;
  for (int i = 0; i < kNoStarTrackerFrames && i < static_cast<int>(s.frames.size()); ++i) {
    s.frames[i].star_tracker.reset();
  }
  return s;
}

SessionOptions Options(const char* model = "10+11") {
  SessionOptions o;
  o.model = *ParseModel(model);
  return o;
}

// The number of values of the version-1 part of a checkpoint (session_checkpoint.cc): 23 values
// before convergence_mark_sigma (m at index 22), m, the gyro count g, 30 per gyro (31 from
// version 8 on), n, P and P0. Version 2 appends its fields after these.
size_t Version1Length(const SessionCheckpoint& c) {
  const size_t record = testing::GyroRecordLength(c);
  const size_t m = static_cast<size_t>(c.values.at(22));
  const size_t g = static_cast<size_t>(c.values.at(23 + m));
  const size_t n = static_cast<size_t>(c.values.at(23 + m + 1 + record * g));
  return 23 + m + 1 + record * g + 1 + 2 * n * n;
}

// The same session's checkpoint in version 1: the theta counts of version 8 and the fields of
// versions 2-7 left out.
SessionCheckpoint AsVersion1(SessionCheckpoint c) {
  c = testing::AsVersion7(std::move(c));
  c.values.resize(Version1Length(c));
  c.version = 1;
  return c;
}

// --- Bitwise comparison ---

bool SameBits(double a, double b) {
  return std::bit_cast<uint64_t>(a) == std::bit_cast<uint64_t>(b);
}

bool SameBits(const Eigen::VectorXd& a, const Eigen::VectorXd& b) {
  if (a.size() != b.size()) return false;
  for (int i = 0; i < a.size(); ++i) {
    if (!SameBits(a(i), b(i))) return false;
  }
  return true;
}

bool SameBits(const std::vector<double>& a, const std::vector<double>& b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    if (!SameBits(a[i], b[i])) return false;
  }
  return true;
}

// The first field in which two reports differ (bit for bit), empty when they are identical.
std::string ReportDifference(const StepReport& a, const StepReport& b) {
  if (a.time != b.time) return "time";
  if (a.measurement_step != b.measurement_step) return "measurement_step";
  if (a.star_tracker_used != b.star_tracker_used) return "star_tracker_used";
  if (a.state != b.state) {
    return absl::StrCat("state ", SessionStateName(a.state), " vs ", SessionStateName(b.state));
  }
  if (a.attitude.time != b.attitude.time) return "attitude.time";
  if (!SameBits(Eigen::VectorXd(a.attitude.q_in_b.coeffs()),
                Eigen::VectorXd(b.attitude.q_in_b.coeffs()))) {
    return "attitude.q_in_b";
  }
  if (!SameBits(Eigen::VectorXd(a.attitude.sigma_b), Eigen::VectorXd(b.attitude.sigma_b))) {
    return "attitude.sigma_b";
  }
  if (a.attitude.pair != b.attitude.pair) return "attitude.pair";
  if (a.attitude.valid != b.attitude.valid) return "attitude.valid";
  if (a.events.size() != b.events.size()) {
    auto kinds = [](const std::vector<Event>& events) {
      std::string out;
      for (const Event& e : events)
        absl::StrAppend(&out, " ", EventKindName(e.kind), " (", e.message, ")");
      return out;
    };
    return absl::StrCat("events:", kinds(a.events), " vs", kinds(b.events));
  }
  for (size_t k = 0; k < a.events.size(); ++k) {
    const Event& x = a.events[k];
    const Event& y = b.events[k];
    if (x.kind != y.kind || x.time != y.time || x.subsystem != y.subsystem ||
        !SameBits(x.value, y.value) || !SameBits(x.threshold, y.threshold) || x.unit != y.unit ||
        x.message != y.message) {
      return absl::StrCat("event ", k, ": ", EventKindName(x.kind), " ", x.message, " vs ",
                          EventKindName(y.kind), " ", y.message);
    }
  }
  if (!SameBits(a.star_tracker_innovation, b.star_tracker_innovation))
    return "star_tracker_innovation";
  if (!SameBits(a.star_tracker_innovation_sigma, b.star_tracker_innovation_sigma)) {
    return "star_tracker_innovation_sigma";
  }
  if (!SameBits(a.star_tracker_test_ratio, b.star_tracker_test_ratio))
    return "star_tracker_test_ratio";
  if (!SameBits(a.star_tracker_nis, b.star_tracker_nis)) return "star_tracker_nis";
  if (!SameBits(a.star_tracker_log_det_s, b.star_tracker_log_det_s))
    return "star_tracker_log_det_s";
  if (!SameBits(a.autonomous_innovation, b.autonomous_innovation)) return "autonomous_innovation";
  if (!SameBits(a.autonomous_innovation_sigma, b.autonomous_innovation_sigma)) {
    return "autonomous_innovation_sigma";
  }
  return "";
}

// The first difference between the sessions' observable state (bit for bit), empty if none.
std::string SessionDifference(const EstimationSession& a, const EstimationSession& b) {
  if (a.state() != b.state()) return "state()";
  if (a.working_pair() != b.working_pair()) return "working_pair()";
  const ConsistencyMonitor& ma = a.consistency_monitor();
  const ConsistencyMonitor& mb = b.consistency_monitor();
  if (ma.tests() != mb.tests() || ma.inconsistent_tests() != mb.inconsistent_tests() ||
      ma.first_inconsistent_time() != mb.first_inconsistent_time()) {
    return absl::StrCat("consistency monitor counters: ", ma.tests(), " vs ", mb.tests(), " tests");
  }
  if (!SameBits(ma.ExportState(), mb.ExportState())) return "consistency monitor state";
  const SessionCheckpoint ca = a.ExportCheckpoint();
  const SessionCheckpoint cb = b.ExportCheckpoint();
  if (ca.version != cb.version) return "checkpoint version";
  if (ca.values.size() != cb.values.size()) return "checkpoint length";
  for (size_t i = 0; i < ca.values.size(); ++i) {
    if (!SameBits(ca.values[i], cb.values[i])) {
      return absl::StrFormat("checkpoint value %d: %.17g vs %.17g", i, ca.values[i], cb.values[i]);
    }
  }
  const Eigen::MatrixXd& pa = a.covariance();
  const Eigen::MatrixXd& pb = b.covariance();
  if (pa.rows() != pb.rows() || pa.cols() != pb.cols()) return "covariance size";
  for (int i = 0; i < pa.rows(); ++i) {
    for (int j = 0; j < pa.cols(); ++j) {
      if (!SameBits(pa(i, j), pb(i, j))) return absl::StrCat("covariance (", i, ",", j, ")");
    }
  }
  const std::vector<GyroEstimate> ga = a.Gyros();
  const std::vector<GyroEstimate> gb = b.Gyros();
  if (ga.size() != gb.size()) return "gyro count";
  for (size_t k = 0; k < ga.size(); ++k) {
    if (ga[k].id != gb[k].id || ga[k].faulty != gb[k].faulty ||
        !SameBits(Eigen::VectorXd(ga[k].coefficients.AsVector()),
                  Eigen::VectorXd(gb[k].coefficients.AsVector())) ||
        !SameBits(Eigen::VectorXd(ga[k].h_in), Eigen::VectorXd(gb[k].h_in))) {
      return absl::StrCat("gyro ", ga[k].id, " estimate");
    }
  }
  return "";
}

// A session after frames [0, cut) with its reports.
struct Prefix {
  EstimationSession session;
  std::vector<StepReport> reports;
};

Prefix RunPrefix(const Scenario& s, const SessionOptions& options, size_t cut) {
  Prefix p{*EstimationSession::Create(s.spec.config, options), {}};
  for (size_t i = 0; i < cut; ++i) {
    auto r = p.session.AddFrame(s.frames[i]);
    EXPECT_THAT(r, IsOk()) << "frame " << i;
    if (!r.ok()) break;
    p.reports.push_back(*std::move(r));
  }
  return p;
}

// Continues `at_cut` (after frames [0, cut)) and a session restored from its checkpoint over
// frames [cut, end) and expects every report and the final state to be identical bit for bit.
// Returns the continuation's reports.
std::vector<StepReport> ExpectResumesBitForBit(const Scenario& s, const SessionOptions& options,
                                               size_t cut, const EstimationSession& at_cut) {
  const SessionCheckpoint checkpoint = at_cut.ExportCheckpoint();
  EXPECT_EQ(checkpoint.version, 10);
  auto restored = EstimationSession::FromCheckpoint(s.spec.config, options, checkpoint);
  EXPECT_THAT(restored, IsOk());
  if (!restored.ok()) return {};
  EstimationSession resumed = *std::move(restored);
  EstimationSession straight = at_cut;
  EXPECT_EQ(SessionDifference(straight, resumed), "") << "right after the restore";
  // Exporting the restored session gives the checkpoint back.
  EXPECT_TRUE(SameBits(resumed.ExportCheckpoint().values, checkpoint.values));
  std::vector<StepReport> reports;
  for (size_t i = cut; i < s.frames.size(); ++i) {
    auto a = straight.AddFrame(s.frames[i]);
    auto b = resumed.AddFrame(s.frames[i]);
    EXPECT_EQ(a.status(), b.status()) << "frame " << i;
    if (!a.ok() || !b.ok()) return reports;
    const std::string report_diff = ReportDifference(*a, *b);
    const std::string session_diff = SessionDifference(straight, resumed);
    if (!report_diff.empty() || !session_diff.empty()) {
      ADD_FAILURE() << "frame " << i << " (" << absl::FormatTime(s.frames[i].time)
                    << "), checkpoint after frame " << cut - 1 << ": report differs in ["
                    << report_diff << "], session differs in [" << session_diff << "]";
      return reports;
    }
    reports.push_back(*std::move(a));
  }
  EXPECT_EQ(reports.size(), s.frames.size() - cut);
  return reports;
}

size_t FrameAt(const Scenario& s, double hours) {
  const absl::Time t = s.spec.start + absl::Seconds(HoursToSeconds(hours));
  size_t i = 0;
  while (i < s.frames.size() && s.frames[i].time < t) ++i;
  return i;
}

bool HasEvent(const StepReport& r, Event::Kind kind) {
  for (const Event& e : r.events) {
    if (e.kind == kind) return true;
  }
  return false;
}

int CountEvents(const std::vector<StepReport>& reports, Event::Kind kind) {
  int n = 0;
  for (const StepReport& r : reports) {
    for (const Event& e : r.events) n += e.kind == kind;
  }
  return n;
}

// Star-tracker data present and not applied at a measurement step: the steps the session's
// rejection counter counts (session_update.cc).
bool StarTrackerRejected(const TelemetryFrame& f, const StepReport& r) {
  return r.measurement_step && f.star_tracker.has_value() && f.star_tracker->valid &&
         !r.star_tracker_used;
}

TEST(SessionCheckpoint, BeforeInitialisationResumesBitForBit) {
  const Scenario s = AllPhases();
  ASSERT_GT(s.frames.size(), 400u);
  const size_t cut = 3;
  const Prefix p = RunPrefix(s, Options(), cut);
  ASSERT_FALSE(p.session.initialized());
  ASSERT_EQ(p.session.state(), SessionState::kNoData);
  const auto after = ExpectResumesBitForBit(s, Options(), cut, p.session);
  // The continuation initialises and goes through the outage, the burst and the fault.
  ASSERT_EQ(after.size(), s.frames.size() - cut);
  EXPECT_EQ(after[kNoStarTrackerFrames - cut].state, SessionState::kCalibrating);
  EXPECT_GE(CountEvents(after, Event::Kind::kStarTrackerInnovation) +
                CountEvents(after, Event::Kind::kStarTrackerFault),
            10);
  EXPECT_NE(after.back().state, SessionState::kFaulted);  // degraded (D94)
}

// A free basis term (a case-fixed drift along case y of gyro 1, calibrated) and a held
// suspension-voltage term of gyro 2 whose voltages the frames carry only until the cut (then
// held): the checkpoint (version 6) carries the terms' current values and the held voltages, and
// the restored session continues bit for bit.
TEST(SessionCheckpoint, AFreeBasisTermAndHeldVoltagesResumeBitForBit) {
  Scenario s;
  s.spec = PaperFlight(29, 3.0);
  BasisTerm fixed;
  fixed.kind = BasisKind::kSpinAxisHarmonic;
  fixed.axis = 2;
  fixed.sigma = DegPerHourToRadPerSec(0.1);
  BasisTerm voltage;
  voltage.kind = BasisKind::kSuspensionVoltage;
  voltage.axis = 3;
  voltage.index = {1, 1};
  voltage.value = DegPerHourToRadPerSec(0.05);
  s.spec.config.gyros[0].basis_terms = {fixed};
  s.spec.config.gyros[1].basis_terms = {voltage};
  auto sim = Simulate(s.spec);
  ASSERT_THAT(sim, IsOk());
  s.frames = sim->recording.frames;
  const size_t cut = FrameAt(s, 1.5);
  for (size_t i = cut - 5; i < s.frames.size(); ++i) {
    if (s.frames[i].gyros[1].has_value()) s.frames[i].gyros[1]->u_k_mv.reset();
  }
  const Prefix p = RunPrefix(s, Options(), cut);
  ASSERT_TRUE(p.session.initialized());
  const std::vector<GyroEstimate> g = p.session.Gyros();
  ASSERT_EQ(g[0].basis_terms.size(), 1u);
  ASSERT_GT(g[0].basis_sigma[0], 0.0);
  ASSERT_LT(g[0].basis_sigma[0], fixed.sigma);
  ASSERT_NE(g[0].basis_terms[0].value, 0.0);  // moved by the updates
  const auto after = ExpectResumesBitForBit(s, Options(), cut, p.session);
  EXPECT_EQ(after.size(), s.frames.size() - cut);
  // The checkpoint does not fit a configuration without the free term.
  SpacecraftConfig other = s.spec.config;
  other.gyros[0].basis_terms.clear();
  EXPECT_THAT(EstimationSession::FromCheckpoint(other, Options(), p.session.ExportCheckpoint()),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("checkpoint")));
}

TEST(SessionCheckpoint, MidOutageResumesBitForBit) {
  const Scenario s = AllPhases();
  const size_t cut = FrameAt(s, 1.5) + 10;
  const Prefix p = RunPrefix(s, Options(), cut);
  ASSERT_EQ(p.session.state(), SessionState::kAutonomous);
  ASSERT_FALSE(s.frames[cut - 1].star_tracker.has_value());
  ASSERT_FALSE(s.frames[cut].star_tracker.has_value());  // the outage goes on after the cut
  ASSERT_FALSE(p.reports.back().star_tracker_used);
  const auto after = ExpectResumesBitForBit(s, Options(), cut, p.session);
  ASSERT_FALSE(after.empty());
  EXPECT_EQ(after.front().state, SessionState::kAutonomous);
}

// A star-tracker mount shift of 2 arcmin at 5 h (D34), across the body rate (the calibration
// profile spins about body x from 3 h to 6 h; along it the shift could be a latency and is not
// corrected): checkpoints taken with the mount-shift
// test's window part full, and after the star tracker was re-referenced, resume bit for bit; the
// first continuation re-references it at the same step as the straight run.
TEST(SessionCheckpoint, MidMountShiftWindowAndAfterTheRealignmentResumeBitForBit) {
  Scenario s;
  s.spec = PaperFlight(23, 6.0);
  s.spec.star_tracker.misalignment_jump = StarTrackerMisalignmentJump{
      HoursToSeconds(5.0) - 30.0, ArcminToRad(2.0) * Eigen::Vector3d(0.0, 0.6, 0.8)};
  auto sim = Simulate(s.spec);
  ASSERT_THAT(sim, IsOk());
  s.frames = sim->recording.frames;
  const Prefix straight = RunPrefix(s, Options(), s.frames.size());
  size_t realigned = 0;
  for (size_t i = 0; i < straight.reports.size() && realigned == 0; ++i) {
    for (const Event& e : straight.reports[i].events) {
      if (e.kind == Event::Kind::kStarTrackerRealigned) realigned = i;
    }
  }
  ASSERT_GT(realigned, FrameAt(s, 5.0));
  EXPECT_EQ(straight.session.StarTrackerMountShift().realignments, 1);
  const size_t mid_window = realigned - 4;
  const Prefix p1 = RunPrefix(s, Options(), mid_window);
  ASSERT_EQ(p1.session.StarTrackerMountShift().realignments, 0);
  const auto after1 = ExpectResumesBitForBit(s, Options(), mid_window, p1.session);
  ASSERT_GT(after1.size(), 4u);
  EXPECT_EQ(CountEvents({after1[4]}, Event::Kind::kStarTrackerRealigned), 1);
  const size_t after_realignment = realigned + 3;
  const Prefix p2 = RunPrefix(s, Options(), after_realignment);
  ASSERT_EQ(p2.session.StarTrackerMountShift().realignments, 1);
  ExpectResumesBitForBit(s, Options(), after_realignment, p2.session);
}

// The checkpoint is taken after the 5th of a streak of star-tracker rejections (the burst of 14
// outliers); in the streak eq. (12) named the star tracker, so at the 10th the reset is withheld
// (D19) whether or not the session was restored in between.
TEST(SessionCheckpoint, MidRejectionStreakResumesBitForBit) {
  const Scenario s = AllPhases();
  const Prefix all = RunPrefix(s, Options(), s.frames.size());
  ASSERT_EQ(all.reports.size(), s.frames.size());
  size_t cut = 0;
  int streak = 0;
  bool voted = false;
  for (size_t i = FrameAt(s, 3.0); i < s.frames.size(); ++i) {
    if (!StarTrackerRejected(s.frames[i], all.reports[i])) {
      streak = 0;
      voted = false;
      continue;
    }
    voted |= HasEvent(all.reports[i], Event::Kind::kStarTrackerFault);
    if (++streak == 5) {
      cut = i + 1;
      break;
    }
  }
  ASSERT_GT(cut, 0u) << "no streak of 5 rejected star-tracker steps after 3 h";
  ASSERT_TRUE(voted) << "eq. (12) did not name the star tracker in the streak";
  // The streak goes on after the cut, past kResetAfterRejections.
  for (size_t i = cut; i < cut + kResetAfterRejections - 5; ++i) {
    ASSERT_TRUE(StarTrackerRejected(s.frames[i], all.reports[i])) << "frame " << i;
  }
  const Prefix p = RunPrefix(s, Options(), cut);
  const auto after = ExpectResumesBitForBit(s, Options(), cut, p.session);
  ASSERT_GE(after.size(), static_cast<size_t>(kResetAfterRejections));
  // The 10th rejected step: the reset is withheld because of the vote.
  const StepReport& tenth = after[kResetAfterRejections - 5 - 1];
  bool withheld = false;
  for (const Event& e : tenth.events) {
    withheld |=
        e.kind == Event::Kind::kStarTrackerFault && e.message.find("withheld") != std::string::npos;
  }
  EXPECT_TRUE(withheld);
  EXPECT_FALSE(HasEvent(tenth, Event::Kind::kFilterReset));
}

TEST(SessionCheckpoint, RightAfterAPairSwitchAndLaterDegradedResumesBitForBit) {
  const Scenario s = AllPhases();
  const Prefix all = RunPrefix(s, Options(), s.frames.size());
  ASSERT_EQ(all.reports.size(), s.frames.size());
  size_t switched = 0;
  for (size_t i = 0; i < all.reports.size() && switched == 0; ++i) {
    if (HasEvent(all.reports[i], Event::Kind::kWorkingPairFault)) switched = i;
  }
  ASSERT_GT(switched, 0u) << "no pair switch";
  for (const size_t cut : {switched + 1, switched + 61}) {
    SCOPED_TRACE(::testing::Message() << "checkpoint after frame " << cut - 1);
    ASSERT_LT(cut, s.frames.size());
    const Prefix p = RunPrefix(s, Options(), cut);
    ASSERT_NE(p.session.state(), SessionState::kFaulted);
    ASSERT_TRUE(p.session.degraded());
    ASSERT_EQ(p.session.working_pair(), (std::array<int, 2>{1, 3}));
    for (const GyroEstimate& g : p.session.Gyros())
      ASSERT_EQ(g.faulty, g.id == 2) << "gyro " << g.id;
    const auto after = ExpectResumesBitForBit(s, Options(), cut, p.session);
    ASSERT_FALSE(after.empty());
    EXPECT_NE(after.back().state, SessionState::kFaulted);
    EXPECT_TRUE(after.back().attitude.valid);
  }
}

// Mid-window: the monitor has tested (its windows are full) and the cut is between two tests,
// so the windows hold steps that the next test sums. A restore with empty windows (version 1)
// tests later, or not at all within the flight: the test counts differ.
TEST(SessionCheckpoint, ConsistencyMonitorMidWindowResumesBitForBit) {
  const Scenario s = AllPhases();
  const size_t cut = FrameAt(s, 4.5) + 7;
  const Prefix p = RunPrefix(s, Options(), cut);
  const ConsistencyMonitor& m = p.session.consistency_monitor();
  ASSERT_GT(m.tests(), 0);
  ASSERT_TRUE(m.last(Channel::kStarTracker).has_value());
  ASSERT_LT(m.last(Channel::kStarTracker)->time, s.frames[cut - 1].time);  // between two tests
  const auto after = ExpectResumesBitForBit(s, Options(), cut, p.session);
  ASSERT_FALSE(after.empty());

  // Version 1 (the same values without its tail) restores with empty windows: it diverges.
  auto old = EstimationSession::FromCheckpoint(s.spec.config, Options(),
                                               AsVersion1(p.session.ExportCheckpoint()));
  ASSERT_THAT(old, IsOk());
  EXPECT_EQ(old->consistency_monitor().tests(), 0);
  EstimationSession straight = p.session;
  for (size_t i = cut; i < s.frames.size(); ++i) {
    ASSERT_THAT(straight.AddFrame(s.frames[i]), IsOk());
    ASSERT_THAT(old->AddFrame(s.frames[i]), IsOk());
  }
  EXPECT_GT(straight.consistency_monitor().tests(), old->consistency_monitor().tests());
}

// A model that cannot explain the data (model 10 without the random walk of eq. (11), on data
// with a 0.0015 deg/h/sqrt(h) walk as deploy/examples/rdk1.json configures): the checkpoint is
// taken with the windows part full before the first MODEL_INCONSISTENT event, which the
// restored session raises at the same step with the same numbers.
TEST(SessionCheckpoint, PendingModelInconsistencyIsRaisedAtTheSameStepAfterARestore) {
  Scenario s;
  s.spec = PaperFlight(3, 12.0);
  s.spec.config.random_walk = DegPerHourSqrtHourToSi(0.0015);
  s.spec.gyros[1].misalignment_b.setZero();
  auto sim = Simulate(s.spec);
  ASSERT_THAT(sim, IsOk());
  s.frames = sim->recording.frames;
  const SessionOptions options = Options("10");
  const Prefix all = RunPrefix(s, options, s.frames.size());
  size_t first = 0;
  for (size_t i = 0; i < all.reports.size() && first == 0; ++i) {
    if (HasEvent(all.reports[i], Event::Kind::kModelInconsistent)) first = i;
  }
  ASSERT_GT(first, 0u) << "model 10 was not found inconsistent";
  const size_t cut = first - 7;  // between two tests (every 15 steps), windows part full
  const Prefix p = RunPrefix(s, options, cut);
  ASSERT_EQ(p.session.consistency_monitor().inconsistent_tests(), 0);
  const auto after = ExpectResumesBitForBit(s, options, cut, p.session);
  ASSERT_GT(after.size(), first - cut);
  EXPECT_TRUE(HasEvent(after[first - cut], Event::Kind::kModelInconsistent));
}

// Before the star tracker is anchored (accepted kResetAfterRejections steps in a row since the
// filter started, D19) a streak of rejections re-anchors even if eq. (12) named the star
// tracker: the pairs rest on the initialisation sample. The checkpoint is taken in such a streak
// (outliers from the 3rd sample after initialisation); the restored session resets at the same
// step. Restored from version 1 (which counts the star tracker as anchored) it withholds the
// reset instead: the flags of version 2 are needed.
TEST(SessionCheckpoint, BeforeTheStarTrackerIsAnchoredResumesBitForBit) {
  Scenario s;
  s.spec = PaperFlight(5, 2.0);
  s.spec.star_tracker.outlier_burst =
      StarTrackerOutlierBurst{60.0 * (kNoStarTrackerFrames + 2), 14, ArcminToRad(10)};
  auto sim = Simulate(s.spec);
  ASSERT_THAT(sim, IsOk());
  s.frames = sim->recording.frames;
  for (int i = 0; i < kNoStarTrackerFrames; ++i) s.frames[i].star_tracker.reset();
  const size_t cut = kNoStarTrackerFrames + 2 + 4;  // after the 4th outlier
  const Prefix p = RunPrefix(s, Options(), cut);
  ASSERT_TRUE(p.session.initialized());
  int rejected = 0;
  for (size_t i = kNoStarTrackerFrames + 1; i < cut; ++i) {
    rejected += StarTrackerRejected(s.frames[i], p.reports[i]);
  }
  ASSERT_EQ(rejected, 4);
  const auto after = ExpectResumesBitForBit(s, Options(), cut, p.session);
  ASSERT_FALSE(after.empty());
  EXPECT_GE(CountEvents(after, Event::Kind::kFilterReset), 1);

  auto old = EstimationSession::FromCheckpoint(s.spec.config, Options(),
                                               AsVersion1(p.session.ExportCheckpoint()));
  ASSERT_THAT(old, IsOk());
  int old_resets = 0;
  for (size_t i = cut; i < s.frames.size(); ++i) {
    auto r = old->AddFrame(s.frames[i]);
    ASSERT_THAT(r, IsOk());
    old_resets += HasEvent(*r, Event::Kind::kFilterReset);
  }
  EXPECT_EQ(old_resets, 0);
}

// Checkpoint, restore and continue at every frame of the whole flight (a chain of restores):
// identical to the uninterrupted run, and the flight visits every phase.
TEST(SessionCheckpoint, RestoredAtEveryFrameEqualsTheUninterruptedRun) {
  const Scenario s = AllPhases();
  EstimationSession straight = *EstimationSession::Create(s.spec.config, Options());
  std::optional<EstimationSession> chained = straight;
  std::vector<int> state_steps(5, 0);
  std::vector<StepReport> reports;
  for (size_t i = 0; i < s.frames.size(); ++i) {
    auto restored =
        EstimationSession::FromCheckpoint(s.spec.config, Options(), chained->ExportCheckpoint());
    ASSERT_THAT(restored, IsOk()) << "frame " << i;
    chained = *std::move(restored);
    auto a = straight.AddFrame(s.frames[i]);
    auto b = chained->AddFrame(s.frames[i]);
    ASSERT_THAT(a, IsOk());
    ASSERT_THAT(b, IsOk());
    const std::string diff = ReportDifference(*a, *b);
    ASSERT_EQ(diff, "") << "frame " << i;
    ++state_steps[static_cast<int>(a->state)];
    reports.push_back(*std::move(a));
  }
  EXPECT_EQ(SessionDifference(straight, *chained), "");
  EXPECT_GT(state_steps[static_cast<int>(SessionState::kNoData)], 0);
  EXPECT_GT(state_steps[static_cast<int>(SessionState::kCalibrating)], 0);
  EXPECT_GT(state_steps[static_cast<int>(SessionState::kAutonomous)], 0);
  EXPECT_EQ(state_steps[static_cast<int>(SessionState::kFaulted)], 0);  // degraded (D94)
  EXPECT_EQ(CountEvents(reports, Event::Kind::kWorkingPairFault), 1);
  EXPECT_GT(straight.consistency_monitor().tests(), 0);
}

// Every single value of a version-2 checkpoint (FAULTED, monitor tested) replaced by a value its
// field may not hold, and every truncation: restored, or refused with DataLoss naming the
// checkpoint; never a crash. A corrupt checkpoint that is restored (a real field changed to a
// finite value) runs on (one frame, any status) without a crash.
TEST(SessionCheckpoint, EveryCorruptedOrTruncatedValueIsRestoredOrDataLoss) {
  const Scenario s = AllPhases();
  const size_t cut = FrameAt(s, 6.5);
  const Prefix p = RunPrefix(s, Options(), cut);
  ASSERT_TRUE(p.session.degraded());
  ASSERT_GT(p.session.consistency_monitor().tests(), 0);
  const SessionCheckpoint good = p.session.ExportCheckpoint();
  ASSERT_EQ(good.version, 10);
  const int n = p.session.state_size();
  // The covariance blocks P and P0 (n x n each) end where the version-2 fields begin.
  const size_t matrices_end = Version1Length(good);
  const size_t matrices_begin = matrices_end - 2 * static_cast<size_t>(n) * n;
  const double bad_values[] = {
      std::nan(""), std::numeric_limits<double>::infinity(), 1e300, -1e300, 0.5, -1.0,
      2147483648.0};
  int restored = 0, refused = 0, ran_on = 0;
  auto check = [&](const SessionCheckpoint& c, const std::string& what, bool run_on) {
    auto r = EstimationSession::FromCheckpoint(s.spec.config, Options(), c);
    if (!r.ok()) {
      EXPECT_THAT(r.status(), StatusIs(absl::StatusCode::kDataLoss, HasSubstr("checkpoint")))
          << what;
      ++refused;
      return;
    }
    ++restored;
    if (run_on) {
      (void)r->AddFrame(s.frames[cut]);  // any status: it must only not crash
      ++ran_on;
    }
  };
  for (size_t i = 0; i < good.values.size(); ++i) {
    // Running on is slow with 42-state covariances: every value outside P and P0, every 97th in.
    const bool run_on = i < matrices_begin || i >= matrices_end || (i - matrices_begin) % 97 == 0;
    for (double bad : bad_values) {
      SessionCheckpoint c = good;
      c.values[i] = bad;
      check(c, absl::StrFormat("value %d = %g", i, bad), run_on);
    }
  }
  for (size_t length = 0; length < good.values.size(); ++length) {
    SessionCheckpoint c = good;
    c.values.resize(length);
    auto r = EstimationSession::FromCheckpoint(s.spec.config, Options(), c);
    EXPECT_THAT(r.status(), StatusIs(absl::StatusCode::kDataLoss, HasSubstr("checkpoint")))
        << "truncated to " << length;
  }
  // The last value is the count of the turns' axes (version 10's trailing block), so a value
  // appended is read as that count: refused, by the count or by what is left over.
  for (const double extra : {0.0, 1.0, static_cast<double>(good.values.back())}) {
    SessionCheckpoint longer = good;
    longer.values.push_back(extra);
    EXPECT_THAT(EstimationSession::FromCheckpoint(s.spec.config, Options(), longer),
                StatusIs(absl::StatusCode::kDataLoss, HasSubstr("checkpoint")))
        << "appended " << extra;
  }
  SessionCheckpoint future = good;
  future.version = 11;  // 10 holds the turns' axes (session_checkpoint.cc)
  EXPECT_THAT(EstimationSession::FromCheckpoint(s.spec.config, Options(), future),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("version 11")));
  RecordProperty("restored", restored);
  RecordProperty("refused", refused);
  std::printf("%zu values: %d corrupt restored (%d ran on), %d refused\n", good.values.size(),
              restored, ran_on, refused);
  EXPECT_GT(refused, 0);
}

// The version-2 tail: the flags and the monitor named by the message when corrupt.
// Found by fuzz/fuzz_checkpoint.cc (docs/fuzzing.md, finding 3): a checkpoint whose initial
// covariance P0 had a zero on its diagonal restored; the next frame put sqrt(P/P0) = inf into the
// convergence record, so the session's own checkpoint no longer restored (the server would have
// written a checkpoint it cannot load). The fuzzer's blob is tested in quarantine_test.cc.
// Version 8 says how many fixed drift coefficients each gyro holds (estimator/model_terms.h):
// a checkpoint that holds another number (written before a fixed term was added or removed) is
// DataLoss naming both counts, never read with its next field taken for a coefficient; the same
// session's values in version 7's layout (13, not stated) still restore, to the same state.
TEST(SessionCheckpoint, ACountOfFixedCoefficientsOtherThanTheModelsIsDataLossAndVersion7Restores) {
  const Scenario s = AllPhases();
  const Prefix p = RunPrefix(s, Options(), FrameAt(s, 6.5));
  const SessionCheckpoint good = p.session.ExportCheckpoint();
  ASSERT_EQ(good.version, 10);
  const size_t m = static_cast<size_t>(good.values.at(22));
  const size_t first_gyro = 23 + m + 1;
  const size_t count_at = first_gyro + testing::kGyroValuesBeforeTheta;
  ASSERT_EQ(good.values.at(count_at), static_cast<double>(kNumDriftCoefficients));
  for (const double other : {12.0, 14.0}) {
    SessionCheckpoint c = good;
    c.values[count_at] = other;
    EXPECT_THAT(EstimationSession::FromCheckpoint(s.spec.config, Options(), c),
                StatusIs(absl::StatusCode::kDataLoss,
                         HasSubstr(absl::StrFormat("gyro %d holds %d fixed drift coefficients, "
                                                   "this build's model has %d",
                                                   static_cast<int>(good.values[first_gyro]),
                                                   static_cast<int>(other), kNumDriftCoefficients))));
  }
  auto from_version7 =
      EstimationSession::FromCheckpoint(s.spec.config, Options(), testing::AsVersion7(good));
  ASSERT_THAT(from_version7, IsOk());
  // The same state, but for the turns' axes, which version 7 does not hold.
  EXPECT_TRUE(SameBits(testing::AsVersion8(from_version7->ExportCheckpoint()).values,
                       testing::AsVersion8(good).values));
}

TEST(SessionCheckpoint, ZeroInitialVarianceIsDataLoss) {
  const Scenario s = AllPhases();
  const Prefix p = RunPrefix(s, Options(), FrameAt(s, 0.5));
  ASSERT_TRUE(p.session.initialized());
  SessionCheckpoint c = p.session.ExportCheckpoint();
  const size_t n = static_cast<size_t>(p.session.state_size());
  const size_t p0_begin = Version1Length(c) - n * n;
  c.values[p0_begin + (n - 5) * n + (n - 5)] = 0.0;  // a diagonal entry of P0
  EXPECT_THAT(EstimationSession::FromCheckpoint(s.spec.config, Options(), c).status(),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("initial covariance diagonal")));
}

// Found by fuzz/fuzz_checkpoint.cc (docs/fuzzing.md, finding 7): a positive but tiny initial
// variance passed the check above, yet sqrt(P/P0) overflowed: the restored session reported an
// infinite relative sigma and wrote it into its own checkpoint, which then did not restore. Now
// P0 must be a positive normal number and the relative sigma is sqrt(P) / sqrt(P0), finite for
// every finite P. The fuzzer's blobs are tested in quarantine_test.cc.
TEST(SessionCheckpoint, SubnormalInitialVarianceIsDataLossAndTheSmallestNormalOneKeepsItFinite) {
  const Scenario s = AllPhases();
  const size_t cut = FrameAt(s, 0.5);
  const Prefix p = RunPrefix(s, Options(), cut);
  ASSERT_TRUE(p.session.initialized());
  const SessionCheckpoint good = p.session.ExportCheckpoint();
  const size_t n = static_cast<size_t>(p.session.state_size());
  const size_t p0_begin = Version1Length(good) - n * n, p_begin = p0_begin - n * n;
  SessionCheckpoint subnormal = good;
  subnormal.values[p0_begin + (n - 5) * n + (n - 5)] = std::numeric_limits<double>::denorm_min();
  EXPECT_THAT(EstimationSession::FromCheckpoint(s.spec.config, Options(), subnormal).status(),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("not a positive normal number")));
  // Every prior variance at the smallest normal number and every variance raised by 1e300 (P
  // stays symmetric and positive semidefinite): P/P0 overflows on every state, sqrt(P)/sqrt(P0)
  // on none. The session restores, reports finite relative sigmas, and whatever the next frame
  // does (a failed step is a status), its own checkpoint restores.
  SessionCheckpoint extreme = good;
  for (size_t i = 0; i < n; ++i) {
    extreme.values[p0_begin + i * n + i] = std::numeric_limits<double>::min();
    extreme.values[p_begin + i * n + i] += 1e300;
  }
  absl::StatusOr<EstimationSession> restored =
      EstimationSession::FromCheckpoint(s.spec.config, Options(), extreme);
  ASSERT_THAT(restored, IsOk());
  int ratios = 0;
  for (const GyroEstimate& g : restored->Gyros()) {
    for (const auto& [coefficient, ratio] : restored->RelativeSigma(g.id)) {
      EXPECT_TRUE(std::isfinite(ratio)) << "gyro " << g.id << " coefficient " << coefficient;
      EXPECT_GT(ratio, 1e300);
      ++ratios;
    }
  }
  EXPECT_GT(ratios, 0);
  (void)restored->AddFrame(s.frames[cut]);  // any status
  EXPECT_THAT(EstimationSession::FromCheckpoint(s.spec.config, Options(),
                                                restored->ExportCheckpoint()),
              IsOk());
}

// Found by fuzz/fuzz_checkpoint.cc (docs/fuzzing.md, finding 8): a checkpoint whose count of
// steps without the star tracker (value 19) was 1e9, the largest integer the restore reads,
// restored; a frame without the star tracker made it 1e9 + 1 and the session's own checkpoint
// did not restore. The session's counts now stop at 1e9. Input:
// fuzz/corpus/checkpoint/regression-step-count-at-limit.bin.
TEST(SessionCheckpoint, StepCountsRestoredAtTheirLimitStayThereAndTheCheckpointRestores) {
  const Scenario s = AllPhases();
  const size_t cut = FrameAt(s, 0.5);
  const Prefix p = RunPrefix(s, Options(), cut);
  ASSERT_TRUE(p.session.initialized());
  SessionCheckpoint c = p.session.ExportCheckpoint();
  c.values[1] = 0.0;   // use_star_tracker: the next frame is a step without it
  c.values[19] = 1e9;  // steps_without_star_tracker
  c.values[20] = 1e9;  // consecutive_rejections
  absl::StatusOr<EstimationSession> restored =
      EstimationSession::FromCheckpoint(s.spec.config, Options(), c);
  ASSERT_THAT(restored, IsOk());
  ASSERT_THAT(restored->AddFrame(s.frames[cut]), IsOk());
  const SessionCheckpoint after = restored->ExportCheckpoint();
  EXPECT_EQ(after.values[19], 1e9);
  EXPECT_THAT(EstimationSession::FromCheckpoint(s.spec.config, Options(), after), IsOk());
  c.values[19] = 1e9 + 1;
  EXPECT_THAT(EstimationSession::FromCheckpoint(s.spec.config, Options(), c).status(),
              StatusIs(absl::StatusCode::kDataLoss,
                       HasSubstr("value 19 = 1000000001: an integer field is not an integer in "
                                 "[-1e9, 1e9]")));
}

// Found by fuzz/fuzz_checkpoint.cc (docs/fuzzing.md, finding 9): a checkpoint whose previous
// mean body rate (version 4) was 1e300 about each axis restored; the next frame extrapolated the
// body rate from it, the reading-fault monitor kept the turn |w| dt = inf, and the session's own
// checkpoint did not restore ("turn inf is not finite"). The monitor now keeps a turn of at most
// kMaxTurnRad, its axis unknown. Input: fuzz/corpus/checkpoint/regression-turn-overflow.bin.
TEST(SessionCheckpoint, ABodyRateRestoredAt1e300KeepsTheTurnFiniteAndTheCheckpointRestores) {
  const Scenario s = AllPhases();
  const size_t cut = FrameAt(s, 0.5);
  const Prefix p = RunPrefix(s, Options(), cut);
  ASSERT_TRUE(p.session.initialized());
  SessionCheckpoint c = p.session.ExportCheckpoint();
  // Version 2's three flags and the consistency monitor's block, version 3's widening block,
  // suspect gyro and time, then version 4's latency and the previous mean rate (3).
  size_t pos = Version1Length(c) + 3;
  pos += 1 + static_cast<size_t>(c.values.at(pos));
  pos += 1 + static_cast<size_t>(c.values.at(pos));
  pos += 1 + 3 + 1;
  for (int i = 0; i < 3; ++i) c.values.at(pos + i) = 1e300;
  c.values.at(pos + 3) = 60.0;  // previous_interval_s: the rate is extrapolated from it
  absl::StatusOr<EstimationSession> restored =
      EstimationSession::FromCheckpoint(s.spec.config, Options(), c);
  ASSERT_THAT(restored, IsOk());
  (void)restored->AddFrame(s.frames[cut]);  // any status
  EXPECT_THAT(EstimationSession::FromCheckpoint(s.spec.config, Options(),
                                                restored->ExportCheckpoint()),
              IsOk());
}

// Found by fuzz/fuzz_checkpoint.cc (docs/fuzzing.md, finding 4): an uninitialised session's
// checkpoint whose working pair named gyro 0 restored (pairs were checked only once initialised),
// and the first frame with a star-tracker fix read the frame's gyro at index -1.
TEST(SessionCheckpoint, UninitialisedSessionWithAPairOutsideTheConfigurationIsDataLoss) {
  auto session = EstimationSession::Create(::esg::testing::PaperConfig(), Options());
  ASSERT_THAT(session, IsOk());
  SessionCheckpoint c = session->ExportCheckpoint();
  ASSERT_EQ(c.values[0], 0.0);  // not initialised
  c.values[14] = 0.0;           // working_pair[0]
  EXPECT_THAT(EstimationSession::FromCheckpoint(::esg::testing::PaperConfig(), Options(), c).status(),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("working pair [0,")));
}

TEST(SessionCheckpoint, CorruptVersionTwoTailIsDataLossNamingTheField) {
  const Scenario s = AllPhases();
  const size_t cut = FrameAt(s, 6.5);
  const Prefix p = RunPrefix(s, Options(), cut);
  const SessionCheckpoint good = p.session.ExportCheckpoint();
  const size_t monitor_size = p.session.consistency_monitor().ExportState().size();
  const size_t tail = Version1Length(good);  // star_tracker_voted_faulty
  auto with = [&](size_t index, double value) {
    SessionCheckpoint c = good;
    c.values[index] = value;
    return EstimationSession::FromCheckpoint(s.spec.config, Options(), c).status();
  };
  EXPECT_THAT(with(tail, 0.5), StatusIs(absl::StatusCode::kDataLoss, HasSubstr("flag")));
  EXPECT_THAT(with(tail + 1, 2), StatusIs(absl::StatusCode::kDataLoss, HasSubstr("flag")));
  EXPECT_THAT(with(tail + 2, -3), StatusIs(absl::StatusCode::kDataLoss, HasSubstr("negative")));
  EXPECT_THAT(with(tail + 3, monitor_size + 1),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("consistency monitor")));
  // Monitor values (ConsistencyMonitor::ExportState): index 0 tests, 5 the star-tracker
  // channel's steps_seen.
  EXPECT_THAT(with(tail + 4, 0.5),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("consistency monitor: tests = 0.5")));
  EXPECT_THAT(with(tail + 4 + 5, -1),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("star_tracker.steps_seen")));
}

}  // namespace
}  // namespace esg::estimator
