// Constants and helpers shared by the source files of EstimationSession (session.cc and
// session_*.cc); not part of the estimator's interface.
#ifndef ESG_ESTIMATOR_SESSION_INTERNAL_H_
#define ESG_ESTIMATOR_SESSION_INTERNAL_H_

#include "Eigen/Core"
#include "absl/time/time.h"
#include "estimator/units.h"

namespace esg::estimator::session_internal {

// d(dh)/dt = J dw_int in the tangent basis of a spin axis: (T w) x h = w2 t1 - w1 t2.
inline const Eigen::Matrix2d kJ = (Eigen::Matrix2d() << 0.0, 1.0, -1.0, 0.0).finished();

// Floors keep R positive definite when a configuration sets a noise to zero [rad].
inline constexpr double kNoiseFloor = 0.01 * kRadPerArcsec;

// Isolation evidence (largest exceeded mismatch over its allowed angle, or sqrt of a gyro's own
// star-tracker chi-square over k_d^2) at or above which a gyro is excluded at once; below it the
// next measurement step must name the same gyro (docs/decisions.md D24).
inline constexpr double kImmediateIsolationStrength = 2.0;

// Measurement steps a drift change named by the accumulated test (D33) is measured on the
// gyro's track before it is called below the limit anyway (D94): beyond the limit it is
// excluded as soon as it shows, below it alerted as soon as it shows, and an estimate that does
// neither in this many steps is alerted as a drift change (a change the track cannot tell from
// the limit is no abrupt fault). Its onset stays inside the track's window of 20 steps.
inline constexpr int kDriftChangeDecisionSteps = 10;

// A count the session keeps (steps without the star tracker, rejections and acceptances in a row,
// star-tracker realignments) stops at this value, 1e9 (1,900 years of steps at one a minute): the
// largest integer its checkpoint restore reads (session_checkpoint.cc). A counter restored at the
// limit and then incremented wrote a checkpoint that did not restore (docs/fuzzing.md, finding 8).
inline constexpr int kMaxCount = 1000000000;
inline void Count(int& counter) {
  if (counter < kMaxCount) ++counter;
}

// A span in seconds, as the integrators take it.
inline double Seconds(absl::Duration d) { return absl::ToDoubleSeconds(d); }

}  // namespace esg::estimator::session_internal

#endif  // ESG_ESTIMATOR_SESSION_INTERNAL_H_
