// The bounded adaptive process noise of noise_widening.h.
#include "estimator/noise_widening.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"
#include "estimator/statistics.h"
#include "estimator/units.h"

namespace esg::estimator {

namespace {
// Per-step cap level: a step's NIS enters at most at its 1 - 1e-3 quantile.
constexpr double kCapLevel = 1e-3;
// Largest degrees of freedom of one step (2 per gyro, at most four gyros).
constexpr int kMaxStepDof = 8;
// A widening below (0.01 arcsec)^2 per step is none.
constexpr double kNegligibleVariance = 2.35e-15;
}  // namespace

NoiseWidening::NoiseWidening(double measurement_step_s, const NoiseWideningOptions& options)
    : options_(options), measurement_step_s_(std::max(measurement_step_s, 1e-3)) {
  options_.window_steps = std::max(options_.window_steps, 1);
  options_.warmup_steps = std::max(options_.warmup_steps, 0);
  options_.alpha = std::clamp(options_.alpha, 1e-12, 0.5);
  options_.alpha_narrow = std::clamp(options_.alpha_narrow, 1e-12, 0.5);
  options_.max_drift_deg_h = std::max(options_.max_drift_deg_h, 0.0);
  const double max_angle = DegPerHourToRadPerSec(options_.max_drift_deg_h) * measurement_step_s_;
  max_variance_ = max_angle * max_angle;
}

double NoiseWidening::EquivalentDriftDegH() const {
  return RadPerSecToDegPerHour(std::sqrt(added_variance_) / measurement_step_s_);
}

std::optional<NoiseWidening::Decision> NoiseWidening::Add(double nis, int dof,
                                                          double mean_variance) {
  if (dof <= 0 || dof > kMaxStepDof || !std::isfinite(nis) || nis < 0.0 ||
      !std::isfinite(mean_variance) || mean_variance <= 0.0) {
    return std::nullopt;
  }
  if (steps_seen_ < options_.warmup_steps) {
    ++steps_seen_;
    return std::nullopt;
  }
  window_.push_back(
      {std::min(nis, ChiSquareQuantile(1.0 - kCapLevel, dof)), dof, mean_variance});
  if (static_cast<int>(window_.size()) < options_.window_steps) return std::nullopt;
  Decision d;
  d.steps = static_cast<int>(window_.size());
  double variance_sum = 0.0;
  for (const Step& s : window_) {
    d.nis_sum += s.nis;
    d.dof += s.dof;
    variance_sum += s.mean_variance;
  }
  const double mean_variance_window = variance_sum / d.steps;
  const double ratio = d.nis_sum / d.dof;
  d.widen_threshold = ChiSquareQuantile(1.0 - options_.alpha, d.dof);
  d.narrow_threshold = ChiSquareQuantile(options_.alpha_narrow, d.dof);
  const bool exceeded = d.nis_sum > d.widen_threshold;
  const bool persistent = exceeded && previous_exceeded_;
  previous_exceeded_ = exceeded;
  const bool from_configured = added_variance_ == 0.0;
  if (persistent && added_variance_ < max_variance_) {
    added_variance_ =
        std::min(added_variance_ + (ratio - 1.0) * mean_variance_window, max_variance_);
    d.change = Decision::Change::kWidened;
  } else if (d.nis_sum < d.narrow_threshold && added_variance_ > 0.0) {
    // Halved, not the moment estimate: a window after a transient misfit (a slew the model
    // misses) is calm, and subtracting its deficit would undo the widening at once.
    added_variance_ = added_variance_ / 2.0 < kNegligibleVariance ? 0.0 : added_variance_ / 2.0;
    d.change = Decision::Change::kNarrowed;
  }
  d.added_variance = added_variance_;
  if (added_variance_ == 0.0) {
    trigger_.reset();
  } else if (from_configured) {
    trigger_ = d;
  }
  window_.clear();
  return d;
}

std::vector<double> NoiseWidening::ExportState() const {
  std::vector<double> out = {added_variance_, static_cast<double>(steps_seen_),
                             previous_exceeded_ ? 1.0 : 0.0};
  if (trigger_.has_value()) {
    out.insert(out.end(), {1.0, trigger_->nis_sum, static_cast<double>(trigger_->dof),
                           trigger_->widen_threshold, static_cast<double>(trigger_->steps)});
  } else {
    out.insert(out.end(), {0.0, 0.0, 0.0, 0.0, 0.0});
  }
  out.push_back(static_cast<double>(window_.size()));
  for (const Step& s : window_) {
    out.push_back(s.nis);
    out.push_back(s.dof);
    out.push_back(s.mean_variance);
  }
  return out;
}

absl::Status NoiseWidening::RestoreState(absl::Span<const double> state) {
  if (state.size() < 9) return absl::DataLossError("noise widening: state truncated");
  const double v = state[0];
  if (!std::isfinite(v) || v < 0.0 || v > max_variance_) {
    return absl::DataLossError(
        absl::StrFormat("noise widening: added variance %g outside [0, %g]", v, max_variance_));
  }
  const double seen = state[1];
  if (!(seen >= 0.0 && seen <= options_.warmup_steps && seen == std::floor(seen))) {
    return absl::DataLossError(
        absl::StrFormat("noise widening: steps seen %g outside [0, %d] or not an integer", seen,
                        options_.warmup_steps));
  }
  if (state[2] != 0.0 && state[2] != 1.0) {
    return absl::DataLossError(
        absl::StrFormat("noise widening: previous-window flag %g is not 0 or 1", state[2]));
  }
  std::optional<Decision> trigger;
  if (state[3] == 1.0) {
    Decision t;
    t.change = Decision::Change::kWidened;
    t.nis_sum = state[4];
    t.widen_threshold = state[6];
    const double dof = state[5], steps = state[7];
    if (!std::isfinite(t.nis_sum) || !std::isfinite(t.widen_threshold) ||
        !(dof >= 1.0 && dof <= 1e9 && dof == std::floor(dof)) ||
        !(steps >= 1.0 && steps <= 1e9 && steps == std::floor(steps))) {
      return absl::DataLossError("noise widening: trigger window malformed");
    }
    t.dof = static_cast<int>(dof);
    t.steps = static_cast<int>(steps);
    t.added_variance = v;
    trigger = t;
  } else if (state[3] != 0.0) {
    return absl::DataLossError(
        absl::StrFormat("noise widening: trigger flag %g is not 0 or 1", state[3]));
  }
  const double w = state[8];
  if (!(w >= 0.0 && w < options_.window_steps && w == std::floor(w)) ||
      state.size() != 9 + 3 * static_cast<size_t>(w)) {
    return absl::DataLossError(absl::StrFormat(
        "noise widening: window length %g does not fit the state (%d values) or the window of %d "
        "steps",
        w, state.size(), options_.window_steps));
  }
  std::vector<Step> window;
  for (size_t i = 9; i < state.size(); i += 3) {
    const double nis = state[i], dof = state[i + 1], var = state[i + 2];
    if (!std::isfinite(nis) || nis < 0.0 || !(dof >= 1.0 && dof <= kMaxStepDof) ||
        dof != std::floor(dof) || !std::isfinite(var) || var <= 0.0) {
      return absl::DataLossError(absl::StrFormat(
          "noise widening: window step %d has NIS %g, %g degrees of freedom, variance %g",
          (i - 9) / 3, nis, dof, var));
    }
    window.push_back({nis, static_cast<int>(dof), var});
  }
  added_variance_ = v;
  steps_seen_ = static_cast<int>(seen);
  previous_exceeded_ = state[2] == 1.0;
  trigger_ = trigger;
  window_ = std::move(window);
  return absl::OkStatus();
}

}  // namespace esg::estimator
