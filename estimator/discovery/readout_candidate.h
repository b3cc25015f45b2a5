// The open-ended basis's readout group as a candidate of each selection round (docs/discovery.md,
// "The open-ended stage"): a symmetric distortion E of a gyro's direction-cosine readout (scale
// factors of the channels, their non-orthogonality; the reading is (I + E) h normalised) is an
// error of the readings, not a drift, so no effect of the library describes it, and left to the
// end it is forced onto the nearest ones (unequal stiffness, a misalignment, a raised random
// walk). It therefore competes with them in every round, in the same currency:
//
//   1. the gyro's deviation from the current model (deviation.h) regressed on the five traceless
//      readout patterns (open_ended.h FitReadoutDistortion), priors OpenEndedOptions::readout_sigma;
//   2. the model with E added to the gyro's GyroConfig::readout_distortion (held, not a filter
//      state) refitted by the filter;
//   3. its evidence 2 ln B = the refit's improvement of -2 log L less Laplace's Occam term of the
//      five coefficients (CandidateFit::occam), as for the library's searched effects.
//
// Found, it is reported as a basis term (report.h kEffectBasisTerm) with its distortion. Pure
// computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_READOUT_CANDIDATE_H_
#define ESG_ESTIMATOR_DISCOVERY_READOUT_CANDIDATE_H_

#include "absl/status/status.h"
#include "estimator/discovery/candidate.h"

namespace esg::estimator::discovery {

// Fits candidate {Effect::kReadoutDistortion, gyro} into `fit` (whose model is the context's
// model with the candidate's name added): parameters, occam, run, description and distortion.
// Errors: InvalidArgument for a gyro that is not configured; those of MeasureDeviations and
// RunModel.
absl::Status FitReadoutCandidate(const Candidate& candidate, const FitContext& ctx,
                                 CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_READOUT_CANDIDATE_H_
