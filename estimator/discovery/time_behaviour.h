// Time behaviour of a drift (docs/discovery.md, "Time behaviour"): how a drift that changes
// during the recording is fitted and described, one job a file. A drift switched on at an onset
// (drift_step.h: the C1 states of eq. (10) released at the onset, the likelihood profiled over
// it), a step of another group of drift coefficients (coefficient_step.h), a warm-up decaying from
// the start (warm_up.h), a transient from an onset (transient.h), and the trend of the suspension
// offset voltages through eq. (3) (voltage_trend.h: a rotor displacement that grows). What they
// share: the onset search (onset_search.h) and the time-constant search (time_constant_search.h).
// The random walk's intensity, common or per gyro, is fitted with the library in candidates.cc.
#ifndef ESG_ESTIMATOR_DISCOVERY_TIME_BEHAVIOUR_H_
#define ESG_ESTIMATOR_DISCOVERY_TIME_BEHAVIOUR_H_

#include "estimator/discovery/coefficient_step.h"
#include "estimator/discovery/drift_step.h"
#include "estimator/discovery/transient.h"
#include "estimator/discovery/voltage_trend.h"
#include "estimator/discovery/warm_up.h"

#endif  // ESG_ESTIMATOR_DISCOVERY_TIME_BEHAVIOUR_H_
