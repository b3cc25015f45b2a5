// The trend of a gyro's suspension offset voltages through eq. (3) (docs/discovery.md, "Time
// behaviour"): a rotor displacement that grows during the recording. Evidence only, for the
// rotor displacement's finding and the open-ended stage. Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_VOLTAGE_TREND_H_
#define ESG_ESTIMATOR_DISCOVERY_VOLTAGE_TREND_H_

#include <vector>

#include "estimator/discovery/candidate.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// The trend of gyro `gyro`'s suspension offset voltages through eq. (3): a robust line per case
// axis [mV/h], the displacement rate it implies [um/h] with its 1-sigma (from the line's residual
// scatter), and a chi-square(3) test of "no trend". Evidence only (a growing displacement is not
// yet a candidate); appended to `fit` (parameters displacementRateUmPerH[0..2],
// displacementRateSizeUmPerH, displacement_trend, a note). Fewer than 10 frames with finite
// voltages, or all at one time, append nothing.
void DescribeVoltageTrend(const SpacecraftConfig& config,
                          const std::vector<TelemetryFrame>& frames, int gyro, CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_VOLTAGE_TREND_H_
