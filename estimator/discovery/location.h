// Location (docs/discovery.md, "Locate" and "Unexplained"): where in time, in which regime span
// and in which gyro the star-tracker residuals of a run exceed what the filter expects, and the
// `unexplained` finding for a mismatch that remains after selection, with where it is. Also the
// residual summaries of the report (RMS, the plotted series).
#ifndef ESG_ESTIMATOR_DISCOVERY_LOCATION_H_
#define ESG_ESTIMATOR_DISCOVERY_LOCATION_H_

#include <vector>

#include "estimator/discovery/candidate.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/regimes.h"
#include "estimator/discovery/report.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// Materiality of a noise misfit: star-tracker differences beyond 1.5 times their predicted
// variance (1.22x their sigma) throughout.
inline constexpr double kMaterialDispersion = 1.5;

// Materiality of a span's residual excess: its star-tracker differences beyond twice their
// predicted size (RMS), the same bound as the held-out errors' (kMaterialNeesRatio). With ~10^2
// samples a span is "significantly" worse already at 1.4x, which the filter's own transients
// after a regime change reach on effect-free recordings (slews); an effect that leaves a span
// unexplained exceeds it (a 0.05 deg/h drift unmodelled for an hour is 180 arcsec).
inline constexpr double kMaterialResidualRatio = 2.0;

// RMS of the star-tracker innovations over the accepted in-sample steps of a run [arcsec].
double ResidualRmsArcsec(const ModelRun& run);

// |star-tracker difference| per gyro and in-sample step, hours since the first frame.
std::vector<ResidualPoint> ResidualSeries(const ModelRun& run,
                                          const std::vector<TelemetryFrame>& frames);

// Where the user's model (`base`) and the model with the findings (`extended`) disagree with the
// recording most: the (gyro, regime span) cell whose residual excess over the extended model's
// own mean stands out, `found` when significant at alpha Bonferroni-corrected over the cells.
// Star-tracker samples that are outliers for the extended model are left out of both.
struct Mismatches {
  Mismatch base;
  Mismatch remaining;
};
Mismatches LocateMismatches(const ModelRun& base, const ModelRun& extended,
                            const std::vector<RegimeSpan>& spans,
                            const std::vector<TelemetryFrame>& frames, double alpha);

// The held-out span whose prediction misses most (largest NEES per degree of freedom) and the
// gyro whose spin axis drifts fastest there (0: none rated), with the p-value of the whole
// held-out NEES; `found` false without a held-out span with degrees of freedom.
Mismatch HeldOutMismatch(const HeldOutResult& held_out);

// What no candidate explains, after selection: a residual mismatch (`remaining.found`, or
// `unresolved`: why the candidates that fit were not taken, e.g. each fits only part of the
// recording or fails its physics check; `unresolved_gyro` the gyro they name, used when no span
// stands out; `unresolved_where`, when found, the place the reason names, used then), a held-out
// misprediction (MispredictsHeldOut), or star-tracker differences materially beyond their
// predicted variance throughout (`fit.dispersion`). The finding `unexplained` with its gyro and
// an explanation that names where it is; `where` is the mismatch it names (for a held-out
// misprediction alone: the held-out span that misses most, and the gyro drifting fastest there).
struct Unexplained {
  Finding finding;
  Mismatch where;
};
std::optional<Unexplained> FindUnexplained(const Mismatch& remaining,
                                           const std::string& unresolved, int unresolved_gyro,
                                           const Mismatch& unresolved_where,
                                           const HeldOutResult& held_out,
                                           const ProfiledDeviance& fit, bool after_findings,
                                           double alpha);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_LOCATION_H_
