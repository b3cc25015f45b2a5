#include "estimator/discovery/turning_displacement.h"

#include <algorithm>
#include <cmath>
#include <initializer_list>
#include <iterator>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/basis_term.h"
#include "estimator/discovery/basis_stage.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/deviation_filter.h"
#include "estimator/discovery/open_ended.h"
#include "estimator/discovery/profile_interval.h"
#include "estimator/discovery/wander.h"
#include "estimator/model_terms.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

namespace {

using Eigen::MatrixXd;
using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::VectorXd;

// A regressor whose RMS over the recording is below this is left out (its drift vanishes on the
// recording: a spin axis perpendicular to case axis m makes h_m^2 vanish).
constexpr double kMinRegressorRms = 1e-3;

double DegH(double x) { return RadPerSecToDegPerHour(x); }

// Where term (sine, c2, axis m) sits among the twelve: cos before sin, C1-like (degree 0) before
// C2-like (h_m^2), case axes x, y, z.
int TermIndex(bool sine, bool c2, int m) { return (sine ? 6 : 0) + (c2 ? 3 : 0) + (m - 1); }

// The twelve terms at the period [s], phase zero at `epoch`, value and sigma 0.
std::vector<BasisTerm> TurnTerms(double period_s, absl::Time epoch) {
  std::vector<BasisTerm> terms(kTurnTerms);
  for (bool sine : {false, true}) {
    for (bool c2 : {false, true}) {
      for (int m = 1; m <= 3; ++m) {
        BasisTerm& t = terms[TermIndex(sine, c2, m)];
        t.kind = BasisKind::kCyclingHarmonic;
        t.axis = m;
        t.exponents = {0, 0, 0};
        if (c2) t.exponents[m - 1] = 2;
        t.sine = sine;
        t.period = period_s;
        t.epoch = epoch;
      }
    }
  }
  return terms;
}

// The term's regressor s, RMS over the series' substeps (time-weighted).
double TermRms(const DeviationSeries& s, const BasisTerm& t) {
  return RegressorRms(s, [&t](const BasisInputs& in) { return BasisScalar(t, in); });
}

// The terms' signatures on the series, list by list, and their prior 1-sigma (term.sigma).
std::vector<std::vector<Vector2d>> TermSignatures(
    const DeviationSeries& s, std::initializer_list<const std::vector<BasisTerm>*> lists,
    std::vector<double>* prior = nullptr) {
  std::vector<std::vector<Vector2d>> out;
  for (const std::vector<BasisTerm>* terms : lists) {
    for (const BasisTerm& t : *terms) {
      out.push_back(Signature(
          s, [&t](const BasisInputs& in) -> Vector3d { return BasisRegressor_k(t, in); }));
      if (prior != nullptr) prior->push_back(t.sigma);
    }
  }
  return out;
}

// The terms kept at a period (their regressor does not vanish: TermIndex order, a subset) and
// each one's prior 1-sigma, c_sigma at its regressor's RMS [rad/s per unit of s].
struct TurnColumns {
  std::vector<BasisTerm> terms;
  VectorXd prior;
};
TurnColumns ColumnsAt(const DeviationSeries& s, double period_s, absl::Time epoch,
                      double drift_sigma) {
  TurnColumns out;
  std::vector<double> prior;
  const std::vector<BasisTerm> all = TurnTerms(period_s, epoch);
  for (int j = 0; j < kTurnTerms; ++j) {
    const double rms = TermRms(s, all[j]);
    if (!(rms >= kMinRegressorRms)) continue;
    out.terms.push_back(all[j]);
    out.terms.back().sigma = drift_sigma / rms;
    prior.push_back(out.terms.back().sigma);
  }
  out.prior = Eigen::Map<const VectorXd>(prior.data(), static_cast<Eigen::Index>(prior.size()));
  return out;
}

// The constant part of a displacement, C1 and C2 of eq. (10) across h (degree 0 and h_m^2 along
// e_m), when the model holds them: columns beside the turning ones at every period.
std::vector<BasisTerm> ConstantTerms() {
  std::vector<BasisTerm> terms;
  for (bool c2 : {false, true}) {
    for (int m = 1; m <= 3; ++m) {
      BasisTerm t;
      t.kind = BasisKind::kSpinAxisHarmonic;
      t.axis = m;
      if (c2) t.exponents[m - 1] = 2;
      terms.push_back(t);
    }
  }
  return terms;
}

// What the deviation and its whitening need, the same at every period.
struct TurnSearch {
  const DeviationSeries* series = nullptr;
  double random_walk = 0.0;
  double w0_sigma = 0.0;
  OpenEndedOptions options;
  absl::Time epoch;
  // The displacement's constant part (C1, C2 across h) with the library's prior of C1, C2: in
  // both regressions, so 2 ln B is the turning part's.
  std::vector<BasisTerm> constant;
  // The same at every period, so computed once (Prepare): the series whitened with its nuisance
  // columns, and the constant part's signatures whitened.
  std::shared_ptr<const SeriesWhitener> whitener;
  std::vector<VectorXd> constant_w;

  // Fills whitener and constant_w once series, random_walk, w0_sigma, options and constant are
  // set.
  void Prepare() {
    whitener = std::make_shared<const SeriesWhitener>(*series, random_walk, w0_sigma, options);
    constant_w = whitener->With(TermSignatures(*series, {&constant})).extra_w;
  }
  double log_min = 0.0, log_max = 0.0;  // ln(P / h)
  std::map<double, double> evidence;    // ln(P / h) -> the regression's 2 ln B

  // The regression's 2 ln B of the terms at period exp(log_p) h against the nuisance groups.
  // `residual_w`: when not null, the whitened residual of the fit with the terms (two rows per
  // sample, the components along u1 and u2).
  double Regress(double log_p, VectorXd* residual_w = nullptr) const {
    const TurnColumns c =
        ColumnsAt(*series, HoursToSeconds(std::exp(log_p)), epoch, options.drift_sigma);
    if (c.terms.empty()) return 0.0;
    WhitenedSeries w = whitener->With(TermSignatures(*series, {&c.terms}));
    w.extra_w.insert(w.extra_w.end(), constant_w.begin(), constant_w.end());
    const int k = static_cast<int>(c.terms.size());
    std::vector<const VectorXd*> all, base;
    std::vector<double> base_prior;
    for (int j = 0; j < static_cast<int>(w.extra_w.size()); ++j) {
      all.push_back(&w.extra_w[j]);
      if (j < k) continue;
      base.push_back(&w.extra_w[j]);
      base_prior.push_back(constant[j - k].sigma);
    }
    for (size_t j = 0; j < w.nuisance_w.size(); ++j) {
      all.push_back(&w.nuisance_w[j]);
      base.push_back(&w.nuisance_w[j]);
      base_prior.push_back(w.nuisance_prior[j]);
    }
    const int n = static_cast<int>(base_prior.size());
    VectorXd prior(k + n), nuisance_prior(n);
    prior.head(k) = c.prior;
    for (int j = 0; j < n; ++j) nuisance_prior(j) = prior(k + j) = base_prior[j];
    const RegressionFit with = FitRegression(w.y_w, all, prior);
    const RegressionFit without = FitRegression(w.y_w, base, nuisance_prior);
    if (residual_w != nullptr) {
      *residual_w = w.y_w;
      for (size_t j = 0; j < all.size(); ++j) *residual_w -= with.mean(j) * *all[j];
    }
    return without.deviance - with.deviance;
  }

  void Evaluate(double log_p) {
    log_p = std::clamp(log_p, log_min, log_max);
    for (const auto& [x, e] : evidence) {
      if (std::abs(x - log_p) < 1e-9) return;
    }
    evidence.emplace(log_p, Regress(log_p));
  }

  std::map<double, double>::const_iterator Best() const {
    auto best = evidence.begin();
    for (auto it = evidence.begin(); it != evidence.end(); ++it) {
      if (it->second > best->second) best = it;
    }
    return best;
  }

  // -2 log L relative: (ln P, -2 ln B), in increasing ln P.
  ProfilePoints Profile() const {
    ProfilePoints p;
    for (const auto& [x, e] : evidence) p.emplace_back(x, -e);
    return p;
  }
};

// The vertex of the parabola through the best point and its neighbours (in ln P; a maximum of
// 2 ln B, a minimum of -2 ln B), or the best point itself at an end of the grid or without a
// maximum there.
double Vertex(const std::map<double, double>& evidence,
              std::map<double, double>::const_iterator best) {
  if (best == evidence.begin() || std::next(best) == evidence.end()) return best->first;
  const auto& [x0, y0] = *std::prev(best);
  const auto& [x2, y2] = *std::next(best);
  const Parabola p = ParabolaThrough(x0, -y0, best->first, -best->second, x2, -y2);
  return p.ok ? p.vertex : best->first;
}

// -2 ln of the regression's Bayes factor averaged over the period's prior (uniform in ln P,
// trapezoid rule over the points evaluated) relative to the best: >= 0, the period's Occam term.
double PeriodOccam(const TurnSearch& s) {
  const ProfilePoints p = s.Profile();
  const double span = s.log_max - s.log_min;
  if (p.size() < 2 || !(span > 0.0)) return 0.0;
  const std::vector<double> weights = TrapezoidWeights(p, span);
  std::vector<std::pair<double, double>> points;
  for (size_t j = 0; j < p.size(); ++j) points.emplace_back(weights[j], p[j].second);
  return std::max(0.0, IntegratedDeviance(points) + s.Best()->second);
}

// The long-run variance of the whitened residual over its variance, per component (u1, u2 rows
// interleaved) with Bartlett weights up to lag L = floor(4 (n / 100)^(2/9)) (Newey and West's
// rule), the larger of the two, at least 1: how much a regression that takes the rows as
// independent overstates its information when the model leaves them correlated in time.
double LongRunVarianceRatio(const VectorXd& e) {
  double worst = 1.0;
  for (int component = 0; component < 2; ++component) {
    std::vector<double> x;
    for (Eigen::Index r = component; r < e.size(); r += 2) x.push_back(e(r));
    const int n = static_cast<int>(x.size());
    if (n < 10) continue;
    double mean = 0.0;
    for (double v : x) mean += v / n;
    auto autocovariance = [&](int lag) {
      double sum = 0.0;
      for (int i = lag; i < n; ++i) sum += (x[i] - mean) * (x[i - lag] - mean);
      return sum / n;
    };
    const double c0 = autocovariance(0);
    if (!(c0 > 0.0)) continue;
    const int L = static_cast<int>(std::floor(4.0 * std::pow(n / 100.0, 2.0 / 9.0)));
    double ratio = 1.0;
    for (int k = 1; k <= L; ++k) ratio += 2.0 * (1.0 - k / (L + 1.0)) * autocovariance(k) / c0;
    worst = std::max(worst, ratio);
  }
  return worst;
}

// The amplitude of a turning part u cos + v sin, sqrt((|u|^2 + |v|^2) / 2), and its 1-sigma by
// the delta method on the coefficients' 1-sigma (taken as independent).
std::pair<double, double> TurnAmplitude(const Vector3d& u, const Vector3d& v,
                                        const Vector3d& u_sigma, const Vector3d& v_sigma) {
  const double a = std::sqrt(0.5 * (u.squaredNorm() + v.squaredNorm()));
  if (!(a > 0.0)) return {0.0, std::sqrt(0.5 * (u_sigma.squaredNorm() + v_sigma.squaredNorm()))};
  const double var =
      (u.cwiseProduct(u_sigma).squaredNorm() + v.cwiseProduct(v_sigma).squaredNorm()) /
      (4.0 * a * a);
  return {a, std::sqrt(var)};
}

// The fitted C1 and C2 turning parts (eq. (10); the terms' drift is -(C1 + C2 h^2) across h):
// cos and sin vectors with their 1-sigma [rad/s], from the run's estimates of the terms.
struct TurnParts {
  Vector3d c1_cos = Vector3d::Zero(), c1_sin = Vector3d::Zero();
  Vector3d c2_cos = Vector3d::Zero(), c2_sin = Vector3d::Zero();
  Vector3d c1_cos_sigma = Vector3d::Zero(), c1_sin_sigma = Vector3d::Zero();
  Vector3d c2_cos_sigma = Vector3d::Zero(), c2_sin_sigma = Vector3d::Zero();
};

void DescribeTurn(const Candidate& candidate, const TurnParts& p, double period_h,
                  const LevelInterval& interval, bool clipped, CandidateFit& fit) {
  const auto [c1, c1_sigma] = TurnAmplitude(p.c1_cos, p.c1_sin, p.c1_cos_sigma, p.c1_sin_sigma);
  const auto [c2, c2_sigma] = TurnAmplitude(p.c2_cos, p.c2_sin, p.c2_cos_sigma, p.c2_sin_sigma);
  // u x v = |u|^2 a for u cos + (a x u) sin; C2's part adds k^2 times the same when C2 = k C1.
  Vector3d axis = p.c1_cos.cross(p.c1_sin) + p.c2_cos.cross(p.c2_sin);
  axis = axis.norm() > 0.0 ? Vector3d(axis.normalized()) : Vector3d::Zero();
  const double lower_h = std::exp(interval.lower), upper_h = std::exp(interval.upper);
  AddVectorParameters("c1TurnCosDegH", p.c1_cos, p.c1_cos_sigma, DegH(1.0), "deg/h", fit.fitted);
  AddVectorParameters("c1TurnSinDegH", p.c1_sin, p.c1_sin_sigma, DegH(1.0), "deg/h", fit.fitted);
  AddVectorParameters("c2TurnCosDegH", p.c2_cos, p.c2_cos_sigma, DegH(1.0), "deg/h", fit.fitted);
  AddVectorParameters("c2TurnSinDegH", p.c2_sin, p.c2_sin_sigma, DegH(1.0), "deg/h", fit.fitted);
  fit.fitted.push_back({"c1TurnDegH", DegH(c1), DegH(c1_sigma), "deg/h"});
  fit.fitted.push_back({"c2TurnDegH", DegH(c2), DegH(c2_sigma), "deg/h"});
  AddVectorParameters("turnAxis", axis, Vector3d::Zero(), 1.0, "1", fit.fitted);
  fit.fitted.push_back(
      {"turnPeriodHours", period_h, 0.5 * (upper_h - lower_h) / 1.959963984540054, "h"});
  fit.fitted.push_back({"turnPeriodLowerHours", lower_h, 0.0, "h"});
  fit.fitted.push_back({"turnPeriodUpperHours", upper_h, 0.0, "h"});
  fit.description = absl::StrFormat(
      "gyro %d: a rotor displacement turning about (%.2f, %.2f, %.2f) (case axes) once every "
      "%.1f h (95%% %.1f-%.1f h%s): the turning parts of C1 and C2 of eq. (10) are %.4f +- %.4f "
      "and %.4f +- %.4f deg/h (a displacement gives C2 = -5 C20 / (C10 + C20) C1, eq. (8), (9))",
      candidate.gyro, axis.x(), axis.y(), axis.z(), period_h, lower_h, upper_h,
      clipped ? ", clipped: the interval reaches an end of the periods searched" : "", DegH(c1),
      DegH(c1_sigma), DegH(c2), DegH(c2_sigma));
}

// Why no turning displacement can be fitted to the gyro on a recording of span_h hours (its basis
// full, or the recording too short to tell a turn from a trend), else empty.
std::string TurnNotFittable(int first_term, double span_h) {
  if (first_term + kTurnTerms > kMaxBasisTermsPerGyro) {
    return "the gyro's basis holds too many terms for twelve more";
  }
  if (kTurnMaxSpans * span_h < 2.0 * kTurnMinPeriodHours) {
    return absl::StrFormat("the recording's %.1f h cannot tell a turn from a trend", span_h);
  }
  return "";
}

// The regression's search over the period: a grid uniform in ln P from kTurnMinPeriodHours to
// kTurnMaxSpans recording spans, then the parabola's vertex near the best, at most
// kTurnVertexSteps times.
void SearchPeriods(double span_h, TurnSearch& s) {
  s.log_min = std::log(kTurnMinPeriodHours);
  s.log_max = std::log(kTurnMaxSpans * span_h);
  const double spacing = std::log(2.0) / kTurnGridPerFactorTwo;
  const int points = 1 + static_cast<int>(std::ceil((s.log_max - s.log_min) / spacing));
  for (int k = 0; k < points; ++k) {
    s.Evaluate(s.log_min + (s.log_max - s.log_min) * k / (points - 1));
  }
  for (int it = 0; it < kTurnVertexSteps; ++it) {
    const double vertex = Vertex(s.evidence, s.Best());
    bool known = false;
    for (const auto& [x, e] : s.evidence) known = known || std::abs(x - vertex) < 1e-3;
    if (known) break;
    s.Evaluate(vertex);
  }
}

// The regression's profile over the period, scaled by the whitened residual's long-run variance
// ratio kappa at the best period log_p (a quasi-likelihood: rows correlated in time carry less
// information than the regression counts), its minimum and its 95% interval.
struct RegressionProfile {
  ProfilePoints points;  // ln(P / h), -2 ln B / kappa
  size_t top = 0;
  LevelInterval interval;
  double kappa = 1.0;
};
RegressionProfile ProfilePeriods(const TurnSearch& s, double log_p) {
  RegressionProfile out;
  VectorXd residual_w;
  s.Regress(log_p, &residual_w);
  out.kappa = LongRunVarianceRatio(residual_w);
  out.points = s.Profile();
  for (auto& [x, v] : out.points) v /= out.kappa;
  out.top = ProfileMinimum(out.points);
  out.interval =
      IntervalAtLevel(out.points, out.top, out.points[out.top].second + kProfileIntervalDrop);
  return out;
}

// A drift that returns to its mean (switching at random, driven by a quantity the telemetry does
// not carry) is partly fitted by any regressor that changes in time: the turning terms at the
// best period against the stationary drift on the same deviation, for the round's physics check
// (selection.cc CheckConstantEffect), as the sun's terms are; the turn's evidence less its
// period's Occam term (fit.occam), the stationary drift's integrated over its grid. The
// candidate's whole model: the turning terms and the constant part (freed by the candidate or
// free in the model).
void CompareWithAStationaryDrift(const TurnSearch& s, const TurnColumns& columns,
                                 const ModelState& model, int gyro, double c_sigma_deg_h,
                                 CandidateFit& fit) {
  std::vector<double> prior;
  const std::vector<std::vector<Vector2d>> signatures =
      TermSignatures(*s.series, {&columns.terms, &s.constant}, &prior);
  const ConstantEffectEvidence w = CompareConstantEffect(
      *s.series, s.random_walk, s.w0_sigma, DegPerHourToRadPerSec(c_sigma_deg_h),
      HeldSteps(model, gyro), signatures, prior);
  fit.wander_compared = true;
  fit.wander_effect = w.effect - fit.occam;
  fit.wander_stationary = w.stationary;
  fit.wander_on_top = w.on_top - fit.occam;
}

// The filter's run with the twelve terms at one period: its profiled -2 log L, the terms, the run.
struct PeriodRun {
  double value = 0.0;
  TurnColumns columns;
  ModelRun run;
};

// The period refined by the filter: its -2 log L at the regression's best period log_p and half
// the regression's interval either side (at least 1%: `delta`), the parabola's vertex run when it
// moves, and the 95% interval where the parabola rises by 3.84. The regression's profile locates
// the period; the filter, which estimates every other state with the terms, decides it (on the
// suite's seeds the regression's best was up to 0.7% off the true period with an interval a third
// as wide). `base` is the candidate's model without the terms; each run counts in fit.runs.
struct RefinedPeriod {
  PeriodRun chosen;
  double log_period = 0.0;
  LevelInterval interval;
  double delta = 0.0;
};
absl::StatusOr<RefinedPeriod> RefinePeriodByFilter(const TurnSearch& s, const ModelState& base,
                                                   int gyro,
                                                   const std::vector<TelemetryFrame>& corrected,
                                                   double log_p, const LevelInterval& interval,
                                                   CandidateFit& fit) {
  auto run_at = [&](double log_period) -> absl::StatusOr<PeriodRun> {
    PeriodRun out;
    out.columns = ColumnsAt(*s.series, HoursToSeconds(std::exp(log_period)), s.epoch,
                            s.options.drift_sigma);
    SpacecraftConfig config = base.config;
    GyroConfig* gc = FindGyroMutable(config, gyro);
    for (const BasisTerm& t : out.columns.terms) gc->basis_terms.push_back(t);
    auto run = RunModel(config, base.options, corrected);
    ++fit.runs;
    if (!run.ok()) return run.status();
    out.value = Profile(*run).value;
    out.run = *std::move(run);
    return out;
  };
  RefinedPeriod out;
  out.delta = std::max(0.5 * (interval.upper - interval.lower), 0.01);
  const double delta = out.delta;
  ASSIGN_OR_RETURN(PeriodRun at_best, run_at(log_p));
  ASSIGN_OR_RETURN(const PeriodRun below, run_at(log_p - delta));
  ASSIGN_OR_RETURN(const PeriodRun above, run_at(log_p + delta));
  // -2 log L = a (x - vertex)^2 + c through the three.
  const Parabola parabola = ParabolaThrough(log_p - delta, below.value, log_p, at_best.value,
                                            log_p + delta, above.value);
  out.log_period = log_p;
  out.interval = interval;
  if (parabola.ok) {
    const double half = std::sqrt(kProfileIntervalDrop / parabola.curvature);
    out.interval.lower = parabola.vertex - half;
    out.interval.upper = parabola.vertex + half;
    out.interval.lower_open = out.interval.lower < s.log_min;
    out.interval.upper_open = out.interval.upper > s.log_max;
    out.log_period = parabola.vertex;
  }
  out.chosen = std::move(at_best);
  if (std::abs(out.log_period - log_p) > 0.1 * delta) {
    ASSIGN_OR_RETURN(PeriodRun at_vertex, run_at(out.log_period));
    if (at_vertex.value <= out.chosen.value) out.chosen = std::move(at_vertex);
    else out.log_period = log_p;
  }
  return out;
}

// The chosen period's twelve terms into the fit's model (after the gyro's first_term existing
// ones), its run adopted, and the terms at the run's estimates into fit.basis_terms; returns them
// as C1 and C2 turning parts.
TurnParts AdoptTurn(PeriodRun chosen, int gyro, int first_term, int released,
                    CandidateFit& fit) {
  const TurnColumns& columns = chosen.columns;
  GyroConfig* gw = FindGyroMutable(fit.model.config, gyro);
  for (const BasisTerm& t : columns.terms) gw->basis_terms.push_back(t);
  fit.run = std::move(chosen.run);
  fit.parameters = static_cast<int>(columns.terms.size()) + released;
  TurnParts parts;
  const GyroEstimate* e = FindEstimate(fit.run.gyros, gyro);
  for (size_t j = 0; j < columns.terms.size(); ++j) {
    BasisTerm t = columns.terms[j];
    const size_t at = first_term + j;
    double value = 0.0, sigma = t.sigma;
    if (e != nullptr && e->basis_terms.size() > at && e->basis_sigma.size() > at) {
      value = e->basis_terms[at].value;
      sigma = e->basis_sigma[at];
    }
    t.value = value;
    fit.basis_terms.push_back(t);
    // The term's drift e_m value s is -(C1 + C2 h^2) across h: C1_m (or C2_m) = -value.
    const int m = t.axis - 1;
    const bool c2 = t.exponents[m] == 2;
    Vector3d& part = t.sine ? (c2 ? parts.c2_sin : parts.c1_sin) : (c2 ? parts.c2_cos : parts.c1_cos);
    Vector3d& part_sigma = t.sine ? (c2 ? parts.c2_sin_sigma : parts.c1_sin_sigma)
                                  : (c2 ? parts.c2_cos_sigma : parts.c1_cos_sigma);
    part(m) = -value;
    part_sigma(m) = sigma;
  }
  return parts;
}

// The constant part the candidate freed with the turn, as rotor_displacement's parameters (their
// names, apply_findings.h) and in the description.
void DescribeConstantPart(const GyroEstimate& e, CandidateFit& fit) {
  const DriftVector value = e.coefficients.AsVector(), sigma = e.sigma.AsVector();
  for (const FixedTermDescriptor& term : kFixedTerms) {
    if (term.effect != EffectId(Effect::kRotorDisplacement)) continue;
    fit.fitted.push_back({FixedTermJsonName(term), DegH(value(term.theta_index)),
                          DegH(sigma(term.theta_index)), std::string(term.unit)});
  }
  const Vector3d c1 = e.coefficients.C1, c2 = e.coefficients.C2;
  absl::StrAppend(&fit.description,
                  absl::StrFormat("; its constant part, freed with it: C1 = (%.4f, %.4f, %.4f), "
                                  "C2 = (%.4f, %.4f, %.4f) deg/h",
                                  DegH(c1.x()), DegH(c1.y()), DegH(c1.z()), DegH(c2.x()),
                                  DegH(c2.y()), DegH(c2.z())));
}

// The notes: how the period was searched and refined, and the regression's profile.
void AddPeriodNotes(const TurnSearch& s, const RegressionProfile& r, double log_p,
                    double best_evidence, const RefinedPeriod& refined, double c_sigma_deg_h,
                    CandidateFit& fit) {
  std::string profile_text;
  for (const auto& [x, v] : r.points) {
    absl::StrAppend(&profile_text,
                    absl::StrFormat(" %.1f:%.1f", std::exp(x), v - r.points[r.top].second));
  }
  fit.notes.push_back(absl::StrFormat(
      "the gyro's deviation regressed on the twelve turning terms at %zu periods of %.0f-%.0f h "
      "(uniform in ln P): best %.1f h, 2 ln B %.1f; the terms freed at it with %.2f deg/h at "
      "each regressor's RMS and run by the filter there and %.1f%% either side (%d runs), the "
      "period %.2f h at the vertex of its -2 log L; the period's Occam term %.1f (the "
      "regression's profile; its interval divided by %.2f, the whitened residual's long-run "
      "variance ratio)",
      s.evidence.size(), kTurnMinPeriodHours, std::exp(s.log_max), std::exp(log_p),
      best_evidence, c_sigma_deg_h, 100.0 * (std::exp(refined.delta) - 1.0), fit.runs,
      std::exp(refined.log_period), fit.occam, r.kappa));
  fit.notes.push_back(
      absl::StrCat("likelihood over the period (h: -2 ln B above the best, scaled):",
                   profile_text));
}

}  // namespace

// The fit as a sequence: room in the basis and a long enough recording, the deviation, the
// period's grid and vertex by regression (refused at an end of the periods searched), the
// comparison with a stationary drift, the twelve terms run by the filter at the best period and
// either side, the terms adopted, and the fit described.
absl::Status FitTurningDisplacement(const Candidate& candidate, const FitContext& ctx,
                                    CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  const ModelState& model = *ctx.model;
  ASSIGN_OR_RETURN(const GyroConfig* g, CandidateGyro(fit.model.config, candidate.gyro));
  fit.time.kind = kTimeTurning;
  const int first_term = static_cast<int>(g->basis_terms.size());
  const double span_h =
      absl::ToDoubleHours(ctx.frames->back().time - ctx.frames->front().time);
  if (const std::string why = TurnNotFittable(first_term, span_h); !why.empty()) {
    fit.notes.push_back(absl::StrCat("no turning displacement fitted: ", why));
    return absl::OkStatus();
  }
  const std::vector<TelemetryFrame> corrected =
      CorrectStarTracker(*ctx.frames, *ctx.rates, model.correction);
  ASSIGN_OR_RETURN(std::vector<DeviationSeries> series,
                   MeasureDeviations(model.config, ctx.model_run->gyros, corrected, *ctx.rates,
                                     *ctx.model_run, {candidate.gyro}));
  // A displacement that turns is a displacement: where the model holds C1, C2 (eq. (10)), the
  // candidate frees them as rotor_displacement does, and the regressions carry their columns.
  const std::optional<FreedCoefficients> freed =
      FreedDriftCoefficients(Effect::kRotorDisplacement, opt);
  int released = 0;
  if (freed.has_value()) {
    const DriftVector sigma = g->model_sigma.AsVector();
    for (int i = freed->first; i < freed->first + freed->count; ++i) {
      released += sigma(i) > 0.0 ? 0 : 1;
    }
  }
  // The regressions carry the constant part's columns whether the model frees C1, C2 or holds
  // them: the deviation is measured from the model's final C1, C2, which a turn moves away from
  // their mean over the recording.
  TurnSearch s;
  s.constant = ConstantTerms();
  for (BasisTerm& t : s.constant) {
    t.sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h) /
              std::max(kMinRegressorRms, TermRms(series.front(), t));
  }
  s.series = &series.front();
  s.random_walk = ModelRandomWalk(model, candidate.gyro);
  s.w0_sigma = ModelInitialDriftSigma(model);
  s.options = ModelOpenEndedOptions(model, opt);
  s.epoch = ctx.frames->front().time;
  s.Prepare();
  SearchPeriods(span_h, s);
  const auto best = s.Best();
  const double log_p = best->first;
  if (best == s.evidence.begin() || std::next(best) == s.evidence.end()) {
    fit.not_fitted = absl::StrFormat(
        "no turning displacement fitted: the best period, %.1f h, is at an end of those searched "
        "(%.0f-%.0f h), where the recording cannot tell a turn from %s",
        std::exp(log_p), kTurnMinPeriodHours, std::exp(s.log_max),
        best == s.evidence.begin() ? "the orbit's harmonics" : "a trend, a decay or a step");
    fit.notes.push_back(fit.not_fitted);
    return absl::OkStatus();
  }
  const RegressionProfile profile = ProfilePeriods(s, log_p);
  // The twelve terms (those whose regressor does not vanish) at the regression's best period.
  const TurnColumns regression_columns =
      ColumnsAt(series.front(), HoursToSeconds(std::exp(log_p)), s.epoch, s.options.drift_sigma);
  fit.occam = PeriodOccam(s);
  CompareWithAStationaryDrift(s, regression_columns, model, candidate.gyro, opt.c_sigma_deg_h,
                              fit);
  if (released > 0) {
    ReleaseHeldCoefficients(fit.model.config, candidate.gyro, freed->first, freed->count,
                            freed->sigma);
  }
  const ModelState base = fit.model;
  ASSIGN_OR_RETURN(RefinedPeriod refined,
                   RefinePeriodByFilter(s, base, candidate.gyro, corrected, log_p,
                                        profile.interval, fit));
  const TurnParts parts =
      AdoptTurn(std::move(refined.chosen), candidate.gyro, first_term, released, fit);
  DescribeTurn(candidate, parts, std::exp(refined.log_period), refined.interval,
               refined.interval.lower_open || refined.interval.upper_open, fit);
  const GyroEstimate* e = FindEstimate(fit.run.gyros, candidate.gyro);
  if (released > 0 && e != nullptr) DescribeConstantPart(*e, fit);
  AddPeriodNotes(s, profile, log_p, best->second, refined, opt.c_sigma_deg_h, fit);
  return absl::OkStatus();
}

}  // namespace esg::estimator::discovery
