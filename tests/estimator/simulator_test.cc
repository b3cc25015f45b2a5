// Seeded simulator (estimator/simulator.h): reproducibility, readings against the truth, eq. (3)
// voltages, spin-axis motion against the paper's printed drift formulas integrated independently,
// the random-walk intensity from all increments, star-tracker noise,
// outliers, outages, latency and invalid flags, faults (readout jump, drift step, frozen and
// missing readings, switch-on, outlier burst, frozen star tracker, misalignment jump), the drift
// effects beyond the paper's models (orbital drift, growing rotor displacement, readout
// distortion, switching drift, hidden-driver drift), validation.
#include "estimator/simulator.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <string>
#include <vector>

#include "estimator/drift_model.h"
#include "estimator/random.h"
#include "estimator/rotation.h"
#include "estimator/sun_direction.h"
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

// The paper's printed drift, typed out here a third time, in its own shape: the x component of
// eq. (1) + (10) + (8) + (9) for the cosines (h1, h2, h3), and y, z from the same function with
// the indices permuted cyclically (1 -> 2 -> 3 -> 1), as the paper prints them. The simulator's
// truth (estimator/simulator_truth.cc) writes every component out; the filter's drift model
// (estimator/drift_model.cc) uses a projected gradient and a regressor. All [rad/s].
struct PaperDrift {
  double k0 = 0.0;
  double C11 = 0.0, C12 = 0.0, C13 = 0.0;                                         // eq. (10)
  double C21 = 0.0, C22 = 0.0, C23 = 0.0;                                         // eq. (10)
  double mu12 = 0.0, mu23 = 0.0, mu31 = 0.0, nu23 = 0.0, nu31 = 0.0, nu12 = 0.0;  // eq. (1)
  double l1 = 0.0, l2 = 0.0, l3 = 0.0, C10 = 0.0, C20 = 0.0;  // eq. (8), (9): lambda, C10, C20
};

double PaperX(double h1, double h2, double h3, double k0, double C11, double C12, double C13,
              double C21, double C22, double C23, double mu12, double mu31, double nu23, double l1,
              double l2, double l3, double C10, double C20) {
  const double eq1_k0 = h1 * (-(1 - h1 * h1) * h1 * h1 + std::pow(h2, 4) + std::pow(h3, 4)) * k0;
  const double eq1_mu_nu = h1 * (mu12 * h2 * h2 - mu31 * h3 * h3) + h2 * h3 * nu23;
  const double eq10_C1 = -(1 - h1 * h1) * C11 + h1 * h2 * C12 + h1 * h3 * C13;
  const double eq10_C2 =
      -(1 - h1 * h1) * h1 * h1 * C21 + h1 * std::pow(h2, 3) * C22 + h1 * std::pow(h3, 3) * C23;
  const double eq8 = (-(1 - h1 * h1) * l1 + h1 * h2 * l2 + h1 * h3 * l3) * C10;
  const double eq9 = (-(1 - h1 * h1) * (1 - 5 * h1 * h1) * l1 + (1 - 5 * h2 * h2) * h1 * h2 * l2 +
                      (1 - 5 * h3 * h3) * h1 * h3 * l3) *
                     C20;
  return eq1_k0 + eq1_mu_nu + eq10_C1 + eq10_C2 + eq8 + eq9;
}

Vector3d PaperDrift_k(const PaperDrift& p, const Vector3d& h) {
  return Vector3d(PaperX(h(0), h(1), h(2), p.k0, p.C11, p.C12, p.C13, p.C21, p.C22, p.C23, p.mu12,
                         p.mu31, p.nu23, p.l1, p.l2, p.l3, p.C10, p.C20),
                  PaperX(h(1), h(2), h(0), p.k0, p.C12, p.C13, p.C11, p.C22, p.C23, p.C21, p.mu23,
                         p.mu12, p.nu31, p.l2, p.l3, p.l1, p.C10, p.C20),
                  PaperX(h(2), h(0), h(1), p.k0, p.C13, p.C11, p.C12, p.C23, p.C21, p.C22, p.mu31,
                         p.mu23, p.nu12, p.l3, p.l1, p.l2, p.C10, p.C20));
}

// The simulator's input for the same drift: DriftCoefficients with mu = (mu12, mu23, mu31),
// nu = (nu23, nu31, nu12) (drift_model.h), and the displacement Delta = size lambda whose
// C10, C20 are c10_per_m |Delta|, c20_per_m |Delta| (simulator.h defaults).
DriftCoefficients AsDriftCoefficients(const PaperDrift& p) {
  DriftCoefficients c;
  c.k0 = p.k0;
  c.C1 = Vector3d(p.C11, p.C12, p.C13);
  c.C2 = Vector3d(p.C21, p.C22, p.C23);
  c.mu = Vector3d(p.mu12, p.mu23, p.mu31);
  c.nu = Vector3d(p.nu23, p.nu31, p.nu12);
  return c;
}

// Classical RK4 with step `step` [s] of dh_in/dt = (C_in_k(t) dw_k(h_k)) x h_in,
// h_k = C_in_k(t)^T h_in, C_in_k = C_in_b(t) C_b_k, from t = 0 to every telemetry time
// m * telemetry_step; returns h_in at each of them.
std::vector<Vector3d> IntegratePaperDrift(const AttitudeProfile& profile, const PaperDrift& p,
                                          const Matrix3d& C_b_k, const Vector3d& h_in0,
                                          double telemetry_step, int num_frames, double step) {
  auto rate = [&](double t, const Vector3d& h_in) {
    const Matrix3d C_in_k = profile.Attitude(t).toRotationMatrix() * C_b_k;
    const Vector3d h_k = C_in_k.transpose() * h_in.normalized();
    return Vector3d((C_in_k * PaperDrift_k(p, h_k)).cross(h_in));
  };
  const int steps_per_frame = static_cast<int>(std::lround(telemetry_step / step));
  std::vector<Vector3d> out = {h_in0};
  Vector3d h = h_in0;
  for (int m = 1; m < num_frames; ++m) {
    for (int i = 0; i < steps_per_frame; ++i) {
      const double t = (m - 1) * telemetry_step + i * step;
      const Vector3d k1 = rate(t, h);
      const Vector3d k2 = rate(t + 0.5 * step, h + 0.5 * step * k1);
      const Vector3d k3 = rate(t + 0.5 * step, h + 0.5 * step * k2);
      const Vector3d k4 = rate(t + step, h + step * k3);
      h = (h + step / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)).normalized();
    }
    out.push_back(h);
  }
  return out;
}

double MaxAngle(const std::vector<Vector3d>& a, const std::vector<TruthSample>& truth, int g) {
  double max_angle = 0.0;
  for (size_t m = 0; m < a.size(); ++m) {
    max_angle = std::max(max_angle, a[m].cross(truth[m].gyros[g]->h_in).norm());
  }
  return max_angle;
}

// Large drifts (several deg/h, every term of eq. (1), (8), (9), (10) present, one gyro also with a
// rotor displacement and a mounting misalignment), so that every term moves the spin axis far
// above the integration error.
std::array<PaperDrift, 3> LargePaperDrifts() {
  std::array<PaperDrift, 3> drifts;
  for (int g = 0; g < 3; ++g) {
    PaperDrift& p = drifts[g];
    const double s = DegPerHourToRadPerSec(1.0) * (1.0 + 0.2 * g);
    p.k0 = 3.0 * s;
    p.C11 = 0.6 * s, p.C12 = -1.6 * s, p.C13 = 1.0 * s;
    p.C21 = -0.6 * s, p.C22 = 0.2 * s, p.C23 = 0.7 * s;
    p.mu12 = 0.5 * s, p.mu23 = -0.5 * s, p.mu31 = 0.25 * s;
    p.nu23 = 0.1 * s, p.nu31 = 0.15 * s, p.nu12 = -0.25 * s;
  }
  return drifts;
}

// The simulator's true spin axes against the printed formulas integrated here, on an inertial
// hold, the paper's calibration profile (a turn per hour, reoriented every 3 h) and an orbital
// profile, with no random walk and no noise in the truth.
//
// Tolerance from the integration steps, tol = discretisation + rounding:
// - The simulator turns h_in by the drift at each step's midpoint (steps of h = 1/8 s), a
//   second-order scheme: the midpoint rule errs by h^3 |f''| / 24 per step, f = w_in = C_in_k dw_k
//   the inertial drift rate, and |f''| <= |dw| (W + |dw|)^2 with W the body rate (it turns the
//   case frame) and |dw| the axis's own motion. Summed over the run:
//   integral of h^2 |dw|max (W(t) + |dw|max)^2 / 24 dt, W(t) sampled every 10 s, |dw|max = 4 deg/h.
//   The reference, RK4 at 0.25 s, errs by order step^4 W^4 |dw| per unit time, 1e-4 of that.
// - Rounding: at most one unit roundoff (2.2e-16) per renormalised step, summed linearly over
//   the simulator's and the reference's steps (172800 + 86400): 5.8e-11 rad.
// Bounds and measured largest angles (seed 42, 6 h): inertial 5.8e-11 / 1.4e-12, calibration
// (1 turn/h and 10-min slews at up to 0.0099 rad/s) 1.2e-9 / 1.1e-10, orbital 4.1e-10 / 2.8e-11.
//
// A single slip in the truth's formulas (one sign, one index, one factor) moves the spin axis by
// 1e-4 to 1e-1 rad over 6 h with these coefficients; the end of the test shows that each such
// slip, made in the reference instead, misses the simulator by more than 1000 tol (measured
// 1.1e-4 rad for k0 x 1.001 up to 0.11 rad for the sign of C12).
TEST(Simulator, TrueSpinAxesFollowThePrintedDriftFormulasIntegratedIndependently) {
  const std::array<PaperDrift, 3> drifts = LargePaperDrifts();
  const Vector3d displacement = kMetresPerUm * Vector3d(2.0, 1.0, -1.0);
  const double hours = 6.0;
  for (const std::string profile : {"inertial", "calibration", "orbital"}) {
    SCOPED_TRACE(profile);
    SimulationSpec spec = TestSpec(hours, profile);
    spec.config.random_walk = 0.0;
    spec.gyros[1].misalignment_b = ArcsecToRad(1.0) * Vector3d(300.0, -200.0, 100.0);
    for (int g = 0; g < 3; ++g) spec.gyros[g].drift = AsDriftCoefficients(drifts[g]);
    spec.gyros[2].rotor_displacement_k = displacement;
    const SimulationResult r = RunSimulation(spec);
    ASSERT_EQ(r.truth.size(), 361u);

    // Tolerance (see above) from the steps, the body rate and the largest drift.
    const double h = 1.0 / spec.integration_rate_hz;
    const double reference_step = 0.25;                   // [s]
    const double max_drift = DegPerHourToRadPerSec(4.0);  // asserted below at every frame
    double discretisation = 0.0;
    for (double t = 5.0; t < spec.duration; t += 10.0) {
      const double W = spec.profile->Rate(t).norm();
      discretisation += 10.0 * h * h * max_drift * (W + max_drift) * (W + max_drift) / 24.0;
    }
    const double rounding = (spec.duration / h + spec.duration / reference_step) *
                            std::numeric_limits<double>::epsilon();
    const double tol = discretisation + rounding;

    for (int g = 0; g < 3; ++g) {
      SCOPED_TRACE(::testing::Message() << "gyro " << g + 1);
      PaperDrift p = drifts[g];
      if (g == 2) {
        const Vector3d lambda = displacement.normalized();
        p.l1 = lambda(0), p.l2 = lambda(1), p.l3 = lambda(2);
        p.C10 = spec.gyros[2].c10_per_m * displacement.norm();
        p.C20 = spec.gyros[2].c20_per_m * displacement.norm();
      }
      // Mounting and starting axis computed here from the spec.
      const Matrix3d C_b_k =
          ExpMatrix(spec.gyros[g].misalignment_b) * spec.config.FindGyro(g + 1)->C_b_k;
      const Vector3d h_in0 =
          (spec.profile->Attitude(0.0).toRotationMatrix() * C_b_k * DefaultInitialSpinAxis(g + 1))
              .normalized();
      EXPECT_LT((r.truth[0].gyros[g]->C_b_k - C_b_k).norm(), 1e-15);
      EXPECT_LT((r.truth[0].gyros[g]->h_in - h_in0).norm(), 1e-15);

      const std::vector<Vector3d> expected = IntegratePaperDrift(
          *spec.profile, p, C_b_k, h_in0, spec.telemetry_step, r.truth.size(), reference_step);
      const double error = MaxAngle(expected, r.truth, g);
      EXPECT_GT(std::acos(h_in0.dot(r.truth.back().gyros[g]->h_in)), DegToRad(1.0))
          << "barely moved";
      EXPECT_LT(error, tol);

      // The reported drift at every frame: the printed formulas here, and the filter's drift
      // model (DriftRate_k and DriftRegressor) with the reported equivalent coefficients, agree
      // with the truth's dw_k to rounding (1e-12 relative).
      const DriftCoefficients& c = *r.true_coefficients[g];
      for (const TruthSample& t : r.truth) {
        const Vector3d& dw_k = t.gyros[g]->dw_k;
        EXPECT_LT(dw_k.norm(), max_drift);
        EXPECT_LT((dw_k - PaperDrift_k(p, t.gyros[g]->h_k)).norm(), 1e-12 * dw_k.norm());
        EXPECT_LT((dw_k - DriftRate_k(c, t.gyros[g]->h_k)).norm(), 1e-12 * dw_k.norm());
        EXPECT_LT((dw_k - DriftRegressor(t.gyros[g]->h_k) * c.AsVector()).norm(),
                  1e-12 * dw_k.norm());
      }
    }

    if (profile != "calibration") continue;
    // Each slip, made in the reference, misses the simulator's gyro 3 by far more than tol.
    struct Slip {
      const char* what;
      std::function<void(PaperDrift&)> apply;
    };
    const std::vector<Slip> slips = {
        {"k0 x 1.001", [](PaperDrift& p) { p.k0 *= 1.001; }},
        {"C12 sign", [](PaperDrift& p) { p.C12 = -p.C12; }},
        {"C21 <-> C23", [](PaperDrift& p) { std::swap(p.C21, p.C23); }},
        {"mu12 <-> mu31", [](PaperDrift& p) { std::swap(p.mu12, p.mu31); }},
        {"nu23 <-> nu12", [](PaperDrift& p) { std::swap(p.nu23, p.nu12); }},
        {"eq. (9) sign", [](PaperDrift& p) { p.C20 = -p.C20; }},
        {"lambda1 <-> lambda2", [](PaperDrift& p) { std::swap(p.l1, p.l2); }},
    };
    for (const Slip& slip : slips) {
      PaperDrift p = drifts[2];
      const Vector3d lambda = displacement.normalized();
      p.l1 = lambda(0), p.l2 = lambda(1), p.l3 = lambda(2);
      p.C10 = spec.gyros[2].c10_per_m * displacement.norm();
      p.C20 = spec.gyros[2].c20_per_m * displacement.norm();
      slip.apply(p);
      const std::vector<Vector3d> slipped = IntegratePaperDrift(
          *spec.profile, p, r.truth[0].gyros[2]->C_b_k, r.truth[0].gyros[2]->h_in,
          spec.telemetry_step, r.truth.size(), reference_step);
      const double miss = MaxAngle(slipped, r.truth, 2);
      EXPECT_GT(miss, 1000.0 * tol) << slip.what;
    }
  }
}

TEST(Simulator, RandomWalkIntensityFromAllIncrementsOfTheResidualDrift) {
  // Zero deterministic drift: the truth's dw_k is the random-walk drift alone, mapped to the case
  // axes. Mapped back to inertial axes, its increment between consecutive frames (60 s apart) is
  // N(0, q 60 s I), independent of every other increment, q = random_walk^2 (model (11)). Every
  // increment of every axis of 3 gyros over 4 seeds x 12 h enters: N = 4 x 720 x 3 x 3 = 25920.
  // Then q_hat = sum(d^2) / (N 60 s) satisfies N q_hat / q ~ chi-square(N): relative standard
  // error sqrt(2 / N) = 0.88%, and the 5-sigma band 4.4% (< 5%; a 2.2% error in the intensity
  // fails). Per inertial axis (N / 3 = 8640 increments): 5 sigma = 7.6%. The lag-1 correlation
  // of the increments and their mean, scaled, are N(0, 1) (5-sigma bounds). Integration rates
  // 8, 4, 2 and 0.5 Hz across the seeds: the per-step variance must scale with the step (a
  // sqrt(h) slip shows at every rate but 1 Hz). The calibration profile turns the body, so the
  // case-to-inertial mapping of the reported dw_k is exercised too.
  const std::array<double, 4> rates_hz = {8.0, 4.0, 2.0, 0.5};
  double q = 0.0;
  double sum_sq = 0.0, sum_lag = 0.0;
  Vector3d sum_sq_axis = Vector3d::Zero();
  Vector3d sum = Vector3d::Zero();
  int n = 0, n_lag = 0;
  double interval = 0.0;
  for (uint64_t seed = 1; seed <= 4; ++seed) {
    SimulationSpec spec = TestSpec(12.0, "calibration");
    spec.integration_rate_hz = rates_hz[seed - 1];
    spec.seed = seed;
    for (int g = 0; g < 3; ++g) spec.gyros[g].drift = DriftCoefficients{};
    q = spec.config.random_walk * spec.config.random_walk;
    interval = spec.telemetry_step;
    const SimulationResult r = RunSimulation(spec);
    ASSERT_EQ(r.truth.size(), 721u);
    for (int g = 0; g < 3; ++g) {
      auto dw_in = [&](size_t m) {
        const TruthSample& t = r.truth[m];
        return Vector3d(t.q_in_b.toRotationMatrix() * t.gyros[g]->C_b_k * t.gyros[g]->dw_k);
      };
      EXPECT_EQ(dw_in(0), Vector3d::Zero());  // starts at zero
      Vector3d previous = Vector3d::Zero();
      for (size_t m = 1; m < r.truth.size(); ++m) {
        const Vector3d d = dw_in(m) - dw_in(m - 1);
        sum_sq += d.squaredNorm();
        sum_sq_axis += d.cwiseAbs2();
        sum += d;
        n += 3;
        if (m > 1) {
          sum_lag += d.dot(previous);
          n_lag += 3;
        }
        previous = d;
      }
    }
  }
  ASSERT_EQ(n, 25920);
  const double variance = q * interval;
  const double q_ratio = sum_sq / (n * variance);
  const double sigma = std::sqrt(2.0 / n);
  EXPECT_LT(5.0 * sigma, 0.05);
  EXPECT_NEAR(q_ratio, 1.0, 5.0 * sigma);
  // The band is sharp enough: the same increments judged against an intensity 3% off fail it.
  EXPECT_GT(std::abs(q_ratio / (1.03 * 1.03) - 1.0), 5.0 * sigma);
  EXPECT_GT(std::abs(q_ratio / (0.97 * 0.97) - 1.0), 5.0 * sigma);
  for (int axis = 0; axis < 3; ++axis) {
    EXPECT_NEAR(sum_sq_axis(axis) / (n / 3 * variance), 1.0, 5.0 * std::sqrt(2.0 / (n / 3)))
        << "axis " << axis;
    // Sum of n/3 increments: N(0, n/3 variance).
    EXPECT_LT(std::abs(sum(axis)) / std::sqrt(n / 3 * variance), 5.0) << "axis " << axis;
  }
  // Lag-1 products of independent increments: mean 0, sd variance sqrt(n_lag).
  EXPECT_LT(std::abs(sum_lag) / (variance * std::sqrt(static_cast<double>(n_lag))), 5.0);
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
    // The filter's DriftRate_k against the truth's printed formulas: equal to rounding.
    EXPECT_LT((tr.gyros[1]->dw_k - expected).norm(), 1e-12 * expected.norm()) << t;
  }
}

// Whether t lies in [start, end). The fault tests below also check that a clean run's frames equal
// the faulted run's outside the fault (same random streams).
bool InWindow(double t, double start, double end) { return t >= start && t < end; }

TEST(Simulator, FrozenGyroReadingRepeatsTheFirstReadingOfItsWindow) {
  const SimulationSpec clean_spec = TestSpec(3.0);
  SimulationSpec spec = clean_spec;
  const double start = HoursToSeconds(1.0) + 30.0, end = HoursToSeconds(2.0);
  GyroFault fault;
  fault.time = start;
  fault.kind = GyroFault::Kind::kReadingFrozen;
  fault.end = end;
  spec.gyros[0].fault = fault;
  const SimulationResult r = RunSimulation(spec);
  const SimulationResult clean = RunSimulation(clean_spec);
  const size_t first = static_cast<size_t>(HoursToSeconds(1.0) / 60.0) + 1;  // 1 h + 60 s
  const GyroReading held = *clean.recording.frames[first].gyros[0];
  int frozen = 0;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const GyroReading& g1 = *r.recording.frames[m].gyros[0];
    for (int g = 1; g < 3; ++g) {
      EXPECT_EQ(r.recording.frames[m].gyros[g]->h_k, clean.recording.frames[m].gyros[g]->h_k);
    }
    if (InWindow(t, start, end)) {
      ++frozen;
      EXPECT_EQ(g1.h_k, held.h_k) << t;
      EXPECT_EQ(*g1.u_k_mv, *held.u_k_mv) << t;
    } else {
      EXPECT_NE(g1.h_k, held.h_k) << t;
      EXPECT_EQ(g1.h_k, clean.recording.frames[m].gyros[0]->h_k) << t;
      EXPECT_EQ(*g1.u_k_mv, *clean.recording.frames[m].gyros[0]->u_k_mv) << t;
    }
    // The truth keeps moving.
    EXPECT_EQ(r.truth[m].gyros[0]->h_k, clean.truth[m].gyros[0]->h_k);
  }
  EXPECT_EQ(frozen, 59);  // 1 h + 60 s ... 1 h + 59 min
}

TEST(Simulator, MissingGyroReadingsAreAbsentExactlyInTheirWindow) {
  const SimulationSpec clean_spec = TestSpec(3.0);
  SimulationSpec spec = clean_spec;
  const double start = HoursToSeconds(1.0), end = HoursToSeconds(1.0) + 600.0;
  GyroFault fault;
  fault.time = start;
  fault.kind = GyroFault::Kind::kReadingsMissing;
  fault.end = end;
  spec.gyros[1].fault = fault;
  const SimulationResult r = RunSimulation(spec);
  const SimulationResult clean = RunSimulation(clean_spec);
  int missing = 0;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const auto& g2 = r.recording.frames[m].gyros[1];
    EXPECT_EQ(g2.has_value(), !InWindow(t, start, end)) << t;
    missing += !g2.has_value();
    if (g2) EXPECT_EQ(g2->h_k, clean.recording.frames[m].gyros[1]->h_k) << t;
    EXPECT_TRUE(r.truth[m].gyros[1].has_value());
    EXPECT_EQ(r.recording.frames[m].gyros[0]->h_k, clean.recording.frames[m].gyros[0]->h_k);
  }
  EXPECT_EQ(missing, 10);  // 10 min: 1 h, 1 h + 1 min ... 1 h + 9 min
}

TEST(Simulator, SpareSwitchedOnHasReadingsFromItsSwitchOnTime) {
  const SimulationSpec clean_spec = TestSpec(3.0);
  SimulationSpec spec = clean_spec;
  const double on = HoursToSeconds(2.0) - 30.0;
  spec.gyros[3].switch_on_time = on;  // the cold spare, not in the pairs
  EXPECT_TRUE(GyroRuns(spec, 4));
  EXPECT_FALSE(GyroRuns(clean_spec, 4));
  const SimulationResult r = RunSimulation(spec);
  const SimulationResult clean = RunSimulation(clean_spec);
  ASSERT_TRUE(r.true_coefficients[3].has_value());
  int present = 0;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const auto& g4 = r.recording.frames[m].gyros[3];
    EXPECT_EQ(g4.has_value(), t >= on) << t;
    EXPECT_EQ(r.truth[m].gyros[3].has_value(), t >= on) << t;
    for (int g = 0; g < 3; ++g) {
      EXPECT_EQ(r.recording.frames[m].gyros[g]->h_k, clean.recording.frames[m].gyros[g]->h_k);
    }
    if (!g4) continue;
    ++present;
    const double error = std::acos(std::min(1.0, g4->h_k.dot(r.truth[m].gyros[3]->h_k)));
    EXPECT_LT(error, 6.0 * spec.config.readout_noise) << t;
  }
  EXPECT_EQ(present, 61);  // 2 h ... 3 h
  SimulationSpec off = spec;
  off.gyros[3].running = false;
  EXPECT_THAT(Simulate(off), StatusIs(absl::StatusCode::kInvalidArgument,
                                      HasSubstr("gyros[3] (gyro 4).switch_on_time")));
}

TEST(Simulator, OutlierBurstIsExactlyCountConsecutiveCrossBoresightSamples) {
  SimulationSpec clean_spec = TestSpec(2.0);
  SimulationSpec spec = clean_spec;
  const double angle = ArcminToRad(4.0);
  spec.star_tracker.outlier_burst = StarTrackerOutlierBurst{HoursToSeconds(1.0) + 10.0, 5, angle};
  // An outage over the 2nd and 3rd frames after the start: they do not count.
  spec.star_tracker.outages = {{HoursToSeconds(1.0) + 100.0, HoursToSeconds(1.0) + 190.0}};
  clean_spec.star_tracker.outages = spec.star_tracker.outages;
  const SimulationResult r = RunSimulation(spec);
  const SimulationResult clean = RunSimulation(clean_spec);
  std::vector<double> flagged;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const TelemetryFrame& f = r.recording.frames[m];
    if (!f.star_tracker) continue;
    const Quaterniond& q_clean = clean.recording.frames[m].star_tracker->q_in_b;
    if (!r.truth[m].star_tracker_outlier) {
      EXPECT_THAT(f.star_tracker->q_in_b, IsNearQuaternion(q_clean, 1e-15)) << t;
      continue;
    }
    flagged.push_back(t);
    EXPECT_EQ(r.truth[m].star_tracker_outlier_angle, angle);
    // The outlier is a body rotation of the burst's angle about an axis perpendicular to z.
    const Vector3d o = LogQuaternion(q_clean.conjugate() * f.star_tracker->q_in_b);
    EXPECT_NEAR(o.norm(), angle, 1e-12) << t;
    EXPECT_NEAR(o.z(), 0.0, 1e-12) << t;
  }
  const double h1 = HoursToSeconds(1.0);
  EXPECT_THAT(flagged, ::testing::ElementsAre(h1 + 60, h1 + 240, h1 + 300, h1 + 360, h1 + 420));
}

TEST(Simulator, FrozenStarTrackerRepeatsTheFirstSampleOfItsWindow) {
  const SimulationSpec clean_spec = TestSpec(3.0);
  SimulationSpec spec = clean_spec;
  const double start = HoursToSeconds(1.0), end = HoursToSeconds(1.5);
  spec.star_tracker.frozen = {{start, end}};
  const SimulationResult r = RunSimulation(spec);
  const SimulationResult clean = RunSimulation(clean_spec);
  const Quaterniond held = clean.recording.frames[60].star_tracker->q_in_b;  // at 1 h
  int frozen = 0;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const Quaterniond& q = r.recording.frames[m].star_tracker->q_in_b;
    if (InWindow(t, start, end)) {
      EXPECT_EQ(q.coeffs(), held.coeffs()) << t;
      EXPECT_EQ(r.truth[m].star_tracker_frozen, t > start) << t;
      ++frozen;
    } else {
      EXPECT_FALSE(r.truth[m].star_tracker_frozen);
      EXPECT_NE(q.coeffs(), held.coeffs()) << t;
      EXPECT_EQ(q.coeffs(), clean.recording.frames[m].star_tracker->q_in_b.coeffs()) << t;
    }
  }
  EXPECT_EQ(frozen, 30);
}

TEST(Simulator, StarTrackerMisalignmentJumpIsABodyRotationFromItsTime) {
  SimulationSpec spec = TestSpec(2.0);
  spec.star_tracker.noise = Vector3d::Zero();
  spec.star_tracker.misalignment_b = ArcsecToRad(1.0) * Vector3d(30, -20, 60);
  const Vector3d jump_b = ArcminToRad(1.0) * Vector3d(2.0, 0.0, 0.0);
  spec.star_tracker.misalignment_jump = StarTrackerMisalignmentJump{HoursToSeconds(1.0), jump_b};
  const SimulationResult r = RunSimulation(spec);
  const Quaterniond mis = ExpQuaternion(spec.star_tracker.misalignment_b);
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const Quaterniond expected = t >= HoursToSeconds(1.0)
                                     ? Quaterniond(r.truth[m].q_in_b * mis * ExpQuaternion(jump_b))
                                     : Quaterniond(r.truth[m].q_in_b * mis);
    EXPECT_THAT(r.recording.frames[m].star_tracker->q_in_b, IsNearQuaternion(expected, 1e-14))
        << t;
  }
}

// The mount following the sun (StarTrackerSunMount): with no noise, q_true^-1 q_meas is
// Exp(misalignment_b) Exp(rotation_b y(t)), y the face's lagged illumination; y integrated here
// by RK4 at 2 s from the sun's direction computed at each instant (no nodes, no midpoint rule) on
// the calibration profile, whose slews turn face +x to and from the sun. Agreement to 1e-4 of
// the full turn; the illumination must vary over the run for the check to mean anything.
TEST(Simulator, StarTrackerMountFollowingTheSunTurnsByTheFacesLaggedIllumination) {
  SimulationSpec spec = TestSpec(6.0);
  spec.star_tracker.noise = Vector3d::Zero();
  spec.star_tracker.misalignment_b = ArcsecToRad(1.0) * Vector3d(10, -5, 20);
  StarTrackerSunMount mount;
  mount.rotation_b = ArcsecToRad(1.0) * Vector3d(25, -15, 10);
  mount.face_axis = 0;
  mount.face_sign = 1;
  mount.time_constant_s = 1800.0;
  spec.star_tracker.sun_mount = mount;
  const SimulationResult r = RunSimulation(spec);
  ASSERT_FALSE(r.truth.empty());
  auto u = [&](double t) {
    const Vector3d s_in = *SunDirection_in(spec.start + absl::Seconds(t));
    const Vector3d s_b = spec.profile->Attitude(t).toRotationMatrix().transpose() * s_in;
    return std::max(0.0, s_b.x());
  };
  auto dy = [&](double t, double y) { return (u(t) - y) / mount.time_constant_s; };
  double y = u(0.0), t = 0.0, y_min = y, y_max = y;
  const double h = 2.0;
  const Quaterniond mis = ExpQuaternion(spec.star_tracker.misalignment_b);
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t_m = 60.0 * static_cast<double>(m);
    while (t < t_m) {
      const double k1 = dy(t, y), k2 = dy(t + h / 2, y + h / 2 * k1);
      const double k3 = dy(t + h / 2, y + h / 2 * k2), k4 = dy(t + h, y + h * k3);
      y += h / 6 * (k1 + 2 * k2 + 2 * k3 + k4);
      t += h;
    }
    y_min = std::min(y_min, y);
    y_max = std::max(y_max, y);
    const Quaterniond turn =
        mis.conjugate() * r.truth[m].q_in_b.conjugate() * r.recording.frames[m].star_tracker->q_in_b;
    EXPECT_LT((LogQuaternion(turn) - mount.rotation_b * y).norm(), 1e-4 * mount.rotation_b.norm())
        << "t " << t_m << " s: y " << y << ", turn " << RadToArcsec(1.0) * LogQuaternion(turn).transpose()
        << " arcsec";
  }
  EXPECT_GT(y_max - y_min, 0.2) << "face +x's illumination hardly varies on this profile";
}

TEST(Simulator, StarTrackerMountFollowingTheSunRefusesABadFaceNamingTheField) {
  SimulationSpec spec = TestSpec(1.0);
  StarTrackerSunMount mount;
  mount.rotation_b = ArcsecToRad(1.0) * Vector3d(25, -15, 10);
  mount.face_sign = 0;
  spec.star_tracker.sun_mount = mount;
  EXPECT_THAT(Simulate(spec), StatusIs(absl::StatusCode::kInvalidArgument,
                                       HasSubstr("star_tracker.sun_mount.face_sign")));
  spec.star_tracker.sun_mount->face_sign = -1;
  spec.star_tracker.sun_mount->face_axis = kSunlitFaceAxis;  // needs the orbit
  EXPECT_THAT(Simulate(spec), StatusIs(absl::StatusCode::kInvalidArgument,
                                       HasSubstr("star_tracker.sun_mount.face_axis")));
  spec.star_tracker.sun_mount->face_axis = 2;
  spec.star_tracker.sun_mount->time_constant_s = 0.0;
  EXPECT_THAT(Simulate(spec), StatusIs(absl::StatusCode::kInvalidArgument,
                                       HasSubstr("star_tracker.sun_mount.time_constant_s")));
}

// ---------------------------------------------------------------------------------------------
// Effects beyond the paper's models (GyroTruth::orbital_drift, rotor_displacement_rate_k_m_s,
// readout_distortion_k, switching_drift, hidden_driver_drift).

// Classical RK4 with step `step` [s] of dh_in/dt = (C_in_k(t) dw_k(t, h_k)) x h_in,
// h_k = C_in_k(t)^T h_in, C_in_k = C_in_b(t) C_b_k, for a drift that may depend on time; returns
// h_in at every telemetry time m * telemetry_step.
std::vector<Vector3d> IntegrateTimeVaryingDrift(
    const AttitudeProfile& profile, const std::function<Vector3d(double, const Vector3d&)>& dw_k,
    const Matrix3d& C_b_k, const Vector3d& h_in0, double telemetry_step, int num_frames,
    double step) {
  auto rate = [&](double t, const Vector3d& h_in) {
    const Matrix3d C_in_k = profile.Attitude(t).toRotationMatrix() * C_b_k;
    const Vector3d h_k = C_in_k.transpose() * h_in.normalized();
    return Vector3d((C_in_k * dw_k(t, h_k)).cross(h_in));
  };
  const int steps_per_frame = static_cast<int>(std::lround(telemetry_step / step));
  std::vector<Vector3d> out = {h_in0};
  Vector3d h = h_in0;
  for (int m = 1; m < num_frames; ++m) {
    for (int i = 0; i < steps_per_frame; ++i) {
      const double t = (m - 1) * telemetry_step + i * step;
      const Vector3d k1 = rate(t, h);
      const Vector3d k2 = rate(t + 0.5 * step, h + 0.5 * step * k1);
      const Vector3d k3 = rate(t + 0.5 * step, h + 0.5 * step * k2);
      const Vector3d k4 = rate(t + step, h + step * k3);
      h = (h + step / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)).normalized();
    }
    out.push_back(h);
  }
  return out;
}

// The integration tolerance of TrueSpinAxesFollowThePrintedDriftFormulasIntegratedIndependently
// (see there): midpoint-rule discretisation for drifts up to max_drift under the profile's body
// rate, plus one unit roundoff per renormalised step of the simulator and of the reference. A
// drift that varies in time at angular frequency omega adds omega to the rate that turns it.
double IntegrationTolerance(const SimulationSpec& spec, double max_drift, double reference_step,
                            double omega = 0.0) {
  const double h = 1.0 / spec.integration_rate_hz;
  double discretisation = 0.0;
  for (double t = 5.0; t < spec.duration; t += 10.0) {
    const double W = spec.profile->Rate(t).norm() + omega;
    discretisation += 10.0 * h * h * max_drift * (W + max_drift) * (W + max_drift) / 24.0;
  }
  return discretisation + (spec.duration / h + spec.duration / reference_step) *
                              std::numeric_limits<double>::epsilon();
}

// The model drift of gyro g (the reported equivalent coefficients, no random walk) plus the
// effects' parts reported in the truth sample.
Vector3d ModelDrift_k(const SimulationResult& r, const TruthSample& t, int g) {
  return DriftRate_k(*r.true_coefficients[g], t.gyros[g]->h_k);
}

// Turning the effects on with zero amplitude (and the streams they draw from with them) changes
// nothing in the recording, bit for bit; with real amplitudes the voltages and the star tracker
// are still bit for bit those of the clean run (the switching drift and the hidden driver draw
// from streams of their own).
TEST(Simulator, DriftEffectsDrawFromTheirOwnStreams) {
  const SimulationSpec clean_spec = TestSpec(3.0);
  const SimulationResult clean = RunSimulation(clean_spec);
  SimulationSpec zero = clean_spec;
  for (int g = 0; g < 3; ++g) {
    zero.gyros[g].orbital_drift = OrbitalDrift{Vector3d::Zero(), 5400.0, 0.3};
    zero.gyros[g].switching_drift = SwitchingDrift{Vector3d::Zero(), 600.0};
    zero.gyros[g].hidden_driver_drift = HiddenDriverDrift{Vector3d::Zero(), 1800.0};
  }
  const SimulationResult r_zero = RunSimulation(zero);
  EXPECT_TRUE(SameRecording(clean.recording, r_zero.recording));
  EXPECT_FALSE(r_zero.effects[0].switch_times_s.empty());  // the streams did draw

  SimulationSpec on = clean_spec;
  const double a = DegPerHourToRadPerSec(0.5);
  on.gyros[0].switching_drift = SwitchingDrift{Vector3d(a, 0, 0), 600.0};
  on.gyros[1].hidden_driver_drift = HiddenDriverDrift{Vector3d(0, a, a), 1800.0};
  on.gyros[2].orbital_drift = OrbitalDrift{Vector3d(0, 0, a), 5400.0, 0.0};
  const SimulationResult r_on = RunSimulation(on);
  for (size_t m = 0; m < r_on.truth.size(); ++m) {
    const TelemetryFrame& f = r_on.recording.frames[m];
    const TelemetryFrame& c = clean.recording.frames[m];
    for (int g = 0; g < 3; ++g) EXPECT_EQ(*f.gyros[g]->u_k_mv, *c.gyros[g]->u_k_mv) << m;
    EXPECT_EQ(f.star_tracker->q_in_b.coeffs(), c.star_tracker->q_in_b.coeffs()) << m;
  }
  // ... while the spin axes do move differently.
  for (int g = 0; g < 3; ++g) {
    EXPECT_GT(r_on.truth.back().gyros[g]->h_in.cross(clean.truth.back().gyros[g]->h_in).norm(),
              1e-5)
        << "gyro " << g + 1;
  }
}

// The orbital drift sample equals A cos(2 pi t / P + phase) at every frame (computed here from the
// spec), its period defaults to the orbital profile's, the total truth drift is the model's plus
// it, and the simulator's spin axis follows RK4 of that drift to the integration tolerance, while
// the same integration without the orbital term misses by far more.
TEST(Simulator, OrbitalDriftCyclesWithTheOrbit) {
  SimulationSpec spec = TestSpec(6.0, "orbital");
  spec.config.random_walk = 0.0;
  const Vector3d A = DegPerHourToRadPerSec(1.0) * Vector3d(2.0, -1.0, 0.5);
  const double phase = DegToRad(40.0);
  spec.gyros[0].orbital_drift = OrbitalDrift{A, std::nullopt, phase};  // the profile's period
  const double P2 = 3000.0;
  spec.gyros[1].orbital_drift = OrbitalDrift{A, P2, 0.0};
  const SimulationResult r = RunSimulation(spec);
  const double P = OrbitalOptions{}.period;
  ASSERT_TRUE(r.effects[0].orbital_drift.has_value());
  EXPECT_EQ(r.effects[0].orbital_drift->period_s, P);
  EXPECT_EQ(r.effects[1].orbital_drift->period_s, P2);
  EXPECT_FALSE(r.effects[2].orbital_drift.has_value());
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const TruthSample& tr = r.truth[m];
    const Vector3d expected1 = A * std::cos(2.0 * kPi * (t - 0.0) / P + phase);
    const Vector3d expected2 = A * std::cos(2.0 * kPi * t / P2);
    EXPECT_LT((tr.gyros[0]->dw_orbital_k_rad_s - expected1).norm(), 1e-12 * A.norm()) << t;
    EXPECT_LT((tr.gyros[1]->dw_orbital_k_rad_s - expected2).norm(), 1e-12 * A.norm()) << t;
    EXPECT_EQ(tr.gyros[2]->dw_orbital_k_rad_s, Vector3d::Zero());
    for (int g = 0; g < 2; ++g) {
      const Vector3d total = ModelDrift_k(r, tr, g) + (g == 0 ? expected1 : expected2);
      EXPECT_LT((tr.gyros[g]->dw_k - total).norm(), 1e-12 * total.norm()) << t;
    }
  }
  // The spin axis of gyro 1 against RK4 of the model drift (printed formulas, test's own) plus
  // A cos(2 pi t / P + phase).
  const double reference_step = 0.25;
  const double max_drift = DegPerHourToRadPerSec(4.0);
  const double tol = IntegrationTolerance(spec, max_drift, reference_step, 2.0 * kPi / P);
  PaperDrift p;
  const DriftCoefficients& c = spec.config.FindGyro(1)->model;
  p.k0 = c.k0;
  p.C11 = c.C1(0), p.C12 = c.C1(1), p.C13 = c.C1(2);
  p.C21 = c.C2(0), p.C22 = c.C2(1), p.C23 = c.C2(2);
  auto integrate = [&](double amplitude_scale) {
    return IntegrateTimeVaryingDrift(
        *spec.profile,
        [&](double t, const Vector3d& h_k) {
          return Vector3d(PaperDrift_k(p, h_k) +
                          amplitude_scale * A * std::cos(2.0 * kPi * t / P + phase));
        },
        r.truth[0].gyros[0]->C_b_k, r.truth[0].gyros[0]->h_in, spec.telemetry_step,
        r.truth.size(), reference_step);
  };
  EXPECT_LT(MaxAngle(integrate(1.0), r.truth, 0), tol);
  EXPECT_GT(MaxAngle(integrate(0.0), r.truth, 0), 1000.0 * tol);

  // Without a period, a profile with no orbit is refused, naming the field.
  SimulationSpec calibration = TestSpec(1.0, "calibration");
  calibration.gyros[0].orbital_drift = OrbitalDrift{A, std::nullopt, 0.0};
  EXPECT_THAT(Simulate(calibration),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[0] (gyro 1).orbital_drift.period_s: required")));
  // The mixed profile has an orbit.
  SimulationSpec mixed = TestSpec(1.0, "mixed");
  mixed.gyros[0].orbital_drift = OrbitalDrift{A, std::nullopt, 0.0};
  auto mixed_result = Simulate(mixed);
  ASSERT_THAT(mixed_result, IsOk());
  EXPECT_EQ(mixed_result->effects[0].orbital_drift->period_s, P);
}

// Delta(t) = Delta0 + rate t: the voltages follow eq. (3) of Delta(t) within the voltage noise
// (chi-square over all frames and axes), u(t) - u(0) is eq. (3) of rate t within 6 sigma sqrt(2)
// per axis; the drift is eq. (8) + (9) at Delta(t) (the test's printed formulas), and the spin
// axis follows RK4 of that time-varying drift.
TEST(Simulator, RotorDisplacementGrowsLinearlyInDriftAndVoltages) {
  SimulationSpec spec = TestSpec(6.0);
  spec.config.random_walk = 0.0;
  const Vector3d delta0 = kMetresPerUm * Vector3d(0.5, -1.0, 0.3);
  const Vector3d rate = kMetresPerUm / kSecondsPerHour * Vector3d(0.5, 0.25, -0.4);  // [m/s]
  spec.gyros[1].rotor_displacement_k = delta0;
  spec.gyros[1].rotor_displacement_rate_k_m_s = rate;
  // Large C10, C20 so that the displacement's drift dominates the spin-axis motion.
  spec.gyros[1].c10_per_m = DegPerHourToRadPerSec(0.3) / kMetresPerUm;
  spec.gyros[1].c20_per_m = DegPerHourToRadPerSec(0.1) / kMetresPerUm;
  const SimulationResult r = RunSimulation(spec);
  const SuspensionConfig& s = spec.config.suspension;
  const double sigma_v = spec.gyros[1].voltage_noise;
  auto eq3 = [&](const Vector3d& d) {  // eq. (3) inverse per axis [V]
    Vector3d u;
    for (int axis = 0; axis < 3; ++axis) {
      u(axis) = OffsetVoltageFromDisplacement(d(axis), s.amplifier_gain, s.reference_voltage, s.gap);
    }
    return u;
  };
  // The rate moves the voltages by far more than their noise over the run.
  EXPECT_GT((eq3(rate * spec.duration) / sigma_v).cwiseAbs().minCoeff(), 30.0);
  double chi2 = 0.0, chi2_constant = 0.0;
  int n = 0;
  const Vector3d u0 = *r.recording.frames[0].gyros[1]->u_k_mv * kVoltsPerMv;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const Vector3d delta = delta0 + rate * t;
    EXPECT_LT((r.truth[m].gyros[1]->rotor_displacement_k_m - delta).norm(), 1e-18);
    const Vector3d u = *r.recording.frames[m].gyros[1]->u_k_mv * kVoltsPerMv;
    chi2 += ((u - eq3(delta)) / sigma_v).squaredNorm();
    chi2_constant += ((u - eq3(delta0)) / sigma_v).squaredNorm();
    n += 3;
    EXPECT_LT((u - u0 - eq3(rate * t)).cwiseAbs().maxCoeff(), 6.0 * std::sqrt(2.0) * sigma_v) << t;
    // eq. (8) + (9) at Delta(t), lambda and sizes computed here.
    PaperDrift p;
    const DriftCoefficients& c = spec.config.FindGyro(2)->model;
    p.k0 = c.k0;
    p.C11 = c.C1(0), p.C12 = c.C1(1), p.C13 = c.C1(2);
    p.C21 = c.C2(0), p.C22 = c.C2(1), p.C23 = c.C2(2);
    const Vector3d lambda = delta.normalized();
    p.l1 = lambda(0), p.l2 = lambda(1), p.l3 = lambda(2);
    p.C10 = spec.gyros[1].c10_per_m * delta.norm();
    p.C20 = spec.gyros[1].c20_per_m * delta.norm();
    const Vector3d expected = PaperDrift_k(p, r.truth[m].gyros[1]->h_k);
    EXPECT_LT((r.truth[m].gyros[1]->dw_k - expected).norm(), 1e-12 * expected.norm()) << t;
  }
  // Sum of n squared standard normals: chi-square(n), +-5 sd.
  EXPECT_NEAR(chi2, n, 5.0 * std::sqrt(2.0 * n));
  EXPECT_GT(chi2_constant, n + 100.0 * std::sqrt(2.0 * n));  // a constant displacement fails
  // The reported coefficients are those of Delta0.
  const DriftCoefficients& c = *r.true_coefficients[1];
  const Vector3d dC1 = c.C1 - spec.config.FindGyro(2)->model.C1;
  EXPECT_NEAR(dC1.normalized().dot(delta0.normalized()), 1.0, 1e-12);

  // The spin axis against RK4 of the printed drift at Delta(t).
  const double reference_step = 0.25;
  const double max_drift = DegPerHourToRadPerSec(4.0);
  const double tol = IntegrationTolerance(spec, max_drift, reference_step);
  auto integrate = [&](const Vector3d& rate_used) {
    return IntegrateTimeVaryingDrift(
        *spec.profile,
        [&](double t, const Vector3d& h_k) {
          PaperDrift p;
          const DriftCoefficients& c = spec.config.FindGyro(2)->model;
          p.k0 = c.k0;
          p.C11 = c.C1(0), p.C12 = c.C1(1), p.C13 = c.C1(2);
          p.C21 = c.C2(0), p.C22 = c.C2(1), p.C23 = c.C2(2);
          const Vector3d delta = delta0 + rate_used * t;
          const Vector3d lambda = delta.normalized();
          p.l1 = lambda(0), p.l2 = lambda(1), p.l3 = lambda(2);
          p.C10 = spec.gyros[1].c10_per_m * delta.norm();
          p.C20 = spec.gyros[1].c20_per_m * delta.norm();
          return PaperDrift_k(p, h_k);
        },
        r.truth[0].gyros[1]->C_b_k, r.truth[0].gyros[1]->h_in, spec.telemetry_step,
        r.truth.size(), reference_step);
  };
  for (const TruthSample& t : r.truth) EXPECT_LT(t.gyros[1]->dw_k.norm(), max_drift);
  EXPECT_LT(MaxAngle(integrate(rate), r.truth, 1), tol);
  EXPECT_GT(MaxAngle(integrate(Vector3d::Zero()), r.truth, 1), 1000.0 * tol);

  // A rate that takes the rotor to the gap within the run is refused.
  SimulationSpec far = spec;
  far.gyros[1].rotor_displacement_rate_k_m_s = Vector3d(10.0 * kMetresPerUm / kSecondsPerHour, 0, 0);
  EXPECT_THAT(Simulate(far), StatusIs(absl::StatusCode::kInvalidArgument,
                                      HasSubstr("gyros[1] (gyro 2).rotor_displacement_rate_k_m_s")));
}

// eq. (3) inverse per suspension axis [V] of the displacement d_k [m].
Vector3d OffsetVoltages_k(const SuspensionConfig& s, const Vector3d& d_k) {
  Vector3d u;
  for (int axis = 0; axis < 3; ++axis) {
    u(axis) =
        OffsetVoltageFromDisplacement(d_k(axis), s.amplifier_gain, s.reference_voltage, s.gap);
  }
  return u;
}

// The paper's drift of gyro `id`'s configured model plus eq. (8) + (9) at the displacement
// delta_k [m] (lambda and sizes computed here), at the spin axis h_k.
Vector3d ModelPlusDisplacementDrift_k(const SimulationSpec& spec, int id, const Vector3d& delta_k,
                                      const Vector3d& h_k) {
  PaperDrift p;
  const DriftCoefficients& c = spec.config.FindGyro(id)->model;
  p.k0 = c.k0;
  p.C11 = c.C1(0), p.C12 = c.C1(1), p.C13 = c.C1(2);
  p.C21 = c.C2(0), p.C22 = c.C2(1), p.C23 = c.C2(2);
  const Vector3d lambda = delta_k.normalized();
  p.l1 = lambda(0), p.l2 = lambda(1), p.l3 = lambda(2);
  p.C10 = spec.gyros[id - 1].c10_per_m * delta_k.norm();
  p.C20 = spec.gyros[id - 1].c20_per_m * delta_k.norm();
  return PaperDrift_k(p, h_k);
}

// Delta(t) = R(z, 2 pi t / 24 h) Delta0, Delta0 = (1.4, 0, 0) um: the truth's displacement is the
// right-handed turn (at 6 h, a quarter turn, (0, 1.4, 0) um), the voltages are eq. (3) of Delta(t)
// (voltage noise off), the drift is eq. (8) + (9) at Delta(t) (the test's printed formulas), and
// the spin axis follows RK4 of that drift while a fixed Delta0 misses it by far. With a rate and
// a tilted axis the growing displacement turns (against Eigen's AngleAxis). A turn of no
// displacement, a zero or non-finite axis, a period <= 0 and a length reaching the gap are
// refused, naming the field.
TEST(Simulator, RotorDisplacementTurnsAboutACaseAxis) {
  SimulationSpec spec = TestSpec(6.0);
  spec.config.random_walk = 0.0;
  const Vector3d delta0 = kMetresPerUm * Vector3d(1.4, 0, 0);
  const double period_s = HoursToSeconds(24.0);
  spec.gyros[1].rotor_displacement_k = delta0;
  // Any non-zero length: the simulator normalises the axis.
  spec.gyros[1].rotor_displacement_turn = DisplacementTurn{Vector3d(0, 0, 2.5), period_s};
  spec.gyros[1].voltage_noise = 0.0;
  spec.gyros[1].c10_per_m = DegPerHourToRadPerSec(0.3) / kMetresPerUm;
  spec.gyros[1].c20_per_m = DegPerHourToRadPerSec(0.1) / kMetresPerUm;
  const SimulationResult r = RunSimulation(spec);
  ASSERT_EQ(r.truth.size(), 361u);
  ASSERT_TRUE(r.effects[1].rotor_displacement_turn.has_value());
  EXPECT_EQ(r.effects[1].rotor_displacement_turn->axis_k, Vector3d::UnitZ());
  EXPECT_EQ(r.effects[1].rotor_displacement_turn->period_s, period_s);
  EXPECT_FALSE(r.effects[0].rotor_displacement_turn.has_value());

  // A quarter turn at 6 h takes case x to case y.
  EXPECT_LT(
      (r.truth.back().gyros[1]->rotor_displacement_k_m - kMetresPerUm * Vector3d(0, 1.4, 0)).norm(),
      1e-12 * delta0.norm());
  const SuspensionConfig& s = spec.config.suspension;
  const double u_size = OffsetVoltages_k(s, delta0).norm();
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const double t = 60.0 * m;
    const double phi = 2.0 * kPi * t / period_s;
    const Vector3d delta = delta0.norm() * Vector3d(std::cos(phi), std::sin(phi), 0.0);
    const GyroTruthSample& gt = *r.truth[m].gyros[1];
    EXPECT_LT((gt.rotor_displacement_k_m - delta).norm(), 1e-12 * delta0.norm()) << t;
    const Vector3d u = *r.recording.frames[m].gyros[1]->u_k_mv * kVoltsPerMv;
    EXPECT_LT((u - OffsetVoltages_k(s, delta)).norm(), 1e-12 * u_size) << t;
    const Vector3d expected = ModelPlusDisplacementDrift_k(spec, 2, delta, gt.h_k);
    EXPECT_LT((gt.dw_k - expected).norm(), 1e-12 * expected.norm()) << t;
  }
  // At 6 h the voltages moved from x to y by the full eq. (3) size.
  const Vector3d u_end = *r.recording.frames.back().gyros[1]->u_k_mv * kVoltsPerMv;
  EXPECT_LT(std::abs(u_end.x()), 1e-12 * u_size);
  EXPECT_NEAR(u_end.y(), OffsetVoltages_k(s, delta0).x(), 1e-12 * u_size);
  // The reported coefficients are those of Delta0.
  const Vector3d dC1 = r.true_coefficients[1]->C1 - spec.config.FindGyro(2)->model.C1;
  EXPECT_NEAR(dC1.normalized().dot(delta0.normalized()), 1.0, 1e-12);

  // The spin axis against RK4 of the printed drift at Delta(t).
  const double reference_step = 0.25;
  const double max_drift = DegPerHourToRadPerSec(4.0);
  const double tol = IntegrationTolerance(spec, max_drift, reference_step);
  auto integrate = [&](bool turning) {
    return IntegrateTimeVaryingDrift(
        *spec.profile,
        [&](double t, const Vector3d& h_k) {
          const double phi = turning ? 2.0 * kPi * t / period_s : 0.0;
          const Vector3d delta = delta0.norm() * Vector3d(std::cos(phi), std::sin(phi), 0.0);
          return ModelPlusDisplacementDrift_k(spec, 2, delta, h_k);
        },
        r.truth[0].gyros[1]->C_b_k, r.truth[0].gyros[1]->h_in, spec.telemetry_step, r.truth.size(),
        reference_step);
  };
  for (const TruthSample& t : r.truth) EXPECT_LT(t.gyros[1]->dw_k.norm(), max_drift);
  EXPECT_LT(MaxAngle(integrate(true), r.truth, 1), tol);
  EXPECT_GT(MaxAngle(integrate(false), r.truth, 1), 1000.0 * tol);

  // Growing and turning together, about a tilted axis.
  SimulationSpec both = spec;
  const Vector3d rate = kMetresPerUm / kSecondsPerHour * Vector3d(0.1, -0.05, 0.2);  // [m/s]
  const Vector3d axis = Vector3d(1.0, -2.0, 0.5).normalized();
  const double period_both_s = HoursToSeconds(5.0);
  both.gyros[1].rotor_displacement_rate_k_m_s = rate;
  both.gyros[1].rotor_displacement_turn = DisplacementTurn{axis, period_both_s};
  const SimulationResult rb = RunSimulation(both);
  ASSERT_EQ(rb.truth.size(), 361u);
  for (size_t m = 0; m < rb.truth.size(); m += 15) {
    const double t = 60.0 * m;
    const Vector3d delta =
        Eigen::AngleAxisd(2.0 * kPi * t / period_both_s, axis).toRotationMatrix() *
        (delta0 + rate * t);
    const GyroTruthSample& gt = *rb.truth[m].gyros[1];
    EXPECT_LT((gt.rotor_displacement_k_m - delta).norm(), 1e-12 * delta.norm()) << t;
    const Vector3d u = *rb.recording.frames[m].gyros[1]->u_k_mv * kVoltsPerMv;
    EXPECT_LT((u - OffsetVoltages_k(s, delta)).norm(), 1e-12 * u_size) << t;
    const Vector3d expected = ModelPlusDisplacementDrift_k(both, 2, delta, gt.h_k);
    EXPECT_LT((gt.dw_k - expected).norm(), 1e-12 * expected.norm()) << t;
  }
  EXPECT_EQ(rb.effects[1].rotor_displacement_rate_k_m_s, rate);

  auto expect_invalid = [](const SimulationSpec& bad, const std::string& field) {
    EXPECT_THAT(Simulate(bad), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr(field)));
  };
  const std::string f = "gyros[1] (gyro 2).rotor_displacement_turn";
  {
    SimulationSpec bad = spec;
    bad.gyros[1].rotor_displacement_k = Vector3d::Zero();
    expect_invalid(bad, f + ": needs a non-zero rotor_displacement_k");
  }
  {
    SimulationSpec bad = spec;
    bad.gyros[1].rotor_displacement_turn->axis_k = Vector3d::Zero();
    expect_invalid(bad, f + ".axis_k: must be a finite non-zero vector");
    bad.gyros[1].rotor_displacement_turn->axis_k = Vector3d(0, std::nan(""), 1);
    expect_invalid(bad, f + ".axis_k: must be a finite non-zero vector");
  }
  for (double period : {0.0, -3600.0, std::numeric_limits<double>::infinity(), std::nan("")}) {
    SimulationSpec bad = spec;
    bad.gyros[1].rotor_displacement_turn->period_s = period;
    expect_invalid(bad, f + ".period_s: must be finite and > 0");
  }
  {
    // Each component inside the gap (accepted without a turn), the length not: refused, as the
    // turn brings the length onto a case axis.
    SimulationSpec bad = spec;
    bad.gyros[1].rotor_displacement_k = 0.8 * s.gap * Vector3d(1, 1, 0);
    expect_invalid(bad, f + ": the turning displacement's length");
    bad.gyros[1].rotor_displacement_turn.reset();
    EXPECT_THAT(Simulate(bad), IsOk());
  }
}

// A turn draws no random number: against the same displaced rotor without a turn, the other gyros
// and the star tracker are bit for bit the same, the turned gyro's first reading (before anything
// has turned) too, and its voltages differ by exactly eq. (3) of the turn (the same noise draws).
TEST(Simulator, RotorDisplacementTurnDrawsNoRandomNumbers) {
  SimulationSpec fixed = TestSpec(3.0);
  const Vector3d delta0 = kMetresPerUm * Vector3d(0.8, -0.6, 0.3);
  fixed.gyros[1].rotor_displacement_k = delta0;
  SimulationSpec turning = fixed;
  const double period_s = HoursToSeconds(6.0);
  turning.gyros[1].rotor_displacement_turn = DisplacementTurn{Vector3d::UnitX(), period_s};
  const SimulationResult rf = RunSimulation(fixed);
  const SimulationResult rt = RunSimulation(turning);
  ASSERT_EQ(rf.truth.size(), rt.truth.size());
  const SuspensionConfig& s = fixed.config.suspension;
  double max_voltage_move = 0.0;
  for (size_t m = 0; m < rt.truth.size(); ++m) {
    const TelemetryFrame& a = rf.recording.frames[m];
    const TelemetryFrame& b = rt.recording.frames[m];
    for (int g : {0, 2}) {
      EXPECT_EQ(a.gyros[g]->h_k, b.gyros[g]->h_k) << m;
      EXPECT_EQ(*a.gyros[g]->u_k_mv, *b.gyros[g]->u_k_mv) << m;
    }
    EXPECT_EQ(a.star_tracker->q_in_b.coeffs(), b.star_tracker->q_in_b.coeffs()) << m;
    const Vector3d moved = OffsetVoltages_k(s, rt.truth[m].gyros[1]->rotor_displacement_k_m) -
                           OffsetVoltages_k(s, delta0);
    const Vector3d du = (*b.gyros[1]->u_k_mv - *a.gyros[1]->u_k_mv) * kVoltsPerMv;
    EXPECT_LT((du - moved).norm(), 1e-13) << m;  // [V]; the noise is 1e-3 V
    max_voltage_move = std::max(max_voltage_move, moved.norm());
  }
  EXPECT_EQ(rf.recording.frames[0].gyros[1]->h_k, rt.recording.frames[0].gyros[1]->h_k);
  EXPECT_GT(max_voltage_move, 0.01);  // the turn does move the voltages [V]
  EXPECT_GT(rt.truth.back().gyros[1]->h_in.cross(rf.truth.back().gyros[1]->h_in).norm(), 1e-6);
}

// With zero readout noise the reading is normalise((I + D) h_true) exactly (to rounding).
TEST(Simulator, ReadoutDistortionIsApplied) {
  SimulationSpec spec = TestSpec(2.0);
  for (int g = 0; g < 3; ++g) spec.gyros[g].readout_noise = 0.0;
  Matrix3d D;
  D << 300e-6, 50e-6, -20e-6,  //
      50e-6, -150e-6, 80e-6,   //
      -20e-6, 80e-6, 100e-6;
  spec.gyros[0].readout_distortion_k = D;
  const SimulationResult r = RunSimulation(spec);
  EXPECT_EQ(r.effects[0].readout_distortion_k, D);
  double max_effect = 0.0;
  for (size_t m = 0; m < r.truth.size(); ++m) {
    const Vector3d& h_true = r.truth[m].gyros[0]->h_k;
    const Vector3d expected = ((Matrix3d::Identity() + D) * h_true).normalized();
    EXPECT_LT((r.recording.frames[m].gyros[0]->h_k - expected).norm(), 1e-15) << m;
    max_effect = std::max(max_effect, (expected - h_true).norm());
    // Gyro 2 has none: its reading is the true axis.
    EXPECT_LT((r.recording.frames[m].gyros[1]->h_k - r.truth[m].gyros[1]->h_k).norm(), 1e-15);
  }
  EXPECT_GT(max_effect, 1e-5);  // the distortion is really there (1e-15 is far below it)
  SimulationSpec bad = spec;
  bad.gyros[0].readout_distortion_k(0, 1) = 0.0;  // not symmetric
  EXPECT_THAT(Simulate(bad), StatusIs(absl::StatusCode::kInvalidArgument,
                                      HasSubstr("gyros[0] (gyro 1).readout_distortion_k")));
}

// Random telegraph process over 200 h with mean dwell tau = 1 h on 3 gyros: the level is only +-1,
// flips exactly at the reported switch times, the drift is the model's plus level * A; the number
// of switches per gyro is Poisson(200): within 5 sd (5 sqrt(200) = 71) of 200, and the total over
// the 3 gyros within 5 sqrt(600) = 122 of 600; the mean dwell (all gaps) within 5 sd
// (sd tau / sqrt(n)) of tau. The same seed reproduces the switches, another does not.
TEST(Simulator, SwitchingDriftIsARandomTelegraphProcess) {
  SimulationSpec spec = TestSpec(200.0, "inertial");
  spec.telemetry_step = 600.0;
  spec.integration_rate_hz = 0.5;
  spec.config.random_walk = 0.0;
  const double tau = HoursToSeconds(1.0);
  const Vector3d A = DegPerHourToRadPerSec(0.05) * Vector3d(1.0, -2.0, 0.5);
  for (int g = 0; g < 3; ++g) spec.gyros[g].switching_drift = SwitchingDrift{A, tau};
  const SimulationResult r = RunSimulation(spec);
  const double expected = spec.duration / tau;
  int total = 0;
  double gap_sum = 0.0;
  int gaps = 0;
  for (int g = 0; g < 3; ++g) {
    SCOPED_TRACE(::testing::Message() << "gyro " << g + 1);
    const GyroEffectsTruth& e = r.effects[g];
    const std::vector<double>& times = e.switch_times_s;
    const int n = static_cast<int>(times.size());
    EXPECT_NEAR(n, expected, 5.0 * std::sqrt(expected));
    total += n;
    EXPECT_TRUE(e.switching_initial_level == 1.0 || e.switching_initial_level == -1.0);
    EXPECT_TRUE(std::is_sorted(times.begin(), times.end()));
    EXPECT_GT(times.front(), 0.0);
    EXPECT_LE(times.back(), spec.duration);
    for (int i = 1; i < n; ++i) {
      gap_sum += times[i] - times[i - 1];
      ++gaps;
    }
    int level_changes = 0;
    for (size_t m = 0; m < r.truth.size(); ++m) {
      const double t = spec.telemetry_step * m;
      const GyroTruthSample& s = *r.truth[m].gyros[g];
      ASSERT_TRUE(s.switching_level == 1.0 || s.switching_level == -1.0);
      const auto flips = std::count_if(times.begin(), times.end(), [&](double x) { return x <= t; });
      EXPECT_EQ(s.switching_level, flips % 2 == 0 ? e.switching_initial_level
                                                  : -e.switching_initial_level);
      EXPECT_EQ(s.dw_switching_k_rad_s, s.switching_level * A);
      const Vector3d total_drift = ModelDrift_k(r, r.truth[m], g) + s.switching_level * A;
      EXPECT_LT((s.dw_k - total_drift).norm(), 1e-12 * total_drift.norm());
      if (m > 0 && s.switching_level != r.truth[m - 1].gyros[g]->switching_level) ++level_changes;
    }
    EXPECT_GT(level_changes, 10);  // seen at the frames too
  }
  EXPECT_NEAR(total, 3.0 * expected, 5.0 * std::sqrt(3.0 * expected));
  EXPECT_NEAR(gap_sum / gaps, tau, 5.0 * tau / std::sqrt(static_cast<double>(gaps)));
  // Reproducible from the seed; another seed switches elsewhere.
  SimulationSpec short_spec = spec;
  short_spec.duration = HoursToSeconds(20.0);
  const SimulationResult a = RunSimulation(short_spec);
  const SimulationResult b = RunSimulation(short_spec);
  EXPECT_EQ(a.effects[0].switch_times_s, b.effects[0].switch_times_s);
  short_spec.seed = 43;
  const SimulationResult c = RunSimulation(short_spec);
  EXPECT_NE(a.effects[0].switch_times_s, c.effects[0].switch_times_s);
  SimulationSpec bad = short_spec;
  bad.gyros[0].switching_drift->mean_dwell_s = 0.0;
  EXPECT_THAT(Simulate(bad), StatusIs(absl::StatusCode::kInvalidArgument,
                                      HasSubstr("gyros[0] (gyro 1).switching_drift.mean_dwell_s")));
}

// The hidden driver x(t) at the frames, 600 s apart, over 2000 h on 3 gyros (tau = 0.5 h): an
// AR(1) sequence with rho = exp(-600 s / tau) = 0.7165 and unit variance. With N = 36003 samples
// (Bartlett's large-sample formulas for an AR(1) sequence): the sample mean has sd
// sqrt((1 + rho) / (1 - rho) / N) = 0.013, the sample variance sd
// sqrt(2 (1 + rho^2) / (1 - rho^2) / N) = 0.013, the lag-1 correlation sd
// sqrt((1 - rho^2) / N) = 0.0037, the lag-3 correlation (rho^3 = 0.368) sd
// sqrt(((1 + rho^2)(1 - rho^6) / (1 - rho^2) - 6 rho^6) / N) = 0.0072; each is checked at 5 sd.
// The lag-3 value separates the exponential correlation of the OU process from other processes
// with the same lag-1 value; a correlation time 20% off misses the lag-1 band (checked). The
// drift is x B plus the model.
TEST(Simulator, HiddenDriverDriftIsAnOrnsteinUhlenbeckProcess) {
  SimulationSpec spec = TestSpec(2000.0, "inertial");
  spec.telemetry_step = 600.0;
  spec.integration_rate_hz = 0.5;
  spec.config.random_walk = 0.0;
  const double tau = HoursToSeconds(0.5);
  const Vector3d B = DegPerHourToRadPerSec(0.02) * Vector3d(0.5, 1.0, -1.0);
  for (int g = 0; g < 3; ++g) spec.gyros[g].hidden_driver_drift = HiddenDriverDrift{B, tau};
  const SimulationResult r = RunSimulation(spec);
  const double rho = std::exp(-spec.telemetry_step / tau);
  double sum = 0.0, sum_sq = 0.0, lag1 = 0.0, lag3 = 0.0;
  int n = 0, n1 = 0, n3 = 0;
  for (int g = 0; g < 3; ++g) {
    for (size_t m = 0; m < r.truth.size(); ++m) {
      const GyroTruthSample& s = *r.truth[m].gyros[g];
      const double x = s.hidden_driver;
      EXPECT_EQ(s.dw_hidden_k_rad_s, x * B);
      if (m % 97 == 0) {
        const Vector3d total = ModelDrift_k(r, r.truth[m], g) + x * B;
        EXPECT_LT((s.dw_k - total).norm(), 1e-12 * total.norm());
      }
      sum += x;
      sum_sq += x * x;
      ++n;
      if (m >= 1) {
        lag1 += x * r.truth[m - 1].gyros[g]->hidden_driver;
        ++n1;
      }
      if (m >= 3) {
        lag3 += x * r.truth[m - 3].gyros[g]->hidden_driver;
        ++n3;
      }
    }
  }
  ASSERT_EQ(n, 3 * 12001);
  const double mean = sum / n;
  const double variance = sum_sq / n - mean * mean;
  const double c1 = lag1 / n1 / variance, c3 = lag3 / n3 / variance;
  EXPECT_NEAR(mean, 0.0, 5.0 * std::sqrt((1.0 + rho) / (1.0 - rho) / n));
  EXPECT_NEAR(variance, 1.0, 5.0 * std::sqrt(2.0 * (1.0 + rho * rho) / (1.0 - rho * rho) / n));
  EXPECT_NEAR(c1, rho, 5.0 * std::sqrt((1.0 - rho * rho) / n));
  const double rho3 = rho * rho * rho;
  EXPECT_NEAR(c3, rho3,
              5.0 * std::sqrt(((1.0 + rho * rho) * (1.0 - rho3 * rho3) / (1.0 - rho * rho) -
                               6.0 * rho3 * rho3) /
                              n));
  // A correlation time off by 20% falls outside the lag-1 band.
  EXPECT_GT(std::abs(c1 - std::exp(-spec.telemetry_step / (1.2 * tau))),
            5.0 * std::sqrt((1.0 - rho * rho) / n));
  SimulationSpec bad = spec;
  bad.duration = 3600.0;
  bad.gyros[2].hidden_driver_drift->correlation_time_s = -1.0;
  EXPECT_THAT(Simulate(bad),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[2] (gyro 3).hidden_driver_drift.correlation_time_s")));
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
  {
    SimulationSpec s = spec;
    s.gyros[0].fault = GyroFault{100.0, GyroFault::Kind::kReadingsMissing, Vector3d::Zero(), 50.0};
    expect_invalid(s, "gyros[0] (gyro 1).fault.end");
  }
  {
    SimulationSpec s = spec;
    s.gyros[3].switch_on_time = std::numeric_limits<double>::infinity();
    expect_invalid(s, "gyros[3] (gyro 4).switch_on_time");
  }
  {
    SimulationSpec s = spec;
    s.star_tracker.outlier_burst = StarTrackerOutlierBurst{0.0, 0, ArcminToRad(2.0)};
    expect_invalid(s, "star_tracker.outlier_burst.count");
  }
  {
    SimulationSpec s = spec;
    s.star_tracker.outlier_burst = StarTrackerOutlierBurst{0.0, 5, 0.0};
    expect_invalid(s, "star_tracker.outlier_burst.angle");
  }
  {
    SimulationSpec s = spec;
    s.star_tracker.frozen = {{0.0, 10.0}, {30.0, 30.0}};
    expect_invalid(s, "star_tracker.frozen[1]");
  }
  {
    SimulationSpec s = spec;
    s.star_tracker.misalignment_jump = StarTrackerMisalignmentJump{std::nan(""), Vector3d::Zero()};
    expect_invalid(s, "star_tracker.misalignment_jump.time");
  }
}

}  // namespace
}  // namespace esg::estimator
