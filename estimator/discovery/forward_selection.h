// Forward selection (docs/discovery.md, "Method" and "Time behaviour"): one effect of the library
// (or the open-ended basis's terms, selection.h) per round while one is found. A round left
// unresolved by a drift that returns to its mean (wander.h) does not end it: that gyro's random
// walk at the library's best intensity stands in for the drift while selection goes on with the
// other gyros and the common effects, once, and goes again at the end. Pure computation through
// the context's runner.
#ifndef ESG_ESTIMATOR_DISCOVERY_FORWARD_SELECTION_H_
#define ESG_ESTIMATOR_DISCOVERY_FORWARD_SELECTION_H_

#include <set>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "estimator/discovery/context.h"
#include "estimator/discovery/report.h"
#include "estimator/discovery/selection.h"

namespace esg::estimator::discovery {

struct ForwardSelection {
  std::vector<Finding> findings;       // in the order taken
  std::vector<CandidateScore> rows;    // every candidate of every round
  // The open-ended stage's residual drift of the last round that took its terms.
  std::vector<ResidualDriftPoint> residual_drift;
  // Why the round that ended selection took nothing, as RoundResult says it (selection.h); with a
  // stand-in, the first unresolved round's (the wandering drift's).
  std::string unresolved, unresolved_note;
  int unresolved_gyro = 0;
  Mismatch unresolved_where;
  double stationary_evidence = -1.0;
  double readout_jump_evidence = -1.0;
  // Gyros whose open-ended terms a round left out for a drift that returns to its mean, and a
  // second wandering gyro found after the stand-in: tested again at the end (wander.h
  // OtherGyrosReturningToTheirMean).
  std::set<int> outdone_gyros;
  // With a stand-in: what it was ("selection went on with the other gyros after round r ..."),
  // and the reason a later round was left unresolved, when it was another (else empty).
  std::string stand_in_note, later_unresolved;
};

// Rounds 0 .. options.max_effects - 1 over `gyros` from `selected`, which ends as the model the
// findings define (without the stand-in). Errors: those of SelectionRound and RunModel.
absl::StatusOr<ForwardSelection> SelectEffects(const std::vector<int>& gyros,
                                               SelectedModel& selected,
                                               DiagnosisContext& context);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_FORWARD_SELECTION_H_
