// The open-ended stage on what forward selection left (docs/discovery.md, "The open-ended
// stage"): when a mismatch remains after the library's rounds, the basis's terms are fitted to
// the model the findings define and taken when they pass the same checks as in a round (a
// wandering gyro's terms must describe its deviation better than a drift that returns to its
// mean, a readout jump must not explain it better, and the held-out prediction must not worsen).
// Pure computation through the context's runner.
#ifndef ESG_ESTIMATOR_DISCOVERY_WHAT_IS_LEFT_H_
#define ESG_ESTIMATOR_DISCOVERY_WHAT_IS_LEFT_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "estimator/discovery/context.h"
#include "estimator/discovery/forward_selection.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/report.h"
#include "estimator/discovery/selection.h"

namespace esg::estimator::discovery {

struct WhatIsLeft {
  // The terms were taken: `selected` is extended (its held-out prediction current), their
  // findings appended to `selection.findings`, and the selection's unresolved reason cleared.
  bool taken = false;
  // What the remaining deviation resembles, and why terms were left out, in words (a note for an
  // `unexplained` finding that remains).
  std::string resembles;
};

// `gyros`: the running gyros; `held_out`: the held-out prediction of `selected` (the model
// without the terms). The stage's residual drift replaces `selection.residual_drift` when it
// found terms or none was kept; the gyros it leaves out for a drift that returns to its mean join
// `selection.outdone_gyros`, and a taken finding carries the stand-in's note (then cleared).
// Errors: those of RunBasisStage and RunModel.
absl::StatusOr<WhatIsLeft> ExplainWhatSelectionLeft(SelectedModel& selected,
                                                    DiagnosisContext& context,
                                                    const std::vector<int>& gyros,
                                                    const HeldOutResult& held_out,
                                                    ForwardSelection& selection);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_WHAT_IS_LEFT_H_
