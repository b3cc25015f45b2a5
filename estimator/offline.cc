#include "estimator/offline.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"
#include "estimator/rotation.h"

namespace esg::estimator {

namespace {

struct LineFit {
  double slope = 0.0;
  double intercept = 0.0;
};

LineFit FitLine(const std::vector<double>& t, const std::vector<double>& y,
                const std::vector<bool>& use) {
  double n = 0, st = 0, sy = 0, stt = 0, sty = 0;
  for (size_t i = 0; i < t.size(); ++i) {
    if (!use[i]) continue;
    n += 1;
    st += t[i];
    sy += y[i];
    stt += t[i] * t[i];
    sty += t[i] * y[i];
  }
  LineFit f;
  const double den = n * stt - st * st;
  if (n < 2 || den == 0.0) return f;
  f.slope = (n * sty - st * sy) / den;
  f.intercept = (sy - f.slope * st) / n;
  return f;
}

double Median(std::vector<double> v) {
  if (v.empty()) return 0.0;
  std::nth_element(v.begin(), v.begin() + v.size() / 2, v.end());
  return v[v.size() / 2];
}

}  // namespace

double FitSlope(const std::vector<double>& t, const std::vector<double>& y) {
  std::vector<bool> use(t.size(), true);
  LineFit f = FitLine(t, y, use);
  std::vector<double> residual(t.size());
  for (size_t i = 0; i < t.size(); ++i) residual[i] = std::abs(y[i] - (f.intercept + f.slope * t[i]));
  const double mad = Median(residual);
  if (mad > 0.0) {
    for (size_t i = 0; i < t.size(); ++i) use[i] = residual[i] <= 5.0 * 1.4826 * mad;
    f = FitLine(t, y, use);
  }
  return f.slope;
}

absl::StatusOr<CalibrationResult> RunCalibration(const SpacecraftConfig& config,
                                                 const SessionOptions& options,
                                                 const std::vector<TelemetryFrame>& frames,
                                                 const ProgressFn& progress,
                                                 EstimationSession* session_out) {
  auto session = EstimationSession::Create(config, options);
  if (!session.ok()) return session.status();
  CalibrationResult result;
  double innovation_sum = 0.0;
  int innovation_count = 0;
  const size_t report_every = std::max<size_t>(1, frames.size() / 100);
  for (size_t i = 0; i < frames.size(); ++i) {
    auto report = session->AddFrame(frames[i]);
    if (!report.ok()) {
      return absl::Status(report.status().code(),
                          absl::StrFormat("frame %d (%s): %s", i,
                                          absl::FormatTime(absl::RFC3339_full, frames[i].time,
                                                           absl::UTCTimeZone()),
                                          report.status().message()));
    }
    ++result.frames;
    if (report->measurement_step) ++result.measurement_steps;
    if (report->star_tracker_used) {
      ++result.star_tracker_steps_used;
      innovation_sum += report->star_tracker_innovation.squaredNorm();
      innovation_count += static_cast<int>(report->star_tracker_innovation.size());
    }
    for (Event& e : report->events) {
      ++result.event_counts[e.kind];
      result.events.push_back(std::move(e));
    }
    result.final_attitude = report->attitude;
    if (progress && i % report_every == 0) progress(static_cast<double>(i) / frames.size());
  }
  if (progress) progress(1.0);
  result.gyros = session->Gyros();
  for (const GyroEstimate& g : result.gyros) result.relative_sigma[g.id] = session->RelativeSigma(g.id);
  result.final_state = session->state();
  result.innovation_rms = innovation_count > 0 ? std::sqrt(innovation_sum / innovation_count) : 0.0;
  if (session_out != nullptr) *session_out = std::move(*session);
  return result;
}

absl::StatusOr<GapResult> RunGap(const SpacecraftConfig& config, const SessionOptions& options,
                                 const std::vector<TelemetryFrame>& frames, absl::Time gap_start,
                                 const ProgressFn& progress) {
  const auto split = std::upper_bound(frames.begin(), frames.end(), gap_start,
                                      [](absl::Time t, const TelemetryFrame& f) { return t < f.time; });
  if (split == frames.begin() || split == frames.end()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "gap-start: %s leaves no frame before or after it (recording %s .. %s)",
        absl::FormatTime(absl::RFC3339_full, gap_start, absl::UTCTimeZone()),
        frames.empty() ? "empty" : absl::FormatTime(absl::RFC3339_full, frames.front().time, absl::UTCTimeZone()),
        frames.empty() ? "empty" : absl::FormatTime(absl::RFC3339_full, frames.back().time, absl::UTCTimeZone())));
  }
  const std::vector<TelemetryFrame> calibration(frames.begin(), split);
  const double n_total = static_cast<double>(frames.size());
  EstimationSession session = *EstimationSession::Create(config, options);
  auto calibrated = RunCalibration(
      config, options, calibration,
      progress ? ProgressFn([&](double f) { progress(f * calibration.size() / n_total); }) : ProgressFn(),
      &session);
  if (!calibrated.ok()) return calibrated.status();
  if (!session.initialized()) {
    return absl::InvalidArgumentError("gap-start: the filter never initialised before the gap (no star-tracker fix)");
  }
  GapResult result;
  result.calibration = std::move(*calibrated);
  session.SetStarTrackerUse(false);
  std::vector<double> t;
  std::array<std::vector<double>, 3> y;
  for (auto it = split; it != frames.end(); ++it) {
    auto report = session.AddFrame(*it);
    if (!report.ok()) return report.status();
    if (progress && (it - frames.begin()) % 50 == 0) progress((it - frames.begin()) / n_total);
    if (!it->star_tracker.has_value() || !it->star_tracker->valid || !report->attitude.valid) continue;
    GapSample s;
    s.time = it->time;
    s.hours_since_gap = absl::ToDoubleHours(it->time - gap_start);
    // q_st = Exp(error_in) (x) q_est  (conventions.h, item 5).
    s.error_in = LogQuaternion(it->star_tracker->q_in_b.normalized() * report->attitude.q_in_b.conjugate());
    s.angle = s.error_in.norm();
    s.sigma_b = report->attitude.sigma_b;
    result.samples.push_back(s);
    t.push_back(absl::ToDoubleSeconds(it->time - gap_start));
    for (int k = 0; k < 3; ++k) y[k].push_back(s.error_in(k));
  }
  if (progress) progress(1.0);
  if (result.samples.size() < 3) {
    return absl::InvalidArgumentError("gap-start: fewer than 3 star-tracker samples in the gap to compare with");
  }
  for (int k = 0; k < 3; ++k) result.slope_in(k) = FitSlope(t, y[k]);
  result.drift_rate = result.slope_in.norm();
  result.final_error = result.samples.back().angle;
  result.gap_hours = result.samples.back().hours_since_gap;
  return result;
}

}  // namespace esg::estimator
