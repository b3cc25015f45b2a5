// Spin-axis propagation (docs/physics.md): dh_in/dt = dw_in x h_in. A constant drift about a fixed
// axis makes h_in precess on a cone about that axis at the rate |dw_in|.
#include "estimator/spin_axis.h"

#include <cmath>

#include "estimator/random.h"
#include "estimator/rotation.h"
#include "estimator/units.h"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

using Eigen::Vector3d;

TEST(SpinAxis, RateIsDriftCrossAxis) {
  const Vector3d dw_in(1e-6, -2e-6, 3e-6);
  const Vector3d h_in = Vector3d(0.3, 0.4, 0.5).normalized();
  EXPECT_LT((SpinAxisRate_in(dw_in, h_in) - dw_in.cross(h_in)).norm(), 1e-22);
  // Along the axis the drift does not move it.
  EXPECT_LT(SpinAxisRate_in(2e-6 * h_in, h_in).norm(), 1e-21);
}

TEST(SpinAxis, ConstantDriftGivesAnalyticPrecessionCone) {
  // Drift 10 deg/h about a fixed axis, 8 Hz for 24 h: h_in(t) = Exp(dw t) h_in(0).
  const Vector3d dw_in = DegPerHourToRadPerSec(10.0) * Vector3d(1.0, -2.0, 0.5).normalized();
  const Vector3d h0 = Vector3d(0.2, 0.7, -0.4).normalized();
  const double dt = 0.125;
  const int steps = static_cast<int>(HoursToSeconds(24.0) / dt);
  Vector3d h = h0;
  const double cone = std::acos(h0.dot(dw_in.normalized()));
  double max_norm_error = 0.0;
  double max_cone_error = 0.0;
  for (int i = 1; i <= steps; ++i) {
    h = StepSpinAxis(h, dw_in, dt);
    max_norm_error = std::max(max_norm_error, std::abs(h.norm() - 1.0));
    if (i % 4800 == 0) {
      const Vector3d expected = ExpMatrix(dw_in * (i * dt)) * h0;
      EXPECT_LT((h - expected).norm(), 1e-9) << "step " << i;
      max_cone_error =
          std::max(max_cone_error, std::abs(std::acos(h.dot(dw_in.normalized())) - cone));
    }
  }
  EXPECT_LT(max_norm_error, 1e-12);
  EXPECT_LT(max_cone_error, 1e-9);
  // 24 h at 10 deg/h is 240 deg around the cone: the end point is far from the start.
  EXPECT_GT((h - h0).norm(), 0.1);
}

TEST(SpinAxis, SlerpIsExactForUniformRotationPerpendicularToSamples) {
  const Vector3d axis = Vector3d(0, 0, 1);
  const Vector3d a = Vector3d(1, 0, 0);
  const Vector3d b = ExpMatrix(0.3 * axis) * a;
  for (double s : {0.0, 0.25, 0.5, 0.9, 1.0}) {
    EXPECT_LT((SlerpUnit(a, b, s) - ExpMatrix(0.3 * s * axis) * a).norm(), 1e-15);
  }
  // Nearly identical samples fall back to linear interpolation without NaN.
  const Vector3d c = (a + Vector3d(0, 1e-12, 0)).normalized();
  EXPECT_TRUE(SlerpUnit(a, c, 0.5).allFinite());
}

}  // namespace
}  // namespace esg::estimator
