// The library of candidate effects (docs/physics.md) and how each is added to a model and fitted
// (docs/discovery.md, "How each effect enters the model"); the fixed terms an effect frees are
// those whose descriptor names it (estimator/model_terms.h `effect`):
//   rotor_displacement (gyro g)   free C1, C2 of g with prior c_sigma (eq. (8)-(10))
//   fourth_harmonic (gyro g)      free k0 of g with prior k0_sigma (eq. (1))
//   unequal_stiffness (gyro g)    free mu, nu of g with prior unequal_stiffness_sigma (eq. (1))
//   gyro_misalignment (gyro g)    misalignment of g estimated with prior misalignment_sigma
//   star_tracker_misalignment     one rotation m common to all gyros: first estimated as the
//                                 information-weighted mean of free per-gyro misalignments, then
//                                 the star tracker corrected by q_st (x) Exp(-m) (3 parameters)
//   star_tracker_latency          one delay tau: q_st corrected by the body rate over tau
//                                 (model_run.h); tau by prediction-error least squares on the
//                                 innovations' finite-difference sensitivity (1 parameter)
//   random_walk_drift             the random-walk intensity of eq. (11), common to all gyros or of
//   (common, or gyro g)           one gyro, by a log-grid search of the likelihood above the
//                                 configured one (1 parameter; its evidence integrated over the
//                                 grid's intensities, equally likely a priori)
//   drift_step (gyro g)           a drift constant in case axes switched on at an onset T (the
//                                 step of C1 of eq. (10)); the likelihood profiled over T on a
//                                 grid of onsets, refined near its maximum (3 parameters, the
//                                 onset integrated over a uniform prior; fitted by
//                                 time_behaviour.h)
//   readout_distortion (gyro g)   not of the library: the open-ended basis's readout group, a
//                                 symmetric traceless distortion of g's readout (5 parameters,
//                                 regressed on the deviation, held; Laplace's Occam term;
//                                 readout_candidate.h), reported as a basis term
// Only what the model lacks is a candidate: a term already free is not, and a common star-tracker
// rotation is not when every running gyro's misalignment is already estimated.
#ifndef ESG_ESTIMATOR_DISCOVERY_CANDIDATES_H_
#define ESG_ESTIMATOR_DISCOVERY_CANDIDATES_H_

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/options.h"
#include "estimator/discovery/regimes.h"
#include "estimator/discovery/report.h"
#include "estimator/session.h"
#include "estimator/spacecraft_config.h"

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
};
std::string CandidateName(const Candidate& c);  // "rotor_displacement[2]"

// The candidates `model` lacks among `effects` (all of the library when empty), for the running
// gyros.
std::vector<Candidate> ListCandidates(const ModelState& model, const std::vector<int>& gyros,
                                      const std::vector<Effect>& effects);

// What the discovery needs to fit a candidate: the recording, the measured rates, the current
// model's full run and the options.
struct FitContext {
  const std::vector<TelemetryFrame>* frames = nullptr;
  const BodyRates* rates = nullptr;
  const ModelState* model = nullptr;
  const ModelRun* model_run = nullptr;
  const DiagnoseOptions* options = nullptr;
  std::vector<int> gyros;
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
  int runs = 0;  // filter runs spent
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

// Fits one candidate (1 to 5 filter runs, sequential; candidates run in parallel).
// Errors: InvalidArgument for a gyro that is not configured; those of RunModel.
absl::StatusOr<CandidateFit> FitCandidate(const Candidate& candidate, const FitContext& context);

// Model-free first estimate of a star-tracker latency: the star tracker's rotation between
// consecutive samples against the gyros' (TRIAD on the inertially fixed spin axes) differs by
// -tau times the change of the body rate over the step. Observable only where the rate changes
// (slews, regime changes): in a steady rotation a latency is a constant misalignment.
struct LatencyEstimate {
  bool observable = false;
  double latency = 0.0;  // [s]
  double sigma = 0.0;    // [s]
  int samples = 0;       // steps used
};
LatencyEstimate LatencyFromRates(const std::vector<TelemetryFrame>& frames, const BodyRates& rates,
                                 const SpacecraftConfig& config);

// Gyro `id` of a configuration to change, and a run's final estimate of gyro `id`; nullptr when
// absent.
GyroConfig* FindGyroMutable(SpacecraftConfig& c, int id);
const GyroEstimate* FindEstimate(const std::vector<GyroEstimate>& gyros, int id);

// The residual random walk of eq. (11) `m` holds for gyro `id` [rad/s/sqrt(s)] and the prior
// 1-sigma of each gyro's residual drift at the start [rad/s], as its session sets them (session.h
// ResidualRandomWalk, InitialResidualDriftSigma); 0 when the model has no random walk.
double ModelRandomWalk(const ModelState& m, int id);
double ModelInitialDriftSigma(const ModelState& m);

// Profiled deviance of a run (ComputeDeviance, then the common noise scale phi = nis / m
// profiled out: N ln(phi) + sum log det S + N), and phi.
struct ProfiledDeviance {
  double value = 0.0;
  double dispersion = 1.0;
  int components = 0;
  int steps = 0;
};
ProfiledDeviance Profile(const ModelRun& run);

// Physics of a fitted rotor displacement (eq. (8)-(10)): C1 = (C10 + C20) lambda,
// C2 = -5 C20 lambda; lambda the dominant common direction of C1 and C2, and the displacement
// implied by the mean suspension offset voltages through eq. (3). Appended to `fit`.
void DescribeRotorDisplacement(const SpacecraftConfig& config,
                               const std::vector<TelemetryFrame>& frames, int gyro,
                               CandidateFit& fit);

// The check of a rotor displacement against the suspension voltages that decides (docs/
// discovery.md, "Physics checks that decide"). A displaced rotor is seen in its suspension offset
// voltages (eq. (3): Delta = k dU d0 / U0); its drift grows with the displacement, about
// kC1DegHPerUm of |C1| per um (the paper's section 1.1: C ~ 0.2 deg/h at 3 um). A rotor's shape
// harmonics set that sensitivity, so it is taken as known only to within kSensitivitySpread
// either way: a fitted |C1| then implies a displacement of at least |C1| / kC1DegHPerUm /
// kSensitivitySpread (`floor_um`). The voltages' mean displacement has a 1-sigma from batch means
// of consecutive samples (robust to noise correlated in time). The voltages decide when they
// could show the floor (kVoltageZ sigma below it); they disagree when even their upper bound
// |Delta| + kVoltageZ sigma stays below it.
inline constexpr double kC1DegHPerUm = 0.2 / 3.0;
inline constexpr double kSensitivitySpread = 10.0;
inline constexpr double kVoltageZ = 3.29;  // two-sided 0.1%
struct VoltageAgreement {
  bool informative = false;       // voltages telemetered and precise enough to decide
  bool agrees = true;
  double drift_implied_um = 0.0;  // |C1| / kC1DegHPerUm
  double floor_um = 0.0;          // drift_implied_um / kSensitivitySpread
  double voltage_um = 0.0;        // |mean displacement| by eq. (3)
  double voltage_sigma_um = 0.0;  // its 1-sigma (norm of the per-axis batch-means sigmas)
  std::string note;
};
VoltageAgreement CheckDisplacementAgainstVoltages(const SpacecraftConfig& config,
                                                  const std::vector<TelemetryFrame>& frames,
                                                  int gyro, const Eigen::Vector3d& C1_k_rad_s);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_CANDIDATES_H_
