// Time behaviour of a drift (docs/discovery.md, "Time behaviour"): how a drift that changes
// during the recording is fitted and described. A drift switched on at an onset (`drift_step`:
// the C1 states of eq. (10) released at the onset, the likelihood profiled over it) and the trend
// of the suspension offset voltages through eq. (3) (a rotor displacement that grows). The random
// walk's intensity, common or per gyro, is fitted with the library in candidates.cc.
#ifndef ESG_ESTIMATOR_DISCOVERY_TIME_BEHAVIOUR_H_
#define ESG_ESTIMATOR_DISCOVERY_TIME_BEHAVIOUR_H_

#include <vector>

#include "absl/status/status.h"
#include "estimator/discovery/candidate.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// A drift step of `candidate.gyro` (docs/discovery.md, "Time behaviour"): the C1 states of the
// gyro released at an onset (session.h CoefficientRelease, prior c_sigma_deg_h), the likelihood
// profiled over the onset on a coarse grid refined twice near its maximum; every onset run
// continues from a checkpoint of one run without the step, so an onset costs the part of a run
// after it. Fills `fit` (model, run, parameters, time, notes). Errors: InvalidArgument for a gyro
// that is not configured; those of RunModel.
absl::Status FitDriftStep(const Candidate& candidate, const FitContext& context,
                          CandidateFit& fit);

// The trend of a gyro's suspension offset voltages through eq. (3): a robust line per case axis
// [mV/h], the displacement rate it implies [um/h] with its 1-sigma (from the line's residual
// scatter), and a chi-square(3) test of "no trend". Evidence only (a growing displacement is not
// yet a candidate); appended to `fit` (parameters displacementRateUmPerH[0..2], a note).
void DescribeVoltageTrend(const SpacecraftConfig& config,
                          const std::vector<TelemetryFrame>& frames, int gyro, CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_TIME_BEHAVIOUR_H_
