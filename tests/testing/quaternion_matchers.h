// Sign-insensitive quaternion comparison (Ceres IsNearQuaternion style).
#ifndef ESG_TESTS_TESTING_QUATERNION_MATCHERS_H_
#define ESG_TESTS_TESTING_QUATERNION_MATCHERS_H_

#include <cmath>

#include "Eigen/Geometry"
#include "gmock/gmock.h"

namespace esg::testing {

// True when q and expected are the same attitude to within angle_tol [rad].
MATCHER_P2(IsNearQuaternion, expected, angle_tol, "") {
  const Eigen::Quaterniond dq = arg.normalized() * expected.normalized().conjugate();
  const double s = Eigen::Vector3d(dq.x(), dq.y(), dq.z()).norm();
  const double angle = 2.0 * std::atan2(s, std::abs(dq.w()));
  *result_listener << "rotation between them is " << angle << " rad";
  return angle <= angle_tol;
}

}  // namespace esg::testing

#endif  // ESG_TESTS_TESTING_QUATERNION_MATCHERS_H_
