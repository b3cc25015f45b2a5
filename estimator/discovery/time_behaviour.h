// Time behaviour of a drift (docs/discovery.md, "Time behaviour"): how a drift that changes
// during the recording is fitted and described. A drift switched on at an onset (`drift_step`:
// the C1 states of eq. (10) released at the onset, the likelihood profiled over it) and the trend
// of the suspension offset voltages through eq. (3) (a rotor displacement that grows). The random
// walk's intensity, common or per gyro, is fitted with the library in candidates.cc.
#ifndef ESG_ESTIMATOR_DISCOVERY_TIME_BEHAVIOUR_H_
#define ESG_ESTIMATOR_DISCOVERY_TIME_BEHAVIOUR_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/time/time.h"
#include "estimator/basis_term.h"
#include "estimator/discovery/candidate.h"
#include "estimator/drift_model.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// A drift step of `candidate.gyro` (docs/discovery.md, "Time behaviour"): the C1 states of the
// gyro released at an onset (session.h CoefficientRelease, prior c_sigma_deg_h), the likelihood
// profiled over the onset on a coarse grid refined twice near its maximum; every onset run
// continues from a checkpoint of one run without the step, so an onset costs the part of a run
// after it. Fills `fit` (model, run, parameters, time, notes). Errors: InvalidArgument for a gyro
// that is not configured; those of RunModel.
absl::Status FitDriftStep(const Candidate& candidate, const FitContext& context,
                          CandidateFit& fit);

// The time behaviour of a warm-up finding (report.h TimeBehaviour::kind).
inline constexpr const char* kTimeWarmUp = "warm_up";

// A group of drift coefficients of eq. (1), (10) (drift_model.h theta[first .. first + count)),
// its name and its step's parameter name in a finding ("k0StepDegH", "c2StepDegH[0..2]", ...).
struct CoefficientGroup {
  std::string name = "k0";
  std::string json_name = "k0StepDegH";
  int first = kThetaK0;
  int count = 1;
};

// The groups a coefficient step of `gyro` may take (D110): k0, every model's, and C2, mu, nu
// where the gyro's model holds one of their coefficients (a value or a prior); C1's step is the
// drift step's.
std::vector<CoefficientGroup> StepGroupsInUse(const GyroConfig& gyro);

// The basis terms of a step of the coefficients theta[first .. first + step.size()) by
// `step_rad_s` [rad/s] at `onset` (D110): spin_axis_harmonic terms switched on at the onset,
// whose drift across h equals that of the step of eq. (1), (10) at every h (k0: three terms
// h_m^3 along m, each -dk0; C1: 1 along m, -dC1m; C2: h_m^2 along m, -dC2m; mu: two terms each,
// nu: one, as printed), at those values, freed with the prior `sigma` [rad/s].
std::vector<BasisTerm> CoefficientStepTerms(int first, const Eigen::VectorXd& step_rad_s,
                                            absl::Time onset, double sigma);

// The time behaviour of a transient-from-an-onset finding.
inline constexpr const char* kTimeTransient = "transient";

// An exponential transient of `candidate.gyro` from an onset (docs/discovery.md, "Time
// behaviour"): a case-fixed drift A e^(-(t - T) / tau) from T on, 0 before, as the warm-up's
// three exponential_decay terms with their epoch at T, freed with the prior c_sigma_deg_h. T is
// searched as the drift step's onset at the middle time constant of the warm-up's grid (every
// run continued from a checkpoint of one run with the terms inert), then tau on the warm-up's
// grid at the best T. The evidence integrates T over a uniform prior and tau over a prior uniform
// in ln tau, separated (at the best T). Fills `fit` (model, run, parameters transientDegH[0..2],
// transientSizeDegH, tauHours, tauLowerHours, tauUpperHours, onsetHours, onsetLowerHours,
// onsetUpperHours, the onset's time behaviour, description, basis_terms, notes). A gyro whose
// basis has no room for three more terms gets no fit. Errors: InvalidArgument for a gyro that
// is not configured; those of RunModel.
absl::Status FitTransient(const Candidate& candidate, const FitContext& context, CandidateFit& fit);

// The time behaviour of a coefficient-step finding.
inline constexpr const char* kTimeCoefficientStep = "coefficient_step";

// A step of one group of `candidate.gyro`'s drift coefficients at an onset (docs/discovery.md,
// "Time behaviour"; D110): for each group of StepGroupsInUse, the onset searched as the drift
// step's (time_behaviour.h FitDriftStep, the same grids and refinement, one run without the step
// with checkpoints shared by the groups), the group's states released at the onset with the prior
// c_sigma_deg_h; the evidence integrates the onset over a uniform prior and the groups over equal
// prior weights, the finding is the group of the largest evidence. Fills `fit` (the best onset's
// run and options, parameters k0StepDegH or <group>StepDegH[0..2] with 1-sigma, onsetHours,
// onsetLowerHours, onsetUpperHours, the onset's time behaviour, description, basis_terms from
// CoefficientStepTerms, notes with each group's profile). Errors: InvalidArgument for a gyro that
// is not configured; those of RunModel.
absl::Status FitCoefficientStep(const Candidate& candidate, const FitContext& context,
                                CandidateFit& fit);

// A warm-up of `candidate.gyro` (docs/discovery.md, "Time behaviour"): a case-fixed drift A e^(-t /
// tau) from the recording's start, as three exponential_decay basis terms (basis_term.h, one per
// case axis, epoch the first frame) freed with the prior c_sigma_deg_h, the filter calibrating A;
// tau profiled over log-spaced time constants from kWarmUpMinTauHours to kWarmUpMaxTauHours,
// refined twice near the best, its evidence integrated over a prior uniform in ln tau across that
// span, its interval where -2 log L stays within 3.84 of its minimum. Fills `fit` (model with the
// terms at the best tau, run, parameters warmUpDegH[0..2], warmUpSizeDegH, tauHours,
// tauLowerHours, tauUpperHours, description, basis_terms, notes). A gyro whose basis has no room
// for three more terms gets no fit (parameters 0, a note). Errors: InvalidArgument for a gyro
// that is not configured; those of RunModel.
inline constexpr double kWarmUpMinTauHours = 0.5;
inline constexpr double kWarmUpMaxTauHours = 24.0;
absl::Status FitWarmUp(const Candidate& candidate, const FitContext& context, CandidateFit& fit);

// The trend of a gyro's suspension offset voltages through eq. (3): a robust line per case axis
// [mV/h], the displacement rate it implies [um/h] with its 1-sigma (from the line's residual
// scatter), and a chi-square(3) test of "no trend". Evidence only (a growing displacement is not
// yet a candidate); appended to `fit` (parameters displacementRateUmPerH[0..2], a note).
void DescribeVoltageTrend(const SpacecraftConfig& config,
                          const std::vector<TelemetryFrame>& frames, int gyro, CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_TIME_BEHAVIOUR_H_
