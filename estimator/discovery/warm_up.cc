#include "estimator/discovery/warm_up.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

namespace {

using Eigen::Vector3d;

double DegH(double x) { return RadPerSecToDegPerHour(x); }

// The search over tau: each time constant's profiled -2 log L and final amplitude, and the best
// run so far. `candidate` and `fit` outlive it; every run adds one to fit.runs.
struct WarmUpSearch {
  const Candidate& candidate;
  CandidateFit& fit;
  std::vector<TelemetryFrame> frames;
  absl::Time t0;
  double sigma = 0.0;   // the terms' prior [rad/s]
  int first_term = 0;   // the gyro's first warm-up term in its basis
  std::map<double, double> value;        // ln(tau / h) -> profiled -2 log L
  std::map<double, Vector3d> amplitude;  // ln(tau / h) -> the run's final A [rad/s, case axes]
  double best_log = 0.0, best_value = 0.0;
  bool any = false;
  ModelRun best_run;

  // One time constant: the model with the terms at tau run over the recording.
  absl::Status Evaluate(double log_tau) {
    const ModelState m = WithWarmUp(fit.model, candidate.gyro, t0, std::exp(log_tau), sigma);
    auto run = RunModel(m.config, m.options, frames);
    ++fit.runs;
    if (!run.ok()) return run.status();
    const double v = Profile(*run).value;
    value[log_tau] = v;
    Vector3d a_k = Vector3d::Zero();
    if (const GyroEstimate* e = FindEstimate(run->gyros, candidate.gyro);
        e != nullptr && static_cast<int>(e->basis_terms.size()) >= first_term + kWarmUpTerms) {
      for (int i = 0; i < kWarmUpTerms; ++i) a_k(i) = e->basis_terms[first_term + i].value;
    }
    amplitude[log_tau] = a_k;
    if (!any || v < best_value) {
      any = true;
      best_value = v;
      best_log = log_tau;
      best_run = *std::move(run);
    }
    return absl::OkStatus();
  }
};

// The likelihood over ln tau, its best time constant and its 95% interval (in ln tau and [h]).
struct TauProfile {
  ProfilePoints points;  // ln(tau / h), -2 log L
  size_t best = 0;
  double lower = 0.0, upper = 0.0;  // ln(tau / h)
  bool lower_open = true, upper_open = true;
};

// The evidence's prior points in `fit`: tau integrated over a prior uniform in ln tau across the
// span searched, by the trapezoid rule on the time constants evaluated (each run is already the
// amplitude's marginal likelihood, freed with its prior). And the interval: where -2 log L stays
// within the chi-square(1) 95% quantile of its minimum, linear in ln tau between the time
// constants evaluated, clipped to the span searched.
TauProfile ProfileTimeConstants(const WarmUpSearch& search, const TauGrid& grid,
                                CandidateFit& fit) {
  TauProfile p;
  p.points.assign(search.value.begin(), search.value.end());
  const std::vector<double> weights = TrapezoidWeights(p.points, grid.log_max - grid.log_min);
  for (size_t j = 0; j < p.points.size(); ++j) {
    fit.prior_points.emplace_back(weights[j], p.points[j].second);
    if (p.points[j].second < p.points[p.best].second) p.best = j;
  }
  const LevelInterval in =
      IntervalAtLevel(p.points, p.best, p.points[p.best].second + kProfileIntervalDrop);
  p.lower = in.lower;
  p.upper = in.upper;
  p.lower_open = in.lower_open;
  p.upper_open = in.upper_open;
  return p;
}

// The best time constant as the fit's: the model with the terms at tau_h, the best run, the
// terms at the amplitude A the run estimated (basis_terms). Returns A [rad/s, case axes] and sets
// `a_sigma` to the filter's 1-sigma of it.
Vector3d AdoptBest(WarmUpSearch& search, double tau_h, Vector3d& a_sigma) {
  CandidateFit& fit = search.fit;
  const int gyro = search.candidate.gyro, first_term = search.first_term;
  fit.model = WithWarmUp(fit.model, gyro, search.t0, tau_h, search.sigma);
  fit.run = std::move(search.best_run);
  fit.parameters = kWarmUpTerms;
  fit.time.onset = search.t0;
  const GyroEstimate* e = FindEstimate(fit.run.gyros, gyro);
  Vector3d a = Vector3d::Zero();
  a_sigma = Vector3d::Zero();
  if (e != nullptr && static_cast<int>(e->basis_terms.size()) >= first_term + kWarmUpTerms &&
      static_cast<int>(e->basis_sigma.size()) >= first_term + kWarmUpTerms) {
    for (int i = 0; i < kWarmUpTerms; ++i) {
      a(i) = e->basis_terms[first_term + i].value;
      a_sigma(i) = e->basis_sigma[first_term + i];
    }
  }
  const GyroConfig* gw = FindGyroMutable(fit.model.config, gyro);
  for (int i = 0; i < kWarmUpTerms; ++i) {
    BasisTerm t = gw->basis_terms[first_term + i];
    t.value = a(i);
    fit.basis_terms.push_back(t);
  }
  return a;
}

// The filter's sigma of A is at the best tau; A moves with tau, so its sigma adds the spread
// tau's uncertainty gives (the delta method on the profile: dA/d ln tau from the time constants
// evaluated at the interval's ends, times the 1-sigma of ln tau, the 95% half-width / 1.96), with
// a note saying so.
void AddTauSpread(const std::map<double, Vector3d>& amplitude, const TauProfile& p,
                  Vector3d& a_sigma, CandidateFit& fit) {
  const double lower = p.lower, upper = p.upper;
  auto inside = [&](const auto& point) {
    return point.first >= lower - 1e-12 && point.first <= upper + 1e-12;
  };
  auto lo = std::find_if(amplitude.begin(), amplitude.end(), inside);
  auto hi = std::find_if(amplitude.rbegin(), amplitude.rend(), inside);
  if (lo == amplitude.end() || hi == amplitude.rend() || !(hi->first > lo->first)) return;
  const Vector3d slope = (hi->second - lo->second) / (hi->first - lo->first);
  const double sigma_log_tau = 0.5 * (upper - lower) / 1.959963984540054;
  const Vector3d from_tau = slope.cwiseAbs() * sigma_log_tau;
  a_sigma = (a_sigma.cwiseAbs2() + from_tau.cwiseAbs2()).cwiseSqrt();
  fit.notes.push_back(absl::StrFormat(
      "the amplitude's 1-sigma includes tau's uncertainty: dA/d ln tau = %s deg/h (from "
      "tau = %.2f h to %.2f h), times the 1-sigma of ln tau %.3f, adds %s deg/h",
      absl::StrFormat("(%.4f, %.4f, %.4f)", DegH(slope.x()), DegH(slope.y()), DegH(slope.z())),
      std::exp(lo->first), std::exp(hi->first), sigma_log_tau,
      absl::StrFormat("(%.4f, %.4f, %.4f)", DegH(from_tau.x()), DegH(from_tau.y()),
                      DegH(from_tau.z()))));
}

// The warm-up's parameters, its description and the profile's note.
void DescribeWarmUp(int gyro, const Vector3d& a, const Vector3d& a_sigma, const TauProfile& p,
                    double best_value, CandidateFit& fit) {
  const double tau_h = std::exp(p.points[p.best].first);
  const double lower_h = std::exp(p.lower), upper_h = std::exp(p.upper);
  double size_sigma = 0.0;
  const double size =
      AddDecayParameters("warmUp", a, a_sigma, tau_h, lower_h, upper_h, size_sigma, fit);
  const Vector3d direction = size > 0 ? Vector3d(a / size) : Vector3d::Zero();
  fit.description = absl::StrFormat(
      "warm-up of gyro %d: a case-fixed drift along (%.2f, %.2f, %.2f) (case axes), %.3f +- "
      "%.3f deg/h at the recording's start, decaying with tau = %.1f h (95%% %.1f-%.1f h%s; "
      "an exponential transient from the start, tau searched over %.1f-%.0f h)",
      gyro, direction.x(), direction.y(), direction.z(), DegH(size), DegH(size_sigma), tau_h,
      lower_h, upper_h,
      p.lower_open || p.upper_open
          ? ", clipped: the interval reaches an end of the span searched"
          : "",
      kWarmUpMinTauHours, kWarmUpMaxTauHours);
  std::string profile_text;
  for (const auto& [x, v] : p.points) {
    absl::StrAppend(&profile_text, absl::StrFormat(" %.2f:%.1f", std::exp(x), v - best_value));
  }
  fit.notes.push_back(absl::StrCat(
      "likelihood over the time constant (h: -2 log L above the best; ", p.points.size(),
      " time constants, integrated over a prior uniform in ln tau):", profile_text));
}

}  // namespace

// The search as a sequence: room for the terms, the time constants searched, the profile's prior
// weights and interval, the best run adopted, tau's spread added to the amplitude's sigma, and the
// warm-up described.
absl::Status FitWarmUp(const Candidate& candidate, const FitContext& ctx, CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  ASSIGN_OR_RETURN(const GyroConfig* g, CandidateGyro(fit.model.config, candidate.gyro));
  fit.time.kind = kTimeWarmUp;
  const int first_term = static_cast<int>(g->basis_terms.size());
  if (first_term + kWarmUpTerms > kMaxBasisTermsPerGyro || ctx.frames->size() < 2) {
    fit.parameters = 0;
    fit.run = *ctx.model_run;
    fit.notes.push_back(absl::StrFormat(
        "no warm-up fitted: gyro %d's basis holds %d terms, at most %d (three more needed)",
        candidate.gyro, first_term, kMaxBasisTermsPerGyro));
    return absl::OkStatus();
  }
  WarmUpSearch search{candidate, fit,
                      CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction)};
  search.t0 = search.frames.front().time;
  search.sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
  search.first_term = first_term;
  const TauGrid grid = WarmUpTauGrid();
  RETURN_IF_ERROR(SearchTimeConstants(
      grid, [&](double log_tau) { return search.Evaluate(log_tau); }, search.value,
      [&] { return search.best_log; }, Profile(*ctx.model_run).value, opt.alpha));
  const TauProfile p = ProfileTimeConstants(search, grid, fit);
  if (p.best + 1 == p.points.size()) {
    // exp(-t / tau) = 1 - t / tau + ...: at the longest time constant searched the recording
    // shows no decay, only a drift changing linearly, which a warm-up does not describe
    // (docs/decisions.md D130).
    fit.parameters = 0;
    fit.run = *ctx.model_run;
    fit.prior_points.clear();
    fit.not_fitted = absl::StrFormat(
        "no warm-up fitted: the best time constant, %.1f h, is the longest searched (%.1f-%.0f "
        "h), where the recording cannot tell a decay from a drift changing linearly",
        std::exp(p.points[p.best].first), kWarmUpMinTauHours, kWarmUpMaxTauHours);
    fit.notes.push_back(fit.not_fitted);
    return absl::OkStatus();
  }
  Vector3d a_sigma;
  const Vector3d a = AdoptBest(search, std::exp(p.points[p.best].first), a_sigma);
  AddTauSpread(search.amplitude, p, a_sigma, fit);
  DescribeWarmUp(candidate.gyro, a, a_sigma, p, search.best_value, fit);
  return absl::OkStatus();
}

}  // namespace esg::estimator::discovery
