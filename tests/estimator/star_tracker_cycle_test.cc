// The star tracker's mount turning with the orbit (estimator/discovery/star_tracker_cycle.h,
// docs/discovery.md "The star tracker's side"): the six signatures against the measured spin axis
// of a star tracker actually turned by a small rotation, and the correction that undoes the
// turn. The whole diagnosis on simulated recordings is in discovery_verdict_test.cc
// (DiagnoseVerdict.AMountTurningWithTheOrbit...) and the confusion row `star_tracker_cycle`.
#include <cmath>
#include <vector>

#include "Eigen/Geometry"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/star_tracker_cycle.h"
#include "estimator/rotation.h"
#include "estimator/units.h"
#include "gtest/gtest.h"

namespace esg::estimator::discovery {
namespace {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector2d;
using Eigen::Vector3d;

// A series of four samples a quarter of the period apart, the body turning between them, a
// mounting turned against the body.
struct CycleSetup {
  DeviationSeries series;
  std::vector<Matrix3d> C_in_b;
  Matrix3d C_b_k;
  double period_s = 3600.0;
};

CycleSetup MakeSetup() {
  CycleSetup s;
  s.C_b_k = ExpMatrix(Vector3d(0.3, -0.2, 0.5));
  const Vector3d h_k = Vector3d(0.2, 0.3, 0.93).normalized();
  for (int k = 0; k < 4; ++k) {
    const Matrix3d C_in_b = ExpMatrix(Vector3d(0.1 * k, 0.4 - 0.2 * k, 0.7 * k));
    s.C_in_b.push_back(C_in_b);
    s.series.hours.push_back(0.25 * k);
    s.series.C_k_in.push_back((C_in_b * s.C_b_k).transpose());
    s.series.h_k.push_back(h_k);
    s.series.y.push_back(Vector2d::Zero());
  }
  s.series.u1 = Vector3d(1, 0, 0);
  s.series.u2 = Vector3d(0, 1, 0);
  return s;
}

// Each signature is the change of the measured inertial spin axis, h_in = C_in_b_st C_b_k h_k,
// when the star tracker reports C_in_b Exp(eps e_i f(t)) instead of C_in_b, per eps, relative to
// the first sample, on (u1, u2): computed here by turning the attitude itself.
TEST(StarTrackerCycle, EachSignatureIsTheMeasuredAxisMovedByTheStarTrackersTurn) {
  const CycleSetup s = MakeSetup();
  const auto signatures = CycleSignatures(s.series, s.C_b_k, s.period_s);
  ASSERT_EQ(signatures.size(), 6u);
  const double eps = 1e-7;
  for (int j = 0; j < 6; ++j) {
    ASSERT_EQ(signatures[j].size(), 4u);
    Vector3d first = Vector3d::Zero();
    for (int k = 0; k < 4; ++k) {
      const double phi = 2.0 * kPi * s.series.hours[k] * 3600.0 / s.period_s;
      const double f = j < 3 ? std::cos(phi) : std::sin(phi);
      const Vector3d turn_b = eps * f * Vector3d::Unit(j % 3);
      const Vector3d h_in = s.C_in_b[k] * s.C_b_k * s.series.h_k[k];
      const Vector3d h_in_turned = s.C_in_b[k] * ExpMatrix(turn_b) * s.C_b_k * s.series.h_k[k];
      const Vector3d moved = (h_in_turned - h_in) / eps;
      if (k == 0) first = moved;
      const Vector3d d = moved - first;
      EXPECT_NEAR(signatures[j][k].x(), d.dot(s.series.u1), 1e-6) << "column " << j << " k " << k;
      EXPECT_NEAR(signatures[j][k].y(), d.dot(s.series.u2), 1e-6) << "column " << j << " k " << k;
    }
  }
  // Not all zero: every column moves the axis somewhere in the recording.
  for (int j = 0; j < 6; ++j) {
    double norm = 0.0;
    for (const Vector2d& v : signatures[j]) norm += v.norm();
    EXPECT_GT(norm, 1e-3) << "column " << j;
  }
}

// A star tracker whose mount turns by m(t) = c cos(phi) + s sin(phi) reports q_in_b (x) Exp(m(t));
// the correction with that cycle gives back q_in_b.
TEST(StarTrackerCycle, TheCorrectionUndoesTheTurnAtEveryFrame) {
  StarTrackerCorrection correction;
  correction.cycle_period_s = 5640.0;
  correction.cycle_epoch = absl::FromUnixSeconds(1551398400);
  correction.cycle_cos_b = ArcsecToRad(1.0) * Vector3d(15.8, -13.9, 16.9);
  correction.cycle_sin_b = ArcsecToRad(1.0) * Vector3d(-7.5, 6.1, -7.9);
  std::vector<TelemetryFrame> frames;
  std::vector<Quaterniond> truth;
  for (int i = 0; i < 5; ++i) {
    TelemetryFrame f;
    f.time = correction.cycle_epoch + absl::Seconds(1000.0 * i);
    const Quaterniond q_in_b(ExpMatrix(Vector3d(0.2 * i, -0.1, 0.3 + 0.05 * i)));
    truth.push_back(q_in_b);
    const double phi = 2.0 * kPi * 1000.0 * i / correction.cycle_period_s;
    const Vector3d m_b = correction.cycle_cos_b * std::cos(phi) +
                         correction.cycle_sin_b * std::sin(phi);
    EXPECT_LT((correction.MisalignmentAt(f.time) - m_b).norm(), 1e-15);
    StarTrackerReading st;
    st.q_in_b = (q_in_b * ExpQuaternion(m_b)).normalized();
    f.star_tracker = st;
    frames.push_back(f);
  }
  EXPECT_FALSE(correction.IsZero());
  const std::vector<TelemetryFrame> corrected = CorrectStarTracker(frames, BodyRates{}, correction);
  for (int i = 0; i < 5; ++i) {
    EXPECT_LT(corrected[i].star_tracker->q_in_b.angularDistance(truth[i]), 1e-12) << "frame " << i;
  }
}

}  // namespace
}  // namespace esg::estimator::discovery
