#include "estimator/discovery/wander.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <optional>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/discovery/deviation_filter.h"
#include "estimator/discovery/location.h"
#include "estimator/statistics.h"
#include "estimator/drift_model.h"
#include "estimator/model_terms.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::VectorXd;

std::vector<absl::Time> HeldSteps(const ModelState& m, int gyro) {
  std::vector<absl::Time> steps;
  for (const SessionOptions::CoefficientRelease& r : m.options.coefficient_releases) {
    if (!r.misalignment && r.gyro_id == gyro) steps.push_back(r.time);
  }
  return steps;
}

namespace {

constexpr std::array<double, 5> kWalkFactors = {2.0, 4.0, 8.0, 16.0, 32.0};
constexpr std::array<double, 5> kCorrelationHours = {0.5, 1.0, 2.0, 4.0, 8.0};
constexpr std::array<double, 5> kStationarySigmaDegH = {0.01, 0.02, 0.04, 0.08, 0.16};
constexpr int kMaxOnsets = 120;
// The walk's grid starts from this intensity when the model configures none [deg/h/sqrt(h)]
// (the library's random_walk_drift candidate does the same).
constexpr double kWalkFloorDegHSqrtH = 0.0005;

// -2 ln L of the series under a noise model (the filter) with the nuisance regressors and
// optional further columns (their priors in `prior`), dispersion profiled.
double SeriesDeviance(const DeviationFilter& f, const std::vector<Vector2d>& y,
                const std::vector<std::vector<Vector2d>>& columns, const VectorXd& prior) {
  const VectorXd y_w = f.Whiten(y);
  std::vector<VectorXd> x_w;
  x_w.reserve(columns.size());
  for (const auto& c : columns) x_w.push_back(f.Whiten(c));
  std::vector<const VectorXd*> X;
  for (const VectorXd& x : x_w) X.push_back(&x);
  return f.log_det() + FitRegression(y_w, X, prior).deviance;
}

// 2 ln B of a grid of models, each equally likely a priori, from their deviances and the base's.
double GridEvidence(double base, const std::vector<double>& deviances) {
  std::vector<std::pair<double, double>> points;
  for (double d : deviances) points.emplace_back(1.0 / deviances.size(), base - d);
  return EvidenceOverPrior(points);
}

// Nuisance regressors: a case-fixed drift before each step the model holds (open_ended.h does
// the same), with the step's prior.
struct Nuisance {
  std::vector<std::vector<Vector2d>> columns;
  VectorXd prior;
};
Nuisance StepNuisance(const DeviationSeries& series, double step_sigma,
                      const std::vector<absl::Time>& steps) {
  Nuisance out;
  for (const absl::Time& t : steps) {
    for (int m = 0; m < 3; ++m) {
      const Vector3d e_m = Vector3d::Unit(m);
      out.columns.push_back(Signature(series, [&](const BasisInputs& in) -> Vector3d {
        return in.time < t ? e_m : Vector3d::Zero();
      }));
    }
  }
  out.prior = VectorXd::Constant(static_cast<int>(out.columns.size()), step_sigma);
  return out;
}

// The deviance of each grid point of the stationary drift (correlation time x sigma, on top of
// the configured walk) with `columns` and their `prior`; the best point's in `best` when given.
struct StationaryPoint {
  double deviance = std::numeric_limits<double>::infinity();
  double correlation_hours = 0.0, sigma_deg_h = 0.0;
};
std::vector<double> StationaryDeviances(const DeviationSeries& series, double random_walk,
                                        double w0_sigma,
                                        const std::vector<std::vector<Vector2d>>& columns,
                                        const VectorXd& prior,
                                        StationaryPoint* best = nullptr) {
  std::vector<double> deviances;
  for (double tau_h : kCorrelationHours) {
    for (double sigma_deg_h : kStationarySigmaDegH) {
      const StationaryDrift g{DegPerHourToRadPerSec(sigma_deg_h), 3600.0 * tau_h};
      const DeviationFilter f(series, random_walk, w0_sigma, 1e-2, g);
      const double d = SeriesDeviance(f, series.y, columns, prior);
      deviances.push_back(d);
      if (best != nullptr && d < best->deviance) *best = {d, tau_h, sigma_deg_h};
    }
  }
  return deviances;
}

// The signature of drift coefficient theta_i on the series: its regressor of eq. (1), (10),
// d(dw_k)/d(theta_i) at the reading.
std::vector<Vector2d> CoefficientSignature(const DeviationSeries& series, int i) {
  return Signature(series,
                   [i](const BasisInputs& in) -> Vector3d { return DriftRegressor(in.h_k).col(i); });
}

absl::StatusOr<DeviationSeries> SeriesOf(const SelectedModel& selected,
                                         const DiagnosisContext& context, int gyro) {
  const std::vector<TelemetryFrame> corrected =
      CorrectStarTracker(context.frames(), context.rates(), selected.model.correction);
  auto series = MeasureDeviations(selected.model.config, selected.run.gyros, corrected,
                                  context.rates(), selected.run, {gyro});
  if (!series.ok()) return series.status();
  return std::move(series->front());
}

}  // namespace

DriftBehaviourEvidence CompareDriftBehaviours(const DeviationSeries& series, double random_walk,
                                              double w0_sigma, double step_sigma,
                                              const std::vector<absl::Time>& steps,
                                              SteppedCoefficients stepped) {
  DriftBehaviourEvidence out;
  out.gyro = series.gyro;
  const int n = static_cast<int>(series.y.size());
  if (n < 10) return out;
  const Nuisance held = StepNuisance(series, step_sigma, steps);
  const std::vector<std::vector<Vector2d>>& nuisance = held.columns;
  const VectorXd& nuisance_prior = held.prior;
  const DeviationFilter base_filter(series, random_walk, w0_sigma);
  const double base = SeriesDeviance(base_filter, series.y, nuisance, nuisance_prior);

  // Step: the signature of a drift r(h) from sample j on is S_r(k) - S_r(j) for k >= j, r the
  // case axes e_m (a case-fixed drift) or the stepped coefficients' regressors, eq. (1), (10).
  std::vector<std::vector<Vector2d>> cumulative;
  if (stepped.count > 0) {
    for (int i = stepped.first; i < stepped.first + stepped.count; ++i) {
      cumulative.push_back(CoefficientSignature(series, i));
    }
    out.step_text = absl::StrCat("one step of ", kFixedTerms[stepped.first].symbol);
  } else {
    for (int m = 0; m < 3; ++m) {
      const Vector3d e_m = Vector3d::Unit(m);
      cumulative.push_back(Signature(series, [&](const BasisInputs&) -> Vector3d { return e_m; }));
    }
  }
  const int columns_per_step = static_cast<int>(cumulative.size());
  const int first = std::max(1, n / 20), last = std::min(n - 2, n - n / 20);
  const int stride = std::max(1, (last - first + 1 + kMaxOnsets - 1) / kMaxOnsets);
  std::vector<double> step_deviance;
  double best_step = std::numeric_limits<double>::infinity();
  VectorXd step_prior(static_cast<int>(nuisance.size()) + columns_per_step);
  step_prior << nuisance_prior, VectorXd::Constant(columns_per_step, step_sigma);
  for (int j = first; j <= last; j += stride) {
    std::vector<std::vector<Vector2d>> columns = nuisance;
    for (const std::vector<Vector2d>& s_r : cumulative) {
      std::vector<Vector2d> c(n, Vector2d::Zero());
      for (int k = j; k < n; ++k) c[k] = s_r[k] - s_r[j];
      columns.push_back(std::move(c));
    }
    const double d = SeriesDeviance(base_filter, series.y, columns, step_prior);
    step_deviance.push_back(d);
    if (d < best_step) {
      best_step = d;
      out.step_onset_hours = series.hours[j] - series.hours.front();
    }
  }
  out.step = GridEvidence(base, step_deviance);

  // Walk: the configured intensity raised.
  const double q0 = random_walk > 0.0 ? random_walk : DegPerHourSqrtHourToSi(kWalkFloorDegHSqrtH);
  std::vector<double> walk_deviance;
  double best_walk = std::numeric_limits<double>::infinity();
  for (double factor : kWalkFactors) {
    const DeviationFilter f(series, factor * q0, w0_sigma);
    const double d = SeriesDeviance(f, series.y, nuisance, nuisance_prior);
    walk_deviance.push_back(d);
    if (d < best_walk) {
      best_walk = d;
      out.walk_factor = factor;
    }
  }
  out.walk = GridEvidence(base, walk_deviance);

  // Stationary: a Gauss-Markov drift on top of the configured walk.
  StationaryPoint best;
  out.stationary = GridEvidence(
      base, StationaryDeviances(series, random_walk, w0_sigma, nuisance, nuisance_prior, &best));
  out.correlation_hours = best.correlation_hours;
  out.sigma_deg_h = best.sigma_deg_h;
  return out;
}

ConstantEffectEvidence CompareConstantEffect(
    const DeviationSeries& series, double random_walk, double w0_sigma, double step_sigma,
    const std::vector<absl::Time>& steps, const std::vector<std::vector<Vector2d>>& effect_columns,
    const std::vector<double>& effect_prior) {
  ConstantEffectEvidence out;
  if (series.y.size() < 10 || effect_columns.empty()) return out;
  const Nuisance held = StepNuisance(series, step_sigma, steps);
  std::vector<std::vector<Vector2d>> with = held.columns;
  with.insert(with.end(), effect_columns.begin(), effect_columns.end());
  VectorXd prior(held.prior.size() + static_cast<int>(effect_prior.size()));
  prior << held.prior, Eigen::Map<const VectorXd>(effect_prior.data(),
                                                  static_cast<int>(effect_prior.size()));
  const DeviationFilter base_filter(series, random_walk, w0_sigma);
  const double base = SeriesDeviance(base_filter, series.y, held.columns, held.prior);
  out.effect = base - SeriesDeviance(base_filter, series.y, with, prior);
  out.stationary = GridEvidence(
      base, StationaryDeviances(series, random_walk, w0_sigma, held.columns, held.prior));
  out.on_top = GridEvidence(base, StationaryDeviances(series, random_walk, w0_sigma, with, prior)) -
               out.stationary;
  return out;
}

absl::StatusOr<DriftBehaviourEvidence> CompareDriftBehavioursOf(const SelectedModel& selected,
                                                                const DiagnosisContext& context,
                                                                int gyro,
                                                                SteppedCoefficients stepped) {
  auto series = SeriesOf(selected, context, gyro);
  if (!series.ok()) return series.status();
  const ModelState& model = selected.model;
  return CompareDriftBehaviours(*series, ModelRandomWalk(model, gyro),
                                ModelInitialDriftSigma(model),
                                DegPerHourToRadPerSec(context.options().c_sigma_deg_h),
                                HeldSteps(model, gyro), stepped);
}

absl::StatusOr<CommonWalkCheck> CheckCommonWalk(const SelectedModel& selected,
                                                const DiagnosisContext& context,
                                                const std::vector<int>& gyros) {
  std::vector<std::optional<absl::StatusOr<DriftBehaviourEvidence>>> evidence(gyros.size());
  context.ForEach(static_cast<int>(gyros.size()), [&](int i) {
    evidence[i] = CompareDriftBehavioursOf(selected, context, gyros[i]);
  });
  CommonWalkCheck out;
  std::string per_gyro;
  int weakest = 0;
  double weakest_walk = 0.0;
  for (size_t i = 0; i < gyros.size(); ++i) {
    if (!evidence[i]->ok()) return evidence[i]->status();
    const double walk = (*evidence[i])->walk;
    absl::StrAppend(&per_gyro, absl::StrFormat("%sgyro %d %.1f", i == 0 ? "" : ", ", gyros[i],
                                               walk));
    if (weakest == 0 || walk < weakest_walk) {
      weakest = gyros[i];
      weakest_walk = walk;
    }
  }
  out.fails = !(weakest_walk > 0.0);
  out.note = out.fails
                 ? absl::StrFormat(
                       "a random walk raised in every gyro is not common to them: on gyro %d's "
                       "own deviation the configured walk is more probable than a raised one "
                       "(2 ln B of the raised walk per gyro: %s), so random_walk_drift is not "
                       "taken",
                       weakest, per_gyro)
                 : absl::StrFormat(
                       "common to the gyros: on each gyro's own deviation a raised walk is more "
                       "probable than the configured one (2 ln B per gyro: %s)",
                       per_gyro);
  return out;
}

bool ReturnsToItsMean(const DriftBehaviourEvidence& e, double threshold) {
  return e.stationary > std::max(e.step, e.walk) + kDecisiveDeviance && e.stationary > threshold;
}

double ReturnsToItsMeanBound(const DriftBehaviourEvidence& e) {
  return EvidenceBound(e.stationary - std::max(e.step, e.walk));
}

std::string ReturnsToItsMeanText(const DriftBehaviourEvidence& e) {
  return absl::StrFormat(
      "the drift of gyro %d returns to its mean: a stationary random drift (correlation time "
      "about %.1f h, 1-sigma about %.2f deg/h per axis) describes its deviation with 2 ln B = "
      "%.1f, decisively better than %s (%.1f, best onset %.2f h) or a raised random walk "
      "(%.1f), as a drift switching at random between levels or one driven by a quantity the "
      "telemetry does not carry would",
      e.gyro, e.correlation_hours, e.sigma_deg_h, e.stationary, e.step_text, e.step,
      e.step_onset_hours, e.walk);
}

std::string WandersBeyondTheWalkText(const DriftBehaviourEvidence& e) {
  return absl::StrFormat(
      "the drift of gyro %d wanders beyond the configured random walk: a stationary random "
      "drift (correlation time about %.1f h, 1-sigma about %.2f deg/h per axis; 2 ln B = %.1f) "
      "and a random walk raised %.0f times (2 ln B = %.1f) describe its deviation about equally "
      "well (within %.0f, the ranking's decisive margin), %s decisively less well (%.1f, "
      "best onset %.2f h): whether it returns to its mean is not decided on this recording",
      e.gyro, e.correlation_hours, e.sigma_deg_h, e.stationary, e.walk_factor, e.walk,
      kDecisiveDeviance, e.step_text, e.step, e.step_onset_hours);
}

Mismatch WanderLocation(int gyro, const std::vector<TelemetryFrame>& frames, double p_value) {
  Mismatch where;
  where.found = true;
  where.gyro = gyro;
  where.start = frames.front().time;
  where.end = frames.back().time;
  where.regime = "whole recording";
  where.source = "the gyro's drift over the recording";
  where.p_value = p_value;
  return where;
}

absl::StatusOr<std::vector<Finding>> OtherGyrosReturningToTheirMean(
    const SelectedModel& selected, const DiagnosisContext& context, const std::set<int>& gyros,
    const HeldOutResult& held_out, bool after_findings, int family, double alpha) {
  std::vector<Finding> out;
  const double threshold = EvidenceThreshold(alpha, family);
  for (int gyro : gyros) {
    auto e = CompareDriftBehavioursOf(selected, context, gyro);
    if (!e.ok()) return e.status();
    // Returning to its mean, decisively; else wandering beyond the configured walk (the
    // stationary drift and the raised walk both decisively above one step), undecided between
    // the two; else nothing is said for the gyro.
    std::string why;
    double p_value = 1.0;
    if (ReturnsToItsMean(*e, threshold)) {
      why = ReturnsToItsMeanText(*e);
      p_value = ReturnsToItsMeanBound(*e);
    } else if (std::min(e->stationary, e->walk) > e->step + kDecisiveDeviance &&
               std::max(e->stationary, e->walk) > threshold) {
      why = WandersBeyondTheWalkText(*e);
      p_value = EvidenceBound(std::max(e->stationary, e->walk));
    } else {
      continue;
    }
    absl::StrAppend(&why, "; the open-ended basis's terms for it were left out for that drift, "
                          "and no effect of the library was taken for it");
    std::optional<Unexplained> u =
        FindUnexplained(Mismatch{}, why, gyro, WanderLocation(gyro, context.frames(), p_value),
                        held_out, selected.fit, after_findings, alpha);
    if (u.has_value()) out.push_back(std::move(u->finding));
  }
  return out;
}

absl::StatusOr<ConstantEffectEvidence> CompareConstantEffectOf(const SelectedModel& selected,
                                                               const DiagnosisContext& context,
                                                               const Candidate& candidate) {
  const DiagnoseOptions& opt = context.options();
  const ModelState& model = selected.model;
  const GyroConfig* g = model.config.FindGyro(candidate.gyro);
  if (g == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat("candidate gyro ", candidate.gyro, " is not configured"));
  }
  const std::optional<FreedCoefficients> freed = FreedDriftCoefficients(candidate.effect, opt);
  if (!freed.has_value() && candidate.effect != Effect::kGyroMisalignment) {
    return absl::InvalidArgumentError(
        absl::StrCat(CandidateName(candidate), " is not a constant effect of one gyro"));
  }
  auto series = SeriesOf(selected, context, candidate.gyro);
  if (!series.ok()) return series.status();
  std::vector<std::vector<Vector2d>> columns;
  std::vector<double> prior;
  if (candidate.effect == Effect::kGyroMisalignment) {
    // A small rotation m of the readout: the reading moves by m x h_k.
    for (int m = 0; m < 3; ++m) {
      Eigen::Matrix3d skew = Eigen::Matrix3d::Zero();
      const Vector3d e_m = Vector3d::Unit(m);
      skew << 0.0, -e_m.z(), e_m.y(), e_m.z(), 0.0, -e_m.x(), -e_m.y(), e_m.x(), 0.0;
      columns.push_back(ReadoutSignature(*series, skew));
      prior.push_back(ArcsecToRad(opt.misalignment_sigma_arcsec));
    }
  } else {
    // Only the coefficients the candidate frees: one the model already estimates is in the
    // deviation's model at its calibrated value.
    const DriftVector held = g->model_sigma.AsVector();
    for (int i = freed->first; i < freed->first + freed->count; ++i) {
      if (held(i) > 0.0) continue;
      columns.push_back(CoefficientSignature(*series, i));
      prior.push_back(freed->sigma);
    }
  }
  return CompareConstantEffect(*series, ModelRandomWalk(model, candidate.gyro),
                               ModelInitialDriftSigma(model),
                               DegPerHourToRadPerSec(opt.c_sigma_deg_h),
                               HeldSteps(model, candidate.gyro), columns, prior);
}

}  // namespace esg::estimator::discovery
