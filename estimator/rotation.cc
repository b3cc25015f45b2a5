#include "estimator/rotation.h"

#include <cmath>

#include "Eigen/SVD"

namespace esg::estimator {

Quaterniond QuaternionFromScalarFirst(const ScalarFirst& q) {
  return Quaterniond(q[0], q[1], q[2], q[3]);  // Eigen constructor order is (w, x, y, z).
}

ScalarFirst ToScalarFirst(const Quaterniond& q) { return {q.w(), q.x(), q.y(), q.z()}; }

Quaterniond Canonical(const Quaterniond& q) {
  if (q.w() < 0.0) return Quaterniond(-q.w(), -q.x(), -q.y(), -q.z());
  return q;
}

Matrix3d Skew(const Vector3d& v) {
  Matrix3d S;
  S << 0.0, -v.z(), v.y(), v.z(), 0.0, -v.x(), -v.y(), v.x(), 0.0;
  return S;
}

Quaterniond ExpQuaternion(const Vector3d& rotation_vector) {
  const double angle = rotation_vector.norm();
  if (angle < 1e-8) {
    // Second-order series keeps the result unit to double precision.
    const Vector3d half = 0.5 * rotation_vector;
    Quaterniond q(1.0 - 0.125 * angle * angle, half.x(), half.y(), half.z());
    return q.normalized();
  }
  const Vector3d axis = rotation_vector / angle;
  const double s = std::sin(0.5 * angle);
  return Quaterniond(std::cos(0.5 * angle), s * axis.x(), s * axis.y(), s * axis.z());
}

Vector3d LogQuaternion(const Quaterniond& q_in) {
  Quaterniond q = Canonical(q_in.normalized());
  const Vector3d v(q.x(), q.y(), q.z());
  const double s = v.norm();
  if (s < 1e-12) return 2.0 * v;
  const double angle = 2.0 * std::atan2(s, q.w());
  return angle * v / s;
}

Matrix3d ExpMatrix(const Vector3d& rotation_vector) {
  return ExpQuaternion(rotation_vector).toRotationMatrix();
}

double RotationAngle(const Quaterniond& q_a, const Quaterniond& q_b) {
  const double d = std::abs(q_a.normalized().dot(q_b.normalized()));
  // 2*acos loses precision near zero; use the vector part instead.
  const Quaterniond dq = q_a.normalized() * q_b.normalized().conjugate();
  const double s = Vector3d(dq.x(), dq.y(), dq.z()).norm();
  return 2.0 * std::atan2(s, d);
}

Vector3d AnyPerpendicular(const Vector3d& u) {
  const Vector3d other = std::abs(u.x()) < 0.9 ? Vector3d::UnitX() : Vector3d::UnitY();
  return u.cross(other).normalized();
}

Matrix3d NearestRotation(const Matrix3d& M) {
  Eigen::JacobiSVD<Matrix3d> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Matrix3d D = Matrix3d::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  return svd.matrixU() * D * svd.matrixV().transpose();
}

}  // namespace esg::estimator
