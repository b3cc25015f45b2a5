// A drift step (docs/discovery.md, "Time behaviour"): the C1 states of eq. (10) released at an
// onset, the likelihood profiled over it (onset_search.h), against the competing jump of the
// gyro's readings (D43). Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_DRIFT_STEP_H_
#define ESG_ESTIMATOR_DISCOVERY_DRIFT_STEP_H_

#include "absl/status/status.h"
#include "estimator/discovery/candidate.h"

namespace esg::estimator::discovery {

// A drift step of `candidate.gyro` (docs/discovery.md, "Time behaviour"): the C1 states of the
// gyro released at an onset (session.h CoefficientRelease, prior c_sigma_deg_h), the likelihood
// profiled over the onset on a coarse grid refined twice near its maximum; every onset run
// continues from a checkpoint of one run without the step, so an onset costs the part of a run
// after it. Fills `fit` (model, run, parameters, time, notes). Errors: InvalidArgument for a gyro
// that is not configured; those of RunModel.
absl::Status FitDriftStep(const Candidate& candidate, const FitContext& context,
                          CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_DRIFT_STEP_H_
