// Held-out scoring (docs/discovery.md, "Locate" and "Method"): which spans of the recording the
// star tracker is withheld over, and how well a model run predicts the attitude and the spin axes
// there, against the filter's own uncertainty. This is the paper's Fig. 7/8 measure: a model
// calibrated in one regime predicts another, so an effect the filter absorbs where it calibrates
// still shows in the held-out spans.
#ifndef ESG_ESTIMATOR_DISCOVERY_HELD_OUT_H_
#define ESG_ESTIMATOR_DISCOVERY_HELD_OUT_H_

#include <vector>

#include "estimator/discovery/model_run.h"
#include "estimator/discovery/options.h"
#include "estimator/discovery/regimes.h"
#include "estimator/discovery/report.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// Materiality of a held-out misfit: with many samples a small excess is already "significant";
// a misfit counts when the errors exceed twice the filter's claimed 1-sigma (NEES per degree of
// freedom above 4).
inline constexpr double kMaterialNeesRatio = 4.0;

// A held-out span: frames [first, last] (inclusive) of regime span `span` (-1: none).
struct Gap {
  int span = -1;
  int first = 0;
  int last = 0;
};

// Up to options.max_gaps spans of at most options.max_gap_hours, no earlier than max(3 h, 15% of
// the recording), each with at least 10 star-tracker samples and an hour of star-tracker data
// between two: the longest span of every regime but the dominant one, then spans of the dominant
// one, latest first. Without such a span, the last quarter of a recording of 4 h or more. In time
// order; empty when nothing qualifies.
std::vector<Gap> ChooseGaps(const std::vector<RegimeSpan>& spans,
                            const std::vector<TelemetryFrame>& frames,
                            const DiagnoseOptions& options);

// The run options that withhold the star tracker over `gaps`.
ModelRunOptions WithheldOver(const std::vector<Gap>& gaps);

// A run's held-out prediction: per gap the attitude drift rate, the spin-axis NEES and its -2 log
// predictive density (GapSummary), their sums, and the attitude error series of the plots.
struct HeldOutResult {
  std::vector<GapSummary> gaps;
  double nees = 0.0;
  double deviance = 0.0;  // -2 log predictive density: the currency of held-out comparisons
  int dof = 0;
  // The gap drift: R = sqrt(mean over the rated gaps of r_k^2), r_k = |b_k| the norm of the slope
  // b_k of gap k's attitude error (three inertial axes, robust line fits) [deg/h].
  double rate_rms_deg_h = 0.0;
  // R's 1-sigma from the line fits' own slope uncertainty [deg/h]: each axis' slope has the
  // least-squares standard error s_ki = sigma_ki / sqrt(S_tt) (sigma_ki the fit's residual
  // standard deviation, S_tt = sum (t - mean t)^2 over the points the fit used, residuals taken
  // as white), carried to r_k and R to first order (the delta method):
  // var r_k = sum_i b_ki^2 s_ki^2 / r_k^2, var R = sum_k (r_k / (n R))^2 var r_k, n the rated
  // gaps. Residuals correlated in time (a drift that bends within the gap) make it smaller than
  // the slope's real scatter, never larger.
  double rate_rms_sigma_deg_h = 0.0;
  std::vector<HeldOutPoint> points;
};

// `run` must have been made with WithheldOver(gaps) on `frames`; `spans` are the regimes.
HeldOutResult SummariseHeldOut(const ModelRun& run, const std::vector<Gap>& gaps,
                               const std::vector<RegimeSpan>& spans,
                               const std::vector<TelemetryFrame>& frames);

// True when the held-out prediction errors exceed the filter's uncertainty significantly (NEES
// chi-square test at alpha / 2) and materially (kMaterialNeesRatio); false without held-out dof.
bool MispredictsHeldOut(const HeldOutResult& held_out, double alpha);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_HELD_OUT_H_
