// Convention pinning tests (docs/conventions.md, conventions.h): the 90 deg example, quaternion ==
// DCM, scalar-first round trip, Eigen constructor versus coeffs() order, tag cancellation.
#include "estimator/conventions.h"

#include <cmath>

#include "estimator/random.h"
#include "estimator/rotation.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/quaternion_matchers.h"

namespace esg::estimator {
namespace {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using ::esg::testing::IsNearQuaternion;

Quaterniond RandomQuaternion(Rng& rng) {
  const double w = rng.Normal();
  const Vector3d v = rng.Normal3();
  return Quaterniond(w, v.x(), v.y(), v.z()).normalized();
}

TEST(Conventions, NinetyDegreeAboutZPinningExample) {
  // conventions.h item 4: b is in turned +90 deg about in's z axis.
  const Quaterniond q_in_b = ExpQuaternion(Vector3d(0, 0, DegToRad(90.0)));
  EXPECT_NEAR(q_in_b.w(), std::cos(DegToRad(45.0)), 1e-15);
  EXPECT_NEAR(q_in_b.x(), 0.0, 1e-15);
  EXPECT_NEAR(q_in_b.y(), 0.0, 1e-15);
  EXPECT_NEAR(q_in_b.z(), std::sin(DegToRad(45.0)), 1e-15);
  const Matrix3d C_in_b = q_in_b.toRotationMatrix();
  EXPECT_LT((C_in_b * Vector3d::UnitX() - Vector3d::UnitY()).norm(), 1e-15);
  EXPECT_LT((q_in_b * Vector3d::UnitX() - Vector3d::UnitY()).norm(), 1e-15);
  // The body y axis points along in's -x.
  EXPECT_LT((C_in_b * Vector3d::UnitY() + Vector3d::UnitX()).norm(), 1e-15);
}

TEST(Conventions, QuaternionRotationMatrixIsTheDcm) {
  // v_a = q_a_b (x) v_b (x) conj(q_a_b) equals C_a_b v_b with C_a_b = q_a_b.toRotationMatrix().
  Rng rng(11);
  for (int i = 0; i < 100; ++i) {
    const Quaterniond q_a_b = RandomQuaternion(rng);
    const Vector3d v_b = rng.Normal3();
    const Quaterniond p(0.0, v_b.x(), v_b.y(), v_b.z());
    const Quaterniond rotated = q_a_b * p * q_a_b.conjugate();
    const Vector3d v_a = q_a_b.toRotationMatrix() * v_b;
    EXPECT_LT((Vector3d(rotated.x(), rotated.y(), rotated.z()) - v_a).norm(), 1e-14);
    EXPECT_NEAR(rotated.w(), 0.0, 1e-14);
  }
}

TEST(Conventions, ScalarFirstRoundTrip) {
  const ScalarFirst wire = {0.5, -0.5, 0.5, 0.5};
  const Quaterniond q = QuaternionFromScalarFirst(wire);
  EXPECT_EQ(q.w(), 0.5);
  EXPECT_EQ(q.x(), -0.5);
  EXPECT_EQ(q.y(), 0.5);
  EXPECT_EQ(q.z(), 0.5);
  EXPECT_EQ(ToScalarFirst(q), wire);
}

TEST(Conventions, EigenConstructorOrderDiffersFromCoeffsStorage) {
  // Eigen #375: Quaterniond(w, x, y, z) stores coeffs() as (x, y, z, w).
  const Quaterniond q(1.0, 2.0, 3.0, 4.0);
  EXPECT_EQ(q.w(), 1.0);
  EXPECT_EQ(q.coeffs()(0), 2.0);
  EXPECT_EQ(q.coeffs()(1), 3.0);
  EXPECT_EQ(q.coeffs()(2), 4.0);
  EXPECT_EQ(q.coeffs()(3), 1.0);
}

TEST(Conventions, CompositionTagsCancelOnRandomTriple) {
  // C_a_c = C_a_b C_b_c and q_a_c = q_a_b (x) q_b_c; inverse by transpose / conjugate.
  Rng rng(12);
  const Quaterniond q_a_b = RandomQuaternion(rng);
  const Quaterniond q_b_c = RandomQuaternion(rng);
  const Quaterniond q_a_c = q_a_b * q_b_c;
  const Matrix3d C_a_c = q_a_b.toRotationMatrix() * q_b_c.toRotationMatrix();
  EXPECT_LT((q_a_c.toRotationMatrix() - C_a_c).norm(), 1e-14);
  const Vector3d v_c = rng.Normal3();
  const Vector3d v_b = q_b_c.toRotationMatrix() * v_c;
  EXPECT_LT((q_a_b.toRotationMatrix() * v_b - C_a_c * v_c).norm(), 1e-14);
  EXPECT_LT((q_a_b.conjugate().toRotationMatrix() - q_a_b.toRotationMatrix().transpose()).norm(),
            1e-15);
  // The reversed product is a different rotation (order matters).
  EXPECT_THAT(q_b_c * q_a_b, ::testing::Not(IsNearQuaternion(q_a_c, 1e-6)));
}

TEST(Conventions, AttitudeErrorIsLeftMultipliedInInertialAxes) {
  // conventions.h item 5: q_true = Exp(dtheta_in) (x) q_est rotates inertial vectors by dtheta_in.
  Rng rng(13);
  const Quaterniond q_est = RandomQuaternion(rng);
  const Vector3d dtheta_in(1e-3, -2e-3, 0.5e-3);
  const Quaterniond q_true = ExpQuaternion(dtheta_in) * q_est;
  const Vector3d v_b = rng.Normal3();
  const Vector3d expected = ExpMatrix(dtheta_in) * (q_est.toRotationMatrix() * v_b);
  EXPECT_LT((q_true.toRotationMatrix() * v_b - expected).norm(), 1e-15 * 10);
  EXPECT_LT((LogQuaternion(q_true * q_est.conjugate()) - dtheta_in).norm(), 1e-15);
}

}  // namespace
}  // namespace esg::estimator
