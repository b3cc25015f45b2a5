// A warm-up (docs/discovery.md, "Time behaviour"): a case-fixed drift that decays from the
// recording's start, its time constant searched (time_constant_search.h). Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_WARM_UP_H_
#define ESG_ESTIMATOR_DISCOVERY_WARM_UP_H_

#include "absl/status/status.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/time_constant_search.h"

namespace esg::estimator::discovery {

// The time behaviour of a warm-up finding (report.h TimeBehaviour::kind).
inline constexpr const char* kTimeWarmUp = "warm_up";

// A warm-up of `candidate.gyro` (docs/discovery.md, "Time behaviour"): a case-fixed drift A e^(-t /
// tau) from the recording's start, as three exponential_decay basis terms (basis_term.h, one per
// case axis, epoch the first frame) freed with the prior c_sigma_deg_h, the filter calibrating A;
// tau profiled over log-spaced time constants from kWarmUpMinTauHours to kWarmUpMaxTauHours,
// refined twice near the best, its evidence integrated over a prior uniform in ln tau across that
// span, its interval where -2 log L stays within 3.84 of its minimum. Fills `fit` (model with the
// terms at the best tau, run, parameters warmUpDegH[0..2], warmUpSizeDegH, tauHours,
// tauLowerHours, tauUpperHours, description, basis_terms, notes). A gyro whose basis has no room
// for three more terms gets no fit (parameters 0, a note). Errors: InvalidArgument for a gyro
// that is not configured; those of RunModel.
absl::Status FitWarmUp(const Candidate& candidate, const FitContext& context, CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_WARM_UP_H_
