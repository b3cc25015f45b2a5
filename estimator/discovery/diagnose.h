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
//   does not pose as an effect).
// - Evidence. Every decision compares two models by 2 ln B, B their Bayes factor: coefficients
//   freed with a prior (modelSigma) make the filter's likelihood their marginal likelihood;
//   parameters fixed by search (onset, random-walk intensity, latency, star-tracker
//   misalignment) are integrated over a stated prior. Since E[B] = 1 without the effect, a
//   threshold of 2 ln(M / alpha) over M comparisons bounds the chance of a false finding by
//   alpha (Markov's inequality). Held-out prediction is compared in the same currency: -2 log of
//   the predictive density of the held-out errors.
// - Select. Each candidate effect the model lacks is added in turn and refitted; the one with
//   the most evidence above the threshold wins; when two are within kDecisiveDeviance,
//   held-out prediction decides. Forward selection repeats on the extended model, so two
//   effects in one recording are both found.
// - Locate. Regimes come from the measured body rate (regimes.h). Residuals are cut per gyro and
//   per regime span; held-out prediction withholds the star tracker over whole regime spans, so
//   the model calibrated in one regime predicts another (a concealed effect shows there).
// - Unexplained. A mismatch that remains after selection (held-out prediction error beyond the
//   filter's own uncertainty, or residual excess concentrated in a span) is reported as
//   `unexplained` with where it is, never forced onto a candidate.
//
// Files: options.h (DiagnoseOptions, the caller's runner), report.h (the report types),
// candidates.h (the library and how each effect is fitted), model_run.h (one filter run and its
// deviance), regimes.h (rates and regimes), held_out.h (held-out spans and scoring), selection.h
// (one forward-selection round), time_behaviour.h (a drift switched on at an onset; the voltage
// trend), location.h (where a mismatch sits; `unexplained`), context.h
// (what the stages share), statistics.h; this file coordinates them.
#ifndef ESG_ESTIMATOR_DISCOVERY_DIAGNOSE_H_
#define ESG_ESTIMATOR_DISCOVERY_DIAGNOSE_H_

#include <vector>

#include "absl/status/statusor.h"
#include "estimator/discovery/options.h"
#include "estimator/discovery/report.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// Errors: InvalidArgument for an invalid configuration, an unknown model or effect option, no
// frames or frames out of order, a recording without star-tracker data; Cancelled when
// options.cancelled returned true; those of the session. Starts no thread (options.h).
absl::StatusOr<DiagnosisReport> Diagnose(const SpacecraftConfig& config,
                                         const std::vector<TelemetryFrame>& frames,
                                         const DiagnoseOptions& options,
                                         const DiagnoseProgressFn& progress = {});

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_DIAGNOSE_H_
