#include "estimator/offline.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "absl/strings/str_format.h"
#include "estimator/line_fit.h"
#include "estimator/rotation.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

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
                                          FormatUtc(frames[i].time),
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
  result.widened_drift_deg_h = session->noise_widening().EquivalentDriftDegH();
  result.star_tracker_latency = session->StarTrackerLatency();
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
        FormatUtc(gap_start),
        frames.empty() ? "empty" : FormatUtc(frames.front().time),
        frames.empty() ? "empty" : FormatUtc(frames.back().time)));
  }
  const std::vector<TelemetryFrame> calibration(frames.begin(), split);
  const double n_total = static_cast<double>(frames.size());
  auto created = EstimationSession::Create(config, options);
  if (!created.ok()) return created.status();
  EstimationSession session = std::move(*created);
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
  for (int k = 0; k < 3; ++k) result.slope_in(k) = FitRobustLine(t, y[k]).slope;
  result.drift_rate = result.slope_in.norm();
  result.final_error = result.samples.back().angle;
  result.gap_hours = result.samples.back().hours_since_gap;
  return result;
}

}  // namespace esg::estimator
