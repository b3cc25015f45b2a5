#include "estimator/discovery/held_out.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <optional>
#include <utility>
#include <vector>

#include "estimator/statistics.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Vector3d;

namespace {

// The least-squares standard error of `line`'s slope over times `t` with white residuals:
// residual_sigma / sqrt(S_tt), S_tt = sum (t - mean t)^2. The robust pass of FitRobustLine drops
// outliers without saying which; S_tt over all the times is scaled by the share of points used
// (the times are evenly spread, so each point carries S_tt / n on average).
double SlopeStandardError(const std::vector<double>& t, const RobustLine& line) {
  if (t.size() < 3 || line.used < 3) return 0.0;
  double mean = 0.0;
  for (double v : t) mean += v;
  mean /= static_cast<double>(t.size());
  double s_tt = 0.0;
  for (double v : t) s_tt += (v - mean) * (v - mean);
  s_tt *= static_cast<double>(line.used) / static_cast<double>(t.size());
  return s_tt > 0.0 ? line.residual_sigma / std::sqrt(s_tt) : 0.0;
}

}  // namespace

std::vector<Gap> ChooseGaps(const std::vector<RegimeSpan>& spans,
                            const std::vector<TelemetryFrame>& frames, const DiagnoseOptions& opt) {
  std::vector<Gap> gaps;
  if (frames.empty()) return gaps;
  const absl::Time t0 = frames.front().time, t1 = frames.back().time;
  const double total_h = HoursSince(t1, t0);
  const double earliest_h = std::max(3.0, 0.15 * total_h);
  auto st_count = [&](int a, int b) {
    int n = 0;
    for (int i = a; i <= b; ++i)
      n += frames[i].star_tracker.has_value() && frames[i].star_tracker->valid;
    return n;
  };
  auto gap_of = [&](int k) -> std::optional<Gap> {
    const RegimeSpan& s = spans[k];
    if (s.regime == Regime::kSlew || s.hours() < 1.0 || HoursSince(s.start, t0) < earliest_h)
      return std::nullopt;
    Gap g{k, s.first_frame, s.first_frame};
    const absl::Time stop = s.start + absl::Seconds(HoursToSeconds(opt.max_gap_hours));
    while (g.last + 1 <= s.last_frame && frames[g.last + 1].time <= stop) ++g.last;
    if (st_count(g.first, g.last) < 10) return std::nullopt;
    return g;
  };
  // Dominant regime by time.
  std::map<Regime, double> time_in;
  for (const RegimeSpan& s : spans) time_in[s.regime] += s.hours();
  Regime dominant = Regime::kOrbital;
  double most = -1;
  for (const auto& [r, h] : time_in) {
    if (r != Regime::kSlew && h > most) {
      most = h;
      dominant = r;
    }
  }
  std::vector<int> order;
  // One span of every other regime (the longest), then spans of the dominant one, latest first.
  std::map<Regime, int> longest;
  for (int k = 0; k < static_cast<int>(spans.size()); ++k) {
    if (!gap_of(k) || spans[k].regime == dominant) continue;
    auto it = longest.find(spans[k].regime);
    if (it == longest.end() || spans[k].hours() > spans[it->second].hours())
      longest[spans[k].regime] = k;
  }
  for (const auto& [r, k] : longest) order.push_back(k);
  for (int k = static_cast<int>(spans.size()) - 1; k >= 0; --k) {
    if (spans[k].regime == dominant && gap_of(k)) order.push_back(k);
  }
  for (int k : order) {
    if (static_cast<int>(gaps.size()) >= opt.max_gaps) break;
    const Gap g = *gap_of(k);
    bool clear = true;
    for (const Gap& other : gaps) {
      // At least an hour of star-tracker data between gaps to re-calibrate.
      const absl::Time a0 = frames[g.first].time - absl::Hours(1),
                       a1 = frames[g.last].time + absl::Hours(1);
      if (!(frames[other.last].time < a0 || frames[other.first].time > a1)) clear = false;
    }
    if (clear) gaps.push_back(g);
  }
  if (gaps.empty() && total_h >= 4.0) {
    // No regime span to hold out: the last quarter of the recording, as in the paper's Fig. 7/8.
    Gap g;
    g.first = static_cast<int>(frames.size()) - 1;
    while (g.first > 0 && HoursSince(frames[g.first - 1].time, t0) >= 0.75 * total_h) --g.first;
    g.last = static_cast<int>(frames.size()) - 1;
    g.span = SpanOfFrame(spans, g.first);
    if (st_count(g.first, g.last) >= 10) gaps.push_back(g);
  }
  std::sort(gaps.begin(), gaps.end(), [](const Gap& a, const Gap& b) { return a.first < b.first; });
  return gaps;
}

ModelRunOptions WithheldOver(const std::vector<Gap>& gaps) {
  ModelRunOptions options;
  for (const Gap& g : gaps) options.withheld.emplace_back(g.first, g.last);
  return options;
}

HeldOutResult SummariseHeldOut(const ModelRun& run, const std::vector<Gap>& gaps,
                               const std::vector<RegimeSpan>& spans,
                               const std::vector<TelemetryFrame>& frames) {
  HeldOutResult out;
  const absl::Time t0 = frames.front().time;
  double rate2 = 0.0;
  int rated = 0;
  std::vector<std::pair<double, double>> rates_and_variances;  // r_k [deg/h], var r_k [(deg/h)^2]
  for (size_t k = 0; k < gaps.size(); ++k) {
    GapSummary g;
    g.span = gaps[k].span;
    g.regime = gaps[k].span >= 0 ? RegimeName(spans[gaps[k].span].regime) : "";
    g.start = frames[gaps[k].first].time;
    g.end = frames[gaps[k].last].time;
    std::vector<double> t;
    std::array<std::vector<double>, 3> y;
    std::map<int, std::vector<double>> gt;
    std::map<int, std::array<std::vector<double>, 3>> gy;
    std::map<int, std::pair<double, double>> sigma_first_last;
    for (const HeldOutSample& s : run.held_out) {
      if (s.span != static_cast<int>(k)) continue;
      t.push_back(s.seconds);
      for (int i = 0; i < 3; ++i) y[i].push_back(s.error_in(i));
      out.points.push_back(
          {HoursSince(frames[s.frame].time, t0), static_cast<int>(k), RadToArcsec(s.error_in.norm())});
      g.final_error_arcsec = RadToArcsec(s.error_in.norm());
      for (const HeldOutGyroError& e : s.gyros) {
        gt[e.id].push_back(s.seconds);
        for (int i = 0; i < 3; ++i) gy[e.id][i].push_back(e.error_in(i));
        auto it = sigma_first_last.find(e.id);
        if (it == sigma_first_last.end()) {
          sigma_first_last[e.id] = {e.sigma, e.sigma};
        } else {
          it->second.second = e.sigma;
        }
      }
    }
    if (t.size() < 3) {
      out.gaps.push_back(g);
      continue;
    }
    Vector3d slope, slope_sigma;
    for (int i = 0; i < 3; ++i) {
      const RobustLine line = FitRobustLine(t, y[i]);
      slope(i) = line.slope;
      slope_sigma(i) = SlopeStandardError(t, line);
    }
    g.drift_rate_deg_h = RadPerSecToDegPerHour(slope.norm());
    // var r_k = sum_i b_ki^2 s_ki^2 / r_k^2 (first order in the slope errors); at r_k = 0 the
    // largest axis variance.
    const double rate_var_rad2_s2 =
        slope.norm() > 0.0 ? slope.cwiseProduct(slope_sigma).squaredNorm() / slope.squaredNorm()
                           : slope_sigma.cwiseAbs2().maxCoeff();
    const double rate_sigma_deg_h = RadPerSecToDegPerHour(std::sqrt(rate_var_rad2_s2));
    rates_and_variances.emplace_back(g.drift_rate_deg_h, rate_sigma_deg_h * rate_sigma_deg_h);
    rate2 += g.drift_rate_deg_h * g.drift_rate_deg_h;
    ++rated;
    // Spin-axis prediction error growth over the gap against the filter's own uncertainty:
    // growth = slope * T per inertial axis (two effective axes, perpendicular to h), its
    // variance the growth of the filter's spin-axis variance plus the line fit's.
    for (const auto& [id, times] : gt) {
      if (times.size() < 3) continue;
      const double T = times.back() - times.front();
      Vector3d growth;
      double fit_var = 0.0;
      for (int i = 0; i < 3; ++i) {
        const RobustLine line = FitRobustLine(times, gy[id][i]);
        growth(i) = line.slope * T;
        fit_var += line.residual_sigma * line.residual_sigma * 12.0 / std::max(1, line.used) / 3.0;
      }
      const auto [s_first, s_last] = sigma_first_last[id];
      const double var = std::max(s_last * s_last - s_first * s_first, 0.0) + fit_var;
      if (var > 0) {
        // Two effective axes across the spin axis, each N(0, var) if the model is right: -2 log
        // of the predictive density is growth^2 / var + 2 ln var (+ const), which a model
        // cannot lower by claiming a larger var.
        g.nees += growth.squaredNorm() / var;
        g.deviance += growth.squaredNorm() / var + 2.0 * std::log(var);
        g.dof += 2;
      }
      g.gyro_drift_rate_deg_h.emplace_back(id,
                                           RadPerSecToDegPerHour(growth.norm() / std::max(T, 1.0)));
    }
    out.nees += g.nees;
    out.deviance += g.deviance;
    out.dof += g.dof;
    out.gaps.push_back(g);
  }
  out.rate_rms_deg_h = rated > 0 ? std::sqrt(rate2 / rated) : 0.0;
  // var R = sum_k (dR/dr_k)^2 var r_k, dR/dr_k = r_k / (n R); at R = 0 the mean of var r_k / n.
  double rate_rms_var = 0.0;
  for (const auto& [rate_deg_h, var_deg2_h2] : rates_and_variances) {
    const double d = out.rate_rms_deg_h > 0.0 ? rate_deg_h / (rated * out.rate_rms_deg_h)
                                              : 1.0 / rated;
    rate_rms_var += d * d * var_deg2_h2;
  }
  out.rate_rms_sigma_deg_h = std::sqrt(rate_rms_var);
  return out;
}

bool MispredictsHeldOut(const HeldOutResult& held_out, double alpha) {
  const double p = held_out.dof > 0 ? ChiSquareSurvival(held_out.nees, held_out.dof) : 1.0;
  return Significant(p, alpha, 2) && held_out.nees > kMaterialNeesRatio * held_out.dof;
}

}  // namespace esg::estimator::discovery
