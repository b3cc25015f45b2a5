// Does a drift that changes during the recording change once, wander without bound, or return to
// its mean? (docs/discovery.md, "Time behaviour"). The library describes a changing drift by a
// step at an onset or by a raised random walk; a drift switching at random between levels, or
// one driven by a quantity the telemetry does not carry (a temperature nobody measures), is
// neither, and forcing either onto it names physics that is not there. On one gyro's deviation
// from the current model (deviation.h), in the reduced filter (deviation_filter.h), three
// descriptions are compared by their evidence 2 ln B against the configured random walk alone,
// each parameter integrated over a stated prior (uniform over a grid):
//
//   step        a case-fixed drift switched on at an onset: 3 coefficients, prior 0.1 deg/h each
//               (the library's drift step), the onset uniform over the samples between 5% and
//               95% of the series (at most 120 onsets); or, for a step of drift coefficients of
//               eq. (1), (10) (a coefficient step), a step of those coefficients: their
//               regressors (DriftRegressor) switched on at the onset, each with the same prior;
//   walk        the random walk of eq. (11) raised 2, 4, 8, 16, 32 times (the library's grid);
//   stationary  a first-order Gauss-Markov drift on top of the configured walk, correlation time
//               0.5, 1, 2, 4, 8 h x stationary 1-sigma 0.01, 0.02, 0.04, 0.08, 0.16 deg/h per axis.
//
// Steps the model already holds for the gyro enter every description as nuisance regressors (a
// case-fixed drift before each). Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_WANDER_H_
#define ESG_ESTIMATOR_DISCOVERY_WANDER_H_

#include <set>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/context.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/report.h"
#include "estimator/discovery/selected_model.h"

namespace esg::estimator::discovery {

struct DriftBehaviourEvidence {
  int gyro = 0;
  double step = 0.0, walk = 0.0, stationary = 0.0;  // 2 ln B of each against the configured walk
  double step_onset_hours = 0.0;   // the best onset [h since the series' first sample]
  // What "one step" was: "one step" (case-fixed) or "one step of <symbol>" (of coefficients).
  std::string step_text = "one step";
  double walk_factor = 0.0;        // the best grid point: times the configured intensity
  double correlation_hours = 0.0;  // the best stationary grid point
  double sigma_deg_h = 0.0;
};

// `random_walk` [rad/s/sqrt(s)] and `w0_sigma` [rad/s] as the model's session holds them;
// `step_sigma` the prior 1-sigma of a step's coefficients [rad/s]; `steps` the times of the
// drift steps the model holds for the series' gyro. `stepped` the drift coefficients whose step
// is the "one step" (candidate.h; count 0: a case-fixed drift).
DriftBehaviourEvidence CompareDriftBehaviours(const DeviationSeries& series, double random_walk,
                                              double w0_sigma, double step_sigma,
                                              const std::vector<absl::Time>& steps,
                                              SteppedCoefficients stepped = {});

// The comparison on gyro `gyro`'s deviation from the selected model.
absl::StatusOr<DriftBehaviourEvidence> CompareDriftBehavioursOf(const SelectedModel& selected,
                                                                const DiagnosisContext& context,
                                                                int gyro,
                                                                SteppedCoefficients stepped = {});

// The library's random walk of every gyro must be common (docs/discovery.md, "Physics checks
// that decide"): on each gyro of `gyros`, its own deviation from `selected` must make a raised
// walk more probable than the configured one (the walk's 2 ln B of CompareDriftBehaviours above
// 0). A walk that one gyro's drift needs (a drift that returns to its mean, or an effect of one
// gyro a walk absorbs) raises the common walk's likelihood through that gyro alone. `fails` when
// a gyro's deviation does not support it; `note` gives every gyro's 2 ln B.
struct CommonWalkCheck {
  bool fails = false;
  std::string note;
};
absl::StatusOr<CommonWalkCheck> CheckCommonWalk(const SelectedModel& selected,
                                                const DiagnosisContext& context,
                                                const std::vector<int>& gyros);

// Whether the comparison says the drift returns to its mean: the stationary drift beats one step
// and a raised walk decisively (by kDecisiveDeviance) and passes `threshold` (2 ln B).
bool ReturnsToItsMean(const DriftBehaviourEvidence& e, double threshold);
// Its p-value: 1/B of the stationary drift against the better of one step and a raised walk.
double ReturnsToItsMeanBound(const DriftBehaviourEvidence& e);

// "the drift of gyro g returns to its mean: a stationary random drift (correlation time about ..)
// describes its deviation with 2 ln B = .., decisively better than one step (..) or a raised
// random walk (..), as a drift switching at random between levels or one driven by a quantity
// the telemetry does not carry would".
std::string ReturnsToItsMeanText(const DriftBehaviourEvidence& e);

// "the drift of gyro g wanders beyond the configured random walk: a stationary random drift (..)
// and a random walk raised .. times (..) describe its deviation about equally well ..., one step
// decisively less well ...": the two descriptions within kDecisiveDeviance of each other.
std::string WandersBeyondTheWalkText(const DriftBehaviourEvidence& e);

// Where such a drift is: gyro `gyro` over the whole recording, with the p-value of its test.
Mismatch WanderLocation(int gyro, const std::vector<TelemetryFrame>& frames, double p_value);

// Gyros other than the verdict's whose drift returns to its mean or wanders: those in `gyros`
// (the open-ended stage left their terms out for a stationary drift during the diagnosis, on the
// model of that time) tested again on their deviation from the final model `selected`, the
// threshold 2 ln(family / alpha). A gyro whose drift returns to its mean (ReturnsToItsMean), or
// whose stationary drift and raised walk both beat one step decisively with the better of the two
// above the threshold (undecided between them: WandersBeyondTheWalkText), is its own
// `unexplained` finding located to its gyro over the whole recording, as the verdict's is;
// `held_out` is the final model's held-out prediction, `after_findings` whether the model holds
// findings (FindUnexplained's wording). The p-value is 1/B of the statement made.
absl::StatusOr<std::vector<Finding>> OtherGyrosReturningToTheirMean(
    const SelectedModel& selected, const DiagnosisContext& context, const std::set<int>& gyros,
    const HeldOutResult& held_out, bool after_findings, int family, double alpha);

// A constant effect of the library for one gyro against the stationary drift on the same
// deviation: a drift that switches at random, or follows a quantity the telemetry does not carry,
// is partly fitted by any term of the spin-axis direction or of the readout, which change with
// the attitude. `effect_columns`: the effect's signatures on the series (Signature,
// ReadoutSignature), one per parameter, with their prior 1-sigma. Each 2 ln B is against the
// configured walk, the stationary drift's integrated over its grid as in CompareDriftBehaviours;
// `on_top` is the effect's on top of the stationary drift (the nested comparison: 2 ln B of both
// against the stationary drift alone).
struct ConstantEffectEvidence {
  double effect = 0.0, stationary = 0.0, on_top = 0.0;
};
// The drift steps model `m` holds for gyro `gyro` (coefficient releases, not misalignments): the
// `steps` of CompareConstantEffect.
std::vector<absl::Time> HeldSteps(const ModelState& m, int gyro);

ConstantEffectEvidence CompareConstantEffect(
    const DeviationSeries& series, double random_walk, double w0_sigma, double step_sigma,
    const std::vector<absl::Time>& steps,
    const std::vector<std::vector<Eigen::Vector2d>>& effect_columns,
    const std::vector<double>& effect_prior);

// The comparison for the library candidate `candidate` of one gyro on that gyro's deviation from
// the selected model: a rotor displacement, a fourth harmonic, unequal stiffness (the drift
// coefficients of eq. (1), (8)-(10) it frees, DriftRegressor) or the gyro's misalignment (three
// small rotations of its readout), each with the options' prior. InvalidArgument for another
// effect or a gyro that is not configured.
absl::StatusOr<ConstantEffectEvidence> CompareConstantEffectOf(const SelectedModel& selected,
                                                               const DiagnosisContext& context,
                                                               const Candidate& candidate);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_WANDER_H_
