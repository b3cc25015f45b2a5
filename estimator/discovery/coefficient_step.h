// A step of a gyro's drift coefficients at an onset (docs/discovery.md, "Time behaviour"; D110):
// the groups of eq. (1), (10) a step may take, the basis terms that hold a step found, the test
// that a step carries its likelihood gain (the drift step's too, drift_step.h), and the step's
// fit, its onset searched as the drift step's (onset_search.h). Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_COEFFICIENT_STEP_H_
#define ESG_ESTIMATOR_DISCOVERY_COEFFICIENT_STEP_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/basis_term.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/onset_search.h"
#include "estimator/drift_model.h"
#include "estimator/spacecraft_config.h"

namespace esg::estimator::discovery {

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

// Whether a step found by releasing coefficients at its onset carries its likelihood gain
// (docs/discovery.md, "A step must carry its gain"): a run of the model without any release, the
// step `step_rad_s` of theta[first ..] [rad/s] held from `onset` as switched-on basis terms
// (CoefficientStepTerms, sigma 0), must improve -2 log L on search.prefix by
// at least the chi-square bound of step_rad_s.size() degrees of freedom at level `alpha`. One
// run more. Returns an empty string when it does (or when the gyro's basis has no room for the
// terms: the evidence alone decides), else the note that says why nothing was fitted, naming
// `name` and `gain` (the -2 log L gain with the release). Errors: InvalidArgument for a gyro
// that is not configured; those of RunModel.
absl::StatusOr<std::string> StepWithoutItsGain(OnsetSearch& search, const std::string& name,
                                               int first, const Eigen::VectorXd& step_rad_s,
                                               absl::Time onset, double alpha, double gain);

// The time behaviour of a coefficient-step finding.
inline constexpr const char* kTimeCoefficientStep = "coefficient_step";

// A step of one group of `candidate.gyro`'s drift coefficients at an onset (docs/discovery.md,
// "Time behaviour"; D110): for each group of StepGroupsInUse, the onset searched as the drift
// step's (drift_step.h FitDriftStep, the same grids and refinement, one run without the step
// with checkpoints shared by the groups), the group's states released at the onset with the prior
// c_sigma_deg_h; the evidence integrates the onset over a uniform prior and the groups over equal
// prior weights, the finding is the group of the largest evidence. Fills `fit` (the best onset's
// run and options, parameters k0StepDegH or <group>StepDegH[0..2] with 1-sigma, onsetHours,
// onsetLowerHours, onsetUpperHours, the onset's time behaviour, description, basis_terms from
// CoefficientStepTerms, notes with each group's profile). Errors: InvalidArgument for a gyro that
// is not configured; those of RunModel.
absl::Status FitCoefficientStep(const Candidate& candidate, const FitContext& context,
                                CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_COEFFICIENT_STEP_H_
