// A candidate effect and its fit: the types every effect's fit takes and fills, and the helpers
// those fits share (the library's dispatch is candidates.h FitCandidate; the drift step's fit is
// time_behaviour.h, the readout distortion's readout_candidate.h, the sun's sun_terms.h). Below
// both, so that no fit
// includes the library that calls it.
#ifndef ESG_ESTIMATOR_DISCOVERY_CANDIDATE_H_
#define ESG_ESTIMATOR_DISCOVERY_CANDIDATE_H_

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/options.h"
#include "estimator/discovery/regimes.h"
#include "estimator/discovery/report.h"
#include "estimator/model_terms.h"
#include "estimator/session.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// A model: the filter configuration (free coefficients, misalignment priors, random walk) and
// the star-tracker correction.
struct ModelState {
  SpacecraftConfig config;
  SessionOptions options;
  StarTrackerCorrection correction;
  std::vector<std::string> added;  // descriptions of the effects added so far
};

struct Candidate {
  Effect effect;
  int gyro = 0;  // 0 for effects common to the spacecraft
  std::string channel;  // kChannelDrift: the declared channel it follows
};
std::string CandidateName(const Candidate& c);  // "rotor_displacement[2]"

// What the discovery needs to fit a candidate: the recording, the measured rates, the current
// model's full run and the options.
struct FitContext {
  const std::vector<TelemetryFrame>* frames = nullptr;
  const BodyRates* rates = nullptr;
  const ModelState* model = nullptr;
  const ModelRun* model_run = nullptr;
  const DiagnoseOptions* options = nullptr;
  std::vector<int> gyros;
  // The recording's attitude regimes (regimes.h), for the orbital period; may be null.
  const std::vector<RegimeSpan>* regimes = nullptr;
};

// Drift coefficients theta[first .. first + count) of eq. (1), (10) (drift_model.h) that a
// coefficient step stepped; count 0: none (a case-fixed drift, as a drift step's).
struct SteppedCoefficients {
  int first = 0;
  int count = 0;
};

struct CandidateFit {
  Candidate candidate;
  ModelState model;  // the model with the effect added
  ModelRun run;      // its full in-sample run
  // For effects freed with a prior: a run with the parameters held from the start at their final
  // estimates (the filter learns them causally, so `run` cannot show whether the fitted physics
  // also holds early in the recording; this run can). Empty for searched effects, whose
  // parameters are constant from the start already.
  std::optional<ModelRun> fixed_run;
  int parameters = 0;
  std::vector<Parameter> fitted;
  std::vector<std::string> notes;
  // Why a candidate searched gave no fit (parameters 0) when a rule refused what the search found
  // (time_behaviour.cc StepWithoutItsGain); shown in the table of candidates tried.
  std::string not_fitted;
  int runs = 0;  // filter runs spent
  // A coefficient step's group (coefficient_step.h); count 0 for every other candidate.
  SteppedCoefficients stepped;
  // Time behaviour (report.h TimeBehaviour). A step and a random walk are exempt from the
  // constant-effect homogeneity test (selection.h): they describe a change in time themselves.
  TimeBehaviour time;
  // The candidate's evidence against the current model, 2 ln B (statistics.h, docs/discovery.md
  // "Evidence"). For parameters freed with a prior, `run`'s likelihood is their marginal
  // likelihood already: both below stay empty. A parameter fixed by a search is integrated over
  // a stated prior, on a grid: `prior_points` holds each point's prior weight (the weights sum
  // to 1) and the profiled -2 log L of its run (a drift step's onsets, a random walk's
  // intensities); or by Laplace's approximation: `occam` = ln det(P0 / P) + theta^T P0^-1 theta
  // of the searched parameters (prior covariance P0, posterior P), subtracted from the best
  // run's improvement (a latency, a star-tracker misalignment).
  std::vector<std::pair<double, double>> prior_points;
  double occam = 0.0;
  // A rotor displacement's suspension-voltage trend (DescribeVoltageTrend), for the report.
  DisplacementTrend displacement_trend;
  // A readout distortion (readout_candidate.h): the gyro's distortion in the model with it, and
  // the finding's description (open_ended.h DescribeGroup).
  Eigen::Matrix3d readout_distortion = Eigen::Matrix3d::Zero();
  std::string description;
  // A warm-up (time_behaviour.h FitWarmUp): the basis terms that add it to a configuration, at
  // their fitted values with the prior they were freed with (the finding's Finding::basis_terms).
  std::vector<BasisTerm> basis_terms;
  // The sun candidate (readout_candidate.h FitSunCandidate): its terms at the best lag against a
  // drift that returns to its mean on the gyro's deviation (wander.h CompareConstantEffect, on the
  // series it regressed): 2 ln B of the terms, of the stationary drift, and of the terms on top
  // of it, for the round's physics check (selection.cc).
  bool wander_compared = false;
  double wander_effect = 0.0, wander_stationary = 0.0, wander_on_top = 0.0;
  // Onset profile of a step: hours since the first frame, -2 log L (profiled).
  std::vector<std::pair<double, double>> onset_profile;
  // A step's competing alternative that is no physics (D43): the gyro's readings jump at the
  // onset (its misalignment states released with the misalignment prior, 3 parameters), profiled
  // over the step's onsets within its interval. -2 log L (profiled) of the best such run, and its
  // onset [h since the first frame]; readout_fitted false when not fitted.
  bool readout_fitted = false;
  double readout_value = 0.0;
  double readout_onset_hours = 0.0;
};

// Gyro `id` of a configuration to change, and a run's final estimate of gyro `id`; nullptr when
// absent.
GyroConfig* FindGyroMutable(SpacecraftConfig& c, int id);
// The candidate's gyro in `c`; InvalidArgument "candidate gyro N is not configured" when absent.
absl::StatusOr<GyroConfig*> CandidateGyro(SpacecraftConfig& c, int gyro);
const GyroEstimate* FindEstimate(const std::vector<GyroEstimate>& gyros, int id);

// Gives the drift coefficients first .. first + count - 1 of gyro `gyro` (configured) that the
// model holds (sigma 0) the prior `sigma` [rad/s], so that the filter calibrates them (or, with
// a tiny sigma, so that they are in the filter's layout to be released later).
void ReleaseHeldCoefficients(SpacecraftConfig& config, int gyro, int first, int count,
                             double sigma);

// The residual random walk of eq. (11) `m` holds for gyro `id` [rad/s/sqrt(s)] and the prior
// 1-sigma of each gyro's residual drift at the start [rad/s], as its session sets them (session.h
// ResidualRandomWalk, InitialResidualDriftSigma); 0 when the model has no random walk.
double ModelRandomWalk(const ModelState& m, int id);
double ModelInitialDriftSigma(const ModelState& m);

// Appends the components of `value` and of its 1-sigma `sigma`, each times `scale`, to `out` as
// the parameters "<name>[0]" .. "<name>[2]" in `unit`.
void AddVectorParameters(const std::string& name, const Eigen::Vector3d& value,
                         const Eigen::Vector3d& sigma, double scale, const std::string& unit,
                         std::vector<Parameter>& out);

// Profiled deviance of a run (ComputeDeviance, then the common noise scale phi = nis / m
// profiled out: N ln(phi) + sum log det S + N), and phi.
struct ProfiledDeviance {
  double value = 0.0;
  double dispersion = 1.0;
  int components = 0;
  int steps = 0;
};
ProfiledDeviance Profile(const ModelRun& run);

// The theta range [first, first + count) of the fixed terms whose descriptor names the effect
// (estimator/model_terms.h `effect`, contiguous in theta); count 0 when none does.
std::pair<int, int> FixedTermsOf(Effect effect);

// The drift coefficients a rotor displacement (C1, C2), a fourth harmonic (k0) or unequal
// stiffness (mu, nu) frees, the fixed terms whose descriptor names the effect (estimator/
// model_terms.h, contiguous in theta): DriftVector indices [first, first + count) with their prior
// 1-sigma from the options [rad/s]; nullopt for any other effect.
struct FreedCoefficients {
  int first = 0;
  int count = 0;
  double sigma = 0.0;
};
std::optional<FreedCoefficients> FreedDriftCoefficients(Effect effect,
                                                        const DiagnoseOptions& options);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_CANDIDATE_H_
