#include "estimator/discovery/candidates.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <iterator>
#include <map>

#include "Eigen/Eigenvalues"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/calibration_model.h"
#include "estimator/discovery/statistics.h"
#include "estimator/drift_model.h"
#include "estimator/rotation.h"
#include "estimator/spacecraft_config.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Vector3d;

namespace {

constexpr int kRandomWalkGridPoints = 5;  // factors 2, 4, ... 32 above the configured intensity
// Reference intensity when the configuration has none: a tenth of the paper-era ESG's
// residual-drift instability [deg/h/sqrt(h)].
constexpr double kRandomWalkFloorDegHSqrtH = 0.0005;

GyroConfig* FindGyroMutable(SpacecraftConfig& c, int id) {
  for (GyroConfig& g : c.gyros) {
    if (g.id == id) return &g;
  }
  return nullptr;
}

bool AllFree(const DriftVector& sigma, int first, int count) {
  for (int i = first; i < first + count; ++i) {
    if (!(sigma(i) > 0.0)) return false;
  }
  return true;
}

const GyroEstimate* FindEstimate(const std::vector<GyroEstimate>& gyros, int id) {
  for (const GyroEstimate& g : gyros) {
    if (g.id == id) return &g;
  }
  return nullptr;
}

double DegH(double x) { return RadPerSecToDegPerHour(x); }

double HoursSinceStart(const std::vector<TelemetryFrame>& frames, int f) {
  return HoursSince(frames[f].time, frames.front().time);
}

void AddVectorParameters(const std::string& name, const Vector3d& value, const Vector3d& sigma,
                         double scale, const std::string& unit, std::vector<Parameter>& out) {
  for (int i = 0; i < 3; ++i) {
    out.push_back(
        Parameter{absl::StrFormat("%s[%d]", name, i), value(i) * scale, sigma(i) * scale, unit});
  }
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

std::string CandidateName(const Candidate& c) {
  if (c.gyro > 0) return absl::StrCat(EffectId(c.effect), "[", c.gyro, "]");
  return EffectId(c.effect);
}

std::vector<Candidate> ListCandidates(const ModelState& model, const std::vector<int>& gyros,
                                      const std::vector<Effect>& effects) {
  std::vector<Candidate> out;
  auto added = [&](const std::string& name) {
    return std::find(model.added.begin(), model.added.end(), name) != model.added.end();
  };
  for (int id : gyros) {
    const GyroConfig* g = model.config.FindGyro(id);
    if (g == nullptr) continue;
    const DriftVector sigma = g->model_sigma.AsVector();
    if (Effective(effects, Effect::kRotorDisplacement) && !AllFree(sigma, kThetaC1, 6)) {
      out.push_back({Effect::kRotorDisplacement, id});
    }
    if (Effective(effects, Effect::kFourthHarmonic) && !AllFree(sigma, kThetaK0, 1)) {
      out.push_back({Effect::kFourthHarmonic, id});
    }
    if (Effective(effects, Effect::kUnequalStiffness) && !AllFree(sigma, kThetaMu, 6)) {
      out.push_back({Effect::kUnequalStiffness, id});
    }
    if (Effective(effects, Effect::kGyroMisalignment) && !(g->misalignment_sigma > 0.0)) {
      out.push_back({Effect::kGyroMisalignment, id});
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
  // Time behaviour: a drift switched on during the recording, per gyro; a random walk raised in
  // every gyro or in one (once one is raised, no other is offered).
  for (int id : gyros) {
    if (model.config.FindGyro(id) == nullptr) continue;
    if (Effective(effects, Effect::kDriftStep) &&
        !added(CandidateName({Effect::kDriftStep, id}))) {
      out.push_back({Effect::kDriftStep, id});
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

ProfiledDeviance Profile(const ModelRun& run) {
  const Deviance d = ComputeDeviance(run);
  ProfiledDeviance p;
  p.components = d.components;
  p.steps = d.steps;
  if (d.components == 0) return p;
  p.dispersion = std::max(d.nis_sum / d.components, 1e-12);
  const double log_det = d.value - d.nis_sum;
  // -2 log L with S -> phi S, minimised over phi: N ln phi + sum log det S + N.
  p.value = d.components * std::log(p.dispersion) + log_det + d.components;
  return p;
}

void DescribeVoltageTrend(const SpacecraftConfig& config,
                          const std::vector<TelemetryFrame>& frames, int gyro, CandidateFit& fit) {
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
  for (int i = 0; i < 3; ++i) {
    const RobustLine line = FitRobustLine(hours, u_mv[i]);
    const double sigma_mv_h =
        line.residual_sigma / std::sqrt(var_t * line.used / static_cast<double>(hours.size()));
    slope_mv_h(i) = line.slope;
    rate_um_h(i) = um(line.slope);
    rate_sigma_um_h(i) = std::abs(um(sigma_mv_h));
    if (sigma_mv_h > 0) chi2 += std::pow(line.slope / sigma_mv_h, 2);
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
  Vector3d lambda = eig.eigenvectors().col(2);
  if (C1.dot(lambda) < 0) lambda = -lambda;
  const double a = C1.dot(lambda);  // C10 + C20
  const double b = C2.dot(lambda);  // -5 C20
  const double C20 = -b / 5.0, C10 = a - C20;
  const double cos_line =
      (C1.norm() > 0 && C2.norm() > 0) ? std::abs(C1.dot(C2)) / (C1.norm() * C2.norm()) : 1.0;
  const double line_angle_deg = RadToDeg(std::acos(std::clamp(cos_line, -1.0, 1.0)));
  // Collinearity test: components of C1, C2 off the common line against their sigmas,
  // chi-square with 6 - 4 = 2 degrees of freedom (lambda: 2, C10 + C20 and C20: 2).
  const Vector3d r1 = C1 - a * lambda, r2 = C2 - b * lambda;
  double chi2 = 0.0;
  for (int i = 0; i < 3; ++i) {
    if (s1(i) > 0) chi2 += r1(i) * r1(i) / (s1(i) * s1(i));
    if (s2(i) > 0) chi2 += r2(i) * r2(i) / (s2(i) * s2(i));
  }
  const double p_collinear = ChiSquareSurvival(chi2, 2.0);
  fit.fitted.push_back({"lineAngleDeg", line_angle_deg, 0.0, "deg"});
  fit.fitted.push_back({"c10DegH", DegH(C10), 0.0, "deg/h"});
  fit.fitted.push_back({"c20DegH", DegH(C20), 0.0, "deg/h"});
  AddVectorParameters("lambda", lambda, Vector3d::Zero(), 1.0, "1", fit.fitted);
  fit.notes.push_back(absl::StrFormat(
      "C1 and C2 lie %.1f deg apart as lines (C1.C2 %s 0); a displaced rotor makes them collinear "
      "(eq. (8)-(10)): collinear fit C10 = %.4f deg/h, C20 = %.4f deg/h along lambda = [%.2f %.2f "
      "%.2f] "
      "(case axes), off-line residual chi2 = %.1f on 2 dof, p = %.2g",
      line_angle_deg, C1.dot(C2) < 0 ? "<" : ">=", DegH(C10), DegH(C20), lambda.x(), lambda.y(),
      lambda.z(), chi2, p_collinear));
  // eq. (3): displacement from the mean suspension offset voltages.
  Vector3d sum = Vector3d::Zero(), sum2 = Vector3d::Zero();
  int n = 0;
  for (const TelemetryFrame& f : frames) {
    const auto& r = f.gyros[gyro - 1];
    if (!r.has_value() || !r->u_k_mv.has_value() || !r->u_k_mv->allFinite()) continue;
    sum += *r->u_k_mv;
    sum2 += r->u_k_mv->cwiseAbs2();
    ++n;
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
  Vector3d displacement_um;
  for (int i = 0; i < 3; ++i) {
    displacement_um(i) = DisplacementFromOffsetVoltage(mean_mv(i) * kVoltsPerMv, s.amplifier_gain,
                                                       s.reference_voltage, s.gap) /
                         kMetresPerUm;
  }
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

namespace {

// The onset search of a drift step (docs/discovery.md, "Time behaviour"): coarse onsets at
// k D / kOnsetCoarse (D the recording's length, k = 1 .. kOnsetCoarse - 1), then twice a grid
// kOnsetRefine times finer within one spacing of the best onset so far.
constexpr int kOnsetCoarse = 12;
constexpr int kOnsetRefine = 4;
// A coefficient the model holds is put in the filter's layout with this prior so that it can be
// released at the onset; before it the filter keeps it at its configured value.
constexpr double kHeldSigmaDegH = 1e-6;
// chi-square(1) 95% quantile: the onset interval is where -2 log L stays within it of its minimum.
constexpr double kOnsetIntervalDrop = 3.841458820694124;

// The first frame at or after `t`.
int FrameAtOrAfter(const std::vector<TelemetryFrame>& frames, absl::Time t) {
  auto it = std::lower_bound(frames.begin(), frames.end(), t,
                             [](const TelemetryFrame& f, absl::Time x) { return f.time < x; });
  return static_cast<int>(it - frames.begin());
}

}  // namespace

absl::Status FitDriftStep(const Candidate& candidate, const FitContext& ctx, CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  GyroConfig* g = FindGyroMutable(fit.model.config, candidate.gyro);
  if (g == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat("candidate gyro ", candidate.gyro, " is not configured"));
  }
  // The step d (case axes) enters eq. (10) as C1 -> C1 - d: (h h^T - I)(-d) = d - (h.d) h, the
  // part of d across the spin axis (the part along it moves nothing).
  DriftVector sigma = g->model_sigma.AsVector();
  for (int i = kThetaC1; i < kThetaC1 + 3; ++i) {
    if (!(sigma(i) > 0.0)) sigma(i) = DegPerHourToRadPerSec(kHeldSigmaDegH);
  }
  g->model_sigma = DriftCoefficients::FromVector(sigma);
  const double step_sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
  const std::vector<TelemetryFrame> frames =
      CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction);
  const int n = static_cast<int>(frames.size());
  const absl::Time t0 = frames.front().time;
  const absl::Duration length = frames.back().time - t0;
  fit.parameters = 3;
  fit.searched_parameters = 1;  // the onset
  fit.time.kind = "step";

  // Prefix run without the step, with checkpoints before the onsets of the first two grids.
  std::vector<int> grid_frames;
  const int fine = kOnsetCoarse * kOnsetRefine;
  for (int k = 1; k < fine; ++k) grid_frames.push_back(FrameAtOrAfter(frames, t0 + length * k / fine));
  grid_frames.erase(std::unique(grid_frames.begin(), grid_frames.end()), grid_frames.end());
  while (!grid_frames.empty() && grid_frames.back() >= n - 1) grid_frames.pop_back();
  if (grid_frames.empty()) return absl::OkStatus();  // too short: parameters stay 0
  ModelRunOptions prefix_options;
  prefix_options.checkpoint_frames = grid_frames;
  auto prefix = RunModel(fit.model.config, fit.model.options, frames, prefix_options);
  ++fit.runs;
  if (!prefix.ok()) return prefix.status();
  std::map<int, SessionCheckpoint> checkpoints;
  for (size_t j = 0; j < prefix->checkpoints.size(); ++j) {
    checkpoints[grid_frames[j]] = std::move(prefix->checkpoints[j]);
  }

  // One onset: continue from the checkpoint with the C1 states released at the onset frame.
  std::map<int, double> value;  // onset frame -> profiled -2 log L
  int best_frame = -1;
  double best_value = 0.0;
  ModelRun best_run;
  SessionOptions best_options;
  auto evaluate = [&](int f) -> absl::Status {
    if (value.count(f) || !checkpoints.count(f)) return absl::OkStatus();
    SessionOptions options = fit.model.options;
    options.coefficient_releases.push_back(
        {candidate.gyro, kThetaC1, 3, frames[f].time, step_sigma});
    ModelRunOptions ro;
    ro.start = &checkpoints[f];
    ro.start_frame = f;
    auto tail = RunModel(fit.model.config, options, frames, ro);
    ++fit.runs;
    if (!tail.ok()) return tail.status();
    ModelRun run;
    for (const StepRecord& s : prefix->steps) {
      if (s.frame < f) run.steps.push_back(s);
    }
    run.steps.insert(run.steps.end(), std::make_move_iterator(tail->steps.begin()),
                     std::make_move_iterator(tail->steps.end()));
    run.gyros = std::move(tail->gyros);
    run.resets = tail->resets;
    run.rejections = tail->rejections;
    const double v = Profile(run).value;
    value[f] = v;
    if (best_frame < 0 || v < best_value) {
      best_frame = f;
      best_value = v;
      best_run = std::move(run);
      best_options = options;
    }
    return absl::OkStatus();
  };
  for (size_t j = kOnsetRefine - 1; j < grid_frames.size(); j += kOnsetRefine) {
    if (absl::Status s = evaluate(grid_frames[j]); !s.ok()) return s;
  }
  if (best_frame < 0) {  // a recording too short for the coarse grid: every onset of the finer
    for (int f : grid_frames) {
      if (absl::Status s = evaluate(f); !s.ok()) return s;
    }
  }
  if (best_frame < 1) {  // nothing to search: no step fitted
    fit.parameters = 0;
    fit.run = *ctx.model_run;
    return absl::OkStatus();
  }
  // Refinement 1: the finer grid within one coarse spacing of the best coarse onset.
  {
    const absl::Duration spacing = length / kOnsetCoarse;
    for (int f : grid_frames) {
      if (absl::AbsDuration(frames[f].time - frames[best_frame].time) <= spacing) {
        if (absl::Status s = evaluate(f); !s.ok()) return s;
      }
    }
  }
  // Further refinements, each kOnsetRefine times finer within one spacing of the best onset so
  // far, down to one frame, while the step is significant at the onsets searched so far (else
  // the onset does not matter: the candidate is not taken): the profile of a real step is
  // sharp, a few minutes wide for 0.04 deg/h against 5 arcsec star-tracker noise. The
  // checkpoints of a level come from a short run continued from the nearest earlier one.
  const double base_value = Profile(*ctx.model_run).value;
  absl::Duration spacing = length / fine;
  const absl::Duration frame_step = (frames.back().time - t0) / std::max(1, n - 1);
  while (spacing > frame_step) {
    const int tests = static_cast<int>(value.size());
    const double p = tests * ChiSquareSurvival(std::max(0.0, base_value - best_value), 3.0);
    if (!(p < opt.alpha)) break;
    const absl::Duration finer = std::max(spacing / kOnsetRefine, frame_step);
    std::vector<int> new_frames;
    for (int k = -kOnsetRefine + 1; k < kOnsetRefine; ++k) {
      const int f = FrameAtOrAfter(frames, frames[best_frame].time + finer * k);
      if (f > 1 && f < n - 1 && !checkpoints.count(f)) new_frames.push_back(f);
    }
    spacing = finer;
    std::sort(new_frames.begin(), new_frames.end());
    new_frames.erase(std::unique(new_frames.begin(), new_frames.end()), new_frames.end());
    if (new_frames.empty()) continue;
    auto from = checkpoints.upper_bound(new_frames.front());
    if (from == checkpoints.begin()) break;
    --from;
    ModelRunOptions ro;
    ro.start = &from->second;
    ro.start_frame = from->first;
    ro.stop_frame = new_frames.back();
    ro.checkpoint_frames = new_frames;
    auto more = RunModel(fit.model.config, fit.model.options, frames, ro);
    ++fit.runs;
    if (!more.ok()) return more.status();
    for (size_t j = 0; j < more->checkpoints.size(); ++j) {
      checkpoints[new_frames[j]] = std::move(more->checkpoints[j]);
    }
    for (int f : new_frames) {
      if (absl::Status s = evaluate(f); !s.ok()) return s;
    }
  }
  fit.lr_tests = static_cast<int>(value.size());

  // The onset interval: where -2 log L stays within kOnsetIntervalDrop of its minimum, linear
  // between evaluated onsets, clipped to the onsets searched.
  std::vector<std::pair<double, double>> profile;  // hours, value
  // A release at frame f widens the coefficients before the propagation from frame f - 1: the
  // modelled drift changes from frames[f - 1].time on, the onset reported.
  for (const auto& [f, v] : value) profile.emplace_back(HoursSinceStart(frames, f - 1), v);
  fit.onset_profile = profile;
  size_t best_j = 0;
  for (size_t j = 0; j < profile.size(); ++j) {
    if (profile[j].second < profile[best_j].second) best_j = j;
  }
  const double level = profile[best_j].second + kOnsetIntervalDrop;
  auto crossing = [&](size_t inside, size_t outside) {
    const auto [x0, y0] = profile[inside];
    const auto [x1, y1] = profile[outside];
    return y1 > y0 ? x0 + (x1 - x0) * (level - y0) / (y1 - y0) : x1;
  };
  double lower = profile.front().first, upper = profile.back().first;
  for (size_t j = best_j; j > 0; --j) {
    if (profile[j - 1].second > level) {
      lower = crossing(j, j - 1);
      break;
    }
  }
  for (size_t j = best_j; j + 1 < profile.size(); ++j) {
    if (profile[j + 1].second > level) {
      upper = crossing(j, j + 1);
      break;
    }
  }
  const double onset_hours = profile[best_j].first;
  fit.time.onset = frames[best_frame - 1].time;
  fit.time.onset_hours = onset_hours;
  fit.time.onset_lower_hours = lower;
  fit.time.onset_upper_hours = upper;
  fit.time.onset_lower = t0 + absl::Hours(lower);
  fit.time.onset_upper = t0 + absl::Hours(upper);
  fit.time.onsets_searched = fit.lr_tests;

  // The step: C1 after it (the run's final estimate) against C1 at the onset (the checkpoint's).
  auto at_onset = EstimationSession::FromCheckpoint(fit.model.config, best_options,
                                                    checkpoints[best_frame]);
  if (!at_onset.ok()) return at_onset.status();
  const std::vector<GyroEstimate> before_all = at_onset->Gyros();
  const GyroEstimate* before = FindEstimate(before_all, candidate.gyro);
  const GyroEstimate* after = FindEstimate(best_run.gyros, candidate.gyro);
  if (before != nullptr && after != nullptr) {
    const Vector3d d = -(after->coefficients.C1 - before->coefficients.C1);
    const Vector3d d_sigma = after->sigma.C1;
    AddVectorParameters("driftStepDegH", d, d_sigma, DegH(1.0), "deg/h", fit.fitted);
    const double size = d.norm();
    const double size_sigma =
        size > 0 ? std::sqrt((d.cwiseProduct(d_sigma)).squaredNorm()) / size : d_sigma.norm();
    fit.fitted.push_back({"driftStepSizeDegH", DegH(size), DegH(size_sigma), "deg/h"});
  }
  fit.fitted.push_back({"onsetHours", onset_hours, 0.5 * (upper - lower), "h"});
  fit.fitted.push_back({"onsetLowerHours", lower, 0.0, "h"});
  fit.fitted.push_back({"onsetUpperHours", upper, 0.0, "h"});
  std::string profile_text;
  for (const auto& [h, v] : profile) {
    absl::StrAppend(&profile_text, absl::StrFormat(" %.2f:%.1f", h, v - profile[best_j].second));
  }
  fit.notes.push_back(absl::StrCat(
      "likelihood over the onset (h from the start: -2 log L above the best; ", fit.lr_tests,
      " onsets, p Bonferroni-corrected over them):", profile_text));
  fit.model.options = best_options;
  fit.run = std::move(best_run);
  return absl::OkStatus();
}

absl::StatusOr<CandidateFit> FitCandidate(const Candidate& candidate, const FitContext& ctx) {
  const DiagnoseOptions& opt = *ctx.options;
  CandidateFit fit;
  fit.candidate = candidate;
  fit.model = *ctx.model;
  fit.model.added.push_back(CandidateName(candidate));
  SpacecraftConfig& config = fit.model.config;
  const std::vector<TelemetryFrame>& frames = *ctx.frames;
  auto run_model = [&](const ModelState& m, ModelRun& out) -> absl::Status {
    const std::vector<TelemetryFrame> corrected =
        CorrectStarTracker(frames, *ctx.rates, m.correction);
    auto run = RunModel(m.config, m.options, corrected);
    ++fit.runs;
    if (!run.ok()) return run.status();
    out = std::move(*run);
    return absl::OkStatus();
  };
  auto set_sigma = [&](int first, int count, double sigma) {
    GyroConfig* g = FindGyroMutable(config, candidate.gyro);
    DriftVector s = g->model_sigma.AsVector();
    for (int i = first; i < first + count; ++i) {
      if (!(s(i) > 0.0)) s(i) = sigma;
    }
    g->model_sigma = DriftCoefficients::FromVector(s);
  };

  switch (candidate.effect) {
    case Effect::kRotorDisplacement:
    case Effect::kFourthHarmonic:
    case Effect::kUnequalStiffness: {
      if (FindGyroMutable(config, candidate.gyro) == nullptr) {
        return absl::InvalidArgumentError(
            absl::StrCat("candidate gyro ", candidate.gyro, " is not configured"));
      }
      int first = kThetaC1, count = 6;
      double sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
      if (candidate.effect == Effect::kFourthHarmonic) {
        first = kThetaK0;
        count = 1;
        sigma = DegPerHourToRadPerSec(opt.k0_sigma_deg_h);
      } else if (candidate.effect == Effect::kUnequalStiffness) {
        first = kThetaMu;
        count = 6;
        sigma = DegPerHourToRadPerSec(opt.mu_nu_sigma_deg_h);
      }
      const DriftVector before = FindGyroMutable(config, candidate.gyro)->model_sigma.AsVector();
      set_sigma(first, count, sigma);
      fit.parameters = 0;
      for (int i = first; i < first + count; ++i) fit.parameters += before(i) > 0.0 ? 0 : 1;
      if (absl::Status s = run_model(fit.model, fit.run); !s.ok()) return s;
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
        if (absl::Status st = run_model(fixed, r); !st.ok()) return st;
        fit.fixed_run = std::move(r);
      }
      return fit;
    }
    case Effect::kGyroMisalignment: {
      GyroConfig* g = FindGyroMutable(config, candidate.gyro);
      if (g == nullptr)
        return absl::InvalidArgumentError(
            absl::StrCat("candidate gyro ", candidate.gyro, " is not configured"));
      g->misalignment_sigma = ArcsecToRad(opt.misalignment_sigma_arcsec);
      fit.parameters = 3;
      if (absl::Status s = run_model(fit.model, fit.run); !s.ok()) return s;
      if (const GyroEstimate* e = FindEstimate(fit.run.gyros, candidate.gyro)) {
        AddVectorParameters("misalignmentArcsec", e->misalignment_b, e->misalignment_sigma_b,
                            RadToArcsec(1.0), "arcsec", fit.fitted);
        ModelState fixed = *ctx.model;
        GyroConfig* gf = FindGyroMutable(fixed.config, candidate.gyro);
        gf->C_b_k = ExpMatrix(e->misalignment_b) * gf->C_b_k;  // session.h: C_b_k = Exp(phi) C_b_k
        ModelRun r;
        if (absl::Status st = run_model(fixed, r); !st.ok()) return st;
        fit.fixed_run = std::move(r);
      }
      return fit;
    }
    case Effect::kStarTrackerMisalignment: {
      // Stage 1: every running gyro's misalignment free; the common part is the star tracker's.
      ModelState free_all = fit.model;
      for (int id : ctx.gyros) {
        GyroConfig* g = FindGyroMutable(free_all.config, id);
        if (g != nullptr && !(g->misalignment_sigma > 0.0)) {
          g->misalignment_sigma = ArcsecToRad(opt.misalignment_sigma_arcsec);
        }
      }
      ModelRun stage1;
      if (absl::Status s = run_model(free_all, stage1); !s.ok()) return s;
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
      // Commonality: the per-gyro estimates against their mean.
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
            chi2 += std::pow((e->misalignment_b(i) - m(i)) / s, 2);
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
      fit.searched = true;
      if (absl::Status s = run_model(fit.model, fit.run); !s.ok()) return s;
      AddVectorParameters("misalignmentArcsec", fit.model.correction.misalignment_b, m_sigma,
                          RadToArcsec(1.0), "arcsec", fit.fitted);
      return fit;
    }
    case Effect::kStarTrackerLatency: {
      // A first, model-free estimate from the rates (LatencyFromRates), then a 1-D search of the
      // filter's likelihood around it: the filter's response to a wrong latency is far from
      // affine (each regime change leaves a step of w tau that eq. (14) rejects and resets
      // absorb), so a search started at zero can stop in a false minimum.
      const LatencyEstimate first = LatencyFromRates(*ctx.frames, *ctx.rates, ctx.model->config);
      fit.parameters = 1;
      fit.searched = true;
      if (!first.observable) {
        fit.parameters = 0;
        fit.run = *ctx.model_run;
        fit.notes.push_back(
            "the body rate never changed enough to observe a star-tracker latency "
            "(in a steady rotation a latency is a constant misalignment)");
        return fit;
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
        if (absl::Status s = run_model(m, runs[k]); !s.ok()) return s;
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
            if (absl::Status s = run_model(m, r); !s.ok()) return s;
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
      std::string grid_text;
      for (size_t k = 0; k < taus.size(); ++k) {
        absl::StrAppend(&grid_text,
                        absl::StrFormat(" %.0f:%.1f", taus[k] * 1e3, value[k] - best_value));
      }
      fit.notes.push_back(
          absl::StrCat("filter likelihood around it (ms: -2 log L above the best):", grid_text));
      return fit;
    }
    case Effect::kRandomWalkDrift: {
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
      fit.boundary = true;
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
        if (absl::Status s = run_model(m, r); !s.ok()) return s;
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
      fit.searched = true;
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
      return fit;
    }
    case Effect::kDriftStep:
      if (absl::Status s = FitDriftStep(candidate, ctx, fit); !s.ok()) return s;
      return fit;
  }
  return absl::InternalError("unknown effect");
}

}  // namespace esg::estimator::discovery
