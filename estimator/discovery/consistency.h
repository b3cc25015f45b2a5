// The model with the findings against its own statistics (docs/discovery.md, "A verdict no
// stronger than its evidence"). After the findings, the diagnosis's consistency tests are run on
// the final model, each a chi-square statistic against its upper quantile at 1 - alpha / 3 (three
// tests, Bonferroni):
// - held-out NEES: the normalised squared spin-axis prediction errors at the held-out span ends
//   (held_out.h), chi-square with the held-out dof (2 per gyro and span);
// - in-sample NIS: the sum of the star-tracker differences' nis over the accepted in-sample steps
//   (capped per step as in the deviance, candidate.h Profile), chi-square with their component
//   count; since the diagnosis profiles a common noise scale (a mis-stated star-tracker noise is
//   not an effect), it fails only when also material, beyond kMaterialDispersion per component
//   (the noise misfit of an `unexplained` finding, location.h); a mismatch confined to a span is
//   the located residual excess's (location.h);
// - whiteness: Box-Pierce at lag 1, the sum over each gyro's two normalised difference series of
//   n r1^2 (r1 their lag-1 autocorrelation, r1 sqrt(n) ~ N(0, 1) for white innovations),
//   chi-square with the number of series.
// A model that fails one explains the recording only in part: the verdict is partly_explained
// and what remains is an `unexplained` finding, located.
#ifndef ESG_ESTIMATOR_DISCOVERY_CONSISTENCY_H_
#define ESG_ESTIMATOR_DISCOVERY_CONSISTENCY_H_

#include <string>
#include <vector>

#include "estimator/discovery/candidate.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/location.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/report.h"

namespace esg::estimator::discovery {

// The three tests on the final model (`run`, its profiled fit `after` and held-out prediction
// `held_out_after`), and the share of the user's model's excess (`before`, `held_out_before`)
// that the findings remove. A test without data (no held-out span, no star-tracker difference)
// passes and is not listed.
ModelConsistency CheckConsistency(const ModelRun& run, const ProfiledDeviance& before,
                                  const ProfiledDeviance& after,
                                  const HeldOutResult& held_out_before,
                                  const HeldOutResult& held_out_after, double alpha);

// Box-Pierce at lag 1 over each gyro's two normalised star-tracker difference series of the
// accepted in-sample steps (series of fewer than 10 values left out), against
// ChiSquareQuantile(level, series).
ConsistencyTest WhitenessTest(const ModelRun& run, double level);

// What remains when the final model fails a test and no `unexplained` finding says so already:
// an `unexplained` finding located where the failed test points (the held-out span that misses
// most for the held-out NEES; else the (gyro, span) cell of the in-sample residuals that exceeds
// most, `remaining`, significant or not).
Unexplained RemainingAfterFindings(const ModelConsistency& consistency,
                                   const HeldOutResult& held_out, const Mismatch& remaining);

// The report's summary of a partly explained recording: what the findings explain (the shares,
// the held-out NEES and gap drift before and after), which tests fail, and where what remains
// is (`remains`: the `unexplained` findings).
std::string PartlyExplainedSummary(const ModelConsistency& consistency, const FitSummary& before,
                                   const FitSummary& after,
                                   const std::vector<const Finding*>& remains);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_CONSISTENCY_H_
