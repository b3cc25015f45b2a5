// What the warm-up (warm_up.h) and the transient from an onset (transient.h) share
// (docs/discovery.md, "Time behaviour"): the three exponential_decay basis terms of a case-fixed
// drift A e^(-(t - T) / tau) (basis_term.h), and the search of the likelihood over tau: a coarse
// grid in ln tau across [kWarmUpMinTauHours, kWarmUpMaxTauHours], refined twice near its best,
// then the ends of its 95% interval resolved by bisection while the drift is significant. Pure
// computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_TIME_CONSTANT_SEARCH_H_
#define ESG_ESTIMATOR_DISCOVERY_TIME_CONSTANT_SEARCH_H_

#include <functional>
#include <map>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/time/time.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/profile_interval.h"

namespace esg::estimator::discovery {

// The span of time constants searched [h].
inline constexpr double kWarmUpMinTauHours = 0.5;
inline constexpr double kWarmUpMaxTauHours = 24.0;

// One exponential_decay term per case axis.
inline constexpr int kWarmUpTerms = 3;

// The coarse grid: kTauCoarse time constants equally spaced in ln tau across the span (factors
// of 1.9); `spacing` its step in ln tau.
inline constexpr int kTauCoarse = 7;
struct TauGrid {
  double log_min = 0.0, log_max = 0.0, spacing = 0.0;
};
TauGrid WarmUpTauGrid();

// The model with the three terms (time constant tau_h [h], epoch t0, value 0) appended to gyro
// `gyro`'s basis (configured), freed with the prior sigma [rad/s].
ModelState WithWarmUp(const ModelState& model, int gyro, absl::Time t0, double tau_h,
                      double sigma);

// The search over ln tau (each point clamped to the grid's span; a point evaluated already, as
// `value` holds it, is skipped): the coarse grid, then twice the two points half a spacing either
// side of `best_log()` (the best so far), then, while `base_value` (the model's -2 log L without
// the drift) exceeds the best by the evidence threshold at level `alpha`, the interval's ends
// bisected in ln tau down to 2% of tau, at most 10 more points. `evaluate(log_tau)` runs one
// point and records its -2 log L in `value`. Errors: those of `evaluate`.
absl::Status SearchTimeConstants(const TauGrid& grid,
                                 const std::function<absl::Status(double log_tau)>& evaluate,
                                 const std::map<double, double>& value,
                                 const std::function<double()>& best_log, double base_value,
                                 double alpha);

// The decaying drift's parameters appended to `fit`: `<name>DegH[0..2]` (the amplitude A [rad/s,
// case axes] with its 1-sigma, in deg/h), `<name>SizeDegH` (|A| with its 1-sigma), tauHours with
// half its 95% interval as 1-sigma, tauLowerHours and tauUpperHours. Returns |A| [rad/s] and sets
// `size_sigma` to its 1-sigma [rad/s].
double AddDecayParameters(const std::string& name, const Eigen::Vector3d& a,
                          const Eigen::Vector3d& a_sigma, double tau_h, double lower_h,
                          double upper_h, double& size_sigma, CandidateFit& fit);


}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_TIME_CONSTANT_SEARCH_H_
