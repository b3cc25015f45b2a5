// The held-out point-prediction guard (docs/discovery.md, "A verdict no stronger than its
// evidence"): a model change is taken only when it does not make the held-out point prediction
// worse. The held-out deviance (-2 log predictive density, held_out.h) scores a prediction and its
// uncertainty together, so a term that widens its own covariance (a raised random walk) can lower
// it while the predicted attitude drifts away faster; the gap drift (the RMS over the held-out
// spans of the attitude error's rate against the withheld star tracker, the paper's Fig. 7/8
// measure) is the point prediction alone, and it is an estimate with its own sampling noise
// (the slope of a line fitted to the noisy held-out attitude error), which the guard allows for.
// Every selection path (the library's constant effects,
// the time behaviours and the random walk, the open-ended basis in a round and after the rounds)
// passes a candidate model through this guard before taking it.
#ifndef ESG_ESTIMATOR_DISCOVERY_POINT_PREDICTION_H_
#define ESG_ESTIMATOR_DISCOVERY_POINT_PREDICTION_H_

#include <string>

#include "absl/status/statusor.h"
#include "estimator/discovery/context.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/selected_model.h"

namespace esg::estimator::discovery {

// A model change may make the held-out gap drift at most this much worse (relative): 5%.
inline constexpr double kMaxGapDriftWorsening = 0.05;

// The confidence at which a worsening beyond kMaxGapDriftWorsening must be shown: the standard
// normal's 0.95 quantile (a one-sided test at 5%).
inline constexpr double kGapDriftWorseningZ = 1.6449;

// True when `after` predicts the held-out spans' attitude materially worse than `before`, beyond
// what the two gap drifts' sampling uncertainty allows. The statistic, with R the gap drifts and
// s their 1-sigma from the held-out line fits' slope uncertainty (HeldOutResult::
// rate_rms_sigma_deg_h), m = kMaxGapDriftWorsening:
//   z = (R_after - (1 + m) R_before) / sqrt(s_after^2 + (1 + m)^2 s_before^2),
// and the change worsens the prediction when z > kGapDriftWorseningZ: the hypothesis "no more
// than 5% worse" is rejected at one-sided 5%. The two estimates are treated as independent; both
// are fitted to the same withheld star tracker, whose noise moves them together, so the true
// sigma of the difference is no larger and the test refuses a change that is not worse with
// probability at most 5%. Without sigmas (s = 0) it is the bare bound R_after > (1 + m) R_before.
// False when either has no held-out span with a rate (nothing to compare).
bool WorsensPointPrediction(const HeldOutResult& before, const HeldOutResult& after);

// z above for `before` and `after` (0 when either has no rate; +-infinity when both sigmas are 0
// and the gap drifts differ).
double GapDriftWorseningZ(const HeldOutResult& before, const HeldOutResult& after);

// The guard's verdict on one candidate model.
struct PointPredictionCheck {
  bool worsens = false;
  HeldOutResult held_out;  // the candidate's held-out prediction (empty without held-out spans)
  std::string note;        // "... gap drift a -> b deg/h ..." when it worsens, else empty
};

// Computes `selected`'s held-out prediction when it is not current (one run; none without
// held-out spans). Errors: Cancelled, those of RunModel.
absl::Status MakeHeldOutCurrent(SelectedModel& selected, DiagnosisContext& context);

// The candidate `model` (named `name` in the note) against `selected`, whose held-out prediction
// is computed first when it is not current. Without held-out spans nothing is run and nothing
// worsens. Errors: Cancelled, those of RunModel.
absl::StatusOr<PointPredictionCheck> CheckPointPrediction(const ModelState& model,
                                                          const std::string& name,
                                                          SelectedModel& selected,
                                                          DiagnosisContext& context);

// The note of a candidate left out by the guard: its held-out gap drift before and after with
// their 1-sigma and z, and what its held-out deviance says about the uncertainty it claims.
std::string PointPredictionNote(const std::string& name, const HeldOutResult& before,
                                const HeldOutResult& after);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_POINT_PREDICTION_H_
