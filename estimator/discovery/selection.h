// Forward selection (docs/discovery.md, "Select"): one round adds each candidate effect the model
// lacks in turn (candidates.h), refits, and scores it by its evidence 2 ln B (B the Bayes factor
// against the current model; significant above 2 ln(M / alpha) over the round's M candidates,
// statistics.h), with the homogeneity test (an effect of the library is constant in time). Deterministic effects come before the random walk;
// candidates within kDecisiveDeviance are decided by held-out prediction (held_out.h); when
// nothing is significant in-sample yet the model mispredicts the held-out spans, the candidates
// are scored by held-out prediction (a concealed effect).
#ifndef ESG_ESTIMATOR_DISCOVERY_SELECTION_H_
#define ESG_ESTIMATOR_DISCOVERY_SELECTION_H_

#include <optional>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "estimator/discovery/candidates.h"
#include "estimator/discovery/context.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/report.h"
#include "estimator/discovery/selected_model.h"

namespace esg::estimator::discovery {

struct RoundResult {
  std::vector<CandidateScore> rows;  // one per candidate tried, in candidate order
  // The effect taken (then `selected` holds the model with it), or none: selection ends.
  std::optional<Finding> finding;
  // Further findings taken with it: the open-ended stage's groups after the first, when the
  // basis was taken before a time behaviour.
  std::vector<Finding> more_findings;
  // The open-ended stage's residual drift when its terms were taken (basis_stage.h).
  std::vector<ResidualDriftPoint> residual_drift;
  // Nothing taken although a candidate fits: why (the best improves only part of the
  // recording, a change in time; or it fails its physics check), else empty; a supporting note
  // (a jump of a gyro's readings explains it at least as well, D43), and the gyro the best
  // candidate names (0: common).
  std::string unresolved;
  std::string unresolved_note;
  int unresolved_gyro = 0;
  // Where, when no span of the residuals stands out but the reason names one gyro's drift over
  // the whole recording (a drift that returns to its mean, wander.h); else not found.
  Mismatch unresolved_where;
  // With unresolved_where: the evidence 2 ln B of the drift that returns to its mean (wander.h),
  // which the open-ended stage's terms for that gyro must beat; else -1.
  double stationary_evidence = -1.0;
  // When a jump of a gyro's readings explained the round at least as well as its time behaviour
  // (D43): the jump's evidence 2 ln B, which anything else must beat (the open-ended stage too).
  double readout_jump_evidence = -1.0;
  // Gyros whose open-ended terms the round left out because a drift that returns to its mean
  // describes their deviation better (basis_stage.h GyrosOutdoneByAStationaryDrift).
  std::vector<int> outdone_gyros;
  // With unresolved_where (a drift that returns to its mean): the model with that gyro's random
  // walk at the library's best intensity (its random_walk_drift fit of the round), which stands
  // in for the drift while selection goes on with the other gyros (forward_selection.h); the intensity
  // [deg/h/sqrt(h)]. Empty when the round did not fit that walk.
  std::optional<SelectedModel> stand_in;
  double stand_in_walk_deg_h_sqrt_h = 0.0;
};

// Round `round` (0 first) of forward selection over the running `gyros`. Updates `selected` (its
// held-out prediction may be computed even when nothing is taken). Errors: Cancelled, those of
// FitCandidate and RunModel.
absl::StatusOr<RoundResult> SelectionRound(int round, const std::vector<int>& gyros,
                                           SelectedModel& selected, DiagnosisContext& context);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_SELECTION_H_
