#include "estimator/discovery/transient.h"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/discovery/onset_search.h"
#include "estimator/discovery/time_constant_search.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

namespace {

using Eigen::Vector3d;

double DegH(double x) { return RadPerSecToDegPerHour(x); }

// The search over tau at the best onset: each time constant's -2 log L, amplitude and its
// 1-sigma, and the best run so far. Every run continues from the onset's checkpoint with the
// terms at the time constant `log_tau` (the variable the onset search's config_at reads).
struct TauAtOnset {
  OnsetSearch& search;
  double& log_tau;
  int onset_frame = 0;
  int first_term = 0;  // the gyro's first transient term in its basis
  std::map<double, double> value;  // ln(tau / h) -> -2 log L
  std::map<double, Vector3d> amplitude, amplitude_sigma;
  double best_log = 0.0;
  ModelRun best_run;

  // A run's final amplitude [rad/s, case axes] and its 1-sigma, recorded at ln tau `lt`.
  void AmplitudeOf(const ModelRun& run, double lt) {
    const GyroEstimate* e = FindEstimate(run.gyros, search.candidate.gyro);
    Vector3d a = Vector3d::Zero(), s = Vector3d::Zero();
    if (e != nullptr && static_cast<int>(e->basis_terms.size()) >= first_term + kWarmUpTerms &&
        static_cast<int>(e->basis_sigma.size()) >= first_term + kWarmUpTerms) {
      for (int i = 0; i < kWarmUpTerms; ++i) {
        a(i) = e->basis_terms[first_term + i].value;
        s(i) = e->basis_sigma[first_term + i];
      }
    }
    amplitude[lt] = a;
    amplitude_sigma[lt] = s;
  }

  absl::Status Evaluate(double lt) {
    log_tau = lt;
    ASSIGN_OR_RETURN(ModelRun run, search.RunFrom(onset_frame, search.fit.model.options));
    const double v = Profile(run).value;
    value[lt] = v;
    AmplitudeOf(run, lt);
    if (v < value[best_log]) {
      best_log = lt;
      best_run = std::move(run);
    }
    return absl::OkStatus();
  }
};

// The evidence over onset and tau, separated: `onset_prior_points` (at the middle time constant
// log_tau0) each shifted by -2 ln R into fit.prior_points, R the likelihood integrated over a
// prior uniform in ln tau at the best onset relative to its value at the middle time constant
// (exact when the likelihood is a product of a function of the onset and one of tau). Returns
// ln R.
double AddSeparatedPriorPoints(const TauAtOnset& taus, const ProfilePoints& tau_profile,
                               size_t best, double log_tau0, const TauGrid& grid,
                               const std::vector<std::pair<double, double>>& onset_prior_points,
                               CandidateFit& fit) {
  const double min_value = tau_profile[best].second;
  double sum = 0.0;
  const std::vector<double> weights = TrapezoidWeights(tau_profile, grid.log_max - grid.log_min);
  for (size_t j = 0; j < tau_profile.size(); ++j) {
    sum += weights[j] * std::exp(-0.5 * (tau_profile[j].second - min_value));
  }
  const double log_r = -0.5 * (min_value - taus.value.at(log_tau0)) + std::log(sum);
  for (const auto& [w, v] : onset_prior_points) fit.prior_points.emplace_back(w, v - 2.0 * log_r);
  return log_r;
}

// A's sigma: the filter's at the best tau, and the spread tau's uncertainty gives (the delta
// method: dA / d ln tau between the time constants beside the best, times the 95% half-width of
// ln tau / 1.96), as the warm-up's.
Vector3d AmplitudeSigma(const TauAtOnset& taus, const LevelInterval& tau_interval) {
  Vector3d a_sigma = taus.amplitude_sigma.at(taus.best_log);
  auto at = taus.value.find(taus.best_log);
  auto lo = at == taus.value.begin() ? at : std::prev(at);
  auto hi = std::next(at) == taus.value.end() ? at : std::next(at);
  if (hi->first > lo->first) {
    const Vector3d slope = (taus.amplitude.at(hi->first) - taus.amplitude.at(lo->first)) /
                           (hi->first - lo->first);
    const double s_log_tau = 0.5 * (tau_interval.upper - tau_interval.lower) / 1.96;
    for (int i = 0; i < 3; ++i) a_sigma(i) = std::hypot(a_sigma(i), slope(i) * s_log_tau);
  }
  return a_sigma;
}

// The transient's parameters and its description.
void DescribeTransient(int gyro, const Vector3d& a, const Vector3d& a_sigma, double tau_h,
                       const LevelInterval& tau_interval, const OnsetProfile& p,
                       CandidateFit& fit) {
  const double lower_h = std::exp(tau_interval.lower), upper_h = std::exp(tau_interval.upper);
  double size_sigma = 0.0;
  const double size =
      AddDecayParameters("transient", a, a_sigma, tau_h, lower_h, upper_h, size_sigma, fit);
  const double onset_hours = p.points[p.best].first;
  fit.fitted.push_back({"onsetHours", onset_hours, 0.5 * (p.upper - p.lower), "h"});
  fit.fitted.push_back({"onsetLowerHours", p.lower, 0.0, "h"});
  fit.fitted.push_back({"onsetUpperHours", p.upper, 0.0, "h"});
  const Vector3d direction = size > 0 ? Vector3d(a / size) : Vector3d::Zero();
  fit.description = absl::StrFormat(
      "transient of gyro %d: a case-fixed drift along (%.2f, %.2f, %.2f) (case axes), %.3f +- "
      "%.3f deg/h at its onset %.2f h from the start (95%% %.2f-%.2f h), decaying with tau = "
      "%.1f h (95%% %.1f-%.1f h; an exponential transient from an onset, tau searched over "
      "%.1f-%.0f h)",
      gyro, direction.x(), direction.y(), direction.z(), DegH(size), DegH(size_sigma),
      onset_hours, p.lower, p.upper, tau_h, lower_h, upper_h, kWarmUpMinTauHours,
      kWarmUpMaxTauHours);
}

// The notes of the two profiles (the onset's at the middle time constant log_tau0, tau's at the
// best onset with 2 ln R) and of the runs the search took.
void AddProfileNotes(const OnsetProfile& p, const ProfilePoints& tau_profile, double min_value,
                     double log_tau0, double log_r, CandidateFit& fit) {
  std::string onset_text, tau_text;
  for (const auto& [h, v] : p.points) {
    absl::StrAppend(&onset_text, absl::StrFormat(" %.2f:%.1f", h, v - p.points[p.best].second));
  }
  for (const auto& [x, v] : tau_profile) {
    absl::StrAppend(&tau_text, absl::StrFormat(" %.2f:%.1f", std::exp(x), v - min_value));
  }
  fit.notes.push_back(absl::StrFormat(
      "likelihood over the onset at tau = %.2f h (h from the start: -2 log L above the best; %d "
      "onsets):%s",
      std::exp(log_tau0), p.points.size(), onset_text));
  fit.notes.push_back(absl::StrFormat(
      "likelihood over the time constant at the best onset (h: -2 log L above the best; %d time "
      "constants, integrated over a prior uniform in ln tau, 2 ln R = %.1f against %.2f h):%s",
      tau_profile.size(), 2.0 * log_r, std::exp(log_tau0), tau_text));
  fit.notes.push_back(absl::StrFormat(
      "%d filter runs: one without the transient, the others continued from its checkpoints",
      fit.runs));
}

}  // namespace

// The search as a sequence: the gyro's basis with three inert exponential_decay terms for the
// run without the transient and its checkpoints, the onset searched at the middle time constant,
// the time constant searched at the best onset, the evidence, and the transient described.
absl::Status FitTransient(const Candidate& candidate, const FitContext& ctx, CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  ASSIGN_OR_RETURN(const GyroConfig* g, CandidateGyro(fit.model.config, candidate.gyro));
  fit.time.kind = kTimeTransient;
  fit.parameters = 0;
  fit.run = *ctx.model_run;
  const int first_term = static_cast<int>(g->basis_terms.size());
  if (first_term + kWarmUpTerms > kMaxBasisTermsPerGyro) {
    fit.notes.push_back(absl::StrFormat(
        "no transient fitted: gyro %d's basis holds %d terms, at most %d (three more needed)",
        candidate.gyro, first_term, kMaxBasisTermsPerGyro));
    return absl::OkStatus();
  }
  const double sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
  const TauGrid grid = WarmUpTauGrid();
  const double log_tau0 = grid.log_min + grid.spacing * (kTauCoarse / 2);  // the middle, 3.5 h
  double log_tau = log_tau0;

  // The onset at the middle time constant.
  OnsetSearch search{candidate, fit,
                     CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction)};
  const std::vector<TelemetryFrame>& frames = search.frames;
  const std::vector<int> grid_frames = GridFrames(frames);
  if (grid_frames.empty()) return absl::OkStatus();  // too short: no transient fitted
  const ModelState model = fit.model;
  // Before its onset a term is 0: the terms switched on after the last frame leave the run
  // without the transient as it is, and give its checkpoints the layout of the runs with it.
  search.base_config =
      WithWarmUp(model, candidate.gyro, frames.back().time + absl::Hours(1),
                 std::exp(log_tau0), sigma)
          .config;
  // The modelled drift changes from frames[f - 1].time on, as a release at frame f's does.
  search.config_at = [&](int f) {
    return WithWarmUp(model, candidate.gyro, frames[f - 1].time, std::exp(log_tau), sigma).config;
  };
  RETURN_IF_ERROR(RunPrefix(search, grid_frames));
  ASSIGN_OR_RETURN(const bool searched, SearchOnsets(search, grid_frames,
                                                     Profile(*ctx.model_run).value, opt.alpha));
  if (!searched) return absl::OkStatus();
  CandidateFit onsets;
  const OnsetProfile p = ProfileOnsets(search, onsets);

  // The time constant at the best onset, on the warm-up's grid refined twice near its best.
  TauAtOnset taus{search, log_tau};
  taus.onset_frame = search.best_frame;
  taus.first_term = first_term;
  taus.value[log_tau0] = search.value[taus.onset_frame];
  taus.AmplitudeOf(search.best_run, log_tau0);
  taus.best_log = log_tau0;
  taus.best_run = std::move(search.best_run);
  RETURN_IF_ERROR(SearchTimeConstants(
      grid, [&](double lt) { return taus.Evaluate(lt); }, taus.value,
      [&] { return taus.best_log; }, Profile(*ctx.model_run).value, opt.alpha));
  log_tau = taus.best_log;
  // tau's interval: -2 log L within 3.84 of its minimum, linear in ln tau between the time
  // constants evaluated, clipped to the span searched.
  const ProfilePoints tau_profile(taus.value.begin(), taus.value.end());
  const size_t best = ProfileMinimum(tau_profile);
  const LevelInterval in =
      IntervalAtLevel(tau_profile, best, tau_profile[best].second + kProfileIntervalDrop);
  const double log_r =
      AddSeparatedPriorPoints(taus, tau_profile, best, log_tau0, grid, onsets.prior_points, fit);

  const double tau_h = std::exp(taus.best_log);
  fit.parameters = kWarmUpTerms;
  DescribeOnset(search, p, fit);
  fit.time.kind = kTimeTransient;
  fit.onset_profile = onsets.onset_profile;
  fit.model = WithWarmUp(model, candidate.gyro, frames[taus.onset_frame - 1].time, tau_h, sigma);
  fit.run = std::move(taus.best_run);
  const Vector3d a = taus.amplitude.at(taus.best_log);
  const Vector3d a_sigma = AmplitudeSigma(taus, in);
  const GyroConfig* gw = FindGyroMutable(fit.model.config, candidate.gyro);
  for (int i = 0; i < kWarmUpTerms; ++i) {
    BasisTerm t = gw->basis_terms[first_term + i];
    t.value = a(i);
    fit.basis_terms.push_back(t);
  }
  DescribeTransient(candidate.gyro, a, a_sigma, tau_h, in, p, fit);
  AddProfileNotes(p, tau_profile, tau_profile[best].second, log_tau0, log_r, fit);
  return absl::OkStatus();
}

}  // namespace esg::estimator::discovery
