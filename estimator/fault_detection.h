// Fault detection of the paper's section 2.
//
// eq. (12): at each measurement step three mismatch rotations are formed between the working
// pair (1), the reserve pair (2) and the star tracker (3): dL_12 = L1 (x) conj(L2), dL_13, dL_23.
// A subsystem is faulty when both mismatches that involve it exceed their allowed angle.
//
// eq. (14): a measurement is rejected when |z| > k_d sigma_z with
// sigma_z = sqrt(diag(H P H^T + R)). The star-tracker measurements z2..z5 share one quaternion's
// noise, so they are tested in sequence: component i is tested by its innovation conditioned on
// the components before it (the Cholesky factor of S), which is eq. (14) for each scalar of a
// sequentially processed vector and equals the printed test when S is diagonal
// (docs/decisions.md).
#ifndef ESG_ESTIMATOR_FAULT_DETECTION_H_
#define ESG_ESTIMATOR_FAULT_DETECTION_H_

#include <array>

#include "Eigen/Core"
#include "Eigen/Geometry"

namespace esg::estimator {

enum class Subsystem { kNone, kWorkingPair, kReservePair, kStarTracker };
const char* SubsystemName(Subsystem s);

struct MismatchTest {
  // Angles [rad] of dL_12, dL_13, dL_23 and their allowed values [rad].
  std::array<double, 3> angle = {0, 0, 0};
  std::array<double, 3> allowed = {0, 0, 0};
  std::array<bool, 3> available = {false, false, false};
  Subsystem faulty = Subsystem::kNone;
};

// eq. (12). Any of the quaternions may be unavailable (nullptr); then the mismatches involving it
// are not formed and no subsystem can be named from fewer than two exceeded mismatches.
MismatchTest TestMismatch(const Eigen::Quaterniond* q_in_b_pair1, const Eigen::Quaterniond* q_in_b_pair2,
                          const Eigen::Quaterniond* q_in_b_star_tracker,
                          const std::array<double, 3>& allowed);

// The allowed angle of eq. (12) for a mismatch rotation vector dtheta [rad] whose covariance is
// Sigma [rad^2]: k_d times the mismatch's sigma along its own direction u = dtheta/|dtheta|,
// k_d / sqrt(u^T Sigma^-1 u), not below floor. The star tracker's boresight noise is six times its
// cross-boresight noise, so one allowed angle for all directions would let a cross-boresight fault
// of several arcminutes pass (docs/decisions.md).
double DirectionalAllowedAngle(const Eigen::Vector3d& dtheta, const Eigen::Matrix3d& Sigma, double k_d,
                               double floor);

struct InnovationTest {
  bool passed = true;
  int worst_index = -1;          // component with the largest normalised innovation
  double worst_ratio = 0.0;      // |e_i| / sigma_i of that component
  double worst_value = 0.0;      // |e_i| (units of z)
  double worst_threshold = 0.0;  // k_d sigma_i (units of z)
  // Normalised innovation squared z^T S^-1 z and log det S: the innovation's Gaussian
  // log-likelihood is -(nis + log_det_s + m log 2 pi) / 2.
  double nis = 0.0;
  double log_det_s = 0.0;
};

// eq. (14) over a vector z with innovation covariance S (sequential conditional form above).
InnovationTest TestInnovation(const Eigen::VectorXd& z, const Eigen::MatrixXd& S, double k_d);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_FAULT_DETECTION_H_
