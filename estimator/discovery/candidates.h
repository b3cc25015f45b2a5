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
//   star_tracker_orbital_         the star tracker's mount turning with the orbital phase,
//   misalignment                  m(t) = c cos(phi) + s sin(phi), common to all gyros: regressed
//                                 on every gyro's deviation at once, then the star tracker
//                                 corrected by it (6 parameters; star_tracker_cycle.h)
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
//   warm_up (gyro g)              a case-fixed drift decaying exponentially from the recording's
//                                 start, A exp(-t / tau): three exponential_decay basis terms
//                                 freed with prior c_sigma, tau profiled on a log grid refined
//                                 near its maximum (3 parameters, tau integrated over a prior
//                                 uniform in ln tau; time_behaviour.h FitWarmUp), reported as a
//                                 basis term
//   coefficient_step (gyro g)     a step at an onset T of one group of g's drift coefficients of
//                                 the model in use (k0; C2, mu, nu where the model holds them;
//                                 C1's is drift_step): the group released at T with prior
//                                 c_sigma, T searched as the drift step's (1 or 3 parameters, the
//                                 onset and the group integrated over uniform priors;
//                                 time_behaviour.h FitCoefficientStep, D110), reported as a basis
//                                 term (spin_axis_harmonic terms switched on at T)
//   transient (gyro g)            a case-fixed drift A exp(-(t - T) / tau) from an onset T: the
//                                 warm-up's three exponential_decay terms with their epoch at T,
//                                 T searched as the drift step's at the middle tau, then tau at
//                                 the best T (3 parameters, T and tau integrated over uniform
//                                 priors, separated; time_behaviour.h FitTransient), reported
//                                 as a basis term
//   readout_distortion (gyro g)   not of the library: the open-ended basis's readout group, a
//                                 symmetric traceless distortion of g's readout (5 parameters,
//                                 regressed on the deviation, held; Laplace's Occam term;
//                                 readout_candidate.h), reported as a basis term
//   sun_drift (gyro g)            not of the library: the open-ended basis's sun families, a drift
//                                 following a body face's illumination through a thermal lag
//                                 (3 parameters, the face and the lag searched; regressed on the
//                                 deviation, held; Laplace's Occam term and the lag's cost;
//                                 readout_candidate.h FitSunCandidate), reported as a basis term
// Only what the model lacks is a candidate: a term already free is not, and a common star-tracker
// rotation is not when every running gyro's misalignment is already estimated.
#ifndef ESG_ESTIMATOR_DISCOVERY_CANDIDATES_H_
#define ESG_ESTIMATOR_DISCOVERY_CANDIDATES_H_

#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/options.h"
#include "estimator/discovery/regimes.h"
#include "estimator/discovery/report.h"
#include "estimator/session.h"
#include "estimator/spacecraft_config.h"

namespace esg::estimator::discovery {

// The candidates `model` lacks among `effects` (all of the library when empty), for the running
// gyros; `with_orbit`: the diagnosis has the orbit, so the sun's families include `sunlit`
// (sun_regressors.h SunFamilies), and a gyro's sun is offered while any of them is not held.
std::vector<Candidate> ListCandidates(const ModelState& model, const std::vector<int>& gyros,
                                      const std::vector<Effect>& effects, bool with_orbit);

// The comparisons a candidate makes in a round's family M of the threshold 2 ln(M / alpha): a
// sun candidate one per family it may try (the faces, and `sunlit` `with_orbit`, that `model`
// does not hold for its gyro; each family's lags are one comparison, their Bayes factors
// averaged: D101), any other candidate 1.
int CandidateComparisons(const Candidate& candidate, const ModelState& model, bool with_orbit);

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
