#include "estimator/discovery/point_prediction.h"

#include <cmath>
#include <limits>

#include "absl/strings/str_format.h"

namespace esg::estimator::discovery {

double GapDriftWorseningZ(const HeldOutResult& before, const HeldOutResult& after) {
  if (!(before.rate_rms_deg_h > 0.0) || !(after.rate_rms_deg_h > 0.0)) return 0.0;
  const double allowed = 1.0 + kMaxGapDriftWorsening;
  const double excess_deg_h = after.rate_rms_deg_h - allowed * before.rate_rms_deg_h;
  const double sigma_deg_h =
      std::hypot(after.rate_rms_sigma_deg_h, allowed * before.rate_rms_sigma_deg_h);
  if (sigma_deg_h > 0.0) return excess_deg_h / sigma_deg_h;
  if (excess_deg_h == 0.0) return 0.0;
  return excess_deg_h > 0.0 ? std::numeric_limits<double>::infinity()
                            : -std::numeric_limits<double>::infinity();
}

bool WorsensPointPrediction(const HeldOutResult& before, const HeldOutResult& after) {
  return GapDriftWorseningZ(before, after) > kGapDriftWorseningZ;
}

std::string PointPredictionNote(const std::string& name, const HeldOutResult& before,
                                const HeldOutResult& after) {
  return absl::StrFormat(
      "%s is not taken: it makes the held-out point prediction worse, gap drift %.4f -> %.4f "
      "deg/h (1-sigma %.4f and %.4f from the held-out line fits: more than %.0f%% worse at z = "
      "%.1f > %.2f), whatever its uncertainty claims (held-out NEES %.1f -> %.1f on %d dof, -2 "
      "log predictive density %.1f -> %.1f)",
      name, before.rate_rms_deg_h, after.rate_rms_deg_h, before.rate_rms_sigma_deg_h,
      after.rate_rms_sigma_deg_h, 100.0 * kMaxGapDriftWorsening, GapDriftWorseningZ(before, after),
      kGapDriftWorseningZ, before.nees, after.nees, after.dof, before.deviance, after.deviance);
}

absl::Status MakeHeldOutCurrent(SelectedModel& selected, DiagnosisContext& context) {
  if (selected.held_out_current || context.gaps().empty()) return absl::OkStatus();
  auto held = context.CheckedRun(selected.model, /*held_out=*/true);
  if (!held.ok()) return held.status();
  selected.held_out = SummariseHeldOut(*held, context.gaps(), context.regimes(), context.frames());
  selected.held_out_current = true;
  return absl::OkStatus();
}

absl::StatusOr<PointPredictionCheck> CheckPointPrediction(const ModelState& model,
                                                          const std::string& name,
                                                          SelectedModel& selected,
                                                          DiagnosisContext& context) {
  PointPredictionCheck out;
  if (context.gaps().empty()) return out;
  if (absl::Status s = MakeHeldOutCurrent(selected, context); !s.ok()) return s;
  auto held = context.CheckedRun(model, /*held_out=*/true);
  if (!held.ok()) return held.status();
  out.held_out = SummariseHeldOut(*held, context.gaps(), context.regimes(), context.frames());
  out.worsens = WorsensPointPrediction(selected.held_out, out.held_out);
  if (out.worsens) out.note = PointPredictionNote(name, selected.held_out, out.held_out);
  return out;
}

}  // namespace esg::estimator::discovery
