#include "estimator/measurements.h"

#include "estimator/rotation.h"

namespace esg::estimator {

using Eigen::Matrix3d;
using Eigen::Vector3d;

Eigen::Matrix<double, 3, 2> TangentBasis(const Vector3d& u) {
  const Vector3d a = AnyPerpendicular(u);
  Eigen::Matrix<double, 3, 2> U;
  U.col(0) = a;
  U.col(1) = u.cross(a);
  return U;
}

StarTrackerDifference MakeStarTrackerDifference(const Vector3d& h_in,
                                                const Eigen::Matrix<double, 3, 2>& T,
                                                const Matrix3d& C_in_b_st, const Matrix3d& C_b_k,
                                                const Vector3d& h_k) {
  // eq. (13): h_et_in = C_in_b(st) C_b_k h_k rebuilt from the star tracker.
  StarTrackerDifference d;
  const Eigen::Matrix<double, 2, 3> Tt = T.transpose();
  const Vector3d h_b = C_b_k * h_k;
  d.z = Tt * ((C_in_b_st * h_b).normalized() - h_in);
  d.H_h = Eigen::Matrix2d::Identity();
  // h_in(true) = C_in_b Exp(dphi) h_b, so h_et = h_in(true) + C_in_b [h_b]x dphi.
  d.H_phi = Tt * C_in_b_st * Skew(h_b);
  // C_in_b(st) = C_in_b Exp(n): h_et gains C_in_b (n x h_b) = -C_in_b [h_b]x n.
  d.G_st = -Tt * C_in_b_st * Skew(h_b);
  d.G_readout = Tt * C_in_b_st * C_b_k * TangentBasis(h_k);
  return d;
}

AutonomousDifference MakeAutonomousDifference(const Vector3d& h_in_a,
                                              const Eigen::Matrix<double, 3, 2>& T_a,
                                              const Matrix3d& C_b_k_a, const Vector3d& h_k_a,
                                              const Vector3d& h_in_b,
                                              const Eigen::Matrix<double, 3, 2>& T_b,
                                              const Matrix3d& C_b_k_b, const Vector3d& h_k_b) {
  // eq. (13): z_avt = cos(theta_R) - cos(theta_S).
  AutonomousDifference d;
  const Vector3d h_ba = C_b_k_a * h_k_a, h_bb = C_b_k_b * h_k_b;
  d.z = h_in_a.dot(h_in_b) - h_ba.dot(h_bb);
  // cos(theta_R) of the true axes = z_pred + (T_a dx_a).h_b + h_a.(T_b dx_b), and the true
  // cos(theta_S) equals it, so z = -(...) + (terms of the misalignment in cos(theta_S)).
  d.H_h_a = -(T_a.transpose() * h_in_b).transpose();
  d.H_h_b = -(T_b.transpose() * h_in_a).transpose();
  // cos(theta_S) with the true mountings: + (dphi_a - dphi_b) . (h_ba x h_bb).
  const Vector3d cross = h_ba.cross(h_bb);
  d.H_phi_a = cross.transpose();
  d.H_phi_b = -cross.transpose();
  d.G_readout_a = -(h_bb.transpose() * C_b_k_a * TangentBasis(h_k_a));
  d.G_readout_b = -(h_ba.transpose() * C_b_k_b * TangentBasis(h_k_b));
  return d;
}

}  // namespace esg::estimator
