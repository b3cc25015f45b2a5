// The measurements of eq. (13) and their Jacobians, with the error convention of conventions.h
// (error = true - estimate; spin-axis error dh = T dx_h in a tangent basis T = [t1, t2] of h_in;
// misalignment C_b_k(true) = Exp(dphi) C_b_k(est); star-tracker noise q_in_b(st) =
// q_in_b (x) Exp(n_st) about body axes; readout noise h_k(meas) = h_k + U r, U a tangent basis
// of h_k). Each measurement is z = H x + G v to first order, x the state errors, v the noise.
#ifndef ESG_ESTIMATOR_MEASUREMENTS_H_
#define ESG_ESTIMATOR_MEASUREMENTS_H_

#include "Eigen/Core"

namespace esg::estimator {

// Orthonormal basis of the plane perpendicular to unit u, as columns (deterministic).
Eigen::Matrix<double, 3, 2> TangentBasis(const Eigen::Vector3d& u);

// Star-tracker difference of one gyro (eq. (13), z2..z5 in the gyro's basis T):
// z = T^T (C_in_b(st) C_b_k h_k - h_in).
struct StarTrackerDifference {
  Eigen::Vector2d z;
  Eigen::Matrix2d H_h;                   // d z / d dx_h  (identity)
  Eigen::Matrix<double, 2, 3> H_phi;     // d z / d dphi  [rad -> rad]
  Eigen::Matrix<double, 2, 3> G_st;      // d z / d n_st
  Eigen::Matrix2d G_readout;             // d z / d r
};
StarTrackerDifference MakeStarTrackerDifference(const Eigen::Vector3d& h_in,
                                                const Eigen::Matrix<double, 3, 2>& T,
                                                const Eigen::Matrix3d& C_in_b_st,
                                                const Eigen::Matrix3d& C_b_k,
                                                const Eigen::Vector3d& h_k);

// Autonomous measurement of a pair (eq. (13)): z_avt = cos(theta_R) - cos(theta_S) =
// h_in_a . h_in_b - (C_b_k_a h_k_a) . (C_b_k_b h_k_b).
struct AutonomousDifference {
  double z = 0.0;
  Eigen::RowVector2d H_h_a, H_h_b;        // d z / d dx_h of each gyro
  Eigen::RowVector3d H_phi_a, H_phi_b;    // d z / d dphi of each gyro
  Eigen::RowVector2d G_readout_a, G_readout_b;
};
AutonomousDifference MakeAutonomousDifference(const Eigen::Vector3d& h_in_a,
                                              const Eigen::Matrix<double, 3, 2>& T_a,
                                              const Eigen::Matrix3d& C_b_k_a,
                                              const Eigen::Vector3d& h_k_a,
                                              const Eigen::Vector3d& h_in_b,
                                              const Eigen::Matrix<double, 3, 2>& T_b,
                                              const Eigen::Matrix3d& C_b_k_b,
                                              const Eigen::Vector3d& h_k_b);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_MEASUREMENTS_H_
