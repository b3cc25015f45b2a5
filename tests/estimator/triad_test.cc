// Pair attitude and the quasi-inertial frame (docs/physics.md, conventions.h): TRIAD recovers the
// attitude from noiseless spin axes; every pair of three gyros agrees; collinear axes are an error.
#include "estimator/triad.h"

#include <array>

#include "estimator/random.h"
#include "estimator/rotation.h"
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

Quaterniond RandomQuaternion(Rng& rng) {
  const double w = rng.Normal();
  const Vector3d v = rng.Normal3();
  return Quaterniond(w, v.x(), v.y(), v.z()).normalized();
}

TEST(PairAttitude, RecoversTrueAttitudeFromNoiselessData) {
  Rng rng(21);
  for (int trial = 0; trial < 200; ++trial) {
    const Quaterniond q_in_b = RandomQuaternion(rng);
    const Matrix3d C_b_in = q_in_b.toRotationMatrix().transpose();
    // Random mountings and random spin axes in inertial space.
    const Matrix3d C_b_k1 = RandomQuaternion(rng).toRotationMatrix();
    const Matrix3d C_b_k2 = RandomQuaternion(rng).toRotationMatrix();
    const Vector3d h_in_1 = rng.UnitVector();
    const Vector3d h_in_2 = rng.UnitVector();
    const Vector3d h_k1 = C_b_k1.transpose() * C_b_in * h_in_1;
    const Vector3d h_k2 = C_b_k2.transpose() * C_b_in * h_in_2;
    auto q = PairAttitude(h_in_1, h_in_2, C_b_k1 * h_k1, C_b_k2 * h_k2);
    ASSERT_THAT(q, IsOk());
    EXPECT_THAT(*q, IsNearQuaternion(q_in_b, 1e-12)) << "trial " << trial;
  }
}

TEST(PairAttitude, AllThreePairsOfThreeGyrosAgree) {
  Rng rng(22);
  for (int trial = 0; trial < 50; ++trial) {
    const Quaterniond q_in_b = RandomQuaternion(rng);
    const Matrix3d C_b_in = q_in_b.toRotationMatrix().transpose();
    Vector3d h_in[3], h_b[3];
    for (int g = 0; g < 3; ++g) {
      h_in[g] = rng.UnitVector();
      h_b[g] = C_b_in * h_in[g];
    }
    auto q12 = PairAttitude(h_in[0], h_in[1], h_b[0], h_b[1]);
    auto q13 = PairAttitude(h_in[0], h_in[2], h_b[0], h_b[2]);
    auto q23 = PairAttitude(h_in[1], h_in[2], h_b[1], h_b[2]);
    ASSERT_THAT(q12, IsOk());
    ASSERT_THAT(q13, IsOk());
    ASSERT_THAT(q23, IsOk());
    EXPECT_THAT(*q12, IsNearQuaternion(*q13, 1e-12));
    EXPECT_THAT(*q12, IsNearQuaternion(*q23, 1e-12));
    EXPECT_THAT(*q13, IsNearQuaternion(*q23, 1e-12));
  }
}

TEST(PairAttitude, ReferenceGyroIsMatchedExactlyWithNoisySecondGyro) {
  // TRIAD with the reference gyro as primary: its axis maps exactly even when the second is off.
  Rng rng(23);
  const Quaterniond q_in_b = RandomQuaternion(rng);
  const Matrix3d C_b_in = q_in_b.toRotationMatrix().transpose();
  const Vector3d h_in_a = rng.UnitVector(), h_in_b = rng.UnitVector();
  const Vector3d h_b_a = C_b_in * h_in_a;
  const Vector3d h_b_b = ExpMatrix(Vector3d(1e-3, -2e-3, 1e-3)) * (C_b_in * h_in_b);
  auto q = PairAttitude(h_in_a, h_in_b, h_b_a, h_b_b);
  ASSERT_THAT(q, IsOk());
  EXPECT_LT((q->toRotationMatrix() * h_b_a - h_in_a).norm(), 1e-12);
  EXPECT_THAT(*q, ::testing::Not(IsNearQuaternion(q_in_b, 1e-6)));
}

// A unit vector of the plane normal to the unit vector v.
Vector3d TangentOf(const Vector3d& v, Rng& rng) {
  const Vector3d r = rng.Normal3();
  return (r - r.dot(v) * v).normalized();
}

// TriadLinearisation against central differences of PairAttitude: moving each of the four
// vectors along a random tangent, the attitude error Log(q(+eps) q(-eps)^-1) / (2 eps) equals
// omega_in - C_in_b omega_b. Central differences of the smooth TRIAD are exact to ~1e-9 here;
// a sign, a frame or the along-t1 part wrong is an error of order one.
TEST(TriadLinearisation, IsTheFirstOrderChangeOfPairAttitude) {
  Rng rng(43);
  const double eps = 1e-5;
  for (int trial = 0; trial < 50; ++trial) {
    const Vector3d a_in = rng.Normal3().normalized(), b_in = rng.Normal3().normalized();
    const Quaterniond q_in_b = RandomQuaternion(rng);
    const Matrix3d C_in_b = q_in_b.toRotationMatrix();
    const Vector3d a_b = C_in_b.transpose() * a_in, b_b = C_in_b.transpose() * b_in;
    const TriadLinearisation inertial(a_in, b_in), body(a_b, b_b);
    const Vector3d none = Vector3d::Zero();
    for (int moved = 0; moved < 4; ++moved) {
      std::array<Vector3d, 4> v = {a_in, b_in, a_b, b_b};
      const Vector3d d = TangentOf(v[moved], rng);
      auto attitude = [&](double step) {
        std::array<Vector3d, 4> w = v;
        w[moved] = (v[moved] + step * d).normalized();
        return *PairAttitude(w[0], w[1], w[2], w[3]);
      };
      const Vector3d numeric =
          LogQuaternion(attitude(eps) * attitude(-eps).conjugate()) / (2 * eps);
      Vector3d analytic;
      switch (moved) {
        case 0: analytic = inertial.RotationOf(d, none); break;
        case 1: analytic = inertial.RotationOf(none, d); break;
        case 2: analytic = -C_in_b * body.RotationOf(d, none); break;
        default: analytic = -C_in_b * body.RotationOf(none, d); break;
      }
      const double sin_theta = a_in.cross(b_in).norm();
      EXPECT_LT((analytic - numeric).norm(), 1e-6 / sin_theta)
          << "trial " << trial << ", vector " << moved << ": analytic " << analytic.transpose()
          << ", numeric " << numeric.transpose();
    }
  }
}

TEST(PairAttitude, CollinearAxesAreAnError) {
  const Vector3d a = Vector3d(0.3, -0.2, 0.9).normalized();
  EXPECT_THAT(PairAttitude(a, a, a, Vector3d::UnitX()),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("collinear")));
  EXPECT_THAT(PairAttitude(a, Vector3d::UnitX(), a, -a),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("collinear")));
}

TEST(QuasiInertialFrame, RowsFollowDesignDefinition) {
  // conventions.h item 6: e2 = h_a, e1 = unit(h_a x h_b), e3 = e1 x e2;
  // h_b = cos(theta) e2 + sin(theta) e3.
  const Vector3d h_a = Vector3d(0.1, 0.2, 0.97).normalized();
  const Vector3d h_b = Vector3d(0.9, -0.3, 0.2).normalized();
  auto C_int_in = QuasiInertialFrame(h_a, h_b);
  ASSERT_THAT(C_int_in, IsOk());
  EXPECT_LT(((*C_int_in) * (*C_int_in).transpose() - Matrix3d::Identity()).norm(), 1e-14);
  EXPECT_NEAR(C_int_in->determinant(), 1.0, 1e-14);
  EXPECT_LT((C_int_in->row(1).transpose() - h_a).norm(), 1e-15);
  const Vector3d h_b_int = *C_int_in * h_b;
  const double theta = std::acos(h_a.dot(h_b));
  EXPECT_NEAR(h_b_int.x(), 0.0, 1e-15);
  EXPECT_NEAR(h_b_int.y(), std::cos(theta), 1e-15);
  EXPECT_NEAR(h_b_int.z(), std::sin(theta), 1e-15);
  EXPECT_THAT(QuasiInertialFrame(h_a, h_a),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("collinear")));
}

}  // namespace
}  // namespace esg::estimator
