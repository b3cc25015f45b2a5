// The estimation session (issue: calibration EKF, fault rejection, long-gap prediction) on
// seeded simulated flights with the paper's calibration profile (section 3): 60 s telemetry,
// 8 Hz integration, star tracker 5/5/30 arcsec, truth with rotor-displacement terms of paper
// size (C ~ 0.05-0.2 deg/h).
#include "estimator/session.h"

#include <cmath>

#include "Eigen/Eigenvalues"
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
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;

// A flight: the configured (a-priori) model is wrong by ~0.1 deg/h in k0 and knows nothing of
// the rotor displacement; gyro 2 is misaligned by tens of arcsec.
SimulationSpec PaperFlight(uint64_t seed, double hours, const char* profile = "calibration") {
  SimulationSpec spec;
  spec.config = testing::PaperConfig();
  spec.duration = HoursToSeconds(hours);
  spec.seed = seed;
  spec.profile = *MakeNamedProfile(profile, spec.duration, seed);
  for (int i = 0; i < 4; ++i) {
    DriftCoefficients d = spec.config.gyros[i].model;
    d.k0 += DegPerHourToRadPerSec(0.1 * (i % 2 ? 1 : -1));
    spec.gyros[i].drift = d;
  }
  spec.gyros[0].rotor_displacement_k = Eigen::Vector3d(1.0e-6, -1.5e-6, 0.8e-6);
  spec.gyros[1].rotor_displacement_k = Eigen::Vector3d(-0.7e-6, 0.5e-6, 1.2e-6);
  spec.gyros[2].rotor_displacement_k = Eigen::Vector3d(0.5e-6, 1.0e-6, -1.0e-6);
  spec.gyros[1].misalignment_b = Eigen::Vector3d(ArcsecToRad(20), ArcsecToRad(-30), ArcsecToRad(15));
  return spec;
}

SessionOptions Model(const char* name) {
  SessionOptions o;
  o.model = *ParseModel(name);
  return o;
}

TEST(CalibrationModel, ParsesModelStringsAndFreesSigmaPositiveTerms) {
  auto m = ParseModel("10+11");
  ASSERT_THAT(m, IsOk());
  EXPECT_TRUE(m->k0 && m->c1c2 && m->random_walk);
  EXPECT_EQ(m->Name(), "10+11");
  EXPECT_EQ(ParseModel("1")->Name(), "1");
  EXPECT_FALSE(ParseModel("1")->c1c2);
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
  // The transient is over when every free coefficient's sigma has fallen below a quarter of its
  // prior and its estimate is within 3 sigma of the truth. The paper reports 6-8 h; by 8 h of the
  // calibration profile (orientation changed every 3 h) it must be over. The ratios sqrt(P/P0)
  // themselves are reported in README (bench/experiment command there).
  for (uint64_t seed : {11, 12, 13}) {
    const SimulationSpec spec = PaperFlight(seed, 8.0);
    auto sim = Simulate(spec);
    ASSERT_THAT(sim, IsOk());
    EstimationSession session = *EstimationSession::Create(spec.config, Model("10+11"));
    auto result = RunCalibration(spec.config, Model("10+11"), sim->recording.frames, {}, &session);
    ASSERT_THAT(result, IsOk());
    for (const GyroEstimate& g : result->gyros) {
      for (const auto& [index, ratio] : session.RelativeSigma(g.id)) {
        EXPECT_LE(ratio, 0.25) << "seed " << seed << " gyro " << g.id << " " << CoefficientName(index);
      }
      const DriftVector truth = sim->true_coefficients[g.id - 1]->AsVector();
      const DriftVector est = g.coefficients.AsVector(), sigma = g.sigma.AsVector();
      for (int i = 0; i < kNumDriftCoefficients; ++i) {
        if (sigma(i) > 0.0) {
          EXPECT_LE(std::abs(est(i) - truth(i)), 3.0 * sigma(i)) << "seed " << seed << " " << CoefficientName(i);
        }
      }
    }
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
    for (size_t i = 0; i < sim->recording.frames.size(); ++i) {
      auto report = session.AddFrame(sim->recording.frames[i]);
      ASSERT_THAT(report, IsOk());
      if (i <= 60 || !report->star_tracker_used) continue;
      ASSERT_EQ(report->star_tracker_innovation.size(), 6);
      sum += report->star_tracker_nis;
      ++n;
    }
    ASSERT_GT(n, 1300);
    const double mean = sum / n;
    const double bound = 3.3 * std::sqrt(12.0 / n);
    EXPECT_NEAR(mean, 6.0, bound) << "seed " << seed << " over " << n << " steps";
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
  EXPECT_EQ(session.state(), SessionState::kFaulted);
  // Output on the reserve pair stays accurate.
  const Eigen::Quaterniond q_true = sim->truth.back().q_in_b;
  EXPECT_LT(RotationAngle(session.CurrentAttitude().q_in_b, q_true), ArcsecToRad(60));
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
