// Finding the physics a model left out (docs/discovery.md): given the user's model (the
// configuration: its drift model and mountings; coefficients with positive modelSigma are
// calibrated, the others held) and a recording, locate where the recording and the model disagree
// (gyro, time span, attitude regime), name the missing effect from the library of docs/physics.md,
// add it to the model, refit, and show the fit improve: in-sample star-tracker residuals and
// long-gap (held-out) prediction error before and after, the measure of the paper's Fig. 7/8.
//
// Method (docs/discovery.md has the full argument):
// - Score. Every model is run through the filter (session.h) over the whole recording; its
//   star-tracker innovations give the Gaussian log-likelihood -2 log L = sum(nis + log det S)
//   (StepReport), capped per step at the chi-square 1e-4 quantile so that star-tracker outliers
//   count alike for every model, and profiled over a common noise scale (a mis-stated noise level
//   does not pose as an effect). Coefficients freed with a prior (modelSigma) make this the
//   model's evidence, which carries its own Occam penalty; parameters fitted by search (latency,
//   star-tracker misalignment, random-walk intensity) pay k ln n (BIC).
// - Select. Each candidate effect the model lacks is added in turn and refitted; its
//   likelihood-ratio statistic is tested against chi-square(k) at a Bonferroni level over the
//   candidates of the round. Among the significant ones the best penalised score wins; when two
//   are within kDecisiveDeviance, held-out prediction decides. Forward selection repeats on the
//   extended model, so two effects in one recording are both found.
// - Locate. Regimes come from the measured body rate (regimes.h). Residuals are cut per gyro and
//   per regime span; held-out prediction withholds the star tracker over whole regime spans, so
//   the model calibrated in one regime predicts another (a concealed effect shows there).
// - Unexplained. A mismatch that remains after selection (held-out prediction error beyond the
//   filter's own uncertainty, or residual excess concentrated in a span) is reported as
//   `unexplained` with where it is, never forced onto a candidate.
#ifndef ESG_ESTIMATOR_DISCOVERY_DIAGNOSE_H_
#define ESG_ESTIMATOR_DISCOVERY_DIAGNOSE_H_

#include <functional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/discovery/regimes.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

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
};
const char* EffectId(Effect e);  // "rotor_displacement", ...
inline constexpr const char* kVerdictNone = "none";
inline constexpr const char* kVerdictUnexplained = "unexplained";

// Two candidates whose penalised scores differ by less than this (in -2 log L) are not told apart
// by the in-sample likelihood (Kass & Raftery: below 10 is not "very strong"); held-out prediction
// decides between them.
inline constexpr double kDecisiveDeviance = 10.0;

struct DiagnoseOptions {
  // Drift model of the user (calibration_model.h ParseModel): "10+11" lets every configured
  // term with a positive modelSigma be calibrated and the residual random walk run.
  std::string model = "10+11";
  // Family-wise false-finding level of each forward-selection round (Bonferroni over its
  // candidates).
  double alpha = 0.01;
  int max_effects = 3;  // forward-selection rounds
  // Integration rate of the filter during diagnosis [Hz]. The drift changes slowly; the
  // deviance at 0.2 Hz equals the one at 8 Hz to ~0.1 in 2e5 (docs/discovery.md), at 1/40 of the
  // cost. <= 0 keeps the configuration's rate.
  double integration_rate_hz = 0.2;
  int threads = 2;
  // Effects to try (empty: all of the library).
  std::vector<Effect> effects;
  // Held-out spans: at most this many, each at most max_gap_hours long.
  int max_gaps = 4;
  double max_gap_hours = 4.0;
  // Priors given to freed coefficients (the paper's sizes, docs/physics.md) and the search grids.
  double c_sigma_deg_h = 0.1;
  double k0_sigma_deg_h = 0.3;
  double mu_nu_sigma_deg_h = 0.1;
  double misalignment_sigma_arcsec = 60.0;
  RegimeOptions regimes;
  // Cancellation (may be empty): polled before each stage and before each candidate or
  // held-out model run (a candidate fit with a parameter search is one unit and is not
  // interrupted); once it returns true Diagnose returns Cancelled "diagnosis cancelled". Called
  // from the diagnosis threads concurrently: it must be thread-safe and cheap (e.g. an atomic
  // flag).
  std::function<bool()> cancelled;
};

struct Parameter {
  std::string name;  // e.g. "c1DegH[0]", "latencyMs"
  double value = 0.0;
  double sigma = 0.0;  // 1-sigma, 0 if not available
  std::string unit;    // "deg/h", "arcsec", "ms", "um", "deg", "deg/h/sqrt(h)", "1"
};

struct Evidence {
  double delta_deviance = 0.0;  // -2 log L(before) - (-2 log L(with the effect)), profiled
  double penalty = 0.0;         // k ln n for searched parameters, 0 for prior-freed ones
  int parameters = 0;           // k
  double lr_p_value = 1.0;      // P(chi2_k > delta_deviance)
  double threshold = 0.0;       // chi2_k quantile at the round's Bonferroni level
  int round = 0;                // forward-selection round (0 first)
  // Held-out prediction with and without the effect, when it was run: sum of the normalised
  // squared spin-axis prediction errors at the held-out span ends (chi-square with
  // held_out_dof degrees of freedom if the model is right).
  double held_out_nees_before = -1.0;
  double held_out_nees_after = -1.0;
  int held_out_dof = 0;
  std::vector<std::string> notes;  // human-readable supporting facts
};

struct Finding {
  std::string effect;  // EffectId, or "unexplained"
  int gyro = 0;        // gyro id where the effect is per gyro, 0 otherwise
  std::vector<Parameter> parameters;
  std::string explanation;
  Evidence evidence;
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
  double penalty = 0.0;
  double score = 0.0;  // delta_deviance - penalty
  double p_value = 1.0;
  bool significant = false;
  // Improves the fit throughout the recording rather than in part of it only (a physical effect
  // of the library is constant in time).
  bool homogeneous = true;
  bool selected = false;
};

// Time series for the report's plots.
struct ResidualPoint {
  double hours = 0.0;  // since the first frame
  int gyro = 0;
  double residual_arcsec = 0.0;  // |star-tracker difference| of that gyro
};
struct HeldOutPoint {
  double hours = 0.0;
  int gap = 0;
  double error_arcsec = 0.0;  // attitude error angle against the withheld star tracker
};

struct DiagnosisReport {
  std::string verdict;            // effect id, "none" or "unexplained"
  std::vector<Finding> findings;  // most important first
  Mismatch mismatch;              // of the user's model
  FitSummary before;              // the user's model
  FitSummary after;               // with the findings added
  std::vector<RegimeSpan> regimes;
  std::vector<CandidateScore> candidates;
  std::vector<ResidualPoint> residuals_before, residuals_after;
  std::vector<HeldOutPoint> held_out_before, held_out_after;
  absl::Time first_frame_time;
  int frames = 0;
  int filter_runs = 0;
  std::vector<int> gyros;  // running gyros
};

using DiagnoseProgressFn = std::function<void(double fraction, const std::string& stage)>;

// Errors: InvalidArgument for an invalid configuration, an unknown model or effect option, no
// frames or frames out of order, a recording without star-tracker data; Cancelled when
// options.cancelled returned true; those of the session.
absl::StatusOr<DiagnosisReport> Diagnose(const SpacecraftConfig& config,
                                         const std::vector<TelemetryFrame>& frames,
                                         const DiagnoseOptions& options,
                                         const DiagnoseProgressFn& progress = {});

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_DIAGNOSE_H_
