// The star-tracker mount-shift test (estimator/star_tracker_mount.h) against data with known
// statistics: a constant rotation with Gaussian noise of the stated covariance, a rotation that
// turns with the body (a frozen output), a short burst; and its checkpoint state.
#include "estimator/star_tracker_mount.h"

#include <cmath>
#include <optional>
#include <vector>

#include "Eigen/Cholesky"
#include "estimator/random.h"
#include "estimator/rotation.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;

// The star tracker's noise of rdk1.json (5, 5, 30 arcsec about body x, y, z) plus 4 arcsec of
// pair attitude error about every axis.
Matrix3d StepCovariance() {
  const Vector3d sigma(ArcsecToRad(std::hypot(5.0, 4.0)), ArcsecToRad(std::hypot(5.0, 4.0)),
                       ArcsecToRad(std::hypot(30.0, 4.0)));
  return Matrix3d(sigma.cwiseAbs2().asDiagonal());
}

Vector3d Draw(Rng& rng, const Matrix3d& R) {
  const Matrix3d L = R.llt().matrixL();
  return L * Vector3d(rng.Normal(), rng.Normal(), rng.Normal());
}

// A constant shift with noise of exactly the stated covariance: the scatter is chi-square(27),
// so the test calls it constant with probability 0.999 per window; over 2000 windows at most a
// handful are refused (expected 2; P(more than 10 | Poisson(2)) < 1e-5), and the shift comes out
// within 3 sigma of its stated covariance in every window but a few (the covariance counts the
// pair's error in full, so more than 99.7% are).
TEST(StarTrackerMount, AConstantShiftIsFoundWithinItsCovarianceAfterOneWindow) {
  const Matrix3d R = StepCovariance();
  const Vector3d shift_b = ArcminToRad(2.0) * Vector3d(0.6, -0.8, 0.0);
  Rng rng(11);
  int refused = 0, outside = 0;
  for (int w = 0; w < 2000; ++w) {
    StarTrackerMountMonitor m;
    std::optional<StarTrackerMountMonitor::Decision> d;
    for (int s = 0; s < m.options().window_steps; ++s) {
      ASSERT_FALSE(d.has_value());
      d = m.AddVoted(shift_b + Draw(rng, R), R);
    }
    if (!d.has_value()) {
      ++refused;
      continue;
    }
    EXPECT_EQ(d->steps, 10);
    EXPECT_NEAR(d->threshold, 55.48, 0.01);  // chi2inv(0.999, 27)
    EXPECT_LE(d->scatter, d->threshold);
    const Vector3d e = d->shift_b - shift_b;
    for (int i = 0; i < 3; ++i) outside += std::abs(e(i)) > 3.0 * std::sqrt(d->covariance_b(i, i));
    EXPECT_EQ(m.window_size(), 0);
  }
  EXPECT_LE(refused, 10);
  EXPECT_LE(outside, 6 * 3 * 2000 / 1000);  // below 0.6% of the components (0.27% for exact sigmas)
}

// A frozen star-tracker output while the body turns at 1 deg/min (slower than any profile the
// filter serves: the calibration profile turns 6 deg/min): the rotation between the frozen sample
// and the pairs grows by 1 deg a step and is never called constant.
TEST(StarTrackerMount, ARotationThatTurnsWithTheBodyIsNeverCalledConstant) {
  const Matrix3d R = StepCovariance();
  Rng rng(13);
  StarTrackerMountMonitor m;
  for (int s = 0; s < 500; ++s) {
    const Vector3d turning_b = DegToRad(1.0) * s * Vector3d::UnitZ();
    EXPECT_FALSE(m.AddVoted(turning_b + Draw(rng, R), R).has_value()) << "step " << s;
  }
}

// Five outliers of 2-10 arcmin in a row, then the star tracker accepted again (Clear): nothing.
// Nine constant steps, a break, nine more: nothing either; the tenth after the break decides.
TEST(StarTrackerMount, ABurstOrABrokenRunDecidesNothing) {
  const Matrix3d R = StepCovariance();
  Rng rng(17);
  StarTrackerMountMonitor m;
  for (int s = 0; s < 5; ++s) {
    const Vector3d outlier_b = ArcminToRad(rng.Uniform(2.0, 10.0)) * Vector3d(1.0, 0.0, 0.0);
    EXPECT_FALSE(m.AddVoted(outlier_b + Draw(rng, R), R).has_value());
  }
  m.Clear();
  const Vector3d shift_b = ArcminToRad(2.0) * Vector3d::UnitY();
  for (int s = 0; s < 9; ++s) EXPECT_FALSE(m.AddVoted(shift_b + Draw(rng, R), R).has_value());
  m.Clear();
  for (int s = 0; s < 9; ++s) EXPECT_FALSE(m.AddVoted(shift_b + Draw(rng, R), R).has_value());
  EXPECT_TRUE(m.AddVoted(shift_b + Draw(rng, R), R).has_value());
}

// While the body turns steadily, a time-tag error tau rotates the star tracker's output by
// -w_b tau, a constant: the decision names the latency as the alternative (with tau) when the
// shift lies along the rate, or when the rate changed since the star tracker was last applied,
// and not when it lies across a rate that has not changed.
TEST(StarTrackerMount, AShiftAlongASteadyBodyRateHasTheLatencyAsItsAlternative) {
  const Matrix3d R = StepCovariance();
  const Vector3d w_b = DegToRad(6.0) / 60.0 * Vector3d(0.0, 0.6, 0.8);  // the calibration profile's
  Rng rng(23);
  // The filter applied the star tracker at this steady rate for an hour before the shift.
  auto decide = [&](const Vector3d& shift_b) {
    StarTrackerMountMonitor m;
    for (int s = 0; s < 60; ++s) m.NoteApplied(w_b);
    std::optional<StarTrackerMountMonitor::Decision> d;
    for (int s = 0; s < m.options().window_steps; ++s)
      d = m.AddVoted(shift_b + Draw(rng, R), R, w_b);
    return d;
  };
  const auto latency = decide(-0.3 * w_b);
  ASSERT_TRUE(latency.has_value());
  EXPECT_TRUE(latency->latency_alternative);
  EXPECT_LT(latency->perpendicular_chi2, latency->perpendicular_threshold);
  EXPECT_NEAR(latency->latency_alternative_s, 0.3, 0.05);
  EXPECT_NEAR((latency->mean_rate_b - w_b).norm(), 0.0, 1e-15);
  // 2 arcmin across the rate (w_b x body x is perpendicular to w_b).
  const auto mount = decide(ArcminToRad(2.0) * w_b.cross(Vector3d::UnitX()).normalized());
  ASSERT_TRUE(mount.has_value());
  EXPECT_FALSE(mount->latency_alternative);
  EXPECT_GT(mount->perpendicular_chi2, mount->perpendicular_threshold);
  // The filter ran on the late star tracker at a rate w_before, whose -w_before tau its
  // misalignment states absorbed; the rate changes and -(w - w_before) tau remains, not along w.
  const Vector3d w_before_b = DegToRad(6.0) / 60.0 * Vector3d(0.8, 0.0, -0.6);
  StarTrackerMountMonitor changed;
  changed.NoteApplied(w_before_b);
  std::optional<StarTrackerMountMonitor::Decision> c;
  for (int s = 0; s < 10; ++s) {
    c = changed.AddVoted(-0.3 * (w_b - w_before_b) + Draw(rng, R), R, w_b);
  }
  ASSERT_TRUE(c.has_value());
  EXPECT_TRUE(c->latency_alternative);
  EXPECT_NEAR(c->latency_alternative_s, 0.3, 0.05);
  EXPECT_EQ(c->rate_before_b, w_before_b);
  // At rest no latency rotates the output.
  StarTrackerMountMonitor rest;
  std::optional<StarTrackerMountMonitor::Decision> d;
  for (int s = 0; s < 10; ++s) d = rest.AddVoted(-0.3 * w_b + Draw(rng, R), R);
  ASSERT_TRUE(d.has_value());
  EXPECT_FALSE(d->latency_alternative);
}

// A step whose values are not finite, or whose covariance is not positive definite, starts the
// window again instead of entering the mean.
TEST(StarTrackerMount, AnUnusableStepStartsTheWindowAgain) {
  const Matrix3d R = StepCovariance();
  StarTrackerMountMonitor m;
  for (int s = 0; s < 5; ++s) EXPECT_FALSE(m.AddVoted(Vector3d::Zero(), R).has_value());
  EXPECT_FALSE(m.AddVoted(Vector3d(std::nan(""), 0, 0), R).has_value());
  EXPECT_EQ(m.window_size(), 0);
  EXPECT_FALSE(m.AddVoted(Vector3d::Zero(), -R).has_value());
  EXPECT_EQ(m.window_size(), 0);
}

// The window survives ExportState/RestoreState and decides at the same step with the same
// numbers; corrupt states are DataLoss and leave the object unchanged.
TEST(StarTrackerMount, StateRoundTripDecidesAlikeAndCorruptionIsDataLoss) {
  const Matrix3d R = StepCovariance();
  const Vector3d shift_b = ArcminToRad(2.0) * Vector3d(0.0, 0.6, 0.8);
  Rng rng(19);
  std::vector<Vector3d> d;
  for (int s = 0; s < 10; ++s) d.push_back(shift_b + Draw(rng, R));
  StarTrackerMountMonitor a;
  for (int s = 0; s < 6; ++s) ASSERT_FALSE(a.AddVoted(d[s], R).has_value());
  StarTrackerMountMonitor b;
  ASSERT_TRUE(b.RestoreState(a.ExportState()).ok());
  EXPECT_EQ(b.ExportState(), a.ExportState());
  std::optional<StarTrackerMountMonitor::Decision> da, db;
  for (int s = 6; s < 10; ++s) {
    da = a.AddVoted(d[s], R);
    db = b.AddVoted(d[s], R);
  }
  ASSERT_TRUE(da.has_value() && db.has_value());
  EXPECT_EQ(da->shift_b, db->shift_b);
  EXPECT_EQ(da->scatter, db->scatter);

  StarTrackerMountMonitor c;
  for (int s = 0; s < 3; ++s) ASSERT_FALSE(c.AddVoted(d[s], R).has_value());
  const std::vector<double> good = c.ExportState();
  // The layout: the applied rates kept (0: none here), the step count (1), then per step d_b
  // (2-4 for the first), R_b (5-13) and w_b.
  ASSERT_EQ(good[0], 0.0);
  auto with = [&](size_t i, double x) {
    std::vector<double> v = good;
    v[i] = x;
    return v;
  };
  const std::vector<std::vector<double>> bad = {
      {},
      {0.0, 10.0},  // a full window is never stored
      {0.0, -1.0},
      {0.0, 1.5},
      {61.0, 0.0},                                        // more applied rates than are kept
      {1.0, 0.0},                                         // an applied rate missing
      {1.0, std::nan(""), 0.0, 0.0, 0.0},                 // an applied rate not finite
      std::vector<double>(good.begin(), good.end() - 1),  // truncated
      with(2, std::nan("")),                              // a shift not finite
      with(5, -1.0),                                      // a covariance not positive
  };
  for (const auto& v : bad) {
    StarTrackerMountMonitor e = c;
    EXPECT_EQ(e.RestoreState(v).code(), absl::StatusCode::kDataLoss);
    EXPECT_EQ(e.ExportState(), good);
  }
}

}  // namespace
}  // namespace esg::estimator
