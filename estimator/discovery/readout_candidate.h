// The open-ended basis's groups as candidates of each selection round: the readout group
// (docs/discovery.md, "The open-ended stage") and, below, the sun's families (FitSunCandidate).
// The readout group: a symmetric distortion E of a gyro's direction-cosine readout (scale
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

// The sun as a candidate of every selection round (docs/discovery.md, "A drift that follows the
// sun"; D104), candidate {Effect::kSunDrift, gyro}, beside the library's effects as the readout
// group is:
//
//   1. the gyro's deviation from the current model (deviation.h) regressed on the sun's families
//      of the faces the model does not hold (open_ended.h FitSunFamilies): each face's Bayes
//      factor averaged over the 41 lags (D101), the face with the most evidence taken, only
//      when no other group of the basis has decisively more evidence there (by the stage's
//      ambiguity, 2 ln B = 6: the sun is the stage's first choice or cannot be told apart from
//      it, D132);
//   2. its drift at the best lag held in the model as a correction of the gyro's readings
//      (sun_terms.h SunReadingShift), the model refitted by the filter;
//   3. its evidence 2 ln B = the refit's improvement of -2 log L less `occam`: Laplace's Occam
//      term of the three coefficients (open_ended.h ReadoutOccam) plus the lag's cost, 2 ln B at
//      the best lag less 2 ln B averaged over the lags in the regression (the refit holds the
//      best lag; the lag integrated over its prior costs what the regression's profile says);
//   4. for the round's physics check (selection.cc: not taken when a drift that returns to its
//      mean describes the deviation better, the stage's rule for its terms), the face's terms at
//      the best lag against that stationary drift on the same deviation (wander.h
//      CompareConstantEffect): CandidateFit::wander_*.
//
// The round counts the candidate once per family it may try, `sunlit` with the orbit (candidates.h
// CandidateComparisons).
// Found, it is reported as a basis term (kEffectBasisTerm, time behaviour kTimeFollowsSun) with
// sun_terms.h SunParameters and DescribeSunGroup. A recording outside the ephemeris's years gives
// no fit (parameters 0, a note). Errors: InvalidArgument for a gyro that is not configured; those
// of MeasureDeviations and RunModel.
absl::Status FitSunCandidate(const Candidate& candidate, const FitContext& ctx, CandidateFit& fit);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_READOUT_CANDIDATE_H_
