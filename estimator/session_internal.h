// Constants and helpers shared by the source files of EstimationSession (session.cc and
// session_*.cc); not part of the estimator's interface.
#ifndef ESG_ESTIMATOR_SESSION_INTERNAL_H_
#define ESG_ESTIMATOR_SESSION_INTERNAL_H_

#include "absl/time/time.h"
#include "estimator/units.h"

namespace esg::estimator::session_internal {

// Floors keep R positive definite when a configuration sets a noise to zero [rad].
inline constexpr double kNoiseFloor = 0.01 * kRadPerArcsec;

// A span in seconds, as the integrators take it.
inline double Seconds(absl::Duration d) { return absl::ToDoubleSeconds(d); }

}  // namespace esg::estimator::session_internal

#endif  // ESG_ESTIMATOR_SESSION_INTERNAL_H_
