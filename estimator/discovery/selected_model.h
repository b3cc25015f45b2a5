// The model forward selection has reached (selection.h) and the margin by which two
// descriptions are told apart in-sample: what the selection round and the stages it calls (the
// open-ended stage, basis_stage.h; the drift that returns to its mean, wander.h) share, below all
// three so that none of them includes another's header both ways.
#ifndef ESG_ESTIMATOR_DISCOVERY_SELECTED_MODEL_H_
#define ESG_ESTIMATOR_DISCOVERY_SELECTED_MODEL_H_

#include "estimator/discovery/candidate.h"
#include "estimator/discovery/held_out.h"
#include "estimator/discovery/model_run.h"

namespace esg::estimator::discovery {

// Two candidates whose evidence 2 ln B differs by less than this are not told apart by the
// recording in-sample (Kass & Raftery: below 10 is not "very strong"); held-out prediction
// decides between them.
inline constexpr double kDecisiveDeviance = 10.0;

// The model selection has reached, and what is known of it.
struct SelectedModel {
  ModelState model;
  ModelRun run;          // its full in-sample run
  ProfiledDeviance fit;  // Profile(run)
  // Its held-out prediction, when `held_out_current`; else that of an earlier model.
  HeldOutResult held_out;
  bool held_out_current = true;
};

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_SELECTED_MODEL_H_
