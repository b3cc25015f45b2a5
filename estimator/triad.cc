#include "estimator/triad.h"

#include "absl/status/status.h"
#include "absl/strings/str_format.h"

namespace esg::estimator {

using Eigen::Matrix3d;
using Eigen::Vector3d;

namespace {

// Columns t1 = a, t2 = unit(a x b), t3 = t1 x t2: the same triad in whichever frame a, b are given.
absl::StatusOr<Matrix3d> Triad(const Vector3d& a, const Vector3d& b, double min_sin_theta,
                               const char* what) {
  const Vector3d t1 = a.normalized();
  const Vector3d cross = t1.cross(b.normalized());
  if (!(cross.norm() > min_sin_theta)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: spin axes are collinear (sin(theta) = %.3g)", what, cross.norm()));
  }
  const Vector3d t2 = cross.normalized();
  Matrix3d T;
  T.col(0) = t1;
  T.col(1) = t2;
  T.col(2) = t1.cross(t2);
  return T;
}

}  // namespace

absl::StatusOr<Matrix3d> QuasiInertialFrame(const Vector3d& h_in_a, const Vector3d& h_in_b,
                                            double min_sin_theta) {
  auto T = Triad(h_in_a, h_in_b, min_sin_theta, "quasi-inertial frame");
  if (!T.ok()) return T.status();
  // conventions.h item 6: e2 = h_a, e1 = unit(h_a x h_b), e3 = e1 x e2.
  const Vector3d e2 = T->col(0);
  const Vector3d e1 = T->col(1);
  const Vector3d e3 = e1.cross(e2);
  Matrix3d C_int_in;
  C_int_in.row(0) = e1.transpose();
  C_int_in.row(1) = e2.transpose();
  C_int_in.row(2) = e3.transpose();
  return C_int_in;
}

absl::StatusOr<Eigen::Quaterniond> PairAttitude(const Vector3d& h_in_a, const Vector3d& h_in_b,
                                                const Vector3d& h_b_a, const Vector3d& h_b_b) {
  auto T_in = Triad(h_in_a, h_in_b, 1e-6, "pair attitude (inertial axes)");
  if (!T_in.ok()) return T_in.status();
  auto T_b = Triad(h_b_a, h_b_b, 1e-6, "pair attitude (body axes)");
  if (!T_b.ok()) return T_b.status();
  // T_in = C_in_b * T_b  =>  C_in_b = T_in * T_b^T.
  const Matrix3d C_in_b = *T_in * T_b->transpose();
  return Eigen::Quaterniond(C_in_b).normalized();
}

TriadLinearisation::TriadLinearisation(const Vector3d& a, const Vector3d& b)
    : t1_(a.normalized()), b_(b.normalized()) {
  const Vector3d cross = t1_.cross(b_);
  const double sin_theta = cross.norm();
  t3_over_sin_ = t1_.cross(cross / sin_theta) / sin_theta;
}

Vector3d TriadLinearisation::RotationOf(const Vector3d& da, const Vector3d& db) const {
  const double along = (da.cross(b_) + t1_.cross(db)).dot(t3_over_sin_);
  return t1_.cross(da) + along * t1_;
}

}  // namespace esg::estimator
