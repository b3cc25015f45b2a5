// What a diagnosis reports (docs/discovery.md, "Physics in the report" and "JSON"): the effect
// identifiers of the library (docs/physics.md), a finding with its fitted parameters and evidence,
// where a mismatch sits, the fit before and after, one row per candidate tried, the time series
// of the plots. Plain values; Diagnose (diagnose.h) fills them, the client and the server print
// and store them.
#ifndef ESG_ESTIMATOR_DISCOVERY_REPORT_H_
#define ESG_ESTIMATOR_DISCOVERY_REPORT_H_

#include <array>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "estimator/basis_term.h"
#include "estimator/discovery/regimes.h"
#include "estimator/spacecraft_config.h"

namespace esg::estimator::discovery {

// Effect identifiers (docs/physics.md, "Effect library of the diagnosis").
enum class Effect {
  kRotorDisplacement,
  kFourthHarmonic,
  kUnequalStiffness,
  kGyroMisalignment,
  kStarTrackerMisalignment,
  kStarTrackerLatency,
  kRandomWalkDrift,
  kDriftStep,
  // Not of the library: the open-ended basis's readout group, a candidate of every round
  // (readout_candidate.h); its finding is a kEffectBasisTerm.
  kReadoutDistortion,
  // Not of the library: the open-ended basis's sun families (a drift that follows a body face's
  // illumination through a thermal lag), a candidate of every round (readout_candidate.h
  // FitSunCandidate); its finding is a kEffectBasisTerm.
  kSunDrift,
  // Not of the library: a drift that follows a housekeeping channel the configuration declares
  // (its value, lag or derivative; channel_candidate.h FitChannelCandidate), a candidate of every
  // round per gyro and channel; its finding is a kEffectBasisTerm (three channel terms).
  kChannelDrift,
  // A time behaviour with its own nonlinear parameter: a case-fixed drift decaying exponentially
  // from the recording's start (a warm-up), its time constant searched (time_behaviour.h
  // FitWarmUp); its finding is a kEffectBasisTerm (three exponential_decay terms).
  kWarmUp,
  // A step of one group of a gyro's drift coefficients of eq. (1), (10) (k0, C2, mu or nu; C1's
  // is kDriftStep) at an onset searched (time_behaviour.h FitCoefficientStep, D110); its finding
  // is a kEffectBasisTerm (spin_axis_harmonic terms switched on at the onset).
  kCoefficientStep,
  // An exponential transient from an onset later than the recording's start (a warm-up after a
  // switch-on or a mode change), its onset and time constant searched (time_behaviour.h
  // FitTransient); its finding is a kEffectBasisTerm (three exponential_decay terms).
  kTransient,
  // The star tracker's side (star_tracker_cycle.h): its mount's misalignment turning with the
  // orbital phase (a thermo-elastic misalignment), common to all gyros, six coefficients
  // regressed on every gyro's deviation at once; tried before gyro terms are taken.
  kStarTrackerCycle,
  // A rotor displacement turning about an axis (turning_displacement.h): C1 and C2 of eq. (10)
  // turning with it, twelve cycling_harmonic terms at a period searched; its finding is a
  // kEffectBasisTerm of time behaviour "turning".
  kTurningDisplacement,
};
// The last of Effect (they are numbered from 0 without gaps).
inline constexpr Effect kLastEffect = Effect::kTurningDisplacement;

// A rotor displacement's C1 and C2 (eq. (8)-(10)) are reported as one displacement (lambda, C10,
// C20) when their collinearity is not rejected at this level (chi-square of (C1, C2) off their
// common line, docs/discovery.md "One physical term, one finding"); the same level as the
// isotropy of a rate coupling (rate_coupling.h).
inline constexpr double kCollinearityP = 0.01;
// "rotor_displacement", ..., "sun_drift", "warm_up", "coefficient_step", "transient",
// "star_tracker_orbital_misalignment", "turning_displacement"
const char* EffectId(Effect e);
// The effect whose EffectId is `id`, or nullopt.
std::optional<Effect> EffectFromId(absl::string_view id);
inline constexpr const char* kVerdictNone = "none";
inline constexpr const char* kVerdictUnexplained = "unexplained";
// Findings were taken but the model with them fails the diagnosis's own consistency tests
// (ModelConsistency): they explain part of the mismatch, the rest is an `unexplained` finding.
inline constexpr const char* kVerdictPartlyExplained = "partly_explained";
// A term of the open-ended stage's basis (docs/discovery.md, "The open-ended stage"): physics
// outside the library, named by the regressor that explains it.
inline constexpr const char* kEffectBasisTerm = "basis_term";

struct Parameter {
  std::string name;  // e.g. "c1DegH[0]", "latencyMs"
  double value = 0.0;
  double sigma = 0.0;  // 1-sigma, 0 if not available
  std::string unit;    // "deg/h", "arcsec", "ms", "um", "deg", "deg/h/sqrt(h)", "1"
};
// The parameter of `ps` named `name`, or nullptr.
const Parameter* FindParameter(const std::vector<Parameter>& ps, absl::string_view name);

struct Evidence {
  // docs/discovery.md "Evidence": every decision compares models by 2 ln B (B their Bayes
  // factor), in-sample and on the held-out spans.
  double delta_deviance = 0.0;  // -2 log L(before) - (-2 log L(with the effect)), profiled
  // The prior's cost of parameters fixed by search (delta_deviance - evidence); 0 for
  // parameters freed with a prior, whose likelihood is their marginal likelihood already.
  double penalty = 0.0;
  double evidence = 0.0;  // 2 ln B against the model without the effect
  int parameters = 0;     // k
  // For a finding of the library: 1 / B, the bound on its false-alarm probability. For an
  // unexplained finding: the p-value of its goodness-of-fit test.
  double p_value = 1.0;
  double threshold = 0.0;  // 2 ln(M / alpha), M the round's candidates
  int round = 0;           // forward-selection round (0 first)
  // Held-out prediction with and without the effect, when it was run: sum of the normalised
  // squared spin-axis prediction errors at the held-out span ends (chi-square with
  // held_out_dof degrees of freedom if the model is right), and their -2 log predictive density
  // (held-out deviance; lower predicts better, and a model cannot lower it by widening its
  // own uncertainty).
  double held_out_nees_before = -1.0;
  double held_out_nees_after = -1.0;
  double held_out_deviance_before = 0.0;
  double held_out_deviance_after = 0.0;
  int held_out_dof = 0;
  std::vector<std::string> notes;  // human-readable supporting facts
};

// How a finding behaves in time (docs/discovery.md, "Time behaviour"): constant over the
// recording (the effects of eq. (1), (8)-(10), mountings, the star tracker), switched on at an
// onset (a drift step), or a random walk whose intensity was raised.
struct TimeBehaviour {
  // "constant", "step", "random_walk", "warm_up" (an exponential decay from the start, its time
  // constant in the finding's parameters tauHours, tauLowerHours, tauUpperHours) or a basis
  // term's kind (basis_stage.cc TimeKind).
  std::string kind = "constant";
  // For "step": the onset maximising the likelihood and its interval where -2 log L stays within
  // the chi-square(1) 95% quantile (3.84) of its minimum; the interval is clipped to the onsets
  // searched (docs/discovery.md).
  absl::Time onset = absl::InfinitePast();
  absl::Time onset_lower = absl::InfinitePast();
  absl::Time onset_upper = absl::InfinitePast();
  double onset_hours = 0.0;  // since the first frame
  double onset_lower_hours = 0.0;
  double onset_upper_hours = 0.0;
  int onsets_searched = 0;  // onsets evaluated (the points its evidence is integrated over)
  // For "step": the likelihood over the onsets searched, (hours since the first frame,
  // -2 log L above its minimum), in time order; the interval above is where it stays below 3.84.
  std::vector<std::pair<double, double>> onset_profile;
};

// The rotor displacement implied through eq. (3) by a gyro's suspension offset voltages over the
// recording, and the robust line fitted per case axis (the voltage trend of a rotor_displacement
// finding, docs/discovery.md "Physics in the report"). Empty when the recording has no voltages.
struct DisplacementTrend {
  struct Sample {
    double hours = 0.0;                       // since the first frame, the middle of the bin
    std::array<double, 3> displacement_um{};  // mean over the bin, case axes [um]
  };
  std::vector<Sample> samples;           // means over at most kMaxSamples bins of equal frame count
  std::array<double, 3> intercept_um{};  // the line at hour 0 [um]
  std::array<double, 3> rate_um_h{};     // its slope [um/h]
  static constexpr int kMaxSamples = 400;
};

struct Finding {
  std::string effect;  // EffectId, kEffectBasisTerm or "unexplained"
  int gyro = 0;        // gyro id where the effect is per gyro, 0 otherwise
  std::vector<Parameter> parameters;
  std::string explanation;
  // kEffectBasisTerm: the physics in words (open_ended.h DescribeGroup), and the model terms
  // that add it to a configuration (GyroConfig::basis_terms of `gyro`, with their fitted values
  // and the prior sigma that frees them) or the readout distortion (GyroConfig::
  // readout_distortion), as the refitted model holds them.
  std::string description;
  std::vector<BasisTerm> basis_terms;
  Eigen::Matrix3d readout_distortion = Eigen::Matrix3d::Zero();
  Evidence evidence;
  TimeBehaviour time;
  DisplacementTrend displacement_trend;  // rotor_displacement with suspension voltages
};

// Where the recording and a model disagree most.
struct Mismatch {
  bool found = false;
  int gyro = 0;  // 0: not one gyro
  absl::Time start;
  absl::Time end;
  std::string regime;  // RegimeName of the span
  int span = -1;       // index into DiagnosisReport::regimes
  // Star-tracker residual RMS in the span for that gyro [arcsec] and the filter's predicted
  // RMS there [arcsec].
  double size_arcsec = 0.0;
  double expected_arcsec = 0.0;
  double excess_deviance = 0.0;  // sum of (nis-like) excess over the span for that gyro [1]
  double p_value = 1.0;          // of the span excess (chi-square over its components)
  // Whiteness and trend of that gyro's normalised residuals in the span: lag-1 autocorrelation
  // (0 for white residuals) and robust slope [1/h].
  double lag1_autocorrelation = 0.0;
  double whiteness_p_value = 1.0;  // of the lag-1 autocorrelation (r sqrt(n) ~ N(0, 1))
  double trend_per_hour = 0.0;
  // The star-tracker difference component (1 or 2: the gyro's tangent axes, the paper's
  // dh_int1 and dh_int3 for the reference gyro) carrying the larger excess; 0 if not one gyro.
  int axis = 0;
  std::string source;  // "in-sample residuals" or "held-out prediction"
};

struct GapSummary {
  int span = -1;  // regime span index
  std::string regime;
  absl::Time start;
  absl::Time end;
  double drift_rate_deg_h = 0.0;  // |slope| of the attitude error against the withheld star tracker
  double final_error_arcsec = 0.0;
  double nees = 0.0;  // sum over gyros of the normalised squared spin-axis error at the end
  // -2 log predictive density of those errors: nees + (each gyro's) dof ln(predicted variance)
  double deviance = 0.0;
  int dof = 0;
  std::vector<std::pair<int, double>> gyro_drift_rate_deg_h;  // gyro id, |slope| of its spin axis
};

struct FitSummary {
  std::string model;                  // description
  double residual_rms_arcsec = 0.0;   // star-tracker innovations, accepted in-sample steps
  double gap_drift_rate_deg_h = 0.0;  // RMS over the held-out spans of the attitude error rate
  double deviance = 0.0;              // profiled -2 log L (+ const)
  double dispersion = 0.0;            // mean nis per component (1 if the noise model is right)
  double held_out_nees = 0.0;
  double held_out_deviance = 0.0;  // -2 log predictive density over the held-out spans
  int held_out_dof = 0;
  std::vector<GapSummary> gaps;
};

// One row per candidate tried.
struct CandidateScore {
  std::string effect;
  int gyro = 0;
  int round = 0;
  int parameters = 0;
  double delta_deviance = 0.0;
  double penalty = 0.0;  // the prior's cost of searched parameters (Evidence)
  double score = 0.0;    // the evidence 2 ln B = delta_deviance - penalty
  double p_value = 1.0;  // 1 / B
  bool significant = false;
  // Improves the fit throughout the recording rather than in part of it only (a physical effect
  // of the library is constant in time).
  bool homogeneous = true;
  bool selected = false;
  // "constant", "step" (onset searched) or "random_walk" (intensity searched); a step and a
  // random walk describe a change in time and are exempt from the homogeneity test.
  std::string time_behaviour = "constant";
  double onset_hours = -1.0;  // best onset of a step, hours since the first frame
  // Why the search's result was refused (a step that does not carry its likelihood gain,
  // docs/discovery.md "A step must carry its gain"); empty when it was fitted or found nothing.
  std::string not_fitted;
};

// Time series for the report's plots.
struct ResidualPoint {
  double hours = 0.0;  // since the first frame
  int gyro = 0;
  double residual_arcsec = 0.0;  // |star-tracker difference| of that gyro
  // The filter's predicted 1-sigma of one component of that difference: the RMS of the two
  // components' sqrt(diag S) [arcsec]. |difference| is then Rayleigh-distributed when the model
  // is right: 90% of it lies between 0.32 and 2.45 sigma.
  double sigma_arcsec = 0.0;
};
// A gyro's residual drift from the open-ended stage (open_ended.h ResidualDrift): the
// fixed-interval smoothed drift the model leaves, case axes [deg/h], before and after the basis
// terms, and its 1-sigma.
struct ResidualDriftPoint {
  double hours = 0.0;
  int gyro = 0;
  std::array<double, 3> before_deg_h{};
  std::array<double, 3> after_deg_h{};
  double sigma_deg_h = 0.0;
};
struct HeldOutPoint {
  double hours = 0.0;
  int gap = 0;
  double error_arcsec = 0.0;  // attitude error angle against the withheld star tracker
};

// One consistency test of the model with the findings (docs/discovery.md, "A verdict no stronger
// than its evidence"): a statistic chi-square with `dof` degrees of freedom when the model is
// right, against its upper quantile at `level`.
struct ConsistencyTest {
  std::string name;  // "held-out NEES", "in-sample NIS" or "whiteness"
  double statistic = 0.0;
  int dof = 0;
  double bound = 0.0;   // ChiSquareQuantile(level, dof)
  double p_value = 1.0;  // ChiSquareSurvival(statistic, dof)
  // > 0: the test fails only when statistic / dof also exceeds it (a material excess).
  double materiality = 0.0;
  bool passed = true;
};

// The model with the findings against the recording, and what the findings explain.
struct ModelConsistency {
  bool checked = false;  // only when findings were taken
  bool passed = true;    // every test passed
  double level = 0.0;    // 1 - alpha / 3: the three tests at alpha, Bonferroni
  std::vector<ConsistencyTest> tests;
  // Share of the mismatch the findings remove: of the in-sample NIS in excess of its chi-square
  // expectation (sum of nis - components), and of the held-out NEES in excess of its dof; in
  // [0, 1], -1 when the user's model showed no excess.
  double in_sample_explained = -1.0;
  double held_out_explained = -1.0;
  std::string summary;  // the above in words, and what remains where
};

struct DiagnosisReport {
  // Effect id of the most important finding, "none", "unexplained" or "partly_explained".
  std::string verdict;
  std::vector<Finding> findings;  // most important first
  Mismatch mismatch;              // of the user's model
  FitSummary before;              // the user's model
  FitSummary after;               // with the findings added
  std::vector<RegimeSpan> regimes;
  std::vector<CandidateScore> candidates;
  std::vector<ResidualPoint> residuals_before, residuals_after;
  std::vector<ResidualDriftPoint> residual_drift;  // when the open-ended stage ran
  std::vector<HeldOutPoint> held_out_before, held_out_after;
  absl::Time first_frame_time;
  int frames = 0;
  int filter_runs = 0;
  // The orbit the diagnosis had (DiagnoseOptions::orbit_source): "<source>: used", or why none
  // was used; empty when nothing was said.
  std::string orbit;
  std::vector<int> gyros;  // running gyros
  ModelConsistency consistency;
};

// `config` with the model terms of the report's `basis_term` findings added (each gyro's
// basis_terms, freed with the prior the diagnosis used, at the fitted values; its readout
// distortion): the configuration `esg calibrate` can run with what the diagnosis found.
SpacecraftConfig WithBasisFindings(const SpacecraftConfig& config, const DiagnosisReport& report);

// Hours from t0 to t (the report's time axis: hours since the first frame).
inline double HoursSince(absl::Time t, absl::Time t0) { return absl::ToDoubleHours(t - t0); }

// The physics of a finding of the library in the units people use (docs/discovery.md, "Physics in
// the report"), from its effect, gyro, parameters and evidence (evidence, parameters, p_value);
// only the statistics for an effect outside the library.
std::string ExplainFinding(const Finding& finding);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_REPORT_H_
