// Quasi-inertial frame of a working pair and pair attitude (docs/physics.md, conventions.h).
#ifndef ESG_ESTIMATOR_TRIAD_H_
#define ESG_ESTIMATOR_TRIAD_H_

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/statusor.h"

namespace esg::estimator {

// C_int_in of the pair (reference gyro a, second gyro b), rows e1, e2, e3 with
// e2 = h_a, e1 = unit(h_a x h_b), e3 = e1 x e2 (conventions.h item 6). InvalidArgument when the
// axes are collinear to within min_sin_theta.
absl::StatusOr<Eigen::Matrix3d> QuasiInertialFrame(const Eigen::Vector3d& h_in_a,
                                                   const Eigen::Vector3d& h_in_b,
                                                   double min_sin_theta = 1e-3);

// Attitude from two unit vectors known in inertial axes (h_in_a, h_in_b, the predicted spin axes)
// and measured in body axes (h_b_a = C_b_k_a h_k_a, h_b_b = C_b_k_b h_k_b). TRIAD with the
// reference gyro a as primary: a is matched exactly, b fixes the rotation about a.
// Returns q_in_b; InvalidArgument when either pair of vectors is collinear.
absl::StatusOr<Eigen::Quaterniond> PairAttitude(const Eigen::Vector3d& h_in_a,
                                                const Eigen::Vector3d& h_in_b,
                                                const Eigen::Vector3d& h_b_a,
                                                const Eigen::Vector3d& h_b_b);

// The first-order rotation of the TRIAD frame of two unit vectors a, b (t1 = a, t2 = unit(a x b),
// t3 = t1 x t2, as PairAttitude forms it in each frame) when a moves by da and b by db, both
// tangent (da . a = 0, db . b = 0): the omega with dt_i = omega x t_i, in the axes a and b are
// given in. Across a `delta` of both frames, C_in_b = T_in T_b^T moves by
// Exp(omega_in - C_in_b omega_b) C_in_b, so this is PairAttitude's Jacobian without differencing:
//   omega = t1 x da + t1 ((da x b + t1 x db) . t3) / |a x b|
// (the part across t1 moves t1; the part along t1 is how far t2 turns towards t3).
// Precondition: |a x b| > 1e-6, as PairAttitude requires.
class TriadLinearisation {
 public:
  TriadLinearisation(const Eigen::Vector3d& a, const Eigen::Vector3d& b);
  Eigen::Vector3d RotationOf(const Eigen::Vector3d& da, const Eigen::Vector3d& db) const;

 private:
  Eigen::Vector3d t1_, b_, t3_over_sin_;
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_TRIAD_H_
