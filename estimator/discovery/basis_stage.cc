#include "estimator/discovery/basis_stage.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <map>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/rate_coupling.h"
#include "estimator/discovery/sun_terms.h"
#include "estimator/statistics.h"
#include "estimator/discovery/time_behaviour.h"
#include "estimator/discovery/wander.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

using Eigen::Matrix3d;

namespace {

// A drift column's coefficient in the configuration JSON's units, and that unit.
std::pair<double, std::string> JsonValue(const BasisColumn& c, double value) {
  const std::string unit(BasisScalarJsonUnit(c.term.kind));
  return {value * BasisValueToJson(c.term.kind), unit == "1" ? "deg/h" : "deg/h per " + unit};
}

std::string TimeKind(const SelectedGroup& g) {
  if (g.sun_face >= 0) return kTimeFollowsSun;
  if (g.columns.empty() || g.columns.front().column.readout) return "constant";
  switch (g.columns.front().column.term.kind) {
    case BasisKind::kOrbitalHarmonic:
      return "orbital_cycle";
    case BasisKind::kRamp:
    case BasisKind::kRampHarmonic:
      return "linear";
    default:
      return "constant";
  }
}

// The paper's rotor-displacement drift per um (section 1.1: C10 ~ 0.05 and C20 ~ 0.015 deg/h per
// um of displacement), for the size of a growing displacement implied by a growing C1.
constexpr double kC10PlusC20DegHPerUm = 0.065;
// A drift growing along the direction of the voltages' trend agrees with it through eq. (3)
// when the two directions are within this angle.
constexpr double kTrendAgreementDeg = 30.0;

// A case-fixed drift growing in time (a ramp) read as a growing rotor displacement (eq. (8)-(10):
// C1 = (C10 + C20) lambda |Delta|, whose drift is (h h^T - I) C1, so a displacement growing at
// dDelta/dt makes the case-fixed drift grow at -(C10 + C20) dDelta/dt), checked against the
// suspension offset voltages' trend through eq. (3) when they are telemetered.
void DescribeGrowingDisplacement(const SpacecraftConfig& config,
                                 const std::vector<TelemetryFrame>& frames, const SelectedGroup& g,
                                 Finding& f) {
  Eigen::Vector3d ramp_deg_h_per_h = Eigen::Vector3d::Zero();
  for (const FittedColumn& c : g.columns) {
    ramp_deg_h_per_h(c.column.term.axis - 1) += c.value * BasisValueToJson(c.column.term.kind);
  }
  const Eigen::Vector3d implied_um_h = -ramp_deg_h_per_h / kC10PlusC20DegHPerUm;
  CandidateFit trend;
  DescribeVoltageTrend(config, frames, g.gyro, trend);
  f.parameters.push_back(Parameter{"impliedDisplacementRateSizeUmPerH", implied_um_h.norm(), 0.0,
                                   "um/h"});
  if (trend.displacement_trend.samples.empty()) {
    absl::StrAppend(&f.description, absl::StrFormat(
        "; read as a rotor displacement growing (eq. (8)-(10)) it would grow at %.4f um/h along "
        "%s with the paper's C10 + C20 = %.3f deg/h per um; no suspension voltages to check it "
        "through eq. (3)",
        implied_um_h.norm(), absl::StrFormat("(%.2f, %.2f, %.2f)", implied_um_h.normalized().x(),
                                             implied_um_h.normalized().y(),
                                             implied_um_h.normalized().z()),
        kC10PlusC20DegHPerUm));
    return;
  }
  const Eigen::Vector3d voltage_um_h(trend.displacement_trend.rate_um_h[0],
                                     trend.displacement_trend.rate_um_h[1],
                                     trend.displacement_trend.rate_um_h[2]);
  const double cosine = implied_um_h.normalized().dot(voltage_um_h.normalized());
  const double angle_deg = RadToDeg(std::acos(std::clamp(cosine, -1.0, 1.0)));
  const bool agrees = angle_deg < kTrendAgreementDeg;
  f.parameters.insert(f.parameters.end(), trend.fitted.begin(), trend.fitted.end());
  f.parameters.push_back(Parameter{"trendAngleDeg", angle_deg, 0.0, "deg"});
  for (const std::string& note : trend.notes) f.evidence.notes.push_back(note);
  f.displacement_trend = trend.displacement_trend;
  f.description = absl::StrFormat(
      "gyro %d: %s: rotor displacement growing at %.4f um/h (from the drift's growth through eq. "
      "(8)-(10) with the paper's C10 + C20 = %.3f deg/h per um; %.4f um/h from the suspension "
      "offset voltages' trend through eq. (3)), the two directions %.0f deg apart; %s",
      g.gyro, agrees ? "agrees with the voltages" : "does NOT agree with the voltages",
      implied_um_h.norm(), kC10PlusC20DegHPerUm, voltage_um_h.norm(), angle_deg,
      f.description.substr(f.description.find(": ") + 2));
  if (!agrees) {
    absl::StrAppend(&f.description, absl::StrFormat(
        "; the voltages do not show this growth (directions more than %.0f deg apart), so the "
        "growing drift is not a displacement the suspension sees",
        kTrendAgreementDeg));
  }
}

// A drift proportional to a suspension offset voltage is a rotor-displacement drift: by eq. (3)
// the voltage measures the displacement along its axis, and eq. (8)-(10) make the drift follow
// it. When the voltages trend (a chi-square(3) test of their robust lines at alpha), the
// displacement and its drift grow in time: the finding's time behaviour is linear.
void DescribeVoltageDrivenDrift(const SpacecraftConfig& config,
                                const std::vector<TelemetryFrame>& frames, double alpha,
                                Finding& f) {
  CandidateFit trend;
  DescribeVoltageTrend(config, frames, f.gyro, trend);
  if (trend.displacement_trend.samples.empty()) return;
  Eigen::Vector3d rate = Eigen::Vector3d::Zero(), sigma = Eigen::Vector3d::Zero();
  for (const Parameter& p : trend.fitted) {
    for (int i = 0; i < 3; ++i) {
      if (p.name == absl::StrCat("displacementRateUmPerH[", i, "]")) {
        rate(i) = p.value;
        sigma(i) = p.sigma;
      }
    }
  }
  double chi2 = 0.0;
  for (int i = 0; i < 3; ++i) {
    if (sigma(i) > 0.0) chi2 += std::pow(rate(i) / sigma(i), 2);
  }
  const double p_value = ChiSquareSurvival(chi2, 3.0);
  f.parameters.insert(f.parameters.end(), trend.fitted.begin(), trend.fitted.end());
  for (const std::string& note : trend.notes) f.evidence.notes.push_back(note);
  f.displacement_trend = trend.displacement_trend;
  const std::string what = f.description.substr(f.description.find(": ") + 2);
  if (p_value < alpha) {
    f.time.kind = "linear";
    f.description = absl::StrFormat(
        "gyro %d: rotor displacement growing at %.4f um/h along (%.2f, %.2f, %.2f) (case axes; "
        "the suspension offset voltages' trend through eq. (3), p = %.2g), with a drift that "
        "follows it (eq. (8)-(10)): %s",
        f.gyro, rate.norm(), rate.normalized().x(), rate.normalized().y(), rate.normalized().z(),
        p_value, what);
  } else {
    f.description = absl::StrFormat(
        "gyro %d: a rotor-displacement drift (eq. (8)-(10)) read through the suspension offset "
        "voltages (eq. (3)), which do not trend (p = %.2g): %s",
        f.gyro, p_value, what);
  }
}

// A selected sun group held in the model as a correction of its gyro's readings (sun_terms.h).
ReadingShift HeldSunDrift(const SelectedGroup& g, const std::vector<DeviationSeries>& series,
                          const std::vector<SunRegressors>& sun,
                          const std::vector<TelemetryFrame>& corrected,
                          const DiagnosisContext& context, const SelectedModel& selected) {
  const SunRegressors* regressors = FindSunRegressors(sun, g.gyro);
  const DeviationSeries* s = nullptr;
  for (const DeviationSeries& d : series) {
    if (d.gyro == g.gyro) s = &d;
  }
  if (regressors == nullptr || s == nullptr) return ReadingShift{g.gyro, nullptr};
  const CarriedAttitude attitude = AttitudeAlongRecording(corrected, context.rates(), selected.run);
  return SunReadingShift(g, *s, *regressors, corrected, attitude,
                         ModelMounting_b_k(selected.model.config, selected.run.gyros, g.gyro));
}

}  // namespace

std::vector<Parameter> ReadoutParameters(const SelectedGroup& group) {
  const Matrix3d E = ReadoutDistortion(group);
  const Matrix3d sigma = ReadoutDistortionSigma(group);
  std::vector<Parameter> out;
  static constexpr std::array<std::pair<int, int>, 6> kEntries = {
      {{0, 0}, {1, 1}, {2, 2}, {0, 1}, {1, 2}, {2, 0}}};
  for (const auto& [r, c] : kEntries) {
    out.push_back(Parameter{absl::StrFormat("basis[readout E_%c%c]", "xyz"[r], "xyz"[c]),
                            E(r, c) * 1e6, sigma(r, c) * 1e6, "ppm"});
  }
  return out;
}

double RecordingOrbitalPeriod(const std::vector<RegimeSpan>& regimes) {
  std::vector<double> periods;
  for (const RegimeSpan& r : regimes) {
    if (r.regime == Regime::kOrbital && r.mean_rate > 0.0) {
      periods.push_back(2.0 * kPi / r.mean_rate);
    }
  }
  if (periods.empty()) return 0.0;
  std::nth_element(periods.begin(), periods.begin() + periods.size() / 2, periods.end());
  return periods[periods.size() / 2];
}

double CandidateOrbitalPeriod(const FitContext& ctx) {
  if (ctx.options->orbital_period_s > 0.0) return ctx.options->orbital_period_s;
  return ctx.regimes != nullptr ? RecordingOrbitalPeriod(*ctx.regimes) : 0.0;
}

OpenEndedOptions ModelOpenEndedOptions(const ModelState& model, const DiagnoseOptions& opt) {
  OpenEndedOptions o;
  o.alpha = opt.alpha;
  o.drift_sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
  o.readout_sigma = ArcsecToRad(opt.misalignment_sigma_arcsec);
  for (const SessionOptions::CoefficientRelease& r : model.options.coefficient_releases) {
    if (!r.misalignment) o.steps.emplace_back(r.gyro_id, r.time);
  }
  o.free_coefficients = FreeCoefficientsOf(model.config);
  return o;
}

ModelState WithBasisTerms(const ModelState& model, const BasisStageResult& stage) {
  ModelState out = model;
  for (const auto& [gyro, term] : stage.added_terms) {
    if (GyroConfig* gc = FindGyroMutable(out.config, gyro)) gc->basis_terms.push_back(term);
  }
  for (const auto& [gyro, E] : stage.added_distortions) {
    if (GyroConfig* gc = FindGyroMutable(out.config, gyro)) gc->readout_distortion += E;
  }
  for (const ReadingShift& shift : stage.added_shifts) {
    out.correction.reading_shifts.push_back(shift);
  }
  for (const SelectedGroup& g : stage.stage.selected) {
    out.added.push_back(absl::StrCat(kEffectBasisTerm, "[", g.gyro, "] ", g.label));
  }
  return out;
}

namespace {

// The open-ended stage's options for `model` (ModelOpenEndedOptions), with the recording's
// orbital period (the options' own when given), the epoch, the sun's regressors less the faces a
// selection round took already (readout_candidate.h FitSunCandidate: held in the model), and each
// gyro's room for basis terms. `sun_note` says why the sun has no regressors, if so.
OpenEndedOptions StageOptions(const ModelState& model, const SelectedModel& selected,
                              const DiagnosisContext& context,
                              const std::vector<DeviationSeries>& series, std::string& sun_note) {
  const DiagnoseOptions& opt = context.options();
  OpenEndedOptions o = ModelOpenEndedOptions(model, opt);
  o.orbital_period_s =
      opt.orbital_period_s > 0.0 ? opt.orbital_period_s : RecordingOrbitalPeriod(context.regimes());
  o.epoch = context.frames().front().time;
  o.sun = SunRegressorsOf(series, model.config, selected.run.gyros, &sun_note, opt.orbit.get());
  for (SunRegressors& r : o.sun) {
    for (int face : HeldSunFaces(model, r.gyro)) {
      if (face < static_cast<int>(r.values.size())) r.values[face].clear();
    }
  }
  for (const GyroConfig& g : model.config.gyros) {
    o.column_budget.emplace_back(
        g.id, std::max(0, kMaxBasisTermsPerGyro - static_cast<int>(g.basis_terms.size())));
  }
  return o;
}

// The residual drift before and after the stage's terms, per gyro and time, in deg/h.
std::vector<ResidualDriftPoint> ResidualDriftPoints(const OpenEndedResult& stage) {
  std::vector<ResidualDriftPoint> out;
  for (const ResidualDrift& r : stage.residual_drift) {
    for (size_t k = 0; k < r.hours.size(); ++k) {
      ResidualDriftPoint p;
      p.hours = r.hours[k];
      p.gyro = r.gyro;
      for (int i = 0; i < 3; ++i) {
        p.before_deg_h[i] = RadPerSecToDegPerHour(r.before_k[k](i));
        p.after_deg_h[i] = RadPerSecToDegPerHour(r.after_k[k](i));
      }
      p.sigma_deg_h = RadPerSecToDegPerHour(r.sigma[k]);
      out.push_back(p);
    }
  }
  return out;
}

// What the remaining deviation resembles most, in words, and the sun's note.
std::string Resembles(const OpenEndedResult& stage, const std::string& sun_note) {
  std::string out;
  if (!stage.best_label.empty()) {
    out = absl::StrFormat(
        "of the open-ended basis (docs/discovery.md), the remaining deviation resembles most "
        "\"%s\" in gyro %d: 2 ln B = %.1f against the threshold %.1f of %d regressor groups",
        stage.best_label, stage.best_gyro, stage.best_evidence, stage.best_threshold,
        stage.groups_tested);
  }
  if (!sun_note.empty()) absl::StrAppend(&out, "; ", sun_note);
  return out;
}

// The selected groups as additions to `model`: each sun group a correction of the readings
// (sun_terms.h, its Occam term added to `sun_occam`), each other group its drift terms (value 0,
// their prior) and its readout distortion. Returns each group's first term's index in its gyro's
// basis_terms once the terms are added.
std::vector<int> AddSelectedGroups(const ModelState& model, const SelectedModel& selected,
                                   DiagnosisContext& context,
                                   const std::vector<DeviationSeries>& series,
                                   const std::vector<TelemetryFrame>& corrected,
                                   BasisStageResult& out, double& sun_occam) {
  const OpenEndedResult& stage = out.stage;
  std::vector<int> first_term(stage.selected.size(), 0);
  for (size_t i = 0; i < stage.selected.size(); ++i) {
    const SelectedGroup& g = stage.selected[i];
    const GyroConfig* gc = model.config.FindGyro(g.gyro);
    if (gc == nullptr) continue;
    if (g.sun_face >= 0) {  // held as a correction of the readings (sun_terms.h)
      out.added_shifts.push_back(
          HeldSunDrift(g, series, out.options.sun, corrected, context, selected));
      sun_occam += ReadoutOccam(g);
      continue;
    }
    int before = static_cast<int>(gc->basis_terms.size());
    for (const auto& [gyro, term] : out.added_terms) before += gyro == g.gyro ? 1 : 0;
    first_term[i] = before;
    const Matrix3d E = ReadoutDistortion(g);
    for (const FittedColumn& c : g.columns) {
      if (c.column.readout) continue;
      BasisTerm t = c.column.term;
      t.value = 0.0;
      t.sigma = c.prior_sigma;
      out.added_terms.emplace_back(g.gyro, t);
    }
    if (!E.isZero(0.0)) out.added_distortions.emplace_back(g.gyro, E);
  }
  return first_term;
}

// The finding of selected group `g` (its drift columns from `first_term` on in the refitted
// filter's `estimate`, may be null), numbered `round`.
Finding GroupFinding(SelectedGroup g, const GyroEstimate* estimate, int first_term,
                     const ModelState& model, const ModelState& extended,
                     const DiagnosisContext& context, const BasisStageResult& out, int round) {
  const DiagnoseOptions& opt = context.options();
  int term = first_term;
  for (FittedColumn& c : g.columns) {
    if (c.column.readout || g.sun_face >= 0) continue;
    if (estimate != nullptr && term < static_cast<int>(estimate->basis_terms.size()) &&
        term < static_cast<int>(estimate->basis_sigma.size())) {
      c.value = estimate->basis_terms[term].value;
      c.sigma = estimate->basis_sigma[term];
    }
    ++term;
  }
  Finding f;
  f.effect = kEffectBasisTerm;
  f.gyro = g.gyro;
  f.description = g.sun_face >= 0 ? absl::StrFormat("gyro %d: %s%s", g.gyro,
                                                    DescribeSunGroup(g, opt.orbit != nullptr),
                                                    DescribeAlternatives(g))
                                  : DescribeGroup(g, out.options);
  f.time.kind = TimeKind(g);
  const GyroConfig* gc = extended.config.FindGyro(g.gyro);
  if (!g.columns.empty() && g.columns.front().column.readout) {
    f.parameters = ReadoutParameters(g);
    if (gc != nullptr) f.readout_distortion = gc->readout_distortion;
  }
  if (g.sun_face >= 0) {
    f.parameters = SunParameters(g);
    f.evidence.notes.push_back(absl::StrFormat(
        "the drift that follows the sun is held in the refit at the regression's values, as a "
        "correction of gyro %d's readings (the filter has no state for the thermal lag); its "
        "values and sigmas are the regression's, and the refit's 2 ln B is its improvement of "
        "-2 log L less the Occam term of the held coefficients (%.1f)",
        g.gyro, ReadoutOccam(g)));
  }
  for (const FittedColumn& c : g.columns) {
    if (c.column.readout || g.sun_face >= 0) continue;
    const auto [value, unit] = JsonValue(c.column, c.value);
    const auto [sigma, unused] = JsonValue(c.column, c.sigma);
    f.parameters.push_back(Parameter{absl::StrCat("basis[", c.column.label, "]"), value,
                                     std::abs(sigma), unit});
    BasisTerm t = c.column.term;
    t.value = c.value;
    t.sigma = c.prior_sigma;
    f.basis_terms.push_back(t);
  }
  f.evidence.delta_deviance = g.evidence;
  f.evidence.evidence = g.evidence;
  f.evidence.parameters = static_cast<int>(g.columns.size());
  f.evidence.p_value = EvidenceBound(g.evidence);
  f.evidence.threshold = g.threshold;
  f.evidence.round = round;
  f.evidence.notes.push_back(absl::StrFormat(
      "found by the open-ended stage: the gyro's deviation from the model regressed on the "
      "basis (docs/discovery.md), 2 ln B = %.1f against 2 ln(M / alpha) = %.1f with M = %d "
      "regressor groups; refitted by the filter with every selected term: 2 ln B = %.1f",
      g.evidence, g.threshold, g.groups_tested, out.refit_evidence));
  if (!g.columns.empty() && !g.columns.front().column.readout &&
      g.columns.front().column.term.kind == BasisKind::kRamp) {
    DescribeGrowingDisplacement(model.config, context.frames(), g, f);
  }
  if (!g.columns.empty() && !g.columns.front().column.readout &&
      g.columns.front().column.term.kind == BasisKind::kSuspensionVoltage) {
    DescribeVoltageDrivenDrift(model.config, context.frames(), opt.alpha, f);
  }
  f.explanation = ExplainFinding(f);
  return f;
}

}  // namespace

// The stage as a sequence: the model's deviations measured, the open-ended regression run on
// them, what the rest resembles, the selected groups added to the model and refitted by the
// filter, and, when the refit confirms them, one finding per group and the extended model.
absl::StatusOr<BasisStageResult> RunBasisStage(const SelectedModel& selected,
                                               DiagnosisContext& context,
                                               const std::vector<int>& gyros, int round) {
  BasisStageResult out;
  const ModelState& model = selected.model;
  const std::vector<TelemetryFrame> corrected =
      CorrectStarTracker(context.frames(), context.rates(), model.correction);
  auto series = MeasureDeviations(model.config, selected.run.gyros, corrected, context.rates(),
                                  selected.run, gyros);
  if (!series.ok()) return series.status();
  std::string sun_note;
  out.options = StageOptions(model, selected, context, *series, sun_note);
  std::vector<double> random_walk, w0;
  for (const DeviationSeries& s : *series) {
    random_walk.push_back(ModelRandomWalk(model, s.gyro));
    w0.push_back(ModelInitialDriftSigma(model));
  }
  out.stage = RunOpenEnded(*series, random_walk, w0, out.options);
  const OpenEndedResult& stage = out.stage;
  out.residual_drift = ResidualDriftPoints(stage);
  out.resembles = Resembles(stage, sun_note);
  if (stage.selected.empty()) return out;

  // The model with the selected terms, refitted by the filter.
  double sun_occam = 0.0;
  const std::vector<int> first_term =
      AddSelectedGroups(model, selected, context, *series, corrected, out, sun_occam);
  const ModelState extended = WithBasisTerms(model, out);
  auto run = context.CheckedRun(extended, /*held_out=*/false);
  if (!run.ok()) return run.status();
  const ProfiledDeviance fit = Profile(*run);
  out.refitted = true;
  out.refit_evidence = selected.fit.value - fit.value - sun_occam;
  out.refit_threshold = 0.0;
  for (const SelectedGroup& g : stage.selected) out.refit_threshold = std::max(out.refit_threshold, g.threshold);
  if (!(out.refit_evidence > out.refit_threshold)) {
    absl::StrAppend(&out.resembles, absl::StrFormat(
        "; the reduced regression selected %d group(s), but the refitted filter does not confirm "
        "them (2 ln B = %.1f, threshold %.1f)",
        stage.selected.size(), out.refit_evidence, out.refit_threshold));
    return out;
  }
  // Findings, with the refitted filter's values of the terms (GyroEstimate::basis_terms, in the
  // configuration's order).
  for (size_t i = 0; i < stage.selected.size(); ++i) {
    const SelectedGroup& g = stage.selected[i];
    out.findings.push_back(GroupFinding(g, FindEstimate(run->gyros, g.gyro), first_term[i], model,
                                        extended, context, out, round));
  }
  // Three body-rate groups of one gyro that are one isotropic coupling: one finding.
  MergeIsotropicRateCoupling(out.findings);
  SelectedModel next;
  next.model = extended;
  next.run = std::move(*run);
  next.fit = fit;
  next.held_out_current = false;
  out.extended = std::move(next);
  return out;
}

absl::StatusOr<OutdoneGyros> GyrosOutdoneByAStationaryDrift(
    const BasisStageResult& stage, const SelectedModel& selected,
    const DiagnosisContext& context, const std::map<int, double>& measured,
    const std::vector<int>& skip, double alpha) {
  std::map<int, double> basis_evidence;
  for (const SelectedGroup& g : stage.stage.selected) {
    if (std::find(skip.begin(), skip.end(), g.gyro) == skip.end()) {
      basis_evidence[g.gyro] += g.evidence;
    }
  }
  OutdoneGyros out;
  for (const auto& [gyro, evidence] : basis_evidence) {
    double stationary = -1.0;
    if (auto it = measured.find(gyro); it != measured.end()) {
      stationary = it->second;
    } else {
      auto e = CompareDriftBehavioursOf(selected, context, gyro);
      if (!e.ok()) return e.status();
      if (ReturnsToItsMean(*e, EvidenceThreshold(alpha, 1))) stationary = e->stationary;
    }
    if (!(stationary > evidence)) continue;
    out.gyros.push_back(gyro);
    absl::StrAppend(&out.note, absl::StrFormat(
        "; the basis's terms for gyro %d (2 ln B = %.1f in the reduced regression) describe its "
        "deviation less well than a drift that returns to its mean (2 ln B = %.1f)",
        gyro, evidence, stationary));
  }
  return out;
}

}  // namespace esg::estimator::discovery
