// Seeded simulator (estimator/simulator.h): reproducibility, readings against the truth, eq. (3)
// voltages, spin-axis motion against an independent integration of DESIGN §3, star-tracker noise,
// outliers, outages, latency and invalid flags, faults, validation.
#include "estimator/simulator.h"

#include <algorithm>
#include <cmath>

#include "estimator/drift_model.h"
#include "estimator/random.h"
#include "estimator/rotation.h"
#include "estimator/triad.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/quaternion_matchers.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using ::esg::testing::IsNearQuaternion;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;

SpacecraftConfig TestConfig() {
  SpacecraftConfig c;
  c.spacecraft_id = "TEST-1";
  const Vector3d mountings[4] = {Vector3d(0, 0, 0), Vector3d(0.0, DegToRad(90.0), 0.0),
                                 Vector3d(DegToRad(-90.0), 0.0, 0.0), Vector3d(0.5, 0.6, -0.7)};
  for (int id = 1; id <= 4; ++id) {
    GyroConfig g;
    g.id = id;
    g.C_b_k = ExpMatrix(mountings[id - 1]);
    g.model.k0 = DegPerHourToRadPerSec(0.2 + 0.05 * id);
    g.model.C1 = DegPerHourToRadPerSec(0.05) * Vector3d(1.0, -0.5, 0.2);
    g.model.C2 = DegPerHourToRadPerSec(0.03) * Vector3d(-0.3, 0.4, 1.0);
    c.gyros.push_back(g);
  }
  c.working_pair = {1, 2};
  c.reserve_pair = {1, 3};
  c.star_tracker.noise = ArcsecToRad(1.0) * Vector3d(5, 5, 30);
  c.readout_noise = ArcsecToRad(3.0);
  c.random_walk = DegPerHourSqrtHourToSi(0.0015);
  return c;
}

SimulationSpec TestSpec(double hours, const std::string& profile = "calibration") {
  SimulationSpec spec;
  spec.config = TestConfig();
  spec.duration = HoursToSeconds(hours);
  spec.profile = *MakeNamedProfile(profile, spec.duration);
  spec.seed = 42;
  return spec;
}

SimulationResult RunSimulation(const SimulationSpec& spec) {
  auto result = Simulate(spec);
  EXPECT_THAT(result, IsOk());
  return result.ok() ? *std::move(result) : SimulationResult{};
}

// Exact (bitwise) equality of two recordings.
bool SameRecording(const Recording& a, const Recording& b) {
  if (a.metadata != b.metadata || a.frames.size() != b.frames.size()) return false;
  for (size_t i = 0; i < a.frames.size(); ++i) {
    const TelemetryFrame& fa = a.frames[i];
    const TelemetryFrame& fb = b.frames[i];
    if (fa.time != fb.time) return false;
    for (int g = 0; g < kMaxGyros; ++g) {
      if (fa.gyros[g].has_value() != fb.gyros[g].has_value()) return false;
      if (!fa.gyros[g]) continue;
      if (fa.gyros[g]->h_k != fb.gyros[g]->h_k) return false;
      if (fa.gyros[g]->u_k_mv.has_value() != fb.gyros[g]->u_k_mv.has_value()) return false;
      if (fa.gyros[g]->u_k_mv && *fa.gyros[g]->u_k_mv != *fb.gyros[g]->u_k_mv) return false;
    }
    if (fa.star_tracker.has_value() != fb.star_tracker.has_value()) return false;
    if (fa.star_tracker) {
      if (fa.star_tracker->q_in_b.coeffs() != fb.star_tracker->q_in_b.coeffs()) return false;
      if (fa.star_tracker->valid != fb.star_tracker->valid) return false;
    }
  }
  return true;
}

TEST(Simulator, SameSeedGivesIdenticalRecordingDifferentSeedDoesNot) {
  SimulationSpec spec = TestSpec(2.0);
  spec.star_tracker.outlier_probability = 0.1;
  spec.star_tracker.outlier_size = ArcminToRad(2.0);
  const SimulationResult a = RunSimulation(spec);
  const SimulationResult b = RunSimulation(spec);
  ASSERT_EQ(a.recording.frames.size(), 121u);
  EXPECT_TRUE(SameRecording(a.recording, b.recording));
  spec.seed = 43;
  const SimulationResult c = RunSimulation(spec);
  EXPECT_FALSE(SameRecording(a.recording, c.recording));
  EXPECT_NE(a.recording.frames[5].gyros[0]->h_k, c.recording.frames[5].gyros[0]->h_k);
  EXPECT_EQ(a.recording.metadata.at("spacecraft_id"), "TEST-1");
  EXPECT_EQ(a.recording.metadata.at("seed"), "42");
  EXPECT_THAT(a.recording.metadata.at("profile"), HasSubstr("calibration"));
}

TEST(Simulator, FramesAreEveryTelemetryStepFromStart) {
  SimulationSpec spec = TestSpec(1.0);
  spec.telemetry_step = 45.0;
  spec.integration_rate_hz = 10.0;  // dt not a power of two: partial steps must line up
  const SimulationResult r = RunSimulation(spec);
  ASSERT_EQ(r.recording.frames.size(), 81u);  // 0, 45, ..., 3600
  for (size_t m = 0; m < r.recording.frames.size(); ++m) {
    EXPECT_EQ(r.recording.frames[m].time, spec.start + absl::Seconds(45.0 * m));
  }
  ASSERT_EQ(r.truth.size(), r.recording.frames.size());
}

TEST(Simulator, ByDefaultGyrosOneToThreeRunAndTheSpareIsOff) {
  const SimulationResult r = RunSimulation(TestSpec(0.5));
  for (const TelemetryFrame& f : r.recording.frames) {
    EXPECT_TRUE(f.gyros[0] && f.gyros[1] && f.gyros[2]);
    EXPECT_FALSE(f.gyros[3].has_value());
    EXPECT_TRUE(f.star_tracker.has_value() && f.star_tracker->valid);
  }
  EXPECT_TRUE(r.true_coefficients[2].has_value());
  EXPECT_FALSE(r.true_coefficients[3].has_value());
  SimulationSpec spec = TestSpec(0.5);
  spec.gyros[3].running = true;
  spec.gyros[1].running = false;
  const SimulationResult r2 = RunSimulation(spec);
  EXPECT_TRUE(r2.recording.frames[3].gyros[3].has_value());
  EXPECT_FALSE(r2.recording.frames[3].gyros[1].has_value());
}

TEST(Simulator, ReadingsAgreeWithTruthAttitudeWithinReadoutNoise) {
  SimulationSpec spec = TestSpec(6.0);
  spec.gyros[1].misalignment_b = ArcsecToRad(1.0) * Vector3d(20, -10, 30);
  const SimulationResult r = RunSimulation(spec);
  const double sigma = spec.config.readout_noise;
  const Matrix3d C_b_k2_true =
      ExpMatrix(spec.gyros[1].misalignment_b) * spec.config.FindGyro(2)->C_b_k;
  double max_pair_error = 0.0;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const TruthSample& t = r.truth[m];
    const TelemetryFrame& f = r.recording.frames[m];
    const Matrix3d C_b_in = t.q_in_b.toRotationMatrix().transpose();
    ASSERT_TRUE(t.gyros[1].has_value());
    EXPECT_LT((t.gyros[1]->C_b_k - C_b_k2_true).norm(), 1e-15);
    for (int g = 0; g < 3; ++g) {
      // C_b_k h_k(measured) against C_b_in h_in(true): within 6 sigma of the 2-D readout noise.
      const Vector3d h_b_meas = t.gyros[g]->C_b_k * f.gyros[g]->h_k;
      const Vector3d h_b_true = C_b_in * t.gyros[g]->h_in;
      EXPECT_LT(std::acos(std::min(1.0, h_b_meas.dot(h_b_true))), 6.0 * sigma) << "frame " << m;
      EXPECT_LT((t.gyros[g]->h_k - t.gyros[g]->C_b_k.transpose() * h_b_true).norm(), 1e-14);
    }
    // Pair attitude from the true inertial axes and the measured body axes.
    auto q = PairAttitude(t.gyros[0]->h_in, t.gyros[1]->h_in, t.gyros[0]->C_b_k * f.gyros[0]->h_k,
                          t.gyros[1]->C_b_k * f.gyros[1]->h_k);
    ASSERT_THAT(q, IsOk());
    max_pair_error = std::max(max_pair_error, RotationAngle(*q, t.q_in_b));
  }
  EXPECT_LT(max_pair_error, 20.0 * sigma);
  EXPECT_GT(max_pair_error, 0.1 * sigma);  // the noise is really there
}

TEST(Simulator, ReadoutNoiseHasConfiguredSigma) {
  SimulationSpec spec = TestSpec(24.0, "inertial");
  spec.telemetry_step = 120.0;
  spec.integration_rate_hz = 1.0;
  const SimulationResult r = RunSimulation(spec);
  // Angle between measured and true h_k: sum of two squared N(0, sigma^2) per frame, chi-square
  // with 2 N degrees of freedom (N = 721 frames, 3 gyros): bound +-5 sd of the chi-square.
  const double sigma = spec.config.readout_noise;
  double sum = 0.0;
  int dof = 0;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    for (int g = 0; g < 3; ++g) {
      const double angle = std::acos(
          std::min(1.0, r.truth[m].gyros[g]->h_k.dot(r.recording.frames[m].gyros[g]->h_k)));
      sum += angle * angle / (sigma * sigma);
      dof += 2;
    }
  }
  EXPECT_NEAR(sum, dof, 5.0 * std::sqrt(2.0 * dof));
}

TEST(Simulator, VoltagesMapBackToDisplacementThroughEq3) {
  SimulationSpec spec = TestSpec(4.0);
  const Vector3d displacement = kMetresPerUm * Vector3d(0.5, -1.0, 0.3);
  spec.gyros[1].rotor_displacement_k = displacement;
  const SimulationResult r = RunSimulation(spec);
  const SuspensionConfig& s = spec.config.suspension;
  const double sigma_v = spec.gyros[1].voltage_noise;
  // One volt of offset is k d0 / U0 = 30 um, so sigma 1 mV is 0.03 um.
  const double sigma_m =
      DisplacementFromOffsetVoltage(sigma_v, s.amplifier_gain, s.reference_voltage, s.gap);
  Vector3d mean = Vector3d::Zero();
  for (const TelemetryFrame& f : r.recording.frames) {
    const Vector3d u_mv = *f.gyros[1]->u_k_mv;
    Vector3d d;
    for (int axis = 0; axis < 3; ++axis) {
      d(axis) = DisplacementFromOffsetVoltage(u_mv(axis) * kVoltsPerMv, s.amplifier_gain,
                                              s.reference_voltage, s.gap);
    }
    EXPECT_LT((d - displacement).cwiseAbs().maxCoeff(), 6.0 * sigma_m);
    mean += d / static_cast<double>(r.recording.frames.size());
    // Gyro 1 has no displacement: its voltages are noise only.
    EXPECT_LT(f.gyros[0]->u_k_mv->cwiseAbs().maxCoeff(), 6.0 * sigma_v / kVoltsPerMv);
  }
  const double n = static_cast<double>(r.recording.frames.size());
  EXPECT_LT((mean - displacement).cwiseAbs().maxCoeff(), 5.0 * sigma_m / std::sqrt(n));
  // The displacement's C1, C2 are in the effective coefficients: paper sizes, collinear.
  const DriftCoefficients& c = *r.true_coefficients[1];
  const DriftCoefficients& model = spec.config.FindGyro(2)->model;
  const Vector3d dC1 = c.C1 - model.C1;
  const Vector3d dC2 = c.C2 - model.C2;
  const double size_um = displacement.norm() / kMetresPerUm;
  EXPECT_NEAR(RadPerSecToDegPerHour(dC1.norm()), (0.05 + 0.015) * size_um, 1e-12);
  EXPECT_NEAR(RadPerSecToDegPerHour(dC2.norm()), 5.0 * 0.015 * size_um, 1e-12);
  EXPECT_NEAR(dC1.normalized().dot(displacement.normalized()), 1.0, 1e-12);
  EXPECT_NEAR(dC2.normalized().dot(displacement.normalized()), -1.0, 1e-12);
}

// RK4 at 1 s of dh_in/dt = (C_in_b(t) C_b_k dw_k(h_k)) x h_in (DESIGN §3), independent of the
// simulator's midpoint/rotation stepping.
Vector3d IndependentSpinAxis(const SimulationSpec& spec, const DriftCoefficients& c,
                             const Matrix3d& C_b_k, Vector3d h, double t_end) {
  auto rate = [&](double t, const Vector3d& h_in) {
    const Matrix3d C_in_k = spec.profile->Attitude(t).toRotationMatrix() * C_b_k;
    const Vector3d h_k = C_in_k.transpose() * h_in.normalized();
    return Vector3d((C_in_k * DriftRate_k(c, h_k)).cross(h_in));
  };
  const double dt = 1.0;
  for (double t = 0.0; t < t_end - 1e-9; t += dt) {
    const Vector3d k1 = rate(t, h);
    const Vector3d k2 = rate(t + 0.5 * dt, h + 0.5 * dt * k1);
    const Vector3d k3 = rate(t + 0.5 * dt, h + 0.5 * dt * k2);
    const Vector3d k4 = rate(t + dt, h + dt * k3);
    h = (h + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)).normalized();
  }
  return h;
}

TEST(Simulator, TrueSpinAxisMovesAtTheDriftModelRate) {
  SimulationSpec spec = TestSpec(6.0);
  spec.config.random_walk = 0.0;
  // Large drift so the motion is far above the integration error: several deg/h.
  for (int g = 0; g < 3; ++g) {
    DriftCoefficients c;
    c.k0 = DegPerHourToRadPerSec(3.0);
    c.C1 = DegPerHourToRadPerSec(2.0) * Vector3d(0.3, -0.8, 0.5);
    c.C2 = DegPerHourToRadPerSec(1.0) * Vector3d(-0.6, 0.2, 0.7);
    c.mu = DegPerHourToRadPerSec(0.5) * Vector3d(1, -1, 0.5);
    c.nu = DegPerHourToRadPerSec(0.5) * Vector3d(0.2, 0.3, -0.5);
    spec.gyros[g].drift = c;
  }
  spec.gyros[2].rotor_displacement_k = kMetresPerUm * Vector3d(2.0, 1.0, -1.0);
  const SimulationResult r = RunSimulation(spec);
  for (int g = 0; g < 3; ++g) {
    const DriftCoefficients& c = *r.true_coefficients[g];
    const Matrix3d& C_b_k = r.truth[0].gyros[g]->C_b_k;
    const Vector3d h0 = r.truth[0].gyros[g]->h_in;
    const Vector3d expected = IndependentSpinAxis(spec, c, C_b_k, h0, spec.duration);
    const Vector3d got = r.truth.back().gyros[g]->h_in;
    EXPECT_GT(std::acos(h0.dot(got)), DegToRad(1.0)) << "gyro " << g + 1 << " barely moved";
    // Both integrators agree to ~2e-11 over 6 h (RK4 at 1 s vs midpoint rotations at 8 Hz); a
    // drift evaluated at the step start instead of the midpoint is off by far more.
    EXPECT_LT((got - expected).norm(), 1e-9) << "gyro " << g + 1;
    // Reported total drift equals the model at the true h_k (no random walk, no fault).
    for (const TruthSample& t : r.truth) {
      EXPECT_LT((t.gyros[g]->dw_k - DriftRate_k(c, t.gyros[g]->h_k)).norm(), 1e-20);
    }
  }
}

TEST(Simulator, RandomWalkSpreadsTheDriftAsConfigured) {
  // Zero model drift, random walk only: the drift vector in inertial axes after T has variance
  // q T per axis; over 3 gyros x 3 axes x 10 seeds (90 values) the chi-square sum stays near 90.
  double sum = 0.0;
  int n = 0;
  for (uint64_t seed = 1; seed <= 10; ++seed) {
    SimulationSpec spec = TestSpec(4.0, "inertial");
    spec.integration_rate_hz = 2.0;
    spec.telemetry_step = 600.0;
    spec.seed = seed;
    for (int g = 0; g < 3; ++g) spec.gyros[g].drift = DriftCoefficients{};
    const SimulationResult r = RunSimulation(spec);
    const TruthSample& last = r.truth.back();
    const Matrix3d C_in_b = last.q_in_b.toRotationMatrix();
    for (int g = 0; g < 3; ++g) {
      const Vector3d dw_in = C_in_b * last.gyros[g]->C_b_k * last.gyros[g]->dw_k;
      const double var = spec.config.random_walk * spec.config.random_walk * spec.duration;
      sum += dw_in.squaredNorm() / var;
      n += 3;
    }
  }
  // chi-square(90): mean 90, sd 13.4; +-5 sd.
  EXPECT_NEAR(sum, n, 5.0 * std::sqrt(2.0 * n));
}

TEST(Simulator, StarTrackerNoiseMatchesConfiguredSigmaPerAxis) {
  SimulationSpec spec = TestSpec(12.0, "inertial");
  spec.telemetry_step = 30.0;
  spec.integration_rate_hz = 1.0;
  const SimulationResult r = RunSimulation(spec);
  const Vector3d sigma = spec.config.star_tracker.noise;
  Vector3d sum_sq = Vector3d::Zero();
  double cross_xy = 0.0;
  const int n = static_cast<int>(r.truth.size());
  for (int m = 0; m < n; ++m) {
    const Quaterniond& q_meas = r.recording.frames[m].star_tracker->q_in_b;
    const Vector3d e_b = LogQuaternion(r.truth[m].q_in_b.conjugate() * q_meas);
    sum_sq += e_b.cwiseQuotient(sigma).cwiseAbs2();
    cross_xy += e_b.x() * e_b.y() / (sigma.x() * sigma.y());
  }
  // Per axis sum of n squared standard normals: chi-square(n), bound +-5 sd (n = 1441, seed 42).
  for (int axis = 0; axis < 3; ++axis) {
    EXPECT_NEAR(sum_sq(axis), n, 5.0 * std::sqrt(2.0 * n)) << "axis " << axis;
  }
  EXPECT_NEAR(cross_xy, 0.0, 5.0 * std::sqrt(static_cast<double>(n)));
}

TEST(Simulator, OutliersOutagesAndInvalidFlagsAsSpecified) {
  SimulationSpec base = TestSpec(12.0, "inertial");
  base.telemetry_step = 30.0;
  base.integration_rate_hz = 1.0;
  SimulationSpec spec = base;
  spec.star_tracker.outlier_probability = 0.05;
  spec.star_tracker.outlier_size = ArcminToRad(2.0);
  spec.star_tracker.outages = {{HoursToSeconds(3.0), HoursToSeconds(4.0)}};
  spec.star_tracker.invalid_probability = 0.02;
  const SimulationResult r = RunSimulation(spec);
  const SimulationResult clean = RunSimulation(base);
  const int n = static_cast<int>(r.truth.size());
  int outliers = 0, invalid = 0, outage_frames = 0;
  const double noise_max = 6.0 * spec.config.star_tracker.noise.maxCoeff();
  for (int m = 0; m < n; ++m) {
    const double t = 30.0 * m;
    const TelemetryFrame& f = r.recording.frames[m];
    const bool in_outage = t >= HoursToSeconds(3.0) && t < HoursToSeconds(4.0);
    EXPECT_EQ(f.star_tracker.has_value(), !in_outage) << "t = " << t;
    // Adding outliers, outages and invalid flags does not change the gyro noise.
    for (int g = 0; g < 3; ++g) {
      EXPECT_EQ(f.gyros[g]->h_k, clean.recording.frames[m].gyros[g]->h_k);
    }
    if (in_outage) {
      ++outage_frames;
      EXPECT_FALSE(r.truth[m].star_tracker_outlier);
      continue;
    }
    const double angle = RotationAngle(f.star_tracker->q_in_b, r.truth[m].q_in_b);
    if (r.truth[m].star_tracker_outlier) {
      ++outliers;
      const double size = r.truth[m].star_tracker_outlier_angle;
      EXPECT_GE(size, ArcminToRad(2.0));
      EXPECT_LE(size, ArcminToRad(6.0));
      EXPECT_NEAR(angle, size, noise_max);
    } else {
      EXPECT_LT(angle, noise_max);
      // Without an outlier the sample equals the clean run's (same noise stream).
      EXPECT_THAT(f.star_tracker->q_in_b,
                  IsNearQuaternion(clean.recording.frames[m].star_tracker->q_in_b, 1e-15));
    }
    if (!f.star_tracker->valid) ++invalid;
  }
  EXPECT_EQ(outage_frames, 120);
  // Binomial counts within 5 sd of their means.
  const double available = n - outage_frames;
  EXPECT_NEAR(outliers, 0.05 * available, 5.0 * std::sqrt(available * 0.05 * 0.95));
  EXPECT_NEAR(invalid, 0.02 * available, 5.0 * std::sqrt(available * 0.02 * 0.98));
  EXPECT_GT(outliers, 0);
  EXPECT_GT(invalid, 0);
}

TEST(Simulator, LatencyShiftsTheQuaternionByRateTimesLatency) {
  SimulationSpec spec = TestSpec(1.0, "orbital");
  spec.star_tracker.noise = Vector3d::Zero();
  spec.star_tracker.latency = 0.3;
  const SimulationResult r = RunSimulation(spec);
  const double rate = 2.0 * kPi / OrbitalOptions{}.period;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const Quaterniond& q = r.recording.frames[m].star_tracker->q_in_b;
    EXPECT_NEAR(RotationAngle(q, r.truth[m].q_in_b), rate * 0.3, 1e-12);
    const double t = 60.0 * m;
    EXPECT_THAT(q, IsNearQuaternion(spec.profile->Attitude(t - 0.3), 1e-12));
    EXPECT_GE(q.w(), 0.0);  // canonical at the output edge
  }
}

TEST(Simulator, StarTrackerMisalignmentIsABodyRotation) {
  SimulationSpec spec = TestSpec(1.0);
  spec.star_tracker.noise = Vector3d::Zero();
  spec.star_tracker.misalignment_b = ArcsecToRad(1.0) * Vector3d(30, -20, 60);
  const SimulationResult r = RunSimulation(spec);
  for (size_t m = 0; m < r.truth.size(); m += 7) {
    EXPECT_THAT(r.recording.frames[m].star_tracker->q_in_b,
                IsNearQuaternion(
                    r.truth[m].q_in_b * ExpQuaternion(spec.star_tracker.misalignment_b), 1e-14));
  }
}

TEST(Simulator, FaultsActFromTheirTime) {
  SimulationSpec spec = TestSpec(4.0);
  spec.config.random_walk = 0.0;
  const Vector3d jump = ArcsecToRad(1.0) * Vector3d(0.0, 120.0, 0.0);
  spec.gyros[0].fault = GyroFault{HoursToSeconds(2.0), GyroFault::Kind::kReadoutJump, jump};
  const Vector3d step_k = DegPerHourToRadPerSec(1.0) * Vector3d(0.0, 0.0, 1.0);
  spec.gyros[1].fault = GyroFault{HoursToSeconds(1.0), GyroFault::Kind::kDriftStep, step_k};
  const SimulationResult r = RunSimulation(spec);
  const double sigma = spec.config.readout_noise;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const TruthSample& tr = r.truth[m];
    const Vector3d h_meas = r.recording.frames[m].gyros[0]->h_k;
    const Vector3d jumped = ExpMatrix(jump) * tr.gyros[0]->h_k;
    if (t >= HoursToSeconds(2.0)) {
      EXPECT_LT(std::acos(std::min(1.0, h_meas.dot(jumped))), 6.0 * sigma) << t;
    } else {
      EXPECT_LT(std::acos(std::min(1.0, h_meas.dot(tr.gyros[0]->h_k))), 6.0 * sigma) << t;
    }
    const Vector3d model = DriftRate_k(*r.true_coefficients[1], tr.gyros[1]->h_k);
    const Vector3d expected = t >= HoursToSeconds(1.0) ? Vector3d(model + step_k) : model;
    EXPECT_LT((tr.gyros[1]->dw_k - expected).norm(), 1e-20) << t;
  }
}

TEST(Simulator, ProgressIsReportedUpToOne) {
  std::vector<double> fractions;
  auto r = Simulate(TestSpec(1.0), [&](double f) { fractions.push_back(f); });
  ASSERT_THAT(r, IsOk());
  ASSERT_GE(fractions.size(), 10u);
  EXPECT_EQ(fractions.back(), 1.0);
  EXPECT_TRUE(std::is_sorted(fractions.begin(), fractions.end()));
}

TEST(Simulator, InvalidSpecsNameTheField) {
  auto expect_invalid = [](SimulationSpec spec, const std::string& field) {
    EXPECT_THAT(Simulate(spec), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr(field)));
  };
  SimulationSpec spec = TestSpec(0.1);
  {
    SimulationSpec s = spec;
    s.duration = -1.0;
    expect_invalid(s, "duration");
  }
  {
    SimulationSpec s = spec;
    s.telemetry_step = 0.0;
    expect_invalid(s, "telemetry_step");
  }
  {
    SimulationSpec s = spec;
    s.integration_rate_hz = std::nan("");
    expect_invalid(s, "integration_rate_hz");
  }
  {
    SimulationSpec s = spec;
    s.profile = nullptr;
    expect_invalid(s, "profile");
  }
  {
    SimulationSpec s = spec;
    s.config.gyros.pop_back();
    s.gyros[3].running = true;
    expect_invalid(s, "gyros[3] (gyro 4).running");
  }
  {
    SimulationSpec s = spec;
    s.star_tracker.outlier_probability = 1.5;
    expect_invalid(s, "star_tracker.outlier_probability");
  }
  {
    SimulationSpec s = spec;
    s.star_tracker.outages = {{10.0, 5.0}};
    expect_invalid(s, "star_tracker.outages[0]");
  }
  {
    SimulationSpec s = spec;
    s.gyros[0].rotor_displacement_k = Vector3d(40e-6, 0, 0);
    expect_invalid(s, "rotor_displacement_k");
  }
  {
    SimulationSpec s = spec;
    s.config.spacecraft_id = "";
    expect_invalid(s, "spacecraftId");
  }
}

}  // namespace
}  // namespace esg::estimator
