// Fault detection of the paper's section 2.
//
// eq. (12): at each measurement step three mismatch rotations are formed between the working
// pair (1), the reserve pair (2) and the star tracker (3): dL_12 = L1 (x) conj(L2), dL_13, dL_23.
// A subsystem is faulty when both mismatches that involve it exceed their allowed angle. The
// decision that follows (which gyro is excluded, which pair carries the output, whether the
// star tracker's measurements are dropped) is DecideFault, a function of plain values; the
// session only applies it.
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
#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "estimator/units.h"

namespace esg::estimator {

enum class Subsystem { kNone, kWorkingPair, kReservePair, kStarTracker };
const char* SubsystemName(Subsystem s);

// Index of each mismatch of eq. (12) in MismatchTest's arrays.
inline constexpr int kMismatch12 = 0;  // working pair against reserve pair
inline constexpr int kMismatch13 = 1;  // working pair against star tracker
inline constexpr int kMismatch23 = 2;  // reserve pair against star tracker

struct MismatchTest {
  // Angles [rad] of dL_12, dL_13, dL_23 and their allowed values [rad].
  std::array<double, 3> angle = {0, 0, 0};
  std::array<double, 3> allowed = {0, 0, 0};
  std::array<bool, 3> available = {false, false, false};
  Subsystem faulty = Subsystem::kNone;
};

// eq. (12), the naming rule: mismatch m exceeds when it is available and angle[m] >= allowed[m];
// the subsystem whose two mismatches exceed is faulty: working pair (12, 13), reserve pair
// (12, 23), star tracker (13, 23), checked in that order (when all three exceed, the working pair
// is named). kNone when no subsystem has two exceeded mismatches.
Subsystem FaultySubsystem(const std::array<double, 3>& angle, const std::array<double, 3>& allowed,
                          const std::array<bool, 3>& available);

// eq. (12). Any of the quaternions may be unavailable (nullptr); then the mismatches involving it
// are not formed and no subsystem can be named from fewer than two exceeded mismatches.
// `faulty` is FaultySubsystem of the formed mismatches.
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

// Smallest allowed angle of an eq. (12) mismatch [rad] (docs/decisions.md D9).
inline constexpr double kMinAllowedMismatch = 2.0 * kRadPerArcsec;

// The allowed angle of the eq. (12) mismatch between the attitudes q_in_b_a and q_in_b_b [rad]:
// `configured` [rad] when it is positive (filter.faultThresholdArcsec), otherwise
// DirectionalAllowedAngle of the mismatch rotation vector Log(q_a (x) conj(q_b)) with its
// covariance Sigma [rad^2], k_d and the floor kMinAllowedMismatch.
double AllowedMismatchAngle(const Eigen::Quaterniond& q_in_b_a, const Eigen::Quaterniond& q_in_b_b,
                            const Eigen::Matrix3d& Sigma, double k_d, double configured);

// What the session does about an eq. (12) result.
struct FaultDecision {
  Subsystem faulty = Subsystem::kNone;
  // The mismatch reported as the evidence (its angle against its allowed angle): kMismatch12 for
  // a pair fault, kMismatch13 for the star tracker; -1 when nothing is faulty.
  int evidence = -1;
  // Id of the gyro excluded from then on (a pair fault), 0 when none: the gyro of the faulty
  // pair that is not in the other pair (docs/decisions.md D10); the second gyro of the faulty
  // pair when the pairs are equal.
  int excluded_gyro = 0;
  // The pair that carries the output after the decision: the reserve pair when the working pair
  // is faulty (output_switched), the working pair otherwise.
  std::array<int, 2> output_pair = {0, 0};
  bool output_switched = false;
  // The star tracker is faulty: its measurements of this step are not used.
  bool reject_star_tracker = false;
};

// eq. (12) policy, from plain values: the mismatch angles, allowed angles and availability of
// `test` (its `faulty` field is not read) and the gyro ids of the working and reserve pairs.
// Working pair faulty: exclude its gyro that is not in the reserve pair and move the output to
// the reserve pair. Reserve pair faulty: exclude its gyro that is not in the working pair.
// Star tracker faulty: reject its measurements.
FaultDecision DecideFault(const MismatchTest& test, const std::array<int, 2>& working_pair,
                          const std::array<int, 2>& reserve_pair);

// Fault isolation with three running gyros a, b, c (docs/decisions.md D18). The three pairs are
// indexed by the gyro they lack: pair k holds every gyro but gyro_ids[k]. Two families of
// mismatches are formed:
//   pair_star[k]: pair k against the star tracker;
//   pair_pair[m]: the two pairs that share gyro m (pair k and pair l, {k, l, m} = {0, 1, 2}).
// Hypotheses and the mismatches each requires to exceed (X), to stay within (o), or leaves free:
//   none          nothing exceeds;
//   gyro g        pair_pair[m] X for m != g (the pairs with g disagree with the pair without it),
//                 pair_pair[g] free (both pairs hold g); pair_star[g] o (the pair without g agrees
//                 with the star tracker) and pair_star[k] X for at least one k != g (the star
//                 tracker confirms: a pair with g disagrees with it);
//   star tracker  every pair_pair o (the pairs agree) and pair_star X for at least two pairs (a
//                 pair whose sigma is large along the error's direction may not see it, as the
//                 30 arcsec boresight; eq. (12) names the star tracker from two).
// Without the star tracker only the pair_pair conditions are tested and the star tracker cannot
// be named. A hypothesis is decided when it is the only one whose conditions hold. Otherwise the
// result is ambiguous (nothing excluded) when at least as many mismatches exceed as a gyro's
// smallest signature (3 with the star tracker, 2 without), and none below that: a single noisy
// pair attitude exceeds the two mismatches it takes part in.
// Per-gyro star-tracker evidence (D22): with the star tracker, each gyro's own star-tracker
// difference of eq. (13) (2 components, normalised by its exact covariance: gyro_star_nis, chi-
// square with 2 degrees of freedom for a healthy gyro and star tracker) names a gyro when exactly
// one gyro's exceeds gyro_star_fail and the others' stay below gyro_star_pass. A star-tracker error
// rotates every rebuilt axis at once and cannot fail one gyro alone while two others, on
// non-parallel axes, pass. This evidence decides between the pair hypotheses when the pairs
// are ambiguous or name another gyro, and names the gyro when fewer mismatches than its
// signature exceeded but a pair holding it disagrees with the pair without it, which agrees with the star
// tracker: a reading error of the second gyro of a pair barely moves that pair's attitude in some
// geometries, while its own star-tracker difference moves fully. For the same reason it names the
// gyro, not the star tracker, when the two pairs holding it (and only they) disagree with the
// star tracker while the pairs agree with each other.
enum class Isolation { kNone, kGyro, kStarTracker, kAmbiguous };
const char* IsolationName(Isolation i);

struct IsolationTest {
  std::array<int, 3> gyro_ids = {0, 0, 0};
  bool star_available = false;
  // Angles [rad] and allowed angles [rad] (AllowedMismatchAngle with the exact covariance).
  std::array<double, 3> pair_star_angle = {0, 0, 0};
  std::array<double, 3> pair_star_allowed = {0, 0, 0};
  std::array<double, 3> pair_pair_angle = {0, 0, 0};
  std::array<double, 3> pair_pair_allowed = {0, 0, 0};
  // Per-gyro star-tracker evidence (above); used when gyro_star_available.
  bool gyro_star_available = false;
  std::array<double, 3> gyro_star_nis = {0, 0, 0};
  double gyro_star_fail = 25.0;   // k_d^2 with eq. (14)'s k_d = 5: P = 3.7e-6 per healthy gyro
  double gyro_star_pass = 9.21;   // chi2inv(0.99, 2)
};

struct IsolationDecision {
  Isolation result = Isolation::kNone;
  int faulty_index = -1;  // index into gyro_ids of the isolated gyro (kGyro)
  int excluded_gyro = 0;  // its id, 0 when none
  // Pair carrying the output: the working pair when it does not hold the excluded gyro,
  // otherwise the pair without it (gyro ids in the order of gyro_ids).
  std::array<int, 2> output_pair = {0, 0};
  bool output_switched = false;
  bool reject_star_tracker = false;
  std::array<bool, 3> pair_star_exceeded = {false, false, false};
  std::array<bool, 3> pair_pair_exceeded = {false, false, false};
  std::array<bool, 3> gyro_star_failed = {false, false, false};
  bool decided_by_gyro_star = false;  // the per-gyro star-tracker evidence named the gyro
  // Hypotheses whose conditions hold (kAmbiguous: zero or several): gyro ids, 0 = star tracker.
  std::vector<int> candidates;
};

// The pair without gyro_ids[k]: the other two ids in the order of gyro_ids.
std::array<int, 2> PairWithout(const std::array<int, 3>& gyro_ids, int k);

// Isolation from plain values (rule above); working_pair is the pair that carries the output.
IsolationDecision DecideIsolation(const IsolationTest& test, const std::array<int, 2>& working_pair);

// A readable summary of the evidence: every formed mismatch with its angle and allowed angle
// [arcsec], exceeded ones marked "EXCEEDS".
std::string IsolationEvidence(const IsolationTest& test, const IsolationDecision& decision);

// Covariance [rad^2] of the mismatch rotation vector between two attitudes whose errors are
// linearised in the same state error dx (covariance P) and the same readout noise r (independent,
// variance readout_var per component): dtheta_x = J_x dx + G_x r, dtheta_y = J_y dx + G_y r.
// The mismatch Log(q_x (x) conj(q_y)) = dtheta_y - dtheta_x to first order, so
//   Sigma = (J_x - J_y) P (J_x - J_y)^T + readout_var (G_x - G_y)(G_x - G_y)^T.
// Two pairs that share a gyro share its state and its reading: their errors are correlated and
// the sum of the two covariances J_x P J_x^T + J_y P J_y^T + ... is not the mismatch's.
Eigen::Matrix3d MismatchCovariance(const Eigen::MatrixXd& J_x, const Eigen::MatrixXd& G_x,
                                   const Eigen::MatrixXd& J_y, const Eigen::MatrixXd& G_y,
                                   const Eigen::MatrixXd& P, double readout_var);

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
