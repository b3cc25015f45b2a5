#include "estimator/discovery/candidates.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <iterator>
#include <map>
#include <utility>
#include <vector>

#include "Eigen/Eigenvalues"
#include "Eigen/LU"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/calibration_model.h"
#include "estimator/discovery/channel_candidate.h"
#include "estimator/discovery/readout_candidate.h"
#include "estimator/discovery/star_tracker_cycle.h"
#include "estimator/discovery/sun_terms.h"
#include "estimator/statistics.h"
#include "estimator/discovery/time_behaviour.h"
#include "estimator/discovery/turning_displacement.h"
#include "estimator/drift_model.h"
#include "estimator/model_terms.h"
#include "estimator/rotation.h"
#include "estimator/spacecraft_config.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Vector3d;

namespace {

// The collinear fit of a rotor displacement (eq. (8)-(10)): C1 = a lambda, C2 = b lambda, the
// unit line lambda and (a, b) by generalised least squares under the full 6 x 6 covariance of
// (C1, C2) (coefficients held, with 0 variance, are left out); chi2 the minimum of r^T Sigma^-1 r
// over lambda and (a, b), on dof = (free components) - 4 degrees of freedom.
// The sigmas are the inverse Fisher information of (two angles of lambda in its tangent plane, a,
// b) at the minimum; lambda_sigma is the root of the two angles' summed variances (rad), the RMS
// angle between the fitted and the true line. determined is false where that information is
// singular (a and b both 0, or too few free components): then no sigma is stated.
struct CollinearFit {
  Vector3d lambda = Vector3d::UnitX();
  double a = 0.0, b = 0.0, chi2 = 0.0;
  int dof = 0;
  bool determined = false;
  double lambda_sigma = 0.0;
  Eigen::Matrix2d ab_covariance = Eigen::Matrix2d::Zero();
};

CollinearFit FitCollinear(const Vector3d& C1, const Vector3d& C2,
                          const Eigen::Matrix<double, 6, 6>& covariance, const Vector3d& start) {
  Eigen::Matrix<double, 6, 1> c;
  c << C1, C2;
  std::vector<int> free;
  for (int i = 0; i < 6; ++i) {
    if (covariance(i, i) > 0.0) free.push_back(i);
  }
  const int m = static_cast<int>(free.size());
  Eigen::MatrixXd sub(m, m);
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j < m; ++j) sub(i, j) = covariance(free[i], free[j]);
  }
  Eigen::Matrix<double, 6, 6> W = Eigen::Matrix<double, 6, 6>::Zero();  // Sigma^-1 on the free
  if (m > 0) {
    const Eigen::MatrixXd inv = sub.ldlt().solve(Eigen::MatrixXd::Identity(m, m));
    for (int i = 0; i < m; ++i) {
      for (int j = 0; j < m; ++j) W(free[i], free[j]) = inv(i, j);
    }
  }
  auto at = [&](const Vector3d& lambda, double& a, double& b) {
    Eigen::Matrix<double, 6, 2> A = Eigen::Matrix<double, 6, 2>::Zero();
    A.block<3, 1>(0, 0) = lambda;
    A.block<3, 1>(3, 1) = lambda;
    const Eigen::Matrix2d N = A.transpose() * W * A;
    const Eigen::Vector2d g = A.transpose() * W * c;
    const Eigen::Vector2d x = N.completeOrthogonalDecomposition().solve(g);
    a = x(0);
    b = x(1);
    return c.dot(W * c) - x.dot(g);
  };
  auto unit = [](double theta, double phi) {
    return Vector3d(std::sin(theta) * std::cos(phi), std::sin(theta) * std::sin(phi),
                    std::cos(theta));
  };
  // Start: the dominant direction and a Fibonacci lattice of the hemisphere; then a pattern search
  // in the two angles.
  double a = 0.0, b = 0.0;
  double best = at(start.normalized(), a, b);
  double theta = std::acos(std::clamp(start.normalized().z(), -1.0, 1.0));
  double phi = std::atan2(start.y(), start.x());
  constexpr int kLattice = 2000;
  const double golden = M_PI * (3.0 - std::sqrt(5.0));
  for (int k = 0; k < kLattice; ++k) {
    const double z = 1.0 - (k + 0.5) / kLattice;  // (0, 1]: one hemisphere (a line's two signs)
    const double t = std::acos(z), p = golden * k;
    const double v = at(unit(t, p), a, b);
    if (v < best) {
      best = v;
      theta = t;
      phi = p;
    }
  }
  for (double step = 0.02; step > 1e-7;) {
    bool moved = false;
    for (const auto& [dt, dp] : {std::pair{step, 0.0}, std::pair{-step, 0.0}, std::pair{0.0, step},
                                 std::pair{0.0, -step}}) {
      const double v = at(unit(theta + dt, phi + dp), a, b);
      if (v < best) {
        best = v;
        theta += dt;
        phi += dp;
        moved = true;
      }
    }
    if (!moved) step *= 0.5;
  }
  CollinearFit out;
  out.lambda = unit(theta, phi);
  out.chi2 = std::max(0.0, at(out.lambda, out.a, out.b));
  if (out.lambda.dot(C1) < 0.0) {
    out.lambda = -out.lambda;
    out.a = -out.a;
    out.b = -out.b;
  }
  out.dof = std::max(0, m - 4);
  // Fisher information of (alpha, beta, a, b), lambda(alpha, beta) = normalised(lambda + alpha u
  // + beta v) with u, v orthonormal across lambda: d[C1; C2] = [a u, a v, lambda, 0; b u, b v, 0,
  // lambda].
  const Vector3d u = out.lambda.unitOrthogonal(), v = out.lambda.cross(u);
  Eigen::Matrix<double, 6, 4> J = Eigen::Matrix<double, 6, 4>::Zero();
  J.block<3, 1>(0, 0) = out.a * u;
  J.block<3, 1>(3, 0) = out.b * u;
  J.block<3, 1>(0, 1) = out.a * v;
  J.block<3, 1>(3, 1) = out.b * v;
  J.block<3, 1>(0, 2) = out.lambda;
  J.block<3, 1>(3, 3) = out.lambda;
  const Eigen::Matrix4d information = J.transpose() * W * J;
  const Eigen::FullPivLU<Eigen::Matrix4d> lu(information);
  if (m >= 4 && lu.rank() == 4) {
    const Eigen::Matrix4d parameters = lu.inverse();
    out.determined = true;
    out.lambda_sigma = std::sqrt(std::max(0.0, parameters(0, 0) + parameters(1, 1)));
    out.ab_covariance = parameters.block<2, 2>(2, 2);
  }
  return out;
}

constexpr int kRandomWalkGridPoints = 5;  // factors 2, 4, ... 32 above the configured intensity
// Reference intensity when the configuration has none: a tenth of the paper-era ESG's
// residual-drift instability [deg/h/sqrt(h)].
constexpr double kRandomWalkFloorDegHSqrtH = 0.0005;

// Every fixed term the effect frees is already free (sigma > 0).
bool AllFree(const DriftVector& sigma, Effect effect) {
  const auto [first, count] = FixedTermsOf(effect);
  for (int i = first; i < first + count; ++i) {
    if (!(sigma(i) > 0.0)) return false;
  }
  return true;
}

double DegH(double x) { return RadPerSecToDegPerHour(x); }

// A gyro's suspension offset voltages [mV, case axes], the frames' finite readings in order.
std::vector<Vector3d> OffsetVoltagesMv(const std::vector<TelemetryFrame>& frames, int gyro) {
  std::vector<Vector3d> out;
  for (const TelemetryFrame& f : frames) {
    const auto& r = f.gyros[gyro - 1];
    if (r.has_value() && r->u_k_mv.has_value() && r->u_k_mv->allFinite()) out.push_back(*r->u_k_mv);
  }
  return out;
}

// eq. (3) per suspension axis: the rotor displacement [um] of offset voltages [mV].
Vector3d DisplacementUm(const SuspensionConfig& s, const Vector3d& u_mv) {
  Vector3d d;
  for (int i = 0; i < 3; ++i) {
    d(i) = DisplacementFromOffsetVoltage(u_mv(i) * kVoltsPerMv, s.amplifier_gain,
                                         s.reference_voltage, s.gap) /
           kMetresPerUm;
  }
  return d;
}

bool Effective(const std::vector<Effect>& effects, Effect e) {
  return effects.empty() || std::find(effects.begin(), effects.end(), e) != effects.end();
}

}  // namespace

LatencyEstimate LatencyFromRates(const std::vector<TelemetryFrame>& frames, const BodyRates& rates,
                                 const SpacecraftConfig& config) {
  // Step i -> i+1: the star tracker's rotation r_st = Log(conj(q_st,i) q_st,i+1) spans
  // [t_i - tau, t_i+1 - tau], the gyros' r_g (TRIAD on the spin axes) spans [t_i, t_i+1]; to first
  // order r_st - r_g = -tau (w(t_i+1) - w(t_i)), body axes. Weighted by the star tracker's noise
  // (twice its variance per step), robust to outliers (5 MAD), least squares in tau.
  LatencyEstimate out;
  const Vector3d noise = config.star_tracker.noise.cwiseMax(ArcsecToRad(0.1));
  const Vector3d weight = (2.0 * noise.cwiseAbs2()).cwiseInverse();
  std::vector<double> e, a, w;
  for (size_t i = 0; i + 1 < frames.size(); ++i) {
    const auto& s0 = frames[i].star_tracker;
    const auto& s1 = frames[i + 1].star_tracker;
    if (!s0 || !s1 || !s0->valid || !s1->valid) continue;
    if (!rates.gyro_valid[i] || !rates.gyro_valid[i + 1] || !rates.gyro_step_valid[i]) continue;
    const double dt = absl::ToDoubleSeconds(frames[i + 1].time - frames[i].time);
    if (!(dt > 0)) continue;
    const Vector3d r_st =
        LogQuaternion(s0->q_in_b.normalized().conjugate() * s1->q_in_b.normalized());
    const Vector3d& r_g = rates.gyro_step[i];
    const Vector3d dw = rates.gyro[i + 1] - rates.gyro[i];
    for (int k = 0; k < 3; ++k) {
      e.push_back(r_st(k) - r_g(k));
      a.push_back(-dw(k));
      w.push_back(weight(k));
    }
  }
  auto solve = [&](const std::vector<bool>& use, double& tau, double& info) {
    double num = 0.0, den = 0.0;
    for (size_t j = 0; j < e.size(); ++j) {
      if (!use[j]) continue;
      num += a[j] * w[j] * e[j];
      den += a[j] * w[j] * a[j];
    }
    info = den;
    tau = den > 0 ? num / den : 0.0;
  };
  std::vector<bool> use(e.size(), true);
  double tau = 0.0, info = 0.0;
  solve(use, tau, info);
  for (int iteration = 0; iteration < 2; ++iteration) {
    std::vector<double> r(e.size());
    for (size_t j = 0; j < e.size(); ++j) r[j] = std::abs(e[j] - a[j] * tau) * std::sqrt(w[j]);
    std::vector<double> sorted = r;
    if (sorted.empty()) break;
    std::nth_element(sorted.begin(), sorted.begin() + sorted.size() / 2, sorted.end());
    const double mad = 1.4826 * sorted[sorted.size() / 2];
    for (size_t j = 0; j < e.size(); ++j) use[j] = r[j] <= 5.0 * std::max(mad, 1e-12);
    solve(use, tau, info);
  }
  // Residual scale for the sigma (the noise weights assume the configured noise).
  double chi2 = 0.0;
  int n = 0;
  for (size_t j = 0; j < e.size(); ++j) {
    if (!use[j]) continue;
    chi2 += std::pow(e[j] - a[j] * tau, 2) * w[j];
    ++n;
  }
  out.samples = n / 3;
  if (!(info > 0) || n < 6) return out;
  const double scale = std::sqrt(std::max(1.0, chi2 / std::max(1, n - 1)));
  out.latency = tau;
  out.sigma = scale / std::sqrt(info);
  // Observable when the rate changes determine tau to better than 0.5 s.
  out.observable = out.sigma < 0.5;
  return out;
}

std::vector<Candidate> ListCandidates(const ModelState& model, const std::vector<int>& gyros,
                                      const std::vector<Effect>& effects, bool with_orbit) {
  std::vector<Candidate> out;
  auto added = [&](const std::string& name) {
    return std::find(model.added.begin(), model.added.end(), name) != model.added.end();
  };
  for (int id : gyros) {
    const GyroConfig* g = model.config.FindGyro(id);
    if (g == nullptr) continue;
    const DriftVector sigma = g->model_sigma.AsVector();
    // A drift effect of the library whose fixed terms are not all free yet.
    auto lacks = [&](Effect e) { return Effective(effects, e) && !AllFree(sigma, e); };
    if (lacks(Effect::kRotorDisplacement)) out.push_back({Effect::kRotorDisplacement, id});
    if (lacks(Effect::kFourthHarmonic)) out.push_back({Effect::kFourthHarmonic, id});
    if (lacks(Effect::kUnequalStiffness)) out.push_back({Effect::kUnequalStiffness, id});
    if (Effective(effects, Effect::kGyroMisalignment) && !(g->misalignment_sigma > 0.0)) {
      out.push_back({Effect::kGyroMisalignment, id});
    }
    if (Effective(effects, Effect::kReadoutDistortion) &&
        !added(CandidateName({Effect::kReadoutDistortion, id}))) {
      out.push_back({Effect::kReadoutDistortion, id});
    }
    if (Effective(effects, Effect::kSunDrift) &&
        static_cast<int>(HeldSunFaces(model, id).size()) < SunFamilies(with_orbit)) {
      out.push_back({Effect::kSunDrift, id});
    }
    // A drift that follows each declared channel (channel_candidate.h); none without channels.
    if (Effective(effects, Effect::kChannelDrift)) {
      for (const std::string& channel : CandidateChannels(model.config)) {
        const Candidate c{Effect::kChannelDrift, id, channel};
        if (!added(CandidateName(c))) out.push_back(c);
      }
    }
  }
  // A rotation common to every gyro is already in the model when every running gyro's
  // misalignment is estimated.
  bool any_fixed_mounting = false;
  for (int id : gyros) {
    const GyroConfig* g = model.config.FindGyro(id);
    if (g != nullptr && !(g->misalignment_sigma > 0.0)) any_fixed_mounting = true;
  }
  if (Effective(effects, Effect::kStarTrackerMisalignment) && any_fixed_mounting &&
      !added(EffectId(Effect::kStarTrackerMisalignment))) {
    out.push_back({Effect::kStarTrackerMisalignment, 0});
  }
  if (Effective(effects, Effect::kStarTrackerLatency) &&
      !added(EffectId(Effect::kStarTrackerLatency))) {
    out.push_back({Effect::kStarTrackerLatency, 0});
  }
  if (Effective(effects, Effect::kStarTrackerCycle) &&
      !added(EffectId(Effect::kStarTrackerCycle))) {
    out.push_back({Effect::kStarTrackerCycle, 0});
  }
  // Time behaviour: a drift switched on during the recording, per gyro; a random walk raised in
  // every gyro or in one (once one is raised, no other is offered).
  for (int id : gyros) {
    if (model.config.FindGyro(id) == nullptr) continue;
    if (Effective(effects, Effect::kDriftStep) &&
        !added(CandidateName({Effect::kDriftStep, id}))) {
      out.push_back({Effect::kDriftStep, id});
    }
    if (Effective(effects, Effect::kWarmUp) && !added(CandidateName({Effect::kWarmUp, id}))) {
      out.push_back({Effect::kWarmUp, id});
    }
    if (Effective(effects, Effect::kCoefficientStep) &&
        !added(CandidateName({Effect::kCoefficientStep, id}))) {
      out.push_back({Effect::kCoefficientStep, id});
    }
    if (Effective(effects, Effect::kTransient) &&
        !added(CandidateName({Effect::kTransient, id}))) {
      out.push_back({Effect::kTransient, id});
    }
    if (Effective(effects, Effect::kTurningDisplacement) &&
        !added(CandidateName({Effect::kTurningDisplacement, id}))) {
      out.push_back({Effect::kTurningDisplacement, id});
    }
  }
  const bool walk_added = std::any_of(model.added.begin(), model.added.end(), [](const auto& a) {
    return a.rfind(EffectId(Effect::kRandomWalkDrift), 0) == 0;
  });
  if (Effective(effects, Effect::kRandomWalkDrift) && model.options.model.random_walk &&
      !walk_added) {
    out.push_back({Effect::kRandomWalkDrift, 0});
    for (int id : gyros) {
      if (model.config.FindGyro(id) != nullptr) out.push_back({Effect::kRandomWalkDrift, id});
    }
  }
  return out;
}

void DescribeRotorDisplacement(const SpacecraftConfig& config,
                               const std::vector<TelemetryFrame>& frames, int gyro,
                               CandidateFit& fit) {
  const GyroEstimate* e = FindEstimate(fit.run.gyros, gyro);
  if (e == nullptr) return;
  const Vector3d C1 = e->coefficients.C1, C2 = e->coefficients.C2;
  const Vector3d s1 = e->sigma.C1, s2 = e->sigma.C2;
  // eq. (8)-(10): C1 = (C10 + C20) lambda, C2 = -5 C20 lambda. lambda: dominant direction of the
  // pair, sign with C1 . lambda > 0.
  const Eigen::Matrix3d M = C1 * C1.transpose() + C2 * C2.transpose();
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eig(M);
  // The covariance of (C1, C2): the run's full one, or the sigmas alone when it has none.
  Eigen::Matrix<double, 6, 6> covariance = Eigen::Matrix<double, 6, 6>::Zero();
  const auto found = std::find_if(fit.run.gyros.begin(), fit.run.gyros.end(),
                                  [&](const GyroEstimate& g) { return g.id == gyro; });
  const size_t at = static_cast<size_t>(std::distance(fit.run.gyros.begin(), found));
  if (at < fit.run.coefficient_covariance.size() &&
      fit.run.coefficient_covariance[at].rows() == kNumDriftCoefficients) {
    covariance = fit.run.coefficient_covariance[at].block<6, 6>(kThetaC1, kThetaC1);
  } else {
    covariance.diagonal() << s1.cwiseAbs2(), s2.cwiseAbs2();
  }
  // Collinearity test: chi-square of (C1, C2) off the best common line under their full
  // covariance, with 6 - 4 = 2 degrees of freedom (lambda: 2, C10 + C20 and C20: 2).
  const CollinearFit line = FitCollinear(C1, C2, covariance, eig.eigenvectors().col(2));
  const Vector3d lambda = line.lambda;
  const double a = line.a;  // C10 + C20
  const double b = line.b;  // -5 C20
  const double C20 = -b / 5.0, C10 = a - C20;
  const double cos_line =
      (C1.norm() > 0 && C2.norm() > 0) ? std::abs(C1.dot(C2)) / (C1.norm() * C2.norm()) : 1.0;
  const double line_angle_deg = RadToDeg(std::acos(std::clamp(cos_line, -1.0, 1.0)));
  const double chi2 = line.chi2;
  const double p_collinear = line.dof > 0 ? ChiSquareSurvival(chi2, line.dof) : 1.0;
  // (C10, C20) = T (a, b), T = [1, 1/5; 0, -1/5]: their covariance is T Cov(a, b) T^T.
  Eigen::Matrix2d T;
  T << 1.0, 0.2, 0.0, -0.2;
  const Eigen::Matrix2d c_covariance = T * line.ab_covariance * T.transpose();
  const double sigma_C10 = line.determined ? std::sqrt(std::max(0.0, c_covariance(0, 0))) : 0.0;
  const double sigma_C20 = line.determined ? std::sqrt(std::max(0.0, c_covariance(1, 1))) : 0.0;
  fit.fitted.push_back({"lineAngleDeg", line_angle_deg, 0.0, "deg"});
  fit.fitted.push_back({"c10DegH", DegH(C10), DegH(sigma_C10), "deg/h"});
  fit.fitted.push_back({"c20DegH", DegH(C20), DegH(sigma_C20), "deg/h"});
  AddVectorParameters("lambda", lambda, Vector3d::Zero(), 1.0, "1", fit.fitted);
  if (line.determined) {
    fit.fitted.push_back({"lambdaSigmaDeg", RadToDeg(line.lambda_sigma), 0.0, "deg"});
  }
  // One physical term (docs/discovery.md, "One physical term, one finding"): the six
  // coefficients are one displacement when the collinearity is not rejected at kCollinearityP.
  fit.fitted.push_back({"collinearityChi2", chi2, 0.0, "1"});
  fit.fitted.push_back({"collinearityDof", static_cast<double>(line.dof), 0.0, "1"});
  fit.fitted.push_back({"collinearityP", p_collinear, 0.0, "1"});
  fit.notes.push_back(absl::StrFormat(
      "C1 and C2 lie %.1f deg apart as lines (C1.C2 %s 0); a displaced rotor makes them collinear "
      "(eq. (8)-(10)): collinear fit C10 = %.4f deg/h, C20 = %.4f deg/h along lambda = [%.2f %.2f "
      "%.2f] "
      "(case axes), off-line residual chi2 = %.1f on %d dof under the full covariance of C1 and "
      "C2, p = %.2g",
      line_angle_deg, C1.dot(C2) < 0 ? "<" : ">=", DegH(C10), DegH(C20), lambda.x(), lambda.y(),
      lambda.z(), chi2, line.dof, p_collinear));
  // eq. (3): displacement from the mean suspension offset voltages.
  const std::vector<Vector3d> u_mv = OffsetVoltagesMv(frames, gyro);
  const int n = static_cast<int>(u_mv.size());
  Vector3d sum = Vector3d::Zero(), sum2 = Vector3d::Zero();
  for (const Vector3d& u : u_mv) {
    sum += u;
    sum2 += u.cwiseAbs2();
  }
  if (n < 2) {
    fit.notes.push_back(
        "no suspension offset voltages in the recording: displacement not checked against eq. (3)");
    return;
  }
  const Vector3d mean_mv = sum / n;
  const Vector3d sd_mv = (sum2 / n - mean_mv.cwiseAbs2()).cwiseMax(0.0).cwiseSqrt();
  DescribeVoltageTrend(config, frames, gyro, fit);
  const SuspensionConfig& s = config.suspension;
  const Vector3d displacement_um = DisplacementUm(s, mean_mv);
  AddVectorParameters("offsetVoltageMv", mean_mv, sd_mv / std::sqrt(static_cast<double>(n)), 1.0,
                      "mV", fit.fitted);
  AddVectorParameters("displacementUm", displacement_um, Vector3d::Zero(), 1.0, "um", fit.fitted);
  const double size_um = displacement_um.norm();
  fit.fitted.push_back({"displacementSizeUm", size_um, 0.0, "um"});
  if (size_um > 0.0) {
    const double cos_d = std::abs(displacement_um.normalized().dot(lambda));
    const double angle_deg = RadToDeg(std::acos(std::clamp(cos_d, -1.0, 1.0)));
    fit.fitted.push_back({"lambdaToVoltageAngleDeg", angle_deg, 0.0, "deg"});
    fit.notes.push_back(absl::StrFormat(
        "mean suspension offset voltages [%.1f %.1f %.1f] mV give by eq. (3) a rotor displacement "
        "of [%.2f %.2f %.2f] um (|%.2f| um, k = %.0f, U0 = %.0f V, d0 = %.0f um), %.1f deg from "
        "the "
        "fitted direction lambda",
        mean_mv.x(), mean_mv.y(), mean_mv.z(), displacement_um.x(), displacement_um.y(),
        displacement_um.z(), size_um, s.amplifier_gain, s.reference_voltage, s.gap / kMetresPerUm,
        angle_deg));
  }
}

VoltageAgreement CheckDisplacementAgainstVoltages(const SpacecraftConfig& config,
                                                  const std::vector<TelemetryFrame>& frames,
                                                  int gyro, const Vector3d& C1_k_rad_s) {
  VoltageAgreement out;
  out.drift_implied_um = DegH(C1_k_rad_s.norm()) / kC1DegHPerUm;
  out.floor_um = out.drift_implied_um / kSensitivitySpread;
  // eq. (3) per sample, in um, in the order of the recording.
  std::vector<Vector3d> displacement_um;
  for (const Vector3d& u : OffsetVoltagesMv(frames, gyro)) {
    displacement_um.push_back(DisplacementUm(config.suspension, u));
  }
  constexpr int kBatches = 16;
  const int n = static_cast<int>(displacement_um.size());
  if (n < 2 * kBatches) {
    out.note = absl::StrFormat(
        "gyro %d's suspension offset voltages: %d samples, too few to check the displacement "
        "against eq. (3)",
        gyro, n);
    return out;
  }
  Vector3d sum_means = Vector3d::Zero(), sum_means2 = Vector3d::Zero();
  for (int b = 0; b < kBatches; ++b) {
    const int first = n * b / kBatches, last = n * (b + 1) / kBatches;
    Vector3d m = Vector3d::Zero();
    for (int i = first; i < last; ++i) m += displacement_um[i];
    m /= (last - first);
    sum_means += m;
    sum_means2 += m.cwiseAbs2();
  }
  const Vector3d mean = sum_means / kBatches;
  const Vector3d var_means =
      ((sum_means2 - kBatches * mean.cwiseAbs2()) / (kBatches - 1)).cwiseMax(0.0);
  out.voltage_um = mean.norm();
  out.voltage_sigma_um = std::sqrt(var_means.sum() / kBatches);
  out.informative = kVoltageZ * out.voltage_sigma_um < out.floor_um;
  out.agrees = !out.informative || out.voltage_um + kVoltageZ * out.voltage_sigma_um >= out.floor_um;
  out.note = absl::StrFormat(
      "|C1| = %.4f deg/h implies a rotor displacement of about %.2f um (the paper's section 1.1: "
      "C ~ 0.2 deg/h at 3 um), at least %.3f um for a rotor within a factor %.0f of that "
      "sensitivity; gyro %d's suspension offset voltages give by eq. (3) |%.3f| um (1-sigma "
      "%.4f um from %d batch means of %d samples): %s",
      DegH(C1_k_rad_s.norm()), out.drift_implied_um, out.floor_um, kSensitivitySpread, gyro,
      out.voltage_um, out.voltage_sigma_um, kBatches, n,
      !out.informative ? "too imprecise to decide"
      : out.agrees     ? "they agree"
                       : "the rotor is not displaced that far, so the drift is not a rotor "
                         "displacement");
  return out;
}

int CandidateComparisons(const Candidate& candidate, const ModelState& model, bool with_orbit) {
  if (candidate.effect != Effect::kSunDrift) return 1;
  return std::max(1, SunFamilies(with_orbit) -
                         static_cast<int>(HeldSunFaces(model, candidate.gyro).size()));
}

namespace {

// The candidate's model run on the recording (its star tracker corrected as `m` corrects it),
// counted in fit.runs.
absl::Status RunCandidateModel(const FitContext& ctx, CandidateFit& fit, const ModelState& m,
                               ModelRun& out) {
  const std::vector<TelemetryFrame> corrected =
      CorrectStarTracker(*ctx.frames, *ctx.rates, m.correction);
  auto run = RunModel(m.config, m.options, corrected);
  ++fit.runs;
  if (!run.ok()) return run.status();
  out = std::move(*run);
  return absl::OkStatus();
}

// The constant drift effects of the library (a rotor displacement, the fourth harmonic, unequal
// stiffness): the gyro's coefficients of eq. (1)/(10) that the effect frees, calibrated; the
// run with them fixed at their fitted values (fixed_run).
absl::Status FitDriftCoefficients(const Candidate& candidate, const FitContext& ctx,
                                  CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  SpacecraftConfig& config = fit.model.config;
  const std::vector<TelemetryFrame>& frames = *ctx.frames;
  if (FindGyroMutable(config, candidate.gyro) == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat("candidate gyro ", candidate.gyro, " is not configured"));
  }
  const auto [first, count, sigma] = *FreedDriftCoefficients(candidate.effect, opt);
  const DriftVector before = FindGyroMutable(config, candidate.gyro)->model_sigma.AsVector();
  ReleaseHeldCoefficients(fit.model.config, candidate.gyro, first, count, sigma);
  fit.parameters = 0;
  for (int i = first; i < first + count; ++i) fit.parameters += before(i) > 0.0 ? 0 : 1;
  if (absl::Status s = RunCandidateModel(ctx, fit, fit.model, fit.run); !s.ok()) return s;
  const GyroEstimate* e = FindEstimate(fit.run.gyros, candidate.gyro);
  if (e != nullptr) {
    const DriftVector v = e->coefficients.AsVector(), sg = e->sigma.AsVector();
    for (int i = first; i < first + count; ++i) {
      fit.fitted.push_back({CoefficientName(i), DegH(v(i)), DegH(sg(i)), "deg/h"});
    }
    const DriftVector configured = ctx.model->config.FindGyro(candidate.gyro)->model.AsVector();
    if (candidate.effect == Effect::kFourthHarmonic) {
      fit.notes.push_back(absl::StrFormat(
          "k0 of gyro %d calibrates to %.4f +- %.4f deg/h; the model held %.4f deg/h",
          candidate.gyro, DegH(v(kThetaK0)), DegH(sg(kThetaK0)), DegH(configured(kThetaK0))));
    }
  }
  if (candidate.effect == Effect::kRotorDisplacement) {
    DescribeRotorDisplacement(config, frames, candidate.gyro, fit);
  }
  if (e != nullptr) {
    ModelState fixed = *ctx.model;
    GyroConfig* g = FindGyroMutable(fixed.config, candidate.gyro);
    DriftVector v = g->model.AsVector();
    const DriftVector fitted = e->coefficients.AsVector();
    for (int i = first; i < first + count; ++i) v(i) = fitted(i);
    g->model = DriftCoefficients::FromVector(v);
    ModelRun r;
    if (absl::Status st = RunCandidateModel(ctx, fit, fixed, r); !st.ok()) return st;
    fit.fixed_run = std::move(r);
  }
  return absl::OkStatus();
}

// A gyro's misalignment: its mounting states freed with the prior misalignment_sigma_arcsec;
// the run with the fitted rotation applied to its mounting (fixed_run).
absl::Status FitGyroMisalignment(const Candidate& candidate, const FitContext& ctx,
                                 CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  SpacecraftConfig& config = fit.model.config;
  GyroConfig* g = FindGyroMutable(config, candidate.gyro);
  if (g == nullptr)
    return absl::InvalidArgumentError(
        absl::StrCat("candidate gyro ", candidate.gyro, " is not configured"));
  g->misalignment_sigma = ArcsecToRad(opt.misalignment_sigma_arcsec);
  fit.parameters = 3;
  if (absl::Status s = RunCandidateModel(ctx, fit, fit.model, fit.run); !s.ok()) return s;
  if (const GyroEstimate* e = FindEstimate(fit.run.gyros, candidate.gyro)) {
    AddVectorParameters("misalignmentArcsec", e->misalignment_b, e->misalignment_sigma_b,
                        RadToArcsec(1.0), "arcsec", fit.fitted);
    ModelState fixed = *ctx.model;
    GyroConfig* gf = FindGyroMutable(fixed.config, candidate.gyro);
    gf->C_b_k = ExpMatrix(e->misalignment_b) * gf->C_b_k;  // session.h: C_b_k = Exp(phi) C_b_k
    ModelRun r;
    if (absl::Status st = RunCandidateModel(ctx, fit, fixed, r); !st.ok()) return st;
    fit.fixed_run = std::move(r);
  }
  return absl::OkStatus();
}

// The star tracker's misalignment, in two stages: every running gyro's mounting free (the
// common part is the star tracker's, tested for commonality), then the star tracker corrected by
// it with the mountings as configured.
absl::Status FitStarTrackerMisalignment(const Candidate& candidate, const FitContext& ctx,
                                        CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  // Stage 1: every running gyro's misalignment free; the common part is the star tracker's.
  ModelState free_all = fit.model;
  for (int id : ctx.gyros) {
    GyroConfig* g = FindGyroMutable(free_all.config, id);
    if (g != nullptr && !(g->misalignment_sigma > 0.0)) {
      g->misalignment_sigma = ArcsecToRad(opt.misalignment_sigma_arcsec);
    }
  }
  ModelRun stage1;
  if (absl::Status s = RunCandidateModel(ctx, fit, free_all, stage1); !s.ok()) return s;
  Vector3d info = Vector3d::Zero(), weighted = Vector3d::Zero();
  for (int id : ctx.gyros) {
    const GyroEstimate* e = FindEstimate(stage1.gyros, id);
    if (e == nullptr) continue;
    for (int i = 0; i < 3; ++i) {
      const double s = e->misalignment_sigma_b(i);
      if (!(s > 0)) continue;
      info(i) += 1.0 / (s * s);
      weighted(i) += e->misalignment_b(i) / (s * s);
    }
  }
  Vector3d m = Vector3d::Zero(), m_sigma = Vector3d::Zero();
  for (int i = 0; i < 3; ++i) {
    if (info(i) > 0) {
      m(i) = -weighted(i) / info(i);  // phi_g = -m (see the file comment)
      m_sigma(i) = 1.0 / std::sqrt(info(i));
    }
  }
  // Commonality: the per-gyro estimates phi_g against their mean, which is -m.
  double chi2 = 0.0;
  int dof = 0;
  std::string per_gyro;
  for (int id : ctx.gyros) {
    const GyroEstimate* e = FindEstimate(stage1.gyros, id);
    if (e == nullptr) continue;
    absl::StrAppend(&per_gyro, absl::StrFormat(" gyro %d [%.1f %.1f %.1f]", id,
                                               RadToArcsec(e->misalignment_b.x()),
                                               RadToArcsec(e->misalignment_b.y()),
                                               RadToArcsec(e->misalignment_b.z())));
    for (int i = 0; i < 3; ++i) {
      const double s = e->misalignment_sigma_b(i);
      if (s > 0) {
        chi2 += std::pow((e->misalignment_b(i) + m(i)) / s, 2);
        ++dof;
      }
    }
  }
  dof = std::max(1, dof - 3);
  fit.notes.push_back(absl::StrFormat(
      "with every gyro's mounting free the fitted misalignments are (arcsec, body axes):%s; "
      "their spread about the common rotation: chi2 = %.1f on %d dof, p = %.2g",
      per_gyro, chi2, dof, ChiSquareSurvival(chi2, dof)));
  // Stage 2: the star tracker corrected by the common rotation, mountings as configured.
  fit.model.correction.misalignment_b = ctx.model->correction.misalignment_b + m;
  fit.parameters = 3;
  // Laplace's approximation of its evidence under the prior misalignment_sigma_arcsec per
  // axis (candidates.h `occam`).
  const double prior = ArcsecToRad(opt.misalignment_sigma_arcsec);
  for (int i = 0; i < 3; ++i) {
    if (!(m_sigma(i) > 0)) continue;
    fit.occam += std::max(0.0, 2.0 * std::log(prior / m_sigma(i))) +
                 m(i) * m(i) / (prior * prior);
  }
  if (absl::Status s = RunCandidateModel(ctx, fit, fit.model, fit.run); !s.ok()) return s;
  AddVectorParameters("misalignmentArcsec", fit.model.correction.misalignment_b, m_sigma,
                      RadToArcsec(1.0), "arcsec", fit.fitted);
  return absl::OkStatus();
}

// The star tracker's latency: a model-free estimate from the rates, then the filter's
// likelihood searched around it.
absl::Status FitStarTrackerLatency(const Candidate& candidate, const FitContext& ctx,
                                   CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  // A first, model-free estimate from the rates (LatencyFromRates), then a 1-D search of the
  // filter's likelihood around it: the filter's response to a wrong latency is far from
  // affine (each regime change leaves a step of w tau that eq. (14) rejects and resets
  // absorb), so a search started at zero can stop in a false minimum.
  const LatencyEstimate first = LatencyFromRates(*ctx.frames, *ctx.rates, ctx.model->config);
  fit.parameters = 1;
  if (!first.observable) {
    fit.parameters = 0;
    fit.run = *ctx.model_run;
    fit.notes.push_back(
        "the body rate never changed enough to observe a star-tracker latency "
        "(in a steady rotation a latency is a constant misalignment)");
    return absl::OkStatus();
  }
  fit.notes.push_back(absl::StrFormat(
      "star-tracker against gyro step rotations over %d rate changes: latency %.0f +- %.0f ms "
      "(model-free)",
      first.samples, first.latency * 1e3, first.sigma * 1e3));
  const double tau0 = ctx.model->correction.latency;
  const double centre = tau0 + first.latency;
  const double step = std::clamp(2.0 * first.sigma, 0.005, 0.05);
  std::vector<double> taus;
  for (int k = -2; k <= 2; ++k) taus.push_back(centre + k * step);
  std::vector<double> value(taus.size());
  std::vector<ModelRun> runs(taus.size());
  for (size_t k = 0; k < taus.size(); ++k) {
    ModelState m = fit.model;
    m.correction.latency = taus[k];
    if (absl::Status s = RunCandidateModel(ctx, fit, m, runs[k]); !s.ok()) return s;
    value[k] = Profile(runs[k]).value;
  }
  size_t best = std::min_element(value.begin(), value.end()) - value.begin();
  double tau = taus[best], tau_sigma = first.sigma;
  double best_value = value[best];
  fit.run = std::move(runs[best]);
  if (best > 0 && best + 1 < taus.size()) {
    const double x0 = taus[best - 1], x1 = taus[best], x2 = taus[best + 1];
    const double y0 = value[best - 1], y1 = value[best], y2 = value[best + 1];
    const double d01 = (y1 - y0) / (x1 - x0), d12 = (y2 - y1) / (x2 - x1);
    const double curvature = 2.0 * (d12 - d01) / (x2 - x0);  // D''
    if (curvature > 0) {
      // -2 log L = const + (tau - tau_hat)^2 / sigma^2; D'(x) = d01 + D'' (x - (x0 + x1) / 2).
      tau_sigma = std::sqrt(2.0 / curvature);
      const double x_star = std::clamp(0.5 * (x0 + x1) - d01 / curvature, x0, x2);
      if (std::abs(x_star - x1) > 1e-3) {
        ModelState m = fit.model;
        m.correction.latency = x_star;
        ModelRun r;
        if (absl::Status s = RunCandidateModel(ctx, fit, m, r); !s.ok()) return s;
        const double v = Profile(r).value;
        if (v < best_value) {
          best_value = v;
          tau = x_star;
          fit.run = std::move(r);
        }
      }
    }
  }
  fit.model.correction.latency = tau;
  fit.fitted.push_back({"latencyMs", tau * 1e3, tau_sigma * 1e3, "ms"});
  // Laplace's approximation of its evidence under the prior latency_sigma_s
  // (candidates.h `occam`).
  fit.occam = std::max(0.0, 2.0 * std::log(opt.latency_sigma_s / std::max(tau_sigma, 1e-6))) +
              std::pow((tau - tau0) / opt.latency_sigma_s, 2);
  std::string grid_text;
  for (size_t k = 0; k < taus.size(); ++k) {
    absl::StrAppend(&grid_text,
                    absl::StrFormat(" %.0f:%.1f", taus[k] * 1e3, value[k] - best_value));
  }
  fit.notes.push_back(
      absl::StrCat("filter likelihood around it (ms: -2 log L above the best):", grid_text));
  return absl::OkStatus();
}

// A raised drift random walk, common (gyro 0) or of one gyro: the intensity over a grid, its
// evidence integrated over it.
absl::Status FitRandomWalk(const Candidate& candidate, const FitContext& ctx,
                           CandidateFit& fit) {
  SpacecraftConfig& config = fit.model.config;
  // Common (gyro 0) or of one gyro (session.h SessionOptions::random_walk_by_gyro).
  if (candidate.gyro > 0 && FindGyroMutable(config, candidate.gyro) == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat("candidate gyro ", candidate.gyro, " is not configured"));
  }
  auto set_intensity = [&](ModelState& m, double q) {
    if (candidate.gyro == 0) {
      m.config.random_walk = q;
      return;
    }
    auto& by_gyro = m.options.random_walk_by_gyro;
    for (auto& [id, value] : by_gyro) {
      if (id == candidate.gyro) {
        value = q;
        return;
      }
    }
    by_gyro.emplace_back(candidate.gyro, q);
  };
  double q0 = ctx.model->config.random_walk;
  for (const auto& [id, value] : ctx.model->options.random_walk_by_gyro) {
    if (id == candidate.gyro) q0 = value;
  }
  fit.time.kind = "random_walk";
  const double base = q0 > 0.0 ? q0 : DegPerHourSqrtHourToSi(kRandomWalkFloorDegHSqrtH);
  std::vector<double> grid, value;
  ModelRun best_run;
  double best = 0.0;
  int best_k = -1;
  for (int k = 0; k < kRandomWalkGridPoints; ++k) {
    // Never beyond what a configuration may hold (docs/service.md "Limits").
    const double q = std::min(base * std::pow(2.0, q0 > 0.0 ? k + 1 : k),
                              DegPerHourSqrtHourToSi(kConfigLimits.random_walk.max));
    ModelState m = fit.model;
    set_intensity(m, q);
    ModelRun r;
    if (absl::Status s = RunCandidateModel(ctx, fit, m, r); !s.ok()) return s;
    const double d = Profile(r).value;
    grid.push_back(q);
    value.push_back(d);
    if (best_k < 0 || d < best) {
      best = d;
      best_k = k;
      best_run = std::move(r);
    }
  }
  set_intensity(fit.model, grid[best_k]);
  fit.run = std::move(best_run);
  fit.parameters = 1;
  // Its evidence: the intensity integrated over the grid, each point equally likely a
  // priori (a log-uniform prior over 2 .. 32 times the configured intensity).
  for (double d : value) fit.prior_points.emplace_back(1.0 / value.size(), d);
  // Parabola in log q through the best point and its neighbours for the reported intensity.
  double q_hat = grid[best_k];
  if (best_k > 0 && best_k + 1 < static_cast<int>(grid.size())) {
    const double y0 = value[best_k - 1], y1 = value[best_k], y2 = value[best_k + 1];
    const double curvature = y0 - 2 * y1 + y2;
    if (curvature > 0) {
      const double offset = 0.5 * (y0 - y2) / curvature;  // in grid steps (factor 2)
      q_hat = grid[best_k] * std::pow(2.0, std::clamp(offset, -1.0, 1.0));
    }
  }
  fit.fitted.push_back(
      {"randomWalkDegHSqrtH", SiToDegPerHourSqrtHour(q_hat), 0.0, "deg/h/sqrt(h)"});
  fit.fitted.push_back(
      {"configuredRandomWalkDegHSqrtH", SiToDegPerHourSqrtHour(q0), 0.0, "deg/h/sqrt(h)"});
  std::string grid_text;
  for (size_t k = 0; k < grid.size(); ++k) {
    absl::StrAppend(&grid_text, absl::StrFormat(" %.4g:%.1f", SiToDegPerHourSqrtHour(grid[k]),
                                                value[k] - value[best_k]));
  }
  fit.notes.push_back(absl::StrCat(
      "likelihood over the intensity grid (deg/h/sqrt(h): -2 log L above the best):",
      grid_text));
  return absl::OkStatus();
}

// Each effect's fit (the library's, the time behaviours', the basis's readout and sun groups).
using EffectFit = absl::Status (*)(const Candidate&, const FitContext&, CandidateFit&);
EffectFit FitOf(Effect effect) {
  switch (effect) {
    case Effect::kRotorDisplacement:
    case Effect::kFourthHarmonic:
    case Effect::kUnequalStiffness:
      return &FitDriftCoefficients;
    case Effect::kGyroMisalignment:
      return &FitGyroMisalignment;
    case Effect::kStarTrackerMisalignment:
      return &FitStarTrackerMisalignment;
    case Effect::kStarTrackerLatency:
      return &FitStarTrackerLatency;
    case Effect::kRandomWalkDrift:
      return &FitRandomWalk;
    case Effect::kDriftStep:
      return &FitDriftStep;
    case Effect::kReadoutDistortion:
      return &FitReadoutCandidate;
    case Effect::kSunDrift:
      return &FitSunCandidate;
    case Effect::kChannelDrift:
      return &FitChannelCandidate;
    case Effect::kWarmUp:
      return &FitWarmUp;
    case Effect::kCoefficientStep:
      return &FitCoefficientStep;
    case Effect::kTransient:
      return &FitTransient;
    case Effect::kStarTrackerCycle:
      return &FitStarTrackerCycle;
    case Effect::kTurningDisplacement:
      return &FitTurningDisplacement;
  }
  return nullptr;
}

}  // namespace

absl::StatusOr<CandidateFit> FitCandidate(const Candidate& candidate, const FitContext& ctx) {
  CandidateFit fit;
  fit.candidate = candidate;
  fit.model = *ctx.model;
  fit.model.added.push_back(CandidateName(candidate));
  // A fit that returns without a run of its own (nothing to fit: no sun regressors, no orbital
  // period, ...) leaves the model's: its row in the table of candidates then shows no change
  // rather than the model's whole -2 log L as its gain.
  if (ctx.model_run != nullptr) fit.run = *ctx.model_run;
  const EffectFit fit_effect = FitOf(candidate.effect);
  if (fit_effect == nullptr) return absl::InternalError("unknown effect");
  RETURN_IF_ERROR(fit_effect(candidate, ctx, fit));
  return fit;
}

}  // namespace esg::estimator::discovery
