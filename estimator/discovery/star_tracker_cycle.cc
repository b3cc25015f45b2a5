#include "estimator/discovery/star_tracker_cycle.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Cholesky"
#include "Eigen/SVD"
#include "absl/strings/str_format.h"
#include "estimator/discovery/basis_stage.h"
#include "estimator/discovery/deviation_filter.h"
#include "estimator/discovery/open_ended.h"
#include "estimator/discovery/sun_terms.h"
#include "estimator/statistics.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Matrix3d;
using Eigen::MatrixXd;
using Eigen::Vector2d;
using Eigen::Vector3d;
using Eigen::VectorXd;

namespace {

constexpr int kCycleCoefficients = 6;  // c_x, c_y, c_z, s_x, s_y, s_z
// A regression step is significant below this chi-square p-value (as the readout group's).
constexpr double kCycleStepP = 0.01;

// The cycle regressed on every gyro's deviation at once: the six coefficients [rad], their
// covariance and 2 ln B against the nuisance groups alone.
struct CycleRegression {
  bool fitted = false;
  VectorXd mean;
  MatrixXd covariance;            // cluster-robust (below)
  MatrixXd model_covariance;      // the regression's posterior, gyros taken as independent
  double evidence = 0.0;
  int samples = 0;
  int clusters = 0;
};

// The star tracker's own noise is one rotation per sample seen by every gyro, the same shape as
// the cycle's signature, so the gyros' rows are not independent as the stacked regression takes
// them: its posterior covariance is too small by up to the number of gyros where the star
// tracker's noise dominates. The covariance reported is the cluster-robust (sandwich) one,
// clusters of kClusterHours of consecutive samples across all gyros (the whitened rows of a
// sample carry noise of the samples just before it too): A M A, A = Sigma / phi the regression's
// inverse Hessian and M = G / (G - 1) sum_c (X_c^T e_c)(X_c^T e_c)^T over the G clusters, e the
// whitened residuals. Right whatever the correlation within a cluster; with independent rows it
// is the posterior covariance to within its sampling scatter.
constexpr double kClusterHours = 0.5;

MatrixXd ClusteredCovariance(const VectorXd& y, const std::vector<const VectorXd*>& X,
                             const RegressionFit& fit, const std::vector<int>& cluster_of_row,
                             int* clusters) {
  const int k = static_cast<int>(X.size());
  VectorXd e = y;
  for (int j = 0; j < k; ++j) e -= fit.mean(j) * *X[j];
  std::vector<VectorXd> u;
  for (int r = 0; r < static_cast<int>(y.size()); ++r) {
    const int c = cluster_of_row[r];
    if (c >= static_cast<int>(u.size())) u.resize(c + 1, VectorXd::Zero(k));
    for (int j = 0; j < k; ++j) u[c](j) += (*X[j])(r) * e(r);
  }
  MatrixXd M = MatrixXd::Zero(k, k);
  int g = 0;
  for (const VectorXd& uc : u) {
    if (uc.isZero(0.0)) continue;
    M += uc * uc.transpose();
    ++g;
  }
  *clusters = g;
  if (g > 1) M *= static_cast<double>(g) / (g - 1);
  const MatrixXd A = fit.covariance / fit.dispersion;
  return A * M * A;
}

CycleRegression RegressCycle(const std::vector<DeviationSeries>& series, const ModelState& model,
                             const std::vector<GyroEstimate>& estimates, double period_s,
                             const OpenEndedOptions& o, double prior_rad) {
  CycleRegression out;
  std::vector<WhitenedSeries> whitened;
  int rows = 0, nuisance = 0;
  std::vector<int> cluster_of_row;
  for (const DeviationSeries& s : series) {
    const Matrix3d C_b_k = ModelMounting_b_k(model.config, estimates, s.gyro);
    whitened.push_back(WhitenSeries(s, ModelRandomWalk(model, s.gyro),
                                    ModelInitialDriftSigma(model), o,
                                    CycleSignatures(s, C_b_k, period_s)));
    rows += static_cast<int>(whitened.back().y_w.size());
    nuisance += static_cast<int>(whitened.back().nuisance_w.size());
    for (size_t r = 0; r < whitened.back().y_w.size(); ++r) {
      const size_t k = std::min(r / 2, s.hours.size() - 1);
      cluster_of_row.push_back(static_cast<int>(s.hours[k] / kClusterHours));
    }
  }
  if (rows == 0) return out;
  // Stacked: the six shared columns, then each gyro's nuisance columns in its own rows.
  VectorXd y(rows);
  std::vector<VectorXd> columns(kCycleCoefficients + nuisance, VectorXd::Zero(rows));
  VectorXd prior(kCycleCoefficients + nuisance);
  prior.head(kCycleCoefficients).setConstant(prior_rad);
  int row = 0, col = kCycleCoefficients;
  for (const WhitenedSeries& w : whitened) {
    const int n = static_cast<int>(w.y_w.size());
    y.segment(row, n) = w.y_w;
    for (int j = 0; j < kCycleCoefficients; ++j) columns[j].segment(row, n) = w.extra_w[j];
    for (size_t j = 0; j < w.nuisance_w.size(); ++j, ++col) {
      columns[col].segment(row, n) = w.nuisance_w[j];
      prior(col) = w.nuisance_prior[j];
    }
    row += n;
  }
  std::vector<const VectorXd*> all, base;
  for (int j = 0; j < static_cast<int>(columns.size()); ++j) {
    all.push_back(&columns[j]);
    if (j >= kCycleCoefficients) base.push_back(&columns[j]);
  }
  const RegressionFit with = FitRegression(y, all, prior);
  const RegressionFit without = FitRegression(y, base, prior.tail(nuisance));
  out.fitted = true;
  out.mean = with.mean.head(kCycleCoefficients);
  out.model_covariance = with.covariance.topLeftCorner(kCycleCoefficients, kCycleCoefficients);
  out.covariance = ClusteredCovariance(y, all, with, cluster_of_row, &out.clusters)
                       .topLeftCorner(kCycleCoefficients, kCycleCoefficients);
  out.evidence = without.deviance - with.deviance;
  out.samples = rows / 2;
  return out;
}

// The largest turn of m(t) = c cos(phi) + s sin(phi): the ellipse's major semi-axis (its length
// and unit axis) from the singular values of [c s].
struct CycleShape {
  double major = 0.0, minor = 0.0;  // [rad]
  Vector3d axis = Vector3d::UnitX();
};
CycleShape Shape(const Vector3d& c, const Vector3d& s) {
  Eigen::Matrix<double, 3, 2> M;
  M.col(0) = c;
  M.col(1) = s;
  const Eigen::JacobiSVD<Eigen::Matrix<double, 3, 2>> svd(M, Eigen::ComputeFullU);
  CycleShape out;
  out.major = svd.singularValues()(0);
  out.minor = svd.singularValues()(1);
  out.axis = svd.matrixU().col(0);
  // The axis's sign: its largest component positive (a rotation about -a is one about a half a
  // period later).
  int i = 0;
  out.axis.cwiseAbs().maxCoeff(&i);
  if (out.axis(i) < 0) out.axis = -out.axis;
  return out;
}

// 1-sigma of the major semi-axis by the delta method on the six coefficients' covariance.
double MajorSigma(const VectorXd& x, const MatrixXd& P) {
  VectorXd gradient(kCycleCoefficients);
  for (int j = 0; j < kCycleCoefficients; ++j) {
    const double h = std::max(1e-12, 1e-6 * x.norm());
    VectorXd up = x, down = x;
    up(j) += h;
    down(j) -= h;
    gradient(j) = (Shape(up.head<3>(), up.tail<3>()).major -
                   Shape(down.head<3>(), down.tail<3>()).major) /
                  (2.0 * h);
  }
  return std::sqrt(std::max(0.0, gradient.dot(P * gradient)));
}

void AddCycleParameters(const StarTrackerCorrection& c, const MatrixXd& P,
                        std::vector<Parameter>& out) {
  const double arcsec = RadToArcsec(1.0);
  Vector3d cos_sigma, sin_sigma;
  for (int i = 0; i < 3; ++i) {
    cos_sigma(i) = std::sqrt(std::max(0.0, P(i, i)));
    sin_sigma(i) = std::sqrt(std::max(0.0, P(3 + i, 3 + i)));
  }
  AddVectorParameters("cycleCosArcsec", c.cycle_cos_b, cos_sigma, arcsec, "arcsec", out);
  AddVectorParameters("cycleSinArcsec", c.cycle_sin_b, sin_sigma, arcsec, "arcsec", out);
  VectorXd x(kCycleCoefficients);
  x << c.cycle_cos_b, c.cycle_sin_b;
  const CycleShape shape = Shape(c.cycle_cos_b, c.cycle_sin_b);
  out.push_back({"cycleAmplitudeArcsec", shape.major * arcsec, MajorSigma(x, P) * arcsec,
                 "arcsec"});
  out.push_back({"cycleMinorArcsec", shape.minor * arcsec, 0.0, "arcsec"});
  AddVectorParameters("cycleAxis", shape.axis, Vector3d::Zero(), 1.0, "1", out);
  out.push_back({"cyclePeriodMin", c.cycle_period_s / 60.0, 0.0, "min"});
}

}  // namespace

std::vector<std::vector<Vector2d>> CycleSignatures(const DeviationSeries& series,
                                                   const Matrix3d& C_b_k, double period_s) {
  std::vector<std::vector<Vector2d>> out(kCycleCoefficients);
  const size_t n = series.y.size();
  const Matrix3d C_k_b = C_b_k.transpose();
  for (int j = 0; j < kCycleCoefficients; ++j) out[j].reserve(n);
  std::array<Vector3d, kCycleCoefficients> first;
  for (size_t k = 0; k < n; ++k) {
    const double phi = 2.0 * kPi * series.hours[k] * 3600.0 / period_s;
    // C_in_b e_i = C_in_k C_k_b e_i, and (C_in_k a) x (C_in_k h_k) = C_in_k (a x h_k).
    const Matrix3d C_in_k = series.C_k_in[k].transpose();
    for (int j = 0; j < kCycleCoefficients; ++j) {
      const double f = j < 3 ? std::cos(phi) : std::sin(phi);
      const Vector3d a_k = C_k_b.col(j % 3) * f;
      const Vector3d s_in = C_in_k * a_k.cross(series.h_k[k]);
      if (k == 0) first[j] = s_in;
      const Vector3d d = s_in - first[j];
      out[j].emplace_back(series.u1.dot(d), series.u2.dot(d));
    }
  }
  return out;
}

absl::Status FitStarTrackerCycle(const Candidate& candidate, const FitContext& ctx,
                                 CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  const ModelState& model = *ctx.model;
  const double period_s = CandidateOrbitalPeriod(ctx);
  if (!(period_s > 0.0)) {
    fit.notes.push_back(
        "no orbital period is known (no --orbital-period, no orbit, no orbital-orientation span "
        "in the recording): a star-tracker misalignment cycling with the orbit is not tried");
    return absl::OkStatus();
  }
  const OpenEndedOptions o = ModelOpenEndedOptions(model, opt);
  const double prior_rad = ArcsecToRad(opt.misalignment_sigma_arcsec);
  StarTrackerCorrection& correction = fit.model.correction;
  correction.cycle_period_s = period_s;
  correction.cycle_epoch = ctx.frames->front().time;
  const ModelRun* from_run = ctx.model_run;
  CycleRegression regression;
  double first_evidence = 0.0;
  // The frames as the model with the cycle so far corrects them (the first: the context's
  // model); the cycle changes the star tracker's correction only, never the configuration.
  std::vector<TelemetryFrame> corrected =
      CorrectStarTracker(*ctx.frames, *ctx.rates, model.correction);
  for (int iteration = 0; iteration < kCycleIterations; ++iteration) {
    auto series = MeasureDeviations(model.config, from_run->gyros, corrected, *ctx.rates,
                                    *from_run, ctx.gyros);
    if (!series.ok()) return series.status();
    regression = RegressCycle(*series, model, from_run->gyros, period_s, o, prior_rad);
    if (!regression.fitted) return absl::OkStatus();
    if (iteration == 0) first_evidence = regression.evidence;
    correction.cycle_cos_b += regression.mean.head<3>();
    correction.cycle_sin_b += regression.mean.tail<3>();
    corrected = CorrectStarTracker(*ctx.frames, *ctx.rates, correction);
    auto run = RunModel(fit.model.config, fit.model.options, corrected);
    ++fit.runs;
    if (!run.ok()) return run.status();
    fit.run = std::move(*run);
    from_run = &fit.run;
    const double chi2 =
        regression.mean.dot(regression.covariance.ldlt().solve(regression.mean));
    if (!(ChiSquareSurvival(chi2, kCycleCoefficients) < kCycleStepP)) break;
  }
  VectorXd x(kCycleCoefficients);
  x << correction.cycle_cos_b, correction.cycle_sin_b;
  fit.parameters = kCycleCoefficients;
  fit.occam =
      LaplaceOccam(x, regression.covariance, VectorXd::Constant(kCycleCoefficients, prior_rad));
  AddCycleParameters(correction, regression.covariance, fit.fitted);
  fit.notes.push_back(absl::StrFormat(
      "every gyro's deviation from the model regressed at once on the star tracker's rotation "
      "cycling with the orbit (period %.1f min; %d samples of %zu gyros; docs/discovery.md, "
      "\"The star tracker's side\"): 2 ln B = %.1f; held at the fitted rotation (%d filter "
      "run%s), the filter's -2 log L is the candidate's, less Laplace's Occam term %.1f of the "
      "six coefficients; sigmas cluster-robust over %d half-hour blocks (the star tracker's "
      "noise is common to the gyros), %.2f times the regression's own",
      period_s / 60.0, regression.samples, ctx.gyros.size(), first_evidence, fit.runs,
      fit.runs == 1 ? "" : "s", fit.occam, regression.clusters,
      std::sqrt(regression.covariance.trace() / regression.model_covariance.trace())));
  return absl::OkStatus();
}

}  // namespace esg::estimator::discovery
