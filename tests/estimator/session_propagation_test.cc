// Integration substeps of the propagation (estimator/session_propagation.cc) bounded by the
// motion over an interval (SessionOptions::Substeps::kMotionBounded, docs/decisions.md D120)
// against the fixed 8 Hz reference: on a short flight of every simulator profile (inertial,
// orbital, calibration, mixed, and slews: inertial holds joined by fast eigen-axis slews) the
// attitude at every frame and the free coefficients at the end within 0.01 of the 8 Hz run's
// 1-sigma, with the same events at the same frames; the substep count across a jump of a gyro's
// readings and across a 7-day gap without telemetry.
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "estimator/attitude_profile.h"
#include "estimator/calibration_model.h"
#include "estimator/frame_gap.h"
#include "estimator/random.h"
#include "estimator/rotation.h"
#include "estimator/session.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;

constexpr double kAgreementSigma = 0.01;
constexpr double kFlightHours = 12.0;  // covers mixed's orbital, calibration and inertial parts

// Inertial holds of 20 min joined by 2 min eigen-axis slews between attitudes drawn from the
// seed (up to 180 deg: up to 2.8 deg/s at the quintic's peak).
ProfilePtr Slews(double duration, uint64_t seed) {
  Rng rng(seed);
  std::vector<ProfileSegment> segments;
  const double hold_s = 1200.0;
  for (double t = 0.0; t < duration + hold_s; t += hold_s) {
    const Eigen::Vector3d axis = rng.UnitVector();
    const double angle = kPi * rng.Uniform(0.0, 1.0);
    segments.push_back({InertialHold(ExpQuaternion(angle * axis)), hold_s});
  }
  return *Sequence(segments, 120.0, "slews");
}

ProfilePtr Profile(const std::string& name, double duration, uint64_t seed) {
  if (name == "slews") return Slews(duration, seed);
  return *MakeNamedProfile(name, duration, seed);
}

struct FilterRun {
  std::vector<StepReport> reports;
  std::vector<GyroEstimate> gyros;
  long long substeps = 0;  // summed over the frames
};

FilterRun Calibrate(const SpacecraftConfig& config, const SessionOptions& options,
                    const std::vector<TelemetryFrame>& frames) {
  FilterRun run;
  auto created = EstimationSession::Create(config, options);
  EXPECT_THAT(created, IsOk());
  if (!created.ok()) return run;
  EstimationSession session = *std::move(created);
  for (const TelemetryFrame& frame : frames) {
    auto report = session.AddFrame(frame);
    EXPECT_THAT(report, IsOk());
    if (!report.ok()) break;
    run.substeps += session.last_propagation_substeps();
    run.reports.push_back(*std::move(report));
  }
  run.gyros = session.Gyros();
  return run;
}

SessionOptions Options(SessionOptions::Substeps substeps) {
  SessionOptions options;
  options.model = *ParseModel("10+11");
  options.substeps = substeps;
  return options;
}

class SubstepsAgreement : public ::testing::TestWithParam<std::string> {};

TEST_P(SubstepsAgreement, AttitudeAndCoefficientsWithinOneHundredthSigmaOf8Hz) {
  SimulationSpec spec = testing::PaperFlight(7, kFlightHours);
  spec.profile = Profile(GetParam(), spec.duration, 7);
  const absl::StatusOr<SimulationResult> sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const SpacecraftConfig config = testing::PaperConfig();
  const std::vector<TelemetryFrame>& frames = sim->recording.frames;
  const FilterRun reference =
      Calibrate(config, Options(SessionOptions::Substeps::kFixedRate), frames);
  const FilterRun bounded =
      Calibrate(config, Options(SessionOptions::Substeps::kMotionBounded), frames);
  ASSERT_EQ(reference.reports.size(), frames.size());
  ASSERT_EQ(bounded.reports.size(), frames.size());

  // The attitude at every frame, about each body axis in units of the 8 Hz 1-sigma; the same
  // events at the same frames.
  double worst_attitude_sigma = 0.0;
  int valid_frames = 0;
  for (size_t k = 0; k < frames.size(); ++k) {
    const StepReport& a = reference.reports[k];
    const StepReport& b = bounded.reports[k];
    ASSERT_EQ(a.events.size(), b.events.size()) << "frame " << k;
    for (size_t e = 0; e < a.events.size(); ++e) {
      EXPECT_EQ(a.events[e].kind, b.events[e].kind) << "frame " << k;
      EXPECT_EQ(a.events[e].subsystem, b.events[e].subsystem) << "frame " << k;
    }
    EXPECT_EQ(a.attitude.valid, b.attitude.valid) << "frame " << k;
    EXPECT_EQ(a.star_tracker_used, b.star_tracker_used) << "frame " << k;
    if (!a.attitude.valid || !b.attitude.valid) continue;
    ++valid_frames;
    const Eigen::Vector3d diff_b = LogQuaternion(a.attitude.q_in_b.conjugate() * b.attitude.q_in_b);
    for (int i = 0; i < 3; ++i) {
      ASSERT_GT(a.attitude.sigma_b(i), 0.0);
      worst_attitude_sigma =
          std::max(worst_attitude_sigma, std::abs(diff_b(i)) / a.attitude.sigma_b(i));
    }
  }
  EXPECT_GT(valid_frames, static_cast<int>(frames.size()) / 2);
  EXPECT_LT(worst_attitude_sigma, kAgreementSigma);

  // Every free coefficient at the end, in units of its 8 Hz 1-sigma.
  ASSERT_EQ(reference.gyros.size(), bounded.gyros.size());
  double worst_coefficient_sigma = 0.0;
  int free_coefficients = 0;
  for (size_t g = 0; g < reference.gyros.size(); ++g) {
    const DriftVector ref = reference.gyros[g].coefficients.AsVector();
    const DriftVector sigma = reference.gyros[g].sigma.AsVector();
    const DriftVector got = bounded.gyros[g].coefficients.AsVector();
    for (int c = 0; c < kNumDriftCoefficients; ++c) {
      if (!(sigma(c) > 0.0)) continue;
      ++free_coefficients;
      worst_coefficient_sigma =
          std::max(worst_coefficient_sigma, std::abs(got(c) - ref(c)) / sigma(c));
    }
  }
  EXPECT_GT(free_coefficients, 0);
  EXPECT_LT(worst_coefficient_sigma, kAgreementSigma);

  // Fewer substeps than 8 Hz: at most the fixed rate's count, which is 480 per 60 s frame.
  EXPECT_LT(bounded.substeps, reference.substeps);
  std::printf("%s: attitude %.2e sigma, coefficients %.2e sigma, substeps %lld of 8 Hz's %lld\n",
              GetParam().c_str(), worst_attitude_sigma, worst_coefficient_sigma, bounded.substeps,
              reference.substeps);
}

INSTANTIATE_TEST_SUITE_P(Profiles, SubstepsAgreement,
                         ::testing::Values("inertial", "orbital", "calibration", "mixed", "slews"),
                         [](const auto& info) { return info.param; });

// A jump of one gyro's readings (a readout fault of 2 deg) and a 7-day gap without telemetry:
// the session neither fails nor takes more substeps than the bound of D120 allows: the largest
// turn over the interval (at most pi for the body and a reading, plus the drift's turn) over
// max_substep_turn_deg, never more than the fixed rate's count.
TEST(SubstepsBound, AReadingJumpAndASevenDayGapTakeBoundedSubsteps) {
  // An inertial hold: the jump is the interval's largest turn.
  SimulationSpec spec = testing::PaperFlight(3, 6.0, "inertial");
  const absl::StatusOr<SimulationResult> sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  const SpacecraftConfig config = testing::PaperConfig();
  SessionOptions options = Options(SessionOptions::Substeps::kMotionBounded);
  auto created = EstimationSession::Create(config, options);
  ASSERT_THAT(created, IsOk());
  EstimationSession session = *std::move(created);
  std::vector<TelemetryFrame> frames = sim->recording.frames;
  const size_t jump_at = frames.size() / 2;
  const Eigen::Matrix3d jump =
      ExpQuaternion(DegToRad(2.0) * Eigen::Vector3d::UnitX()).toRotationMatrix();
  for (size_t k = jump_at; k < frames.size(); ++k) {
    if (frames[k].gyros[0].has_value()) frames[k].gyros[0]->h_k = jump * frames[k].gyros[0]->h_k;
  }
  const double bound_rad = options.max_substep_turn_deg * kRadPerDeg;
  int jump_substeps = 0;
  for (size_t k = 0; k < frames.size(); ++k) {
    ASSERT_THAT(session.AddFrame(frames[k]), IsOk()) << "frame " << k;
    if (k == jump_at) jump_substeps = session.last_propagation_substeps();
  }
  // At least the jump's 2 / 0.5 = 4 substeps; at most pi / 0.5 = 360, the largest turn a body
  // attitude or a reading can show between two frames (the attitude pair's attitude, gyro 1 in it,
  // turns by more than the reading where the jump is not along the pair's plane).
  EXPECT_GE(jump_substeps, static_cast<int>(std::ceil(DegToRad(2.0) / bound_rad - 1e-9)));
  EXPECT_LE(jump_substeps, static_cast<int>(std::ceil(kPi / bound_rad)));

  // The next frame 7 days later (the service's largest frame gap, frame_gap.h), its readings
  // those of the last frame turned by a body rotation of 170 deg.
  TelemetryFrame after_gap = frames.back();
  after_gap.time = frames.back().time + kMaxFrameGap;
  const Eigen::Matrix3d turn =
      ExpQuaternion(DegToRad(170.0) * Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
  for (auto& reading : after_gap.gyros) {
    if (reading.has_value()) reading->h_k = turn * reading->h_k;
  }
  ASSERT_THAT(session.AddFrame(after_gap), IsOk());
  const int gap_substeps = session.last_propagation_substeps();
  double drift_rad_s = 0.0;
  for (const GyroEstimate& g : session.Gyros()) {
    // The model's drift bounded by the sum of its coefficients' magnitudes (|h| = 1), plus the
    // residual drift of eq. (11).
    drift_rad_s =
        std::max(drift_rad_s, g.coefficients.AsVector().cwiseAbs().sum() + g.residual_drift.norm());
  }
  const double gap_s = absl::ToDoubleSeconds(kMaxFrameGap);
  const double bound = std::ceil(std::max(kPi, drift_rad_s * gap_s) / bound_rad);
  EXPECT_GE(gap_substeps, 1);
  EXPECT_LE(gap_substeps, bound);
  EXPECT_LT(gap_substeps, gap_s * config.filter.integration_rate_hz);
  std::printf(
      "reading jump of 2 deg: %d substeps; 7-day gap: %d substeps (bound %.0f, 8 Hz %.0f)\n",
      jump_substeps, gap_substeps, bound, gap_s * config.filter.integration_rate_hz);
}

TEST(SubstepsBound, ATurnBoundOutsideItsRangeIsRefused) {
  SessionOptions options = Options(SessionOptions::Substeps::kMotionBounded);
  options.max_substep_turn_deg = 0.0;
  EXPECT_FALSE(EstimationSession::Create(testing::PaperConfig(), options).ok());
  options.max_substep_turn_deg = 11.0;
  EXPECT_FALSE(EstimationSession::Create(testing::PaperConfig(), options).ok());
  options.max_substep_turn_deg = 0.5;
  EXPECT_THAT(EstimationSession::Create(testing::PaperConfig(), options), IsOk());
}

}  // namespace
}  // namespace esg::estimator
