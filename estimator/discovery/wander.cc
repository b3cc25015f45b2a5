#include "estimator/discovery/wander.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "estimator/discovery/deviation_filter.h"
#include "estimator/discovery/statistics.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::VectorXd;

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

}  // namespace

DriftBehaviourEvidence CompareDriftBehaviours(const DeviationSeries& series, double random_walk,
                                              double w0_sigma, double step_sigma,
                                              const std::vector<absl::Time>& steps) {
  DriftBehaviourEvidence out;
  out.gyro = series.gyro;
  const int n = static_cast<int>(series.y.size());
  if (n < 10) return out;
  // Nuisance: a case-fixed drift before each step the model holds (open_ended.h does the same).
  std::vector<std::vector<Vector2d>> nuisance;
  for (const absl::Time& t : steps) {
    for (int m = 0; m < 3; ++m) {
      const Vector3d e_m = Vector3d::Unit(m);
      nuisance.push_back(Signature(series, [&](const BasisInputs& in) -> Vector3d {
        return in.time < t ? e_m : Vector3d::Zero();
      }));
    }
  }
  const VectorXd nuisance_prior = VectorXd::Constant(static_cast<int>(nuisance.size()), step_sigma);
  const DeviationFilter base_filter(series, random_walk, w0_sigma);
  const double base = SeriesDeviance(base_filter, series.y, nuisance, nuisance_prior);

  // Step: the signature of a drift e_m from sample j on is S_m(k) - S_m(j) for k >= j.
  std::array<std::vector<Vector2d>, 3> cumulative;
  for (int m = 0; m < 3; ++m) {
    const Vector3d e_m = Vector3d::Unit(m);
    cumulative[m] = Signature(series, [&](const BasisInputs&) -> Vector3d { return e_m; });
  }
  const int first = std::max(1, n / 20), last = std::min(n - 2, n - n / 20);
  const int stride = std::max(1, (last - first + 1 + kMaxOnsets - 1) / kMaxOnsets);
  std::vector<double> step_deviance;
  double best_step = std::numeric_limits<double>::infinity();
  VectorXd step_prior(static_cast<int>(nuisance.size()) + 3);
  step_prior << nuisance_prior, VectorXd::Constant(3, step_sigma);
  for (int j = first; j <= last; j += stride) {
    std::vector<std::vector<Vector2d>> columns = nuisance;
    for (int m = 0; m < 3; ++m) {
      std::vector<Vector2d> c(n, Vector2d::Zero());
      for (int k = j; k < n; ++k) c[k] = cumulative[m][k] - cumulative[m][j];
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
  std::vector<double> stationary_deviance;
  double best_stationary = std::numeric_limits<double>::infinity();
  for (double tau_h : kCorrelationHours) {
    for (double sigma_deg_h : kStationarySigmaDegH) {
      const StationaryDrift g{DegPerHourToRadPerSec(sigma_deg_h), 3600.0 * tau_h};
      const DeviationFilter f(series, random_walk, w0_sigma, 1e-2, g);
      const double d = SeriesDeviance(f, series.y, nuisance, nuisance_prior);
      stationary_deviance.push_back(d);
      if (d < best_stationary) {
        best_stationary = d;
        out.correlation_hours = tau_h;
        out.sigma_deg_h = sigma_deg_h;
      }
    }
  }
  out.stationary = GridEvidence(base, stationary_deviance);
  return out;
}

absl::StatusOr<DriftBehaviourEvidence> CompareDriftBehavioursOf(const SelectedModel& selected,
                                                                const DiagnosisContext& context,
                                                                int gyro) {
  const ModelState& model = selected.model;
  const std::vector<TelemetryFrame> corrected =
      CorrectStarTracker(context.frames(), context.rates(), model.correction);
  auto series = MeasureDeviations(model.config, selected.run.gyros, corrected, context.rates(),
                                  selected.run, {gyro});
  if (!series.ok()) return series.status();
  std::vector<absl::Time> steps;
  for (const SessionOptions::CoefficientRelease& r : model.options.coefficient_releases) {
    if (!r.misalignment && r.gyro_id == gyro) steps.push_back(r.time);
  }
  return CompareDriftBehaviours(series->front(), ModelRandomWalk(model, gyro),
                                ModelInitialDriftSigma(model),
                                DegPerHourToRadPerSec(context.options().c_sigma_deg_h), steps);
}

}  // namespace esg::estimator::discovery
