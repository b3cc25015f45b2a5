// The estimation session (issue: calibration EKF, fault rejection, long-gap prediction) on
// seeded simulated flights with the paper's calibration profile (section 3): 60 s telemetry,
// 8 Hz integration, star tracker 5/5/30 arcsec, truth with rotor-displacement terms of paper
// size (C ~ 0.05-0.2 deg/h).
#include "estimator/session.h"

#include <cmath>
#include <cstdio>
#include <optional>
#include <vector>

#include "Eigen/Eigenvalues"
#include "absl/strings/str_cat.h"
#include "estimator/calibration_model.h"
#include "estimator/ekf.h"
#include "estimator/fault_detection.h"
#include "estimator/offline.h"
#include "estimator/rotation.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::PaperFlight;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;

SessionOptions Model(const char* name) {
  SessionOptions o;
  o.model = *ParseModel(name);
  return o;
}

TEST(CalibrationModel, ParsesModelStringsAndFreesSigmaPositiveTerms) {
  auto m = ParseModel("10+11");
  ASSERT_THAT(m, IsOk());
  EXPECT_TRUE((m->parts & kModelPart10) && m->random_walk);
  EXPECT_EQ(m->Name(), "10+11");
  EXPECT_EQ(ParseModel("1")->Name(), "1");
  EXPECT_EQ(ParseModel("1")->parts, kModelPart1);
  EXPECT_THAT(ParseModel("12"), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("'12'")));
  EXPECT_THAT(ParseModel(""), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("model")));
  const SpacecraftConfig config = testing::PaperConfig();
  // Model 10 frees k0 and C1, C2 (sigma > 0); mu and nu have no sigma and stay held.
  EXPECT_EQ(FreeCoefficients(*ParseModel("10"), config.gyros[0]).size(), 7u);
  EXPECT_EQ(FreeCoefficients(*ParseModel("1"), config.gyros[0]).size(), 1u);
  EXPECT_TRUE(FreeCoefficients(*ParseModel("11"), config.gyros[0]).empty());
  // Model 11 alone applies the configured model; model 1 drops C1, C2.
  GyroConfig g = config.gyros[0];
  g.model.C1 = Eigen::Vector3d(1, 2, 3);
  EXPECT_EQ(ModelCoefficients(*ParseModel("11"), g)(kThetaC1), 1.0);
  EXPECT_EQ(ModelCoefficients(*ParseModel("1"), g)(kThetaC1), 0.0);
}

TEST(FaultDetection, NamesTheSubsystemWhoseTwoMismatchesExceed) {
  // eq. (12): a subsystem is faulty when both mismatches that involve it exceed the allowed angle.
  const Eigen::Quaterniond q = ExpQuaternion(Eigen::Vector3d(0.3, -0.2, 0.9));
  const Eigen::Quaterniond off = ExpQuaternion(Eigen::Vector3d(0, 0, ArcminToRad(3))) * q;
  const std::array<double, 3> allowed = {ArcminToRad(1), ArcminToRad(1), ArcminToRad(1)};
  EXPECT_EQ(TestMismatch(&off, &q, &q, allowed).faulty, Subsystem::kWorkingPair);
  EXPECT_EQ(TestMismatch(&q, &off, &q, allowed).faulty, Subsystem::kReservePair);
  EXPECT_EQ(TestMismatch(&q, &q, &off, allowed).faulty, Subsystem::kStarTracker);
  EXPECT_EQ(TestMismatch(&q, &q, &q, allowed).faulty, Subsystem::kNone);
  // Without the reserve pair no subsystem can be named.
  EXPECT_EQ(TestMismatch(&q, nullptr, &off, allowed).faulty, Subsystem::kNone);
  const MismatchTest t = TestMismatch(&off, &q, &q, allowed);
  EXPECT_NEAR(t.angle[0], ArcminToRad(3), 1e-12);
  EXPECT_NEAR(t.angle[2], 0.0, 1e-12);
}

TEST(FaultDetection, InnovationTestIsEq14ForUncorrelatedComponents) {
  // eq. (14): |z| > k_d sqrt(diag(S)) rejects. With diagonal S the sequential form is the same.
  Eigen::VectorXd z(3);
  z << 1.0, -2.0, 3.0;
  Eigen::MatrixXd S = Eigen::Vector3d(1.0, 1.0, 0.25).asDiagonal();
  const InnovationTest t = TestInnovation(z, S, 5.0);
  EXPECT_FALSE(t.passed);  // |3| / 0.5 = 6 > 5
  EXPECT_EQ(t.worst_index, 2);
  EXPECT_NEAR(t.worst_ratio, 6.0, 1e-12);
  EXPECT_NEAR(t.worst_value, 3.0, 1e-12);
  EXPECT_NEAR(t.worst_threshold, 5.0 * 0.5, 1e-12);
  EXPECT_TRUE(TestInnovation(z, S, 6.5).passed);
}

TEST(FaultDetection, AllowedAngleFollowsTheMismatchDirection) {
  // Boresight (z) sigma 30 arcsec, cross-boresight 5: k_d = 5 allows 150 arcsec about z, 25 about x.
  const Eigen::Matrix3d Sigma =
      Eigen::Vector3d(ArcsecToRad(5), ArcsecToRad(5), ArcsecToRad(30)).cwiseAbs2().asDiagonal();
  EXPECT_NEAR(RadToArcsec(DirectionalAllowedAngle(Eigen::Vector3d(0, 0, 1e-4), Sigma, 5.0, 0.0)), 150.0, 1e-9);
  EXPECT_NEAR(RadToArcsec(DirectionalAllowedAngle(Eigen::Vector3d(1e-4, 0, 0), Sigma, 5.0, 0.0)), 25.0, 1e-9);
  EXPECT_NEAR(RadToArcsec(DirectionalAllowedAngle(Eigen::Vector3d(1e-4, 0, 0), Sigma, 5.0, ArcsecToRad(40))), 40.0, 1e-9);
}

TEST(Ekf, JosephUpdateMatchesTheScalarKalmanFilter) {
  Eigen::MatrixXd P(1, 1), H(1, 1), R(1, 1);
  P << 4.0;
  H << 1.0;
  R << 1.0;
  Eigen::VectorXd z(1), dx;
  z << 2.0;
  ASSERT_THAT(JosephUpdate(H, z, R, P, dx), IsOk());
  EXPECT_NEAR(dx(0), 2.0 * 4.0 / 5.0, 1e-15);
  EXPECT_NEAR(P(0, 0), 4.0 * 1.0 / 5.0, 1e-15);
  // A non-finite measurement leaves P untouched and reports Internal.
  Eigen::MatrixXd before = P;
  z << NAN;
  EXPECT_THAT(JosephUpdate(H, z, R, P, dx), StatusIs(absl::StatusCode::kInternal, HasSubstr("finite")));
  EXPECT_EQ(P, before);
}

// Calibration over many seeded flights: the estimates of every free coefficient are within
// 3 sigma of the truth in at least 95% of (run, coefficient) cases, and each run's normalised
// errors are consistent (chi-square bound). 40 runs of 12 h (the transient is < 8 h).
TEST(Session, CoefficientsWithinThreeSigmaOfTruthIn95PercentOf40Runs) {
  int within = 0, total = 0, runs_all_within = 0;
  for (uint64_t seed = 1; seed <= 40; ++seed) {
    const SimulationSpec spec = PaperFlight(seed, 12.0);
    auto sim = Simulate(spec);
    ASSERT_THAT(sim, IsOk());
    auto result = RunCalibration(spec.config, Model("10+11"), sim->recording.frames);
    ASSERT_THAT(result, IsOk());
    bool all = true;
    for (const GyroEstimate& g : result->gyros) {
      const DriftVector truth = sim->true_coefficients[g.id - 1]->AsVector();
      const DriftVector est = g.coefficients.AsVector();
      const DriftVector sigma = g.sigma.AsVector();
      for (int i = 0; i < kNumDriftCoefficients; ++i) {
        if (sigma(i) == 0.0) continue;
        ++total;
        const bool ok = std::abs(est(i) - truth(i)) <= 3.0 * sigma(i);
        within += ok;
        all &= ok;
      }
    }
    runs_all_within += all;
  }
  ASSERT_EQ(total, 40 * 3 * 7);
  const double fraction = static_cast<double>(within) / total;
  RecordProperty("fraction_within_3sigma", std::to_string(fraction));
  RecordProperty("runs_all_within_3sigma", std::to_string(runs_all_within));
  EXPECT_GE(fraction, 0.95) << within << " of " << total;
}

TEST(Session, TransientEndsWithin8Hours) {
  // The transient is over when every free coefficient's sigma has fallen well below its prior and
  // its estimate is within 3 sigma of the truth. The paper reports 6-8 h; by 8 h of the
  // calibration profile (orientation changed every 3 h) it must be over, and at 4 h it must not
  // be (a filter whose covariance collapsed at once would pass an 8 h bound alone). Measured on
  // these seeds (largest sqrt(P/P0) over every free coefficient): see kBound8h / kRatio4hTo8h.
  constexpr double kBound8h = 0.12;     // measured 0.092-0.095 (seeds 11-13)
  constexpr double kRatio4hTo8h = 1.5;  // measured 0.19-0.45 at 4 h: 2.1-4.7 times the 8 h value
  for (uint64_t seed : {11, 12, 13}) {
    const SimulationSpec spec = PaperFlight(seed, 8.0);
    auto sim = Simulate(spec);
    ASSERT_THAT(sim, IsOk());
    EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
    double worst_4h = 0.0;
    for (const TelemetryFrame& frame : sim->recording.frames) {
      ASSERT_THAT(session.AddFrame(frame), IsOk());
      if (frame.time - spec.start == absl::Hours(4)) {
        for (const GyroEstimate& g : session.Gyros()) {
          for (const auto& [index, ratio] : session.RelativeSigma(g.id)) {
            worst_4h = std::max(worst_4h, ratio);
          }
        }
      }
    }
    double worst_8h = 0.0;
    for (const GyroEstimate& g : session.Gyros()) {
      for (const auto& [index, ratio] : session.RelativeSigma(g.id)) {
        worst_8h = std::max(worst_8h, ratio);
        EXPECT_LE(ratio, kBound8h) << "seed " << seed << " gyro " << g.id << " " << CoefficientName(index);
      }
      const DriftVector truth = sim->true_coefficients[g.id - 1]->AsVector();
      const DriftVector est = g.coefficients.AsVector(), sigma = g.sigma.AsVector();
      for (int i = 0; i < kNumDriftCoefficients; ++i) {
        if (sigma(i) > 0.0) {
          EXPECT_LE(std::abs(est(i) - truth(i)), 3.0 * sigma(i)) << "seed " << seed << " " << CoefficientName(i);
        }
      }
    }
    std::printf("seed %llu: largest sqrt(P/P0) %.3f at 4 h, %.3f at 8 h\n",
                static_cast<unsigned long long>(seed), worst_4h, worst_8h);
    EXPECT_GT(worst_4h, kRatio4hTo8h * worst_8h) << "seed " << seed;
  }
}

TEST(Session, NormalisedInnovationSquaredIsChiSquareConsistent) {
  // NIS of the star-tracker differences (6 components for three gyros) averaged over a 24 h run:
  // for a consistent filter the sum of n NIS values is chi-square with 6n degrees of freedom, so
  // the mean is 6 with sigma sqrt(12/n); 3.3 sigma is the 99.9% two-sided bound. The first hour
  // (initial transient) is left out.
  for (uint64_t seed : {1, 2, 3}) {
    const SimulationSpec spec = PaperFlight(seed, 24.0);
    auto sim = Simulate(spec);
    ASSERT_THAT(sim, IsOk());
    EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
    double sum = 0.0;
    int n = 0;
    std::string events;  // everything but the routine eq. (14) rejections, for the failure text
    for (size_t i = 0; i < sim->recording.frames.size(); ++i) {
      auto report = session.AddFrame(sim->recording.frames[i]);
      ASSERT_THAT(report, IsOk());
      for (const Event& e : report->events) {
        if (e.kind == Event::Kind::kStarTrackerInnovation) continue;
        absl::StrAppend(&events, "\n  ", absl::FormatTime(e.time), " ", EventKindName(e.kind), " ",
                        e.message);
      }
      if (i <= 60 || !report->star_tracker_used) continue;
      ASSERT_EQ(report->star_tracker_innovation.size(), 6);
      sum += report->star_tracker_nis;
      ++n;
    }
    ASSERT_GT(n, 1300);
    const double mean = sum / n;
    const double bound = 3.3 * std::sqrt(12.0 / n);
    EXPECT_NEAR(mean, 6.0, bound) << "seed " << seed << " over " << n << " steps" << events;
  }
}

TEST(Session, CovarianceStaysSymmetricPositiveDefiniteOver48Hours) {
  SimulationSpec spec = PaperFlight(5, 48.0, "mixed");
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
  for (size_t i = 0; i < sim->recording.frames.size(); ++i) {
    ASSERT_THAT(session.AddFrame(sim->recording.frames[i]), IsOk()) << "frame " << i;
    if (i % 240 == 0 && session.initialized()) {
      const Eigen::MatrixXd& P = session.covariance();
      ASSERT_EQ((P - P.transpose()).cwiseAbs().maxCoeff(), 0.0);
      Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> es(P);
      ASSERT_GT(es.eigenvalues().minCoeff(), 0.0) << "frame " << i;
    }
  }
}

TEST(Session, RejectsStarTrackerOutliersAndFewCleanSteps) {
  // Outliers of 1-3 arcmin about random axes, 2% of samples, 24 h. A rotation about the 30 arcsec
  // boresight is a 2-6 sigma event of the star tracker's own noise and cannot be told from it;
  // every outlier whose cross-boresight part is 1 arcmin or more must be rejected, and fewer than
  // 0.5% of the clean steps.
  SimulationSpec spec = PaperFlight(21, 24.0);
  spec.star_tracker.outlier_probability = 0.02;
  spec.star_tracker.outlier_size = ArcminToRad(1.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
  int outliers = 0, cross_outliers = 0, cross_rejected = 0, any_rejected = 0, clean = 0,
      clean_rejected = 0;
  for (size_t i = 0; i < sim->recording.frames.size(); ++i) {
    auto report = session.AddFrame(sim->recording.frames[i]);
    ASSERT_THAT(report, IsOk());
    if (i == 0) continue;
    bool rejected = false;
    for (const Event& e : report->events) {
      rejected |= e.kind == Event::Kind::kStarTrackerInnovation || e.kind == Event::Kind::kStarTrackerFault;
    }
    const TruthSample& truth = sim->truth[i];
    if (truth.star_tracker_outlier) {
      ++outliers;
      any_rejected += rejected;
      const Eigen::Vector3d err_b =
          LogQuaternion(truth.q_in_b.conjugate() * sim->recording.frames[i].star_tracker->q_in_b);
      if (err_b.head<2>().norm() >= ArcminToRad(1.0)) {
        ++cross_outliers;
        cross_rejected += rejected;
      }
    } else {
      ++clean;
      clean_rejected += rejected;
    }
  }
  RecordProperty("outliers", outliers);
  RecordProperty("outliers_rejected", any_rejected);
  ASSERT_GT(cross_outliers, 10);
  EXPECT_EQ(cross_rejected, cross_outliers);
  EXPECT_LT(clean_rejected, 0.005 * clean) << clean_rejected << " of " << clean;
}

TEST(Session, WorkingPairFaultSwitchesToReserveWithinOneStep) {
  SimulationSpec spec = PaperFlight(3, 10.0);
  GyroFault fault;
  fault.time = HoursToSeconds(9.0) + 30.0;  // between two frames
  fault.kind = GyroFault::Kind::kReadoutJump;
  fault.value = Eigen::Vector3d(ArcminToRad(5), 0, 0);
  spec.gyros[1].fault = fault;  // gyro 2: in the working pair [1,2], not in the reserve [1,3]
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
  std::optional<absl::Time> switched;
  for (size_t i = 0; i < sim->recording.frames.size(); ++i) {
    auto report = session.AddFrame(sim->recording.frames[i]);
    ASSERT_THAT(report, IsOk());
    for (const Event& e : report->events) {
      if (e.kind == Event::Kind::kWorkingPairFault && !switched) {
        switched = e.time;
        EXPECT_GT(e.value, e.threshold);
        EXPECT_EQ(report->attitude.pair, (std::array<int, 2>{1, 3}));
      }
    }
    if (sim->recording.frames[i].time < spec.start + absl::Seconds(fault.time)) {
      ASSERT_FALSE(switched.has_value()) << "switched before the fault at frame " << i;
    }
  }
  ASSERT_TRUE(switched.has_value());
  // The first frame after the fault is 30 s after it: detected at that measurement step.
  EXPECT_EQ(*switched, spec.start + absl::Seconds(fault.time + 30.0));
  // Degraded, not FAULTED: the clean pair carries a valid output (docs/decisions.md D94).
  EXPECT_NE(session.state(), SessionState::kFaulted);
  EXPECT_TRUE(session.degraded());
  for (const GyroEstimate& g : session.Gyros()) {
    EXPECT_EQ(g.faulty, g.id == 2) << "gyro " << g.id;
    if (g.faulty) {
      EXPECT_TRUE(g.exclusion.reason == ExclusionReason::kReadingJump ||
                  g.exclusion.reason == ExclusionReason::kBeyondAnyDrift)
          << ExclusionReasonName(g.exclusion.reason);
    }
  }
  // Output on the reserve pair stays accurate.
  const Eigen::Quaterniond q_true = sim->truth.back().q_in_b;
  EXPECT_LT(RotationAngle(session.CurrentAttitude().q_in_b, q_true), ArcsecToRad(60));
}

// --- Fault isolation with three running gyros (fault_detection.h DecideIsolation) ---

struct FaultRun {
  std::vector<Event> events;
  std::vector<GyroEstimate> gyros;
  std::array<int, 2> final_pair = {0, 0};
  std::optional<absl::Time> isolated;  // first gyro isolation
  double max_error_after_rad = 0.0;    // output against the truth from the isolation on
  int rejected_steps_after = 0;        // steps with a star-tracker or z_avt rejection after it
  int steps_after = 0;
};

// Runs a session over `frames` (truth `sim`) and collects what the fault tests assert.
FaultRun RunFaulted(const SimulationSpec& spec, const SimulationResult& sim,
                    const std::vector<TelemetryFrame>& frames) {
  FaultRun run;
  EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
  for (size_t i = 0; i < frames.size(); ++i) {
    auto report = session.AddFrame(frames[i]);
    EXPECT_THAT(report, IsOk());
    if (!report.ok()) return run;
    bool rejected = false;
    for (const Event& e : report->events) {
      run.events.push_back(e);
      if ((e.kind == Event::Kind::kWorkingPairFault || e.kind == Event::Kind::kReservePairFault) &&
          !run.isolated) {
        run.isolated = e.time;
        continue;
      }
      rejected |= e.kind == Event::Kind::kStarTrackerInnovation ||
                  e.kind == Event::Kind::kGyroDataRejected || e.kind == Event::Kind::kStarTrackerFault;
    }
    if (run.isolated && report->measurement_step) {
      ++run.steps_after;
      run.rejected_steps_after += rejected;
      run.max_error_after_rad =
          std::max(run.max_error_after_rad, RotationAngle(report->attitude.q_in_b, sim.truth[i].q_in_b));
    }
  }
  run.gyros = session.Gyros();
  run.final_pair = session.working_pair();
  return run;
}

int CountEvents(const std::vector<Event>& events, Event::Kind kind) {
  int n = 0;
  for (const Event& e : events) n += e.kind == kind;
  return n;
}

// Each running gyro x a 5 arcmin readout jump at 5 h (30 s before a frame), calibration profile,
// 12 h, seeded: the faulty gyro and only it is excluded, at the first measurement step after the
// jump or the second (when less of the jump shows than a drift change could do in one step, D94); the output moves to the pair without it (gyro 1, shared by the configured pairs [1,2] and
// [1,3]: pair [2,3]); the event carries the evidence and recommends the cold spare; afterwards the
// output stays within 30 arcsec of the truth (measured: 16.0 / 11.9 / 22.8 arcsec) and the
// star tracker is used again (rejections after the switch in < 1% of the steps).
TEST(FaultIsolation, ReadoutJumpInEachRunningGyroExcludesThatGyro) {
  const std::array<int, 2> expected_pair[3] = {{2, 3}, {1, 3}, {1, 2}};
  for (int faulty = 1; faulty <= 3; ++faulty) {
    SCOPED_TRACE(::testing::Message() << "gyro " << faulty);
    SimulationSpec spec = PaperFlight(10 + faulty, 12.0);
    GyroFault fault;
    fault.time = HoursToSeconds(5.0) - 30.0;
    fault.kind = GyroFault::Kind::kReadoutJump;
    fault.value = Eigen::Vector3d(ArcminToRad(5), 0, 0);
    spec.gyros[faulty - 1].fault = fault;
    auto sim = Simulate(spec);
    ASSERT_THAT(sim, IsOk());
    const FaultRun run = RunFaulted(spec, *sim, sim->recording.frames);
    ASSERT_TRUE(run.isolated.has_value());
    // At the first measurement step after the jump, or the second where the jump's visible part
    // is within what a drift change could do in one step (gyro 1 here: 90 arcsec of its 5
    // arcmin show in its spin axis; docs/decisions.md D94).
    EXPECT_GE(*run.isolated, spec.start + absl::Hours(5));
    EXPECT_LE(*run.isolated, spec.start + absl::Hours(5) + absl::Minutes(1));
    for (const GyroEstimate& g : run.gyros) EXPECT_EQ(g.faulty, g.id == faulty) << "gyro " << g.id;
    EXPECT_EQ(run.final_pair, expected_pair[faulty - 1]);
    int isolations = 0;
    for (const Event& e : run.events) {
      if (e.kind != Event::Kind::kWorkingPairFault && e.kind != Event::Kind::kReservePairFault) continue;
      ++isolations;
      EXPECT_EQ(e.kind, faulty == 3 ? Event::Kind::kReservePairFault : Event::Kind::kWorkingPairFault);
      EXPECT_EQ(e.subsystem, absl::StrCat("gyro ", faulty));
      EXPECT_GT(e.value, e.threshold);
      EXPECT_THAT(e.message, HasSubstr("EXCEEDS"));
      EXPECT_THAT(e.message, HasSubstr("cold spare (gyro 4)"));
    }
    EXPECT_EQ(isolations, 1);
    EXPECT_EQ(CountEvents(run.events, Event::Kind::kFilterReset), 0);
    // At most the first step's: the gyro named before its readings' verdict, withheld.
    EXPECT_LE(CountEvents(run.events, Event::Kind::kFaultAmbiguous),
              *run.isolated > spec.start + absl::Hours(5) ? 1 : 0);
    RecordProperty(absl::StrCat("max_error_after_arcsec_gyro", faulty), RadToArcsec(run.max_error_after_rad));
    std::printf("gyro %d: max error after %.1f arcsec, rejected %d of %d steps\n", faulty,
                RadToArcsec(run.max_error_after_rad), run.rejected_steps_after, run.steps_after);
    EXPECT_LT(run.max_error_after_rad, ArcsecToRad(30));
    EXPECT_LT(run.rejected_steps_after, 0.01 * run.steps_after);
  }
}

// The star tracker's frames from `from` on (for `duration`, or to the end) changed by `change`.
template <typename Change>
std::vector<TelemetryFrame> ChangeStarTracker(std::vector<TelemetryFrame> frames, absl::Time from,
                                              absl::Duration duration, Change change) {
  std::optional<Eigen::Quaterniond> first;
  for (TelemetryFrame& f : frames) {
    if (f.time < from || f.time >= from + duration || !f.star_tracker.has_value()) continue;
    if (!first) first = f.star_tracker->q_in_b;
    f.star_tracker->q_in_b = change(f.star_tracker->q_in_b, *first);
  }
  return frames;
}

// A star-tracker misalignment jump of 2 arcmin (cross-boresight) at 5 h for the rest of the
// flight: named the star tracker at the first step and at every step of the next 3 h, no gyro
// excluded, output pair unchanged, and the filter reset never re-anchors to it (withheld, each
// time because eq. (12) voted it faulty). Measured on this seed: after ~4.3 h without the star
// tracker the pairs' own uncertainty has grown enough for a 2 arcmin offset to pass eq. (12) and
// (14) for a few steps (the limit of what the gyros can tell), which ends the streak; a new
// streak withholds the reset again.
TEST(FaultIsolation, StarTrackerMisalignmentJumpIsNamedAndNeverAdopted) {
  const SimulationSpec spec = PaperFlight(31, 10.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const absl::Time jump = spec.start + absl::Hours(5);
  const Eigen::Quaterniond turn = ExpQuaternion(Eigen::Vector3d(ArcminToRad(2), 0, 0));
  const auto frames = ChangeStarTracker(sim->recording.frames, jump, absl::InfiniteDuration(),
                                        [&](const Eigen::Quaterniond& q, const Eigen::Quaterniond&) {
                                          return Eigen::Quaterniond(q * turn);
                                        });
  const FaultRun run = RunFaulted(spec, *sim, frames);
  EXPECT_FALSE(run.isolated.has_value());
  for (const GyroEstimate& g : run.gyros) EXPECT_FALSE(g.faulty) << "gyro " << g.id;
  EXPECT_EQ(run.final_pair, (std::array<int, 2>{1, 2}));
  EXPECT_EQ(CountEvents(run.events, Event::Kind::kFilterReset), 0);
  int named = 0, named_first_3h = 0, withheld = 0;
  std::optional<absl::Time> first_named;
  for (const Event& e : run.events) {
    if (e.kind != Event::Kind::kStarTrackerFault) continue;
    if (e.message.find("withheld") != std::string::npos) {
      ++withheld;
      EXPECT_THAT(e.message, HasSubstr("eq. (12) voted the star tracker faulty"));
      continue;
    }
    ++named;
    named_first_3h += e.time < jump + absl::Hours(3);
    if (!first_named) first_named = e.time;
  }
  ASSERT_TRUE(first_named.has_value());
  EXPECT_EQ(*first_named, jump);
  EXPECT_EQ(named_first_3h, 180);  // every measurement step of the 3 h after the jump
  EXPECT_GE(withheld, 1);
  std::printf("misalignment jump: named %d, withheld %d, ambiguous %d\n", named, withheld,
              CountEvents(run.events, Event::Kind::kFaultAmbiguous));
}

// A star tracker frozen for 30 min at 5 h: named the star tracker, no gyro excluded, no reset
// adopts the frozen attitude; afterwards it is used again and the output is back within 30
// arcsec of the truth (measured: 13 arcsec at 8 h).
TEST(FaultIsolation, FrozenStarTrackerIsNamedAndNeverAdopted) {
  const SimulationSpec spec = PaperFlight(32, 8.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const absl::Time freeze = spec.start + absl::Hours(5);
  const auto frames = ChangeStarTracker(
      sim->recording.frames, freeze, absl::Minutes(30),
      [](const Eigen::Quaterniond&, const Eigen::Quaterniond& first) { return first; });
  EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
  int named = 0, resets = 0, used_after = 0, steps_after = 0;
  double error_end = 0.0;
  for (size_t i = 0; i < frames.size(); ++i) {
    auto report = session.AddFrame(frames[i]);
    ASSERT_THAT(report, IsOk());
    for (const Event& e : report->events) {
      named += e.kind == Event::Kind::kStarTrackerFault;
      resets += e.kind == Event::Kind::kFilterReset;
    }
    if (frames[i].time >= freeze + absl::Minutes(31) && report->measurement_step) {
      ++steps_after;
      used_after += report->star_tracker_used;
    }
    error_end = RotationAngle(report->attitude.q_in_b, sim->truth[i].q_in_b);
  }
  for (const GyroEstimate& g : session.Gyros()) EXPECT_FALSE(g.faulty) << "gyro " << g.id;
  EXPECT_EQ(session.working_pair(), (std::array<int, 2>{1, 2}));
  EXPECT_EQ(resets, 0);
  EXPECT_GE(named, 25);  // the first frozen sample is the true attitude
  std::printf("frozen: named %d, used after %d, end error %.1f arcsec\n", named, used_after,
              RadToArcsec(error_end));
  EXPECT_GE(used_after, steps_after - 1);  // used again at (nearly) every step after the freeze
  EXPECT_GT(steps_after, 140);
  EXPECT_LT(error_end, ArcsecToRad(30));
}

// Clean data, 24 h, three seeds: no gyro is ever excluded and no isolation or ambiguity event.
TEST(FaultIsolation, NoExclusionOnCleanDataOver24HoursForThreeSeeds) {
  for (uint64_t seed : {41, 42, 43}) {
    SCOPED_TRACE(::testing::Message() << "seed " << seed);
    const SimulationSpec spec = PaperFlight(seed, 24.0);
    auto sim = Simulate(spec);
    ASSERT_THAT(sim, IsOk());
    const FaultRun run = RunFaulted(spec, *sim, sim->recording.frames);
    EXPECT_FALSE(run.isolated.has_value());
    for (const GyroEstimate& g : run.gyros) EXPECT_FALSE(g.faulty) << "gyro " << g.id;
    EXPECT_EQ(run.final_pair, (std::array<int, 2>{1, 2}));
    std::printf("seed %d: ambiguous %d, st fault %d, resets %d\n", static_cast<int>(seed),
                CountEvents(run.events, Event::Kind::kFaultAmbiguous),
                CountEvents(run.events, Event::Kind::kStarTrackerFault),
                CountEvents(run.events, Event::Kind::kFilterReset));
    EXPECT_EQ(CountEvents(run.events, Event::Kind::kFaultAmbiguous), 0);
    EXPECT_EQ(CountEvents(run.events, Event::Kind::kFilterReset), 0);
  }
}

// When the model is short of the truth (model 11 alone with a 2.9 um rotor displacement in gyro
// 1: the rotor-displacement terms are missing), the filter widens its process noise
// (noise_widening.h, docs/decisions.md D20) instead of rejecting the star tracker until a reset:
// FILTER_WIDENED and MODEL_INCONSISTENT are raised, no healthy gyro is excluded, the star
// tracker stays in use, and a reset (if any) never re-anchors to a star tracker eq. (12) voted
// faulty in its streak (D19).
TEST(FaultIsolation, ShortModelWidensTheFilterInsteadOfResettingOrExcluding) {
  SimulationSpec spec = PaperFlight(6, 24.0);
  spec.gyros[0].rotor_displacement_k = Eigen::Vector3d(2.0e-6, -1.5e-6, 1.6e-6);  // as the paper's
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  EstimationSession session = *EstimationSession::Create(spec.config, Model("11"));
  bool voted_in_streak = false;
  int widened = 0, inconsistent = 0, excluded = 0, steps_after_widening = 0, used_after = 0;
  for (const TelemetryFrame& frame : sim->recording.frames) {
    auto report = session.AddFrame(frame);
    ASSERT_THAT(report, IsOk());
    for (const Event& e : report->events) {
      if (e.kind == Event::Kind::kStarTrackerFault && e.message.find("withheld") == std::string::npos) {
        voted_in_streak = true;
      }
      if (e.kind == Event::Kind::kFilterReset) {
        EXPECT_FALSE(voted_in_streak) << "reset at " << absl::FormatTime(e.time)
                                      << " to a star tracker voted faulty in this streak";
        voted_in_streak = false;
      }
      if (e.kind == Event::Kind::kFilterWidened) ++widened;
      if (e.kind == Event::Kind::kModelInconsistent) ++inconsistent;
      if (e.kind == Event::Kind::kWorkingPairFault || e.kind == Event::Kind::kReservePairFault) {
        ++excluded;
      }
    }
    if (report->star_tracker_used) voted_in_streak = false;
    if (widened > 0 && report->measurement_step) {
      ++steps_after_widening;
      used_after += report->star_tracker_used ? 1 : 0;
    }
  }
  EXPECT_GE(widened, 1);
  EXPECT_GE(inconsistent, 1);
  EXPECT_EQ(excluded, 0);
  for (const GyroEstimate& g : session.Gyros()) EXPECT_FALSE(g.faulty) << "gyro " << g.id;
  // Measured on this seed: the star tracker used in 99% of the steps after the first widening.
  ASSERT_GT(steps_after_widening, 0);
  EXPECT_GE(static_cast<double>(used_after) / steps_after_widening, 0.95)
      << used_after << " of " << steps_after_widening;
}

// A star tracker stamped 0.3 s late on the calibration profile (slews up to ~0.3 deg/s). With the
// latency in the configuration the filter corrects every sample with the body rate at the sample,
// extrapolated from the mean rates of the last two intervals (60 s readings), and trusts a
// correction made while the rate changes less (docs/physics.md "Star-tracker latency"). Measured:
// 0 rejections against 62 without the correction and 55 with the sign wrong; asserted: fewer
// than a fifth of the uncorrected rejections, fewer than with the sign wrong, and every
// coefficient and misalignment within 3 sigma of the truth.
TEST(Session, ConfiguredStarTrackerLatencyIsCorrectedWithTheMeasuredBodyRate) {
  SimulationSpec spec = PaperFlight(3, 24.0, "calibration");
  spec.star_tracker.latency = 0.3;
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  struct Outcome {
    int rejected = 0;
    double worst_sigma = 0.0;  // over coefficients and misalignments of every gyro
  };
  auto run = [&](double configured_latency) {
    Outcome o;
    SpacecraftConfig config = spec.config;
    config.star_tracker.latency = configured_latency;
    EstimationSession session = *EstimationSession::Create(config, Model("10+11"));
    for (const TelemetryFrame& frame : sim->recording.frames) {
      auto report = session.AddFrame(frame);
      EXPECT_THAT(report, IsOk());
      if (!report.ok()) return o;
      for (const Event& e : report->events) {
        o.rejected += e.kind == Event::Kind::kStarTrackerInnovation ||
                      e.kind == Event::Kind::kStarTrackerFault;
      }
    }
    for (const GyroEstimate& g : session.Gyros()) {
      const DriftVector t = sim->true_coefficients[g.id - 1]->AsVector();
      const DriftVector e = g.coefficients.AsVector(), sg = g.sigma.AsVector();
      for (int i = 0; i < kNumDriftCoefficients; ++i) {
        if (sg(i) > 0.0) o.worst_sigma = std::max(o.worst_sigma, std::abs(e(i) - t(i)) / sg(i));
      }
      const Eigen::Vector3d truth = spec.gyros[g.id - 1].misalignment_b;
      for (int k = 0; k < 3; ++k) {
        if (g.misalignment_sigma_b(k) <= 0.0) continue;
        o.worst_sigma = std::max(
            o.worst_sigma, std::abs(g.misalignment_b(k) - truth(k)) / g.misalignment_sigma_b(k));
      }
    }
    return o;
  };
  const Outcome corrected = run(0.3), uncorrected = run(0.0), wrong_sign = run(-0.3);
  std::printf("rejections / worst sigma: corrected %d / %.1f, uncorrected %d / %.1f, sign wrong "
              "%d / %.1f\n",
              corrected.rejected, corrected.worst_sigma, uncorrected.rejected,
              uncorrected.worst_sigma, wrong_sign.rejected, wrong_sign.worst_sigma);
  EXPECT_LE(corrected.worst_sigma, 3.0);
  EXPECT_LT(5 * corrected.rejected, uncorrected.rejected);
  EXPECT_LT(corrected.rejected, wrong_sign.rejected);
}

// The gap experiment's claim (the paper's Fig. 7/8, docs/measurements.md "Results against the
// paper"): after 24 h of calibration on a mixed-profile flight whose gyros have displaced rotors
// (as deploy/examples/scenarios/paper_fig78_low_rw.json: 0.0005 deg/h/sqrt(h) random walk), model
// (10)+(11) drifts across a 24 h gap at least 3 times slower than model (1)+(11), which lacks the
// rotor-displacement terms; and model (1)+(11) excludes no healthy gyro (D20, D21).
TEST(Session, GapExperimentModelTenIsAtLeastThreeTimesBetterThanModelOne) {
  for (uint64_t seed : {1, 2}) {
    SimulationSpec spec;
    spec.config = testing::PaperConfig();
    spec.config.random_walk = DegPerHourSqrtHourToSi(0.0005);
    spec.duration = HoursToSeconds(48.0);
    spec.seed = seed;
    spec.profile = *MakeNamedProfile("mixed", spec.duration, seed);
    const double um = 1e-6;
    spec.gyros[0].rotor_displacement_k = Eigen::Vector3d(0.8, -1.0, 0.6) * um;
    spec.gyros[1].rotor_displacement_k = Eigen::Vector3d(0.5, -1.0, 0.3) * um;
    spec.gyros[2].rotor_displacement_k = Eigen::Vector3d(-0.9, 0.4, 0.8) * um;
    spec.star_tracker.outlier_probability = 0.01;
    spec.star_tracker.outlier_size = ArcminToRad(1.0);
    auto sim = Simulate(spec);
    ASSERT_THAT(sim, IsOk());
    const absl::Time gap_start = spec.start + absl::Hours(24);
    auto model_1 = RunGap(spec.config, Model("1+11"), sim->recording.frames, gap_start);
    auto model_10 = RunGap(spec.config, Model("10+11"), sim->recording.frames, gap_start);
    ASSERT_THAT(model_1, IsOk());
    ASSERT_THAT(model_10, IsOk());
    const double rate_1 = RadPerSecToDegPerHour(model_1->drift_rate);
    const double rate_10 = RadPerSecToDegPerHour(model_10->drift_rate);
    std::printf("seed %llu: gap drift rate model (1)+(11) %.4f deg/h, (10)+(11) %.4f deg/h\n",
                static_cast<unsigned long long>(seed), rate_1, rate_10);
    EXPECT_GE(rate_1, 3.0 * rate_10) << "seed " << seed;
    std::string isolations;
    for (const Event& e : model_1->calibration.events) {
      if (e.kind == Event::Kind::kWorkingPairFault || e.kind == Event::Kind::kReservePairFault) {
        absl::StrAppend(&isolations, "\n  ", absl::FormatTime(e.time), " ", e.message);
      }
    }
    for (const GyroEstimate& g : model_1->calibration.gyros) {
      EXPECT_FALSE(g.faulty) << "seed " << seed << " model (1)+(11) excluded healthy gyro " << g.id
                             << isolations;
    }
  }
}

// Normal operation against the truth: the output attitude's error about each body axis against
// its reported 1-sigma, after the first 2 h and through a 1 h star-tracker outage (AUTONOMOUS) at
// 12 h. A consistent envelope leaves a step outside 3 sigma on some axis with probability
// 1 - 0.9973^3 = 0.81% (measured on this seed: 11 of 1321 steps, 0.83%); the bound is 2%,
// which a 1.5x-overconfident envelope (3 sigma shown where 2.45 true sigma lie: 4.2% of steps)
// exceeds. Every gyro's misalignment (gyro 2's truth 20, -30, 15 arcsec) within 3 sigma.
TEST(Session, AttitudeAndMisalignmentAgreeWithTheTruthAlsoAcrossAnOutage) {
  SimulationSpec spec = PaperFlight(4, 24.0);
  spec.star_tracker.outages = {{HoursToSeconds(12.0), HoursToSeconds(13.0)}};
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
  int checked = 0, outside = 0, autonomous_checked = 0, autonomous_outside = 0;
  int overconfident_outside = 0;
  double worst_ratio = 0.0;
  for (size_t i = 0; i < sim->recording.frames.size(); ++i) {
    auto report = session.AddFrame(sim->recording.frames[i]);
    ASSERT_THAT(report, IsOk());
    if (sim->recording.frames[i].time - spec.start < absl::Hours(2)) continue;
    ASSERT_TRUE(report->attitude.valid) << report->attitude.invalid_reason;
    // Error about body axes: Log(q_est^-1 q_true) (conventions.h: error = true - estimate).
    const Eigen::Vector3d e_b =
        LogQuaternion(report->attitude.q_in_b.conjugate() * sim->truth[i].q_in_b);
    bool out = false, out_overconfident = false;
    for (int k = 0; k < 3; ++k) {
      const double ratio = std::abs(e_b(k)) / report->attitude.sigma_b(k);
      worst_ratio = std::max(worst_ratio, ratio);
      out = out || ratio > 3.0;
      // Negative control: the envelope of a filter whose variance is 1.5x too small.
      out_overconfident = out_overconfident || ratio * std::sqrt(1.5) > 3.0;
    }
    overconfident_outside += out_overconfident ? 1 : 0;
    ++checked;
    outside += out ? 1 : 0;
    if (report->state == SessionState::kAutonomous) {
      ++autonomous_checked;
      autonomous_outside += out ? 1 : 0;
    }
  }
  std::printf("attitude: %d of %d steps outside 3 sigma (worst %.1f sigma; %d with a 1.5x "
              "overconfident envelope); autonomous: %d of %d\n",
              outside, checked, worst_ratio, overconfident_outside, autonomous_outside,
              autonomous_checked);
  EXPECT_GE(autonomous_checked, 55) << "the outage must put the session in AUTONOMOUS";
  EXPECT_LE(outside, checked / 50);
  EXPECT_GT(overconfident_outside, checked / 50) << "the bound must reject a 1.5x overconfident envelope";
  EXPECT_LE(autonomous_outside, 1);
  for (const GyroEstimate& g : session.Gyros()) {
    const Eigen::Vector3d truth = spec.gyros[g.id - 1].misalignment_b;
    for (int k = 0; k < 3; ++k) {
      EXPECT_LE(std::abs(g.misalignment_b(k) - truth(k)), 3.0 * g.misalignment_sigma_b(k))
          << "gyro " << g.id << " axis " << k;
    }
  }
}

TEST(Session, CheckpointResumesBitForBit) {
  const SimulationSpec spec = PaperFlight(8, 6.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const auto& frames = sim->recording.frames;
  EstimationSession straight = *EstimationSession::Create(spec.config, Model("10+11"));
  EstimationSession first = straight;
  for (size_t i = 0; i < frames.size(); ++i) ASSERT_THAT(straight.AddFrame(frames[i]), IsOk());
  const size_t half = frames.size() / 2;
  for (size_t i = 0; i < half; ++i) ASSERT_THAT(first.AddFrame(frames[i]), IsOk());
  auto resumed = EstimationSession::FromCheckpoint(spec.config, Model("10+11"), first.ExportCheckpoint());
  ASSERT_THAT(resumed, IsOk());
  for (size_t i = half; i < frames.size(); ++i) ASSERT_THAT(resumed->AddFrame(frames[i]), IsOk());
  EXPECT_EQ(resumed->ExportCheckpoint().values, straight.ExportCheckpoint().values);
  // A checkpoint of another model does not fit.
  EXPECT_THAT(EstimationSession::FromCheckpoint(spec.config, Model("1"), first.ExportCheckpoint()),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("checkpoint")));
  SessionCheckpoint truncated = first.ExportCheckpoint();
  truncated.values.pop_back();
  EXPECT_THAT(EstimationSession::FromCheckpoint(spec.config, Model("10+11"), truncated),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("checkpoint")));
}

// A routine start: the first frames carry no valid star-tracker attitude, so the session is not
// initialised when its checkpoint is taken. Restoring it must work (it once read the empty
// covariance and crashed every later start of the service).
// A checkpoint whose values decode but name what the session does not have is DataLoss, never a
// crash later (the service then rebuilds the session from its archive). Value indices per the
// version-1 layout in session_checkpoint.cc: 14-15 working pair, 18 state.
TEST(Session, CheckpointNamingMissingGyrosOrNonIntegersIsDataLoss) {
  const SimulationSpec spec = PaperFlight(10, 1.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
  for (const TelemetryFrame& f : sim->recording.frames) ASSERT_THAT(session.AddFrame(f), IsOk());
  ASSERT_TRUE(session.initialized());
  const SessionCheckpoint good = session.ExportCheckpoint();
  ASSERT_THAT(EstimationSession::FromCheckpoint(spec.config, Model("10+11"), good), IsOk());
  auto with = [&](size_t index, double value) {
    SessionCheckpoint c = good;
    c.values[index] = value;
    return EstimationSession::FromCheckpoint(spec.config, Model("10+11"), c).status();
  };
  EXPECT_THAT(with(14, 7), StatusIs(absl::StatusCode::kDataLoss, HasSubstr("working pair")));
  EXPECT_THAT(with(15, good.values[14]),
              StatusIs(absl::StatusCode::kDataLoss, HasSubstr("working pair")));
  EXPECT_THAT(with(18, std::nan("")), StatusIs(absl::StatusCode::kDataLoss, HasSubstr("integer")));
  EXPECT_THAT(with(18, 1e300), StatusIs(absl::StatusCode::kDataLoss, HasSubstr("integer")));
  EXPECT_THAT(with(18, 42), StatusIs(absl::StatusCode::kDataLoss, HasSubstr("session state")));
}

TEST(Session, CheckpointBeforeInitialisationRestoresAndResumesBitForBit) {
  const SimulationSpec spec = PaperFlight(9, 2.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  std::vector<TelemetryFrame> frames = sim->recording.frames;
  for (size_t i = 0; i < 5; ++i) frames[i].star_tracker.reset();
  EstimationSession straight = *EstimationSession::Create(spec.config, Model("10+11"));
  EstimationSession first = straight;
  for (const TelemetryFrame& f : frames) ASSERT_THAT(straight.AddFrame(f), IsOk());
  for (size_t i = 0; i < 5; ++i) ASSERT_THAT(first.AddFrame(frames[i]), IsOk());
  ASSERT_FALSE(first.initialized());
  auto resumed =
      EstimationSession::FromCheckpoint(spec.config, Model("10+11"), first.ExportCheckpoint());
  ASSERT_THAT(resumed, IsOk());
  EXPECT_FALSE(resumed->initialized());
  for (size_t i = 5; i < frames.size(); ++i) ASSERT_THAT(resumed->AddFrame(frames[i]), IsOk());
  EXPECT_TRUE(resumed->initialized());
  EXPECT_EQ(resumed->ExportCheckpoint().values, straight.ExportCheckpoint().values);
}

TEST(Session, FrameNotAfterThePreviousIsOutOfRange) {
  const SimulationSpec spec = PaperFlight(2, 0.5);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
  ASSERT_THAT(session.AddFrame(sim->recording.frames[0]), IsOk());
  ASSERT_THAT(session.AddFrame(sim->recording.frames[1]), IsOk());
  const auto before = session.ExportCheckpoint().values;
  EXPECT_THAT(session.AddFrame(sim->recording.frames[1]),
              StatusIs(absl::StatusCode::kOutOfRange, HasSubstr("not after")));
  EXPECT_EQ(session.ExportCheckpoint().values, before);  // unchanged
}

TEST(Offline, GapWithAnInvalidConfigurationReturnsTheErrorNamingTheField) {
  const SimulationSpec spec = PaperFlight(2, 1.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  SpacecraftConfig bad = spec.config;
  bad.working_pair = {1, 9};
  EXPECT_THAT(RunGap(bad, Model("10+11"), sim->recording.frames,
                     sim->recording.frames[30].time),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("workingPair")));
}

TEST(Session, PredictionEnvelopeCoversTheTruthAcrossAGap) {
  // Calibrate 10 h, then predict 6 h ahead along the true attitude profile: the predicted spin
  // axes stay within 3 sigma of the true ones and the envelope grows with time.
  const SimulationSpec spec = PaperFlight(4, 16.0);
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const size_t calibrated = 600;
  const std::vector<TelemetryFrame> head(sim->recording.frames.begin(),
                                         sim->recording.frames.begin() + calibrated + 1);
  EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
  ASSERT_THAT(RunCalibration(spec.config, Model("10+11"), head, {}, &session), IsOk());
  std::vector<absl::Time> times;
  for (size_t i = calibrated + 1; i < sim->truth.size(); ++i) times.push_back(sim->truth[i].time);
  auto predicted = session.Predict(times, spec.profile.get(), spec.start);
  ASSERT_THAT(predicted, IsOk());
  ASSERT_EQ(predicted->size(), times.size());
  EXPECT_GT(predicted->back().attitude.sigma_b.norm(), 2.0 * predicted->front().attitude.sigma_b.norm());
  for (size_t k = 0; k < predicted->size(); k += 30) {
    const TruthSample& truth = sim->truth[calibrated + 1 + k];
    for (const auto& [id, h_in] : (*predicted)[k].h_in) {
      const double err = (h_in - truth.gyros[id - 1]->h_in).norm();
      // Envelope of one axis from the attitude sigma (an upper bound of the axis sigma is the
      // attitude sigma's norm: the pair attitude is built from these axes).
      EXPECT_LE(err, 3.0 * (*predicted)[k].attitude.sigma_b.norm() + ArcsecToRad(3.0))
          << "gyro " << id << " at " << k << " min";
    }
  }
  // Times not after the last frame are refused.
  EXPECT_THAT(session.Predict({head.back().time}, nullptr, spec.start),
              StatusIs(absl::StatusCode::kOutOfRange, HasSubstr("prediction time")));
}

}  // namespace
}  // namespace esg::estimator
