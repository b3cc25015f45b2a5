#include "estimator/discovery/channel_candidate.h"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <limits>
#include <map>
#include <optional>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/basis_term.h"
#include "estimator/discovery/profile_interval.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

namespace {

using Eigen::Vector3d;

constexpr int kTerms = 3;
// The chi-square(1) 95% quantile: the lag's interval is where -2 log L stays within it.
constexpr double kIntervalDrop = kProfileIntervalDrop;

double DegH(double x) { return RadPerSecToDegPerHour(x); }

// The channel's mean and standard deviation over the frames that carry it; count 0 when none.
struct ChannelSpread {
  int count = 0;
  double mean = 0.0, sd = 0.0;
};
ChannelSpread SpreadOf(const std::vector<TelemetryFrame>& frames, const std::string& name) {
  ChannelSpread s;
  double sum = 0.0, sum2 = 0.0;
  for (const TelemetryFrame& f : frames) {
    const double* x = f.channels.Find(name);
    if (x == nullptr) continue;
    ++s.count;
    sum += *x;
  }
  if (s.count == 0) return s;
  s.mean = sum / s.count;
  for (const TelemetryFrame& f : frames) {
    if (const double* x = f.channels.Find(name)) sum2 += (*x - s.mean) * (*x - s.mean);
  }
  s.sd = s.count > 1 ? std::sqrt(sum2 / (s.count - 1)) : 0.0;
  return s;
}

// `model` with gyro's three channel terms of `form` (tau [s] for the lag and derivative) freed
// with prior `sigma` [rad/s per unit], then, with `offset_sigma` > 0, three case-fixed drifts
// (spin_axis_harmonic of degree 0) freed with it [rad/s]: the drift where the channel is at its
// mean, which the channel's own reference cannot tell from a constant drift.
ModelState WithChannelTerms(const ModelState& model, int gyro, const std::string& channel,
                            ChannelForm form, double tau_s, double reference, double sigma,
                            double offset_sigma) {
  ModelState m = model;
  GyroConfig* g = FindGyroMutable(m.config, gyro);
  for (int axis = 1; axis <= kTerms && offset_sigma > 0.0; ++axis) {
    BasisTerm t;
    t.kind = BasisKind::kSpinAxisHarmonic;
    t.axis = axis;
    t.sigma = offset_sigma;
    g->basis_terms.push_back(t);
  }
  for (int axis = 1; axis <= kTerms; ++axis) {
    BasisTerm t;
    t.kind = BasisKind::kChannel;
    t.axis = axis;
    t.channel = channel;
    t.form = form;
    t.time_constant = form == ChannelForm::kValue ? 0.0 : tau_s;
    t.reference = form == ChannelForm::kDerivative ? 0.0 : reference;
    t.sigma = sigma;
    g->basis_terms.push_back(t);
  }
  return m;
}

// The parabola through the best point of `lag` and its two neighbours (in ln tau): its vertex and
// its curvature a (-2 log L = a (x - vertex)^2 + c); not ok at an end of the grid or without a
// positive curvature.
template <typename Map>
Parabola VertexOf(const Map& lag, typename Map::const_iterator best) {
  if (best == lag.begin() || std::next(best) == lag.end()) return Parabola{};
  const auto& [x0, r0] = *std::prev(best);
  const auto& [x2, r2] = *std::next(best);
  return ParabolaThrough(x0, r0.value, best->first, best->second.value, x2, r2.value);
}

// One run of a form: its profiled -2 log L, the channel terms' gain a [rad/s per unit] and the
// offsets b [rad/s] with their 1-sigma, and the run.
struct FormRun {
  double value = 0.0;  // profiled -2 log L
  Vector3d a = Vector3d::Zero(), a_sigma = Vector3d::Zero();
  Vector3d b = Vector3d::Zero(), b_sigma = Vector3d::Zero();  // the offsets [rad/s]
  ModelRun run;
};

// What every form's run shares (the recording, the priors, where the terms sit in the gyro's
// basis) and the lag's runs by ln(tau / h). `candidate` and `fit` outlive it; every run adds one
// to fit.runs.
struct ChannelSearch {
  const Candidate& candidate;
  CandidateFit& fit;
  std::vector<TelemetryFrame> frames;
  double sigma = 0.0;         // the gain's prior [rad/s per unit]
  double reference = 0.0;     // the channel's mean [its unit]
  bool offset = false;        // whether three case-fixed drifts come with the channel terms
  double offset_sigma = 0.0;  // their prior [rad/s]
  int first_term = 0;         // the first of the terms in the gyro's basis
  int terms = 0;              // how many
  int channel_first = 0;      // the first channel term (after the offsets)
  double log_min = 0.0, log_max = 0.0, spacing = 0.0;  // the lag's grid in ln(tau / h)
  std::map<double, FormRun> lag;  // ln(tau / h) -> run

  // The model with the terms of `form` (tau [s] for the lag and derivative), run over the
  // recording.
  absl::Status RunForm(ChannelForm form, double tau_s, FormRun& out) {
    const ModelState m = WithChannelTerms(fit.model, candidate.gyro, candidate.channel, form,
                                          tau_s, reference, sigma, offset_sigma);
    auto run = RunModel(m.config, m.options, frames);
    ++fit.runs;
    if (!run.ok()) return run.status();
    out.value = Profile(*run).value;
    if (const GyroEstimate* e = FindEstimate(run->gyros, candidate.gyro);
        e != nullptr && static_cast<int>(e->basis_terms.size()) >= first_term + terms &&
        static_cast<int>(e->basis_sigma.size()) >= first_term + terms) {
      for (int i = 0; i < kTerms; ++i) {
        out.a(i) = e->basis_terms[channel_first + i].value;
        out.a_sigma(i) = e->basis_sigma[channel_first + i];
        if (offset) {
          out.b(i) = e->basis_terms[first_term + i].value;
          out.b_sigma(i) = e->basis_sigma[first_term + i];
        }
      }
    }
    out.run = *std::move(run);
    return absl::OkStatus();
  }

  // The lag form at ln(tau / h) (clamped to the grid; skipped when evaluated already).
  absl::Status EvaluateLag(double log_tau) {
    log_tau = std::clamp(log_tau, log_min, log_max);
    for (const auto& [x, r] : lag) {
      if (std::abs(x - log_tau) < 1e-9) return absl::OkStatus();
    }
    FormRun r;
    RETURN_IF_ERROR(RunForm(ChannelForm::kLag, HoursToSeconds(std::exp(log_tau)), r));
    lag.emplace(log_tau, std::move(r));
    return absl::OkStatus();
  }

  // The lag of the smallest -2 log L (the first of equals).
  std::map<double, FormRun>::iterator BestLag() {
    auto best = lag.begin();
    for (auto it = lag.begin(); it != lag.end(); ++it) {
      if (it->second.value < best->second.value) best = it;
    }
    return best;
  }
};

// Why no drift following the channel can be fitted (not declared, too few values, constant, no
// room in the gyro's basis); empty when one can.
std::string WhyNoChannelFit(const std::optional<ChannelConfig>& declared,
                            const ChannelSpread& spread, int first_term) {
  if (declared.has_value() && spread.count >= 2 && spread.sd > 0.0 &&
      first_term + 2 * kTerms <= kMaxBasisTermsPerGyro) {
    return std::string();
  }
  return !declared.has_value()  ? "the channel is not declared"
         : spread.count < 2     ? "the recording carries fewer than two of its values"
         : !(spread.sd > 0.0)   ? "its value does not change over the recording"
                                : "the gyro's basis holds too many terms for three more";
}

// The lag's search: the coarse grid, twice the two points half a spacing either side of the best,
// then the vertex of the parabola through the best time constant and its neighbours (near its
// minimum -2 log L is a parabola in ln tau: the lag is well determined by a wandering channel,
// its profile falls by hundreds within a quarter of a grid spacing), run up to
// kChannelLagVertexRuns times while it moves by more than 0.005 in ln tau.
absl::Status SearchLags(ChannelSearch& s) {
  for (int k = 0; k < kChannelLagCoarse; ++k) {
    RETURN_IF_ERROR(s.EvaluateLag(s.log_min + k * s.spacing));
  }
  for (int r = 1; r <= kChannelLagRefine; ++r) {
    const double half = s.spacing / std::pow(2.0, r);
    const double centre = s.BestLag()->first;
    if (centre - half >= s.log_min - 1e-12) RETURN_IF_ERROR(s.EvaluateLag(centre - half));
    if (centre + half <= s.log_max + 1e-12) RETURN_IF_ERROR(s.EvaluateLag(centre + half));
  }
  for (int it = 0; it < kChannelLagVertexRuns; ++it) {
    const Parabola p = VertexOf(s.lag, s.BestLag());
    if (!p.ok) break;
    bool known = false;
    for (const auto& [x, r] : s.lag) known = known || std::abs(x - p.vertex) < 0.005;
    if (known) break;
    RETURN_IF_ERROR(s.EvaluateLag(p.vertex));
  }
  return absl::OkStatus();
}

// The evidence's prior points in `fit`, each form a third of the prior: the value's and the
// derivative's runs, and the lag's points with their weights (uniform in ln tau, trapezoid rule).
// Returns the lag's profile (ln(tau / h), -2 log L) and sets `lag_integrated` to its -2 log L
// integrated over tau.
ProfilePoints AddFormPriorPoints(const ChannelSearch& s, double value_form, double derivative_form,
                                 double& lag_integrated, CandidateFit& fit) {
  const double span = s.log_max - s.log_min;
  std::vector<std::pair<double, double>> lag_points;
  ProfilePoints profile;
  for (const auto& [x, r] : s.lag) profile.emplace_back(x, r.value);
  const std::vector<double> weights = TrapezoidWeights(profile, span);
  for (size_t j = 0; j < profile.size(); ++j) lag_points.emplace_back(weights[j], profile[j].second);
  fit.prior_points.emplace_back(1.0 / 3.0, value_form);
  fit.prior_points.emplace_back(1.0 / 3.0, derivative_form);
  for (const auto& [w, v] : lag_points) fit.prior_points.emplace_back(w / 3.0, v);
  lag_integrated = IntegratedDeviance(lag_points);
  return profile;
}

// The form reported: the largest evidence of the three (the lag's integrated over tau), the
// value's on a tie.
ChannelForm ChooseForm(double value_form, double derivative_form, double lag_integrated) {
  ChannelForm form = ChannelForm::kValue;
  double form_value = value_form;
  if (derivative_form < form_value) {
    form = ChannelForm::kDerivative;
    form_value = derivative_form;
  }
  if (lag_integrated < form_value) form = ChannelForm::kLag;
  return form;
}

// The lag form's time constant and its 95% interval [h] (the parabola's where it has one, else
// the profile's), whether the interval reaches an end of the lags searched, and the variance the
// gain's sigma gains from tau's uncertainty [(rad/s per unit)^2].
struct LagEstimate {
  double tau_h = 0.0, lower_h = 0.0, upper_h = 0.0;
  bool clipped = false;
  Vector3d gain_variance_from_tau = Vector3d::Zero();
};
LagEstimate EstimateLag(const ChannelSearch& s, const ProfilePoints& profile,
                        std::map<double, FormRun>::const_iterator best) {
  LagEstimate out;
  const Parabola parabola = VertexOf(s.lag, best);
  const size_t top = ProfileMinimum(profile);
  const LevelInterval in = IntervalAtLevel(profile, top, profile[top].second + kIntervalDrop);
  double lower = in.lower, upper = in.upper;
  bool lower_open = in.lower_open, upper_open = in.upper_open;
  if (parabola.ok) {
    // The interval of the parabola: -2 log L within 3.84 of its minimum.
    const double half = std::sqrt(kIntervalDrop / parabola.curvature);
    lower = std::max(s.log_min, parabola.vertex - half);
    upper = std::min(s.log_max, parabola.vertex + half);
    lower_open = parabola.vertex - half < s.log_min;
    upper_open = parabola.vertex + half > s.log_max;
  }
  out.clipped = lower_open || upper_open;
  out.tau_h = std::exp(parabola.ok ? parabola.vertex : profile[top].first);
  out.lower_h = std::exp(lower);
  out.upper_h = std::exp(upper);
  // The gain moves with tau: its sigma adds the spread tau's uncertainty gives (the delta method
  // on the profile, da/d ln tau between the time constants inside the interval, times the
  // 1-sigma of ln tau, the 95% half-width / 1.96), as the warm-up's amplitude does.
  auto inside = [&](const auto& point) {
    return point.first >= lower - 1e-12 && point.first <= upper + 1e-12;
  };
  auto lo = std::find_if(s.lag.begin(), s.lag.end(), inside);
  auto hi = std::find_if(s.lag.rbegin(), s.lag.rend(), inside);
  if (lo != s.lag.end() && hi != s.lag.rend() && hi->first > lo->first) {
    const Vector3d slope = (hi->second.a - lo->second.a) / (hi->first - lo->first);
    const double sigma_log_tau = 0.5 * (upper - lower) / 1.959963984540054;
    out.gain_variance_from_tau = (slope.cwiseAbs() * sigma_log_tau).cwiseAbs2();
  }
  return out;
}

// The chosen form's run as the fit's: the model with its terms (tau [s]), its run, and the terms
// at the values the run estimated, the channel terms first (Finding::basis_terms.front() names
// the channel), then the offsets.
void AdoptForm(ChannelSearch& s, ChannelForm form, double tau_s, FormRun& chosen) {
  CandidateFit& fit = s.fit;
  fit.model = WithChannelTerms(fit.model, s.candidate.gyro, s.candidate.channel, form, tau_s,
                               s.reference, s.sigma, s.offset_sigma);
  fit.run = std::move(chosen.run);
  fit.parameters = s.terms;
  const GyroConfig* gw = FindGyroMutable(fit.model.config, s.candidate.gyro);
  for (int i = 0; i < kTerms; ++i) {
    BasisTerm t = gw->basis_terms[s.channel_first + i];
    t.value = chosen.a(i);
    fit.basis_terms.push_back(t);
  }
  for (int i = 0; i < kTerms && s.offset; ++i) {
    BasisTerm t = gw->basis_terms[s.first_term + i];
    t.value = chosen.b(i);
    fit.basis_terms.push_back(t);
  }
}

// The fit's parameters and description: the offsets, the gain in deg/h per unit of the channel
// (per unit per hour for the derivative) with its 1-sigma `a_sigma`, the reference, the lag.
void DescribeChannelFit(const ChannelSearch& s, const ChannelConfig& declared, ChannelForm form,
                        const FormRun& chosen, const Vector3d& a_sigma, const LagEstimate& lag,
                        CandidateFit& fit) {
  const Vector3d a = chosen.a, b = chosen.b, b_sigma = chosen.b_sigma;
  for (int i = 0; i < kTerms && s.offset; ++i) {
    fit.fitted.push_back(
        {absl::StrFormat("channelOffsetDegH[%d]", i), DegH(b(i)), DegH(b_sigma(i)), "deg/h"});
  }
  const std::string unit = form == ChannelForm::kDerivative
                               ? absl::StrCat("deg/h per ", declared.unit, "/h")
                               : absl::StrCat("deg/h per ", declared.unit);
  for (int i = 0; i < kTerms; ++i) {
    fit.fitted.push_back(
        {absl::StrFormat("channelGainDegH[%d]", i), DegH(a(i)), DegH(a_sigma(i)), unit});
  }
  const double size = a.norm();
  const double size_sigma =
      size > 0 ? std::sqrt((a.cwiseProduct(a_sigma)).squaredNorm()) / size : a_sigma.norm();
  fit.fitted.push_back({"channelGainSizeDegH", DegH(size), DegH(size_sigma), unit});
  fit.fitted.push_back({"channelReference", s.reference, 0.0, declared.unit});
  if (form == ChannelForm::kLag) {
    fit.fitted.push_back({"channelLagHours", lag.tau_h, 0.5 * (lag.upper_h - lag.lower_h), "h"});
    fit.fitted.push_back({"channelLagLowerHours", lag.lower_h, 0.0, "h"});
    fit.fitted.push_back({"channelLagUpperHours", lag.upper_h, 0.0, "h"});
  }
  const Vector3d direction = size > 0 ? Vector3d(a / size) : Vector3d::Zero();
  const std::string& channel = s.candidate.channel;
  const std::string what =
      form == ChannelForm::kValue ? channel
      : form == ChannelForm::kLag ? channel
                                  : absl::StrCat("the rate of change of ", channel);
  std::string lag_text;
  if (form == ChannelForm::kLag) {
    lag_text = absl::StrFormat(" with a %.0f min lag (95%% %.0f-%.0f min%s)", lag.tau_h * 60.0,
                               lag.lower_h * 60.0, lag.upper_h * 60.0,
                               lag.clipped ? ", clipped: the interval reaches an end of the lags "
                                             "searched"
                                           : "");
  }
  fit.description = absl::StrFormat(
      "gyro %d drift along (%.2f, %.2f, %.2f) (case axes) follows %s at %.4f +- %.4f %s%s "
      "(%s at %s = %.6g %s, its mean over the recording)",
      s.candidate.gyro, direction.x(), direction.y(), direction.z(), what, DegH(size),
      DegH(size_sigma), unit, lag_text,
      s.offset ? absl::StrFormat("plus a case-fixed drift (%.4f, %.4f, %.4f) deg/h", DegH(b.x()),
                                 DegH(b.y()), DegH(b.z()))
               : std::string("zero"),
      channel, s.reference, declared.unit);
}

// The notes of the three forms' -2 log L and of the lag's profile.
void AddFormNotes(const ChannelSearch& s, const ChannelConfig& declared,
                  const ChannelSpread& spread, double value_form, double derivative_form,
                  double lag_integrated, const ProfilePoints& profile,
                  std::map<double, FormRun>::const_iterator best, CandidateFit& fit) {
  fit.notes.push_back(absl::StrFormat(
      "-2 log L of the forms: value %.1f, derivative (of a %.0f min lag) %.1f, lag integrated "
      "over tau %.1f (best %.2f h: %.1f); the three forms equally likely a priori, tau uniform in "
      "ln tau over %.1f-%.0f h; terms freed with %.4f deg/h per %s (c_sigma per 1-sigma of the "
      "channel, %.4g %s)",
      value_form, kChannelDerivativeSmoothingHours * 60.0, derivative_form, lag_integrated,
      std::exp(best->first), best->second.value, kChannelLagMinHours, kChannelLagMaxHours,
      DegH(s.sigma), declared.unit, spread.sd, declared.unit));
  std::string profile_text;
  for (const auto& [x, v] : profile) {
    absl::StrAppend(&profile_text,
                    absl::StrFormat(" %.2f:%.1f", std::exp(x), v - best->second.value));
  }
  fit.notes.push_back(
      absl::StrCat("likelihood over the lag (h: -2 log L above the best):", profile_text));
}

}  // namespace

std::vector<std::string> CandidateChannels(const SpacecraftConfig& config) {
  std::vector<std::string> names;
  for (const ChannelConfig& c : config.channels) names.push_back(c.name);
  return names;
}

// The fit as a sequence: whether the channel can carry a drift, the value and derivative forms
// run once, the lag searched, the forms' prior points, the form of the largest evidence, its lag
// and interval, its run adopted, and the fit described.
absl::Status FitChannelCandidate(const Candidate& candidate, const FitContext& ctx,
                                 CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  ASSIGN_OR_RETURN(const GyroConfig* g, CandidateGyro(fit.model.config, candidate.gyro));
  fit.time.kind = kTimeFollowsChannel;
  const int first_term = static_cast<int>(g->basis_terms.size());
  const ChannelSpread spread = SpreadOf(*ctx.frames, candidate.channel);
  // A copy: fit.model is replaced below.
  std::optional<ChannelConfig> declared;
  for (const ChannelConfig& c : fit.model.config.channels) {
    if (c.name == candidate.channel) declared = c;
  }
  if (const std::string why = WhyNoChannelFit(declared, spread, first_term); !why.empty()) {
    fit.parameters = 0;
    fit.notes.push_back(
        absl::StrFormat("no drift following %s fitted: %s", candidate.channel, why));
    return absl::OkStatus();
  }
  ChannelSearch s{candidate, fit,
                  CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction)};
  // The prior: c_sigma of drift per 1-sigma of the channel [rad/s per unit].
  s.sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h) / spread.sd;
  s.reference = spread.mean;
  // The constant drift at the channel's mean, unless the gyro's C1 (eq. (8), the same case-fixed
  // drift) is free already.
  s.offset = !(g->model_sigma.C1.maxCoeff() > 0.0);
  s.offset_sigma = s.offset ? DegPerHourToRadPerSec(opt.c_sigma_deg_h) : 0.0;
  s.first_term = first_term;
  s.terms = s.offset ? 2 * kTerms : kTerms;
  // The channel terms follow the offsets (WithChannelTerms).
  s.channel_first = first_term + (s.offset ? kTerms : 0);
  s.log_min = std::log(kChannelLagMinHours);
  s.log_max = std::log(kChannelLagMaxHours);
  s.spacing = (s.log_max - s.log_min) / (kChannelLagCoarse - 1);

  FormRun value_run, derivative_run;
  RETURN_IF_ERROR(s.RunForm(ChannelForm::kValue, 0.0, value_run));
  const double smoothing_s = HoursToSeconds(kChannelDerivativeSmoothingHours);
  RETURN_IF_ERROR(s.RunForm(ChannelForm::kDerivative, smoothing_s, derivative_run));
  RETURN_IF_ERROR(SearchLags(s));
  double lag_integrated = 0.0;
  const ProfilePoints profile =
      AddFormPriorPoints(s, value_run.value, derivative_run.value, lag_integrated, fit);
  const ChannelForm form = ChooseForm(value_run.value, derivative_run.value, lag_integrated);
  const auto best = s.BestLag();
  FormRun* chosen = form == ChannelForm::kLag          ? &best->second
                    : form == ChannelForm::kDerivative ? &derivative_run
                                                       : &value_run;
  LagEstimate lag;
  if (form == ChannelForm::kLag) lag = EstimateLag(s, profile, best);
  const Vector3d a_sigma =
      (chosen->a_sigma.cwiseAbs2() + lag.gain_variance_from_tau).cwiseSqrt();
  const double tau_s = form == ChannelForm::kLag          ? HoursToSeconds(lag.tau_h)
                       : form == ChannelForm::kDerivative ? smoothing_s
                                                          : 0.0;
  AdoptForm(s, form, tau_s, *chosen);
  DescribeChannelFit(s, *declared, form, *chosen, a_sigma, lag, fit);
  AddFormNotes(s, *declared, spread, value_run.value, derivative_run.value, lag_integrated,
               profile, best, fit);
  return absl::OkStatus();
}

}  // namespace esg::estimator::discovery
