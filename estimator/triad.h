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

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_TRIAD_H_
