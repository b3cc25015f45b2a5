// Spin-axis motion in inertial space (docs/physics.md): dh_in/dt = (C_in_k dw_k) x h_in, and the
// interpolation of 60-s case-frame readings to the integration rate.
#ifndef ESG_ESTIMATOR_SPIN_AXIS_H_
#define ESG_ESTIMATOR_SPIN_AXIS_H_

#include "Eigen/Core"

namespace esg::estimator {

// dh_in/dt [1/s] for drift dw_in = C_in_k dw_k [rad/s].
Eigen::Vector3d SpinAxisRate_in(const Eigen::Vector3d& dw_in, const Eigen::Vector3d& h_in);

// One step of length dt [s] with the drift dw_in [rad/s] held over the step (evaluate it at the
// step's midpoint for second order): h_in rotates by the rotation vector dw_in * dt, which keeps
// |h_in| = 1 to rounding. The result is renormalised.
Eigen::Vector3d StepSpinAxis(const Eigen::Vector3d& h_in, const Eigen::Vector3d& dw_in, double dt);

// Interpolates a unit vector between two samples: spherical linear interpolation at fraction
// s in [0, 1] from a to b. Used for case-frame readings h_k between telemetry frames; exact for
// a rotation at constant rate about an axis perpendicular to both samples.
Eigen::Vector3d SlerpUnit(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double s);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_SPIN_AXIS_H_
