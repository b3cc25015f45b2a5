#include "estimator/discovery/readout_candidate.h"

#include <algorithm>
#include <utility>
#include <vector>

#include "Eigen/Cholesky"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "estimator/discovery/basis_stage.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/open_ended.h"
#include "estimator/discovery/sun_terms.h"
#include "estimator/discovery/wander.h"
#include "estimator/units.h"
#include "estimator/statistics.h"
#include "estimator/status_macros.h"

namespace esg::estimator::discovery {

namespace {

// At most this many regressions and filter runs (readout_candidate.h).
constexpr int kReadoutIterations = 3;
// A regression step is significant below this chi-square p-value.
constexpr double kReadoutStepP = 0.01;

}  // namespace

absl::Status FitReadoutCandidate(const Candidate& candidate, const FitContext& ctx,
                                 CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  ASSIGN_OR_RETURN(GyroConfig* gc, CandidateGyro(fit.model.config, candidate.gyro));
  const ModelState& model = *ctx.model;
  const OpenEndedOptions o = ModelOpenEndedOptions(model, opt);
  // Gauss-Newton: the deviation is linear in E about the model it is measured from; a few
  // iterations, each regressing the deviation of the model with the E so far, while the step is
  // significant (below).
  const ModelRun* from_run = ctx.model_run;
  const ModelState* from = &model;
  // E changes the gyro's readings, not the star-tracker correction: one corrected copy serves
  // every regression and run.
  const std::vector<TelemetryFrame> corrected =
      CorrectStarTracker(*ctx.frames, *ctx.rates, model.correction);
  Eigen::Matrix3d E = Eigen::Matrix3d::Zero();
  ReadoutFit readout;
  double first_evidence = 0.0;
  for (int iteration = 0; iteration < kReadoutIterations; ++iteration) {
    auto series = MeasureDeviations(from->config, from_run->gyros, corrected, *ctx.rates,
                                    *from_run, {candidate.gyro});
    if (!series.ok()) return series.status();
    readout = FitReadoutDistortion(series->front(), ModelRandomWalk(model, candidate.gyro),
                                   ModelInitialDriftSigma(model), o);
    if (readout.group.columns.empty()) return absl::OkStatus();
    if (iteration == 0) first_evidence = readout.group.evidence;
    const Eigen::Matrix3d step = ReadoutDistortion(readout.group);
    E += step;
    gc->readout_distortion += step;
    auto run = RunModel(fit.model.config, fit.model.options, corrected);
    ++fit.runs;
    if (!run.ok()) return run.status();
    fit.run = std::move(*run);
    from_run = &fit.run;
    from = &fit.model;
    // The filter re-estimates its other states with E held, so the next deviation may still
    // carry a part of E; another step only while this one was significant (its chi-square on
    // the coefficients' covariance above the 0.99 quantile).
    const int n = static_cast<int>(readout.group.columns.size());
    Eigen::VectorXd a(n);
    for (int i = 0; i < n; ++i) a(i) = readout.group.columns[i].value;
    const double chi2 = a.dot(readout.group.covariance.ldlt().solve(a));
    if (!(ChiSquareSurvival(chi2, n) < kReadoutStepP)) break;
  }
  // The group as reported: the whole E on the last regression's covariance.
  for (FittedColumn& c : readout.group.columns) {
    c.value = (E.array() * ReadoutPattern(c.column.readout_index).array()).sum();
  }
  fit.parameters = static_cast<int>(readout.group.columns.size());
  fit.occam = ReadoutOccam(readout.group);
  fit.readout_distortion = gc->readout_distortion;
  fit.fitted = ReadoutParameters(readout.group);
  fit.description = DescribeGroup(readout.group, o);
  fit.notes.push_back(absl::StrFormat(
      "the gyro's deviation from the model regressed on the readout distortion's five patterns "
      "(docs/discovery.md, \"The open-ended stage\"): 2 ln B = %.1f; held at the fitted E "
      "(%d filter run%s), the filter's -2 log L is the candidate's, less Laplace's Occam term "
      "%.1f of the five coefficients",
      first_evidence, fit.runs, fit.runs == 1 ? "" : "s", fit.occam));
  return absl::OkStatus();
}

absl::Status FitSunCandidate(const Candidate& candidate, const FitContext& ctx,
                             CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  if (FindGyroMutable(fit.model.config, candidate.gyro) == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat("candidate gyro ", candidate.gyro, " is not configured"));
  }
  const ModelState& model = *ctx.model;
  const std::vector<TelemetryFrame> corrected =
      CorrectStarTracker(*ctx.frames, *ctx.rates, model.correction);
  auto series = MeasureDeviations(model.config, ctx.model_run->gyros, corrected, *ctx.rates,
                                  *ctx.model_run, {candidate.gyro});
  if (!series.ok()) return series.status();
  OpenEndedOptions o = ModelOpenEndedOptions(model, opt);
  o.orbital_period_s = CandidateOrbitalPeriod(ctx);
  o.epoch = ctx.frames->front().time;
  std::string sun_note;
  o.sun = SunRegressorsOf(*series, model.config, ctx.model_run->gyros, &sun_note, opt.orbit.get());
  const SunRegressors* regressors = FindSunRegressors(o.sun, candidate.gyro);
  if (regressors == nullptr) {
    if (!sun_note.empty()) fit.notes.push_back(sun_note);
    return absl::OkStatus();
  }
  const SunFamilyFit sun =
      FitSunFamilies(series->front(), ModelRandomWalk(model, candidate.gyro),
                     ModelInitialDriftSigma(model), o, HeldSunFaces(model, candidate.gyro));
  const SelectedGroup& g = sun.group;
  if (g.sun_face < 0 || g.columns.empty()) return absl::OkStatus();
  // The sun enters a round as the open-ended basis's choice for the gyro: when another group of
  // the basis (a ramp, an orbital harmonic, a case-fixed drift, ...) describes the deviation with
  // decisively more evidence (replacing it by the sun loses o.ambiguity or more), the stage would
  // select that group first, and the sun is not the description. Within o.ambiguity the recording
  // cannot tell the two apart (a constant illumination and a case-fixed drift: a face the sun
  // lights at a constant level): the sun is an alternative to that group and is fitted.
  if (sun.best_other_evidence >= g.evidence + o.ambiguity) {
    fit.not_fitted = absl::StrFormat(
        "the sun's best face (%s, 2 ln B = %.1f averaged over the lags) is not the open-ended "
        "basis's first choice on gyro %d's deviation: \"%s\" has 2 ln B = %.1f",
        SunFaceName(g.sun_face), g.evidence, candidate.gyro, sun.best_other_label,
        sun.best_other_evidence);
    fit.notes.push_back(fit.not_fitted);
    return absl::OkStatus();
  }
  // A drift that returns to its mean (switching at random, driven by a quantity the telemetry
  // does not carry) is partly fitted by any regressor that changes in time: the face's terms at
  // the best lag against the stationary drift on the same deviation, for the round's physics
  // check (selection.cc CheckConstantEffect), as the library's constant effects of one gyro.
  {
    std::vector<std::vector<Eigen::Vector2d>> columns;
    std::vector<double> prior;
    const std::vector<double>& values =
        regressors->values[g.sun_face][g.columns.front().column.sun_lag];
    for (const FittedColumn& c : g.columns) {
      columns.push_back(TabulatedSignature(series->front(), values,
                                           Eigen::Vector3d::Unit(c.column.term.axis - 1)));
      prior.push_back(c.prior_sigma);
    }
    const ConstantEffectEvidence e = CompareConstantEffect(
        series->front(), ModelRandomWalk(model, candidate.gyro), ModelInitialDriftSigma(model),
        DegPerHourToRadPerSec(opt.c_sigma_deg_h), HeldSteps(model, candidate.gyro), columns,
        prior);
    fit.wander_compared = true;
    fit.wander_effect = e.effect;
    fit.wander_stationary = e.stationary;
    fit.wander_on_top = e.on_top;
  }
  // Held at the best lag's values as a correction of the gyro's readings, refitted.
  const CarriedAttitude attitude = AttitudeAlongRecording(corrected, *ctx.rates, *ctx.model_run);
  fit.model.correction.reading_shifts.push_back(SunReadingShift(
      g, series->front(), *regressors, corrected, attitude,
      ModelMounting_b_k(model.config, ctx.model_run->gyros, candidate.gyro)));
  fit.model.added.push_back(HeldSunGroupName(candidate.gyro, g.label));
  auto run = RunModel(fit.model.config, fit.model.options,
                      CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction));
  ++fit.runs;
  if (!run.ok()) return run.status();
  fit.run = std::move(*run);
  const double lag_cost = std::max(0.0, sun.best_lag_evidence - g.evidence);
  const double coefficients_occam = ReadoutOccam(g);
  fit.parameters = static_cast<int>(g.columns.size());
  fit.occam = coefficients_occam + lag_cost;
  fit.fitted = SunParameters(g);
  fit.time.kind = kTimeFollowsSun;
  fit.description =
      absl::StrFormat("gyro %d: %s%s", candidate.gyro, DescribeSunGroup(g, opt.orbit != nullptr),
                      DescribeAlternatives(g));
  fit.notes.push_back(absl::StrFormat(
      "the gyro's deviation from the model regressed on the sun's families (docs/discovery.md, "
      "\"A drift that follows the sun\"): face %s has the most evidence of the %d faces tried, "
      "2 ln B = %.1f averaged over the lags (%.1f at its best lag, %s); held at that lag's values "
      "as a correction of gyro %d's readings (the filter has no state for the thermal lag), the "
      "filter's -2 log L is the candidate's, less Laplace's Occam term %.1f of the three "
      "coefficients and the lag's cost %.1f (2 ln B at the best lag less its average over the "
      "lags); values and sigmas are the regression's",
      SunFaceName(g.sun_face), g.groups_tested, g.evidence, sun.best_lag_evidence, g.label,
      candidate.gyro, coefficients_occam, lag_cost));
  return absl::OkStatus();
}

}  // namespace esg::estimator::discovery
