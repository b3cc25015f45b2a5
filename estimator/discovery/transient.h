// A transient from an onset (docs/discovery.md, "Time behaviour"): the warm-up's decaying drift
// switched on during the recording, its onset searched as a drift step's (onset_search.h) and its
// time constant as the warm-up's (time_constant_search.h). Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_TRANSIENT_H_
#define ESG_ESTIMATOR_DISCOVERY_TRANSIENT_H_

#include "absl/status/status.h"
#include "estimator/discovery/candidate.h"

namespace esg::estimator::discovery {

// The time behaviour of a transient-from-an-onset finding.
inline constexpr const char* kTimeTransient = "transient";

// An exponential transient of `candidate.gyro` from an onset (docs/discovery.md, "Time
// behaviour"): a case-fixed drift A e^(-(t - T) / tau) from T on, 0 before, as the warm-up's
// three exponential_decay terms with their epoch at T, freed with the prior c_sigma_deg_h. T is
// searched as the drift step's onset at the middle time constant of the warm-up's grid (every
// run continued from a checkpoint of one run with the terms inert), then tau on the warm-up's
// grid at the best T. The evidence integrates T over a uniform prior and tau over a prior uniform
// in ln tau, separated (at the best T). Fills `fit` (model, run, parameters transientDegH[0..2],
// transientSizeDegH, tauHours, tauLowerHours, tauUpperHours, onsetHours, onsetLowerHours,
// onsetUpperHours, the onset's time behaviour, description, basis_terms, notes). A gyro whose
// basis has no room for three more terms gets no fit. Errors: InvalidArgument for a gyro that
// is not configured; those of RunModel.
absl::Status FitTransient(const Candidate& candidate, const FitContext& context, CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_TRANSIENT_H_
