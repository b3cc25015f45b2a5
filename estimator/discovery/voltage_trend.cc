#include "estimator/discovery/voltage_trend.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <vector>

#include "Eigen/Core"
#include "absl/strings/str_format.h"
#include "estimator/drift_model.h"
#include "estimator/statistics.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Vector3d;

void DescribeVoltageTrend(const SpacecraftConfig& config, const std::vector<TelemetryFrame>& frames,
                          int gyro, CandidateFit& fit) {
  // A robust line per suspension axis of the offset voltage against time; eq. (3) is linear in
  // dU, so the slopes [mV/h] give the rate of the displacement [um/h].
  std::array<std::vector<double>, 3> u_mv;
  std::vector<double> hours;
  const absl::Time t0 = frames.front().time;
  for (const TelemetryFrame& f : frames) {
    const auto& r = f.gyros[gyro - 1];
    if (!r.has_value() || !r->u_k_mv.has_value() || !r->u_k_mv->allFinite()) continue;
    hours.push_back(HoursSince(f.time, t0));
    for (int i = 0; i < 3; ++i) u_mv[i].push_back((*r->u_k_mv)(i));
  }
  if (hours.size() < 10) return;
  double mean_t = 0.0, var_t = 0.0;
  for (double t : hours) mean_t += t;
  mean_t /= hours.size();
  for (double t : hours) var_t += (t - mean_t) * (t - mean_t);
  if (!(var_t > 0.0)) return;
  const SuspensionConfig& s = config.suspension;
  auto um = [&](double mv) {
    return DisplacementFromOffsetVoltage(mv * kVoltsPerMv, s.amplifier_gain, s.reference_voltage,
                                         s.gap) /
           kMetresPerUm;
  };
  Vector3d rate_um_h, rate_sigma_um_h, slope_mv_h;
  double chi2 = 0.0;
  std::array<RobustLine, 3> lines;
  for (int i = 0; i < 3; ++i) {
    const RobustLine& line = lines[i] = FitRobustLine(hours, u_mv[i]);
    const double sigma_mv_h =
        line.residual_sigma / std::sqrt(var_t * line.used / static_cast<double>(hours.size()));
    slope_mv_h(i) = line.slope;
    rate_um_h(i) = um(line.slope);
    rate_sigma_um_h(i) = std::abs(um(sigma_mv_h));
    if (sigma_mv_h > 0) chi2 += std::pow(line.slope / sigma_mv_h, 2);
  }
  // The series of the report's trend plot: the implied displacement, averaged over bins.
  DisplacementTrend& trend = fit.displacement_trend;
  const size_t n = hours.size();
  const size_t bins = std::min<size_t>(n, DisplacementTrend::kMaxSamples);
  for (size_t b = 0; b < bins; ++b) {
    const size_t first = b * n / bins, last = (b + 1) * n / bins;
    DisplacementTrend::Sample sample;
    for (size_t j = first; j < last; ++j) {
      sample.hours += hours[j];
      for (int i = 0; i < 3; ++i) sample.displacement_um[i] += um(u_mv[i][j]);
    }
    sample.hours /= static_cast<double>(last - first);
    for (double& d : sample.displacement_um) d /= static_cast<double>(last - first);
    trend.samples.push_back(sample);
  }
  for (int i = 0; i < 3; ++i) {
    trend.intercept_um[i] = um(lines[i].intercept);
    trend.rate_um_h[i] = rate_um_h(i);
  }
  const double p = ChiSquareSurvival(chi2, 3.0);
  const double span_hours = hours.back() - hours.front();
  AddVectorParameters("displacementRateUmPerH", rate_um_h, rate_sigma_um_h, 1.0, "um/h",
                      fit.fitted);
  fit.fitted.push_back({"displacementRateSizeUmPerH", rate_um_h.norm(), 0.0, "um/h"});
  fit.notes.push_back(absl::StrFormat(
      "suspension offset voltages drift by [%.2f %.2f %.2f] mV/h: by eq. (3) the displacement "
      "changes by [%.4f %.4f %.4f] um/h (|%.4f| um/h, %.2f um over the %.1f h), trend chi2 = %.1f "
      "on 3 dof, p = %.2g: %s",
      slope_mv_h.x(), slope_mv_h.y(), slope_mv_h.z(), rate_um_h.x(), rate_um_h.y(), rate_um_h.z(),
      rate_um_h.norm(), rate_um_h.norm() * span_hours, span_hours, chi2, p,
      p < 0.01 ? "the displacement grows during the recording (the C1, C2 fitted are its mean; "
                 "a growing displacement is not yet a candidate)"
               : "no trend: a constant displacement, as the constant effect assumes"));
}

}  // namespace esg::estimator::discovery
