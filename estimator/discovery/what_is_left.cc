#include "estimator/discovery/what_is_left.h"

#include <algorithm>
#include <map>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/discovery/basis_stage.h"
#include "estimator/discovery/model_run.h"
#include "estimator/discovery/point_prediction.h"

namespace esg::estimator::discovery {

absl::StatusOr<WhatIsLeft> ExplainWhatSelectionLeft(SelectedModel& selected,
                                                    DiagnosisContext& context,
                                                    const std::vector<int>& gyros,
                                                    const HeldOutResult& held_out,
                                                    ForwardSelection& selection) {
  WhatIsLeft out;
  const double alpha = context.options().alpha;
  const int round = static_cast<int>(selection.findings.size());
  auto stage = RunBasisStage(selected, context, gyros, round);
  if (!stage.ok()) return stage.status();
  if (!stage->findings.empty() || selection.residual_drift.empty()) {
    selection.residual_drift = stage->residual_drift;
  }
  out.resembles = stage->resembles;
  // A gyro whose drift returns to its mean (wander.h): the basis's terms for it must describe
  // its deviation better than that stationary drift does, in the same reduced regression's
  // currency (2 ln B against the configured walk). Every gyro the terms are for is tested, not
  // only the one the library's last round left unresolved. When the unresolved gyro's terms
  // lose, none are taken: its wandering drift, which no term models, spills over into the other
  // gyros' deviations through the shared star tracker. When only other gyros' terms lose, they
  // are left out and the stage runs again on the rest.
  const Mismatch& unresolved_where = selection.unresolved_where;
  if (!stage->findings.empty()) {
    std::map<int, double> measured;
    if (unresolved_where.found && selection.stationary_evidence > 0.0) {
      measured[unresolved_where.gyro] = selection.stationary_evidence;
    }
    auto outdone = GyrosOutdoneByAStationaryDrift(*stage, selected, context, measured, {}, alpha);
    if (!outdone.ok()) return outdone.status();
    if (!outdone->gyros.empty()) {
      selection.outdone_gyros.insert(outdone->gyros.begin(), outdone->gyros.end());
      absl::StrAppend(&out.resembles, outdone->note);
      stage->findings.clear();
      const bool unresolved_lost =
          unresolved_where.found && outdone->Contains(unresolved_where.gyro);
      const bool others =
          !unresolved_lost &&
          std::any_of(stage->stage.selected.begin(), stage->stage.selected.end(),
                      [&](const SelectedGroup& g) { return !outdone->Contains(g.gyro); });
      if (others) {
        auto again = RunBasisStage(selected, context, outdone->Others(gyros), round);
        if (!again.ok()) return again.status();
        if (!again->findings.empty()) selection.residual_drift = again->residual_drift;
        stage = std::move(again);
      }
    }
  }
  // A jump of a gyro's readings that explained the last round as well as its time behaviour
  // (D43) must be beaten by the basis too: a ramp fitted to a jump is no physics.
  if (!stage->findings.empty() && selection.readout_jump_evidence > stage->refit_evidence) {
    absl::StrAppend(&out.resembles,
                    absl::StrFormat("; the basis's terms (2 ln B = %.1f) explain it less well "
                                    "than a jump of the gyro's readings (2 ln B = %.1f)",
                                    stage->refit_evidence, selection.readout_jump_evidence));
    stage->findings.clear();
  }
  // The terms must predict the held-out spans at least as well as the model without them, by the
  // predictive density and by the point prediction (point_prediction.h).
  if (!stage->findings.empty() && stage->extended.has_value() && !context.gaps().empty()) {
    auto held = context.CheckedRun(stage->extended->model, /*held_out=*/true);
    if (!held.ok()) return held.status();
    HeldOutResult with =
        SummariseHeldOut(*held, context.gaps(), context.regimes(), context.frames());
    if (with.deviance > held_out.deviance) {
      absl::StrAppend(&out.resembles,
                      absl::StrFormat("; the basis's terms fit in-sample (2 ln B = %.1f) but "
                                      "predict the held-out spans worse (-2 log predictive "
                                      "density %.1f against %.1f without them)",
                                      stage->refit_evidence, with.deviance, held_out.deviance));
      stage->findings.clear();
    } else if (WorsensPointPrediction(held_out, with)) {
      absl::StrAppend(&out.resembles, "; ", PointPredictionNote("the basis's terms", held_out, with));
      stage->findings.clear();
    } else {
      stage->extended->held_out = std::move(with);
      stage->extended->held_out_current = true;
    }
  }
  if (stage->findings.empty() || !stage->extended.has_value()) return out;
  // The stand-in (removed before this stage) let selection go on past this drift: its note goes
  // with the terms that explain the drift.
  if (!selection.stand_in_note.empty()) {
    stage->findings.front().evidence.notes.push_back(selection.stand_in_note);
    selection.stand_in_note.clear();
  }
  for (Finding& f : stage->findings) selection.findings.push_back(std::move(f));
  selected = std::move(*stage->extended);
  selection.unresolved.clear();
  selection.unresolved_note.clear();
  selection.unresolved_gyro = 0;
  selection.unresolved_where = Mismatch{};
  selection.stationary_evidence = -1.0;
  out.taken = true;
  return out;
}

}  // namespace esg::estimator::discovery
