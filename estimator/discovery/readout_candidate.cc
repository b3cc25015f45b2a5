#include "estimator/discovery/readout_candidate.h"

#include <utility>
#include <vector>

#include "Eigen/Cholesky"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/discovery/basis_stage.h"
#include "estimator/discovery/deviation.h"
#include "estimator/discovery/open_ended.h"
#include "estimator/statistics.h"

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
  GyroConfig* gc = FindGyroMutable(fit.model.config, candidate.gyro);
  if (gc == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat("candidate gyro ", candidate.gyro, " is not configured"));
  }
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

}  // namespace esg::estimator::discovery
