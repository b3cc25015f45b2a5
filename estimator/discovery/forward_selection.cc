#include "estimator/discovery/forward_selection.h"

#include <algorithm>
#include <optional>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"

namespace esg::estimator::discovery {

absl::StatusOr<ForwardSelection> SelectEffects(const std::vector<int>& gyros,
                                               SelectedModel& selected,
                                               DiagnosisContext& context) {
  ForwardSelection out;
  std::vector<int> active_gyros = gyros;
  struct StandIn {
    int gyro = 0;
    std::vector<std::pair<int, double>> walks_before;  // SessionOptions::random_walk_by_gyro
  };
  std::optional<StandIn> stood_in;
  for (int round = 0; round < context.options().max_effects; ++round) {
    auto result = SelectionRound(round, active_gyros, selected, context);
    if (!result.ok()) return result.status();
    out.rows.insert(out.rows.end(), result->rows.begin(), result->rows.end());
    out.outdone_gyros.insert(result->outdone_gyros.begin(), result->outdone_gyros.end());
    if (result->finding.has_value()) {
      out.findings.push_back(std::move(*result->finding));
      for (Finding& f : result->more_findings) out.findings.push_back(std::move(f));
      if (!result->residual_drift.empty()) out.residual_drift = result->residual_drift;
      continue;
    }
    if (stood_in.has_value()) {
      // After the stand-in: a second wandering gyro is tested again at the end; another reason
      // is a note on the verdict's finding.
      if (result->unresolved_where.found) {
        out.outdone_gyros.insert(result->unresolved_where.gyro);
      } else if (!result->unresolved.empty()) {
        out.later_unresolved = absl::StrCat(
            "with that stand-in, a later round left a further mismatch unresolved: ",
            result->unresolved);
      }
      break;
    }
    out.unresolved = result->unresolved;
    out.unresolved_note = result->unresolved_note;
    out.unresolved_gyro = result->unresolved_gyro;
    out.unresolved_where = result->unresolved_where;
    out.stationary_evidence = result->stationary_evidence;
    out.readout_jump_evidence = result->readout_jump_evidence;
    if (!result->stand_in.has_value() || active_gyros.size() < 2) break;
    const int gyro = out.unresolved_where.gyro;
    out.stand_in_note = absl::StrFormat(
        "selection went on with the other gyros after round %d, gyro %d's random walk raised to "
        "%.4f deg/h/sqrt(h) (the library's best intensity for it) standing in for this drift "
        "meanwhile: not a finding, and removed again before the open-ended stage and the fit "
        "after the findings",
        round + 1, gyro, result->stand_in_walk_deg_h_sqrt_h);
    stood_in = StandIn{gyro, selected.model.options.random_walk_by_gyro};
    selected = std::move(*result->stand_in);
    std::erase(active_gyros, gyro);
  }
  if (!stood_in.has_value()) return out;
  // The stand-in goes: the gyro's walk as it was before it (the findings taken since keep
  // theirs), so what follows describes that gyro's drift on the model the findings define.
  ModelState restored = selected.model;
  auto& walks = restored.options.random_walk_by_gyro;
  std::erase_if(walks, [&](const auto& w) { return w.first == stood_in->gyro; });
  for (const auto& w : stood_in->walks_before) {
    if (w.first == stood_in->gyro) walks.push_back(w);
  }
  auto run = context.CheckedRun(restored, /*held_out=*/false);
  if (!run.ok()) return run.status();
  selected.model = std::move(restored);
  selected.run = std::move(*run);
  selected.fit = Profile(selected.run);
  selected.held_out_current = false;
  return out;
}

}  // namespace esg::estimator::discovery
