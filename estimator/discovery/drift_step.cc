#include "estimator/discovery/drift_step.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/discovery/coefficient_step.h"
#include "estimator/discovery/onset_search.h"
#include "estimator/drift_model.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

namespace {

using Eigen::Vector3d;

double DegH(double x) { return RadPerSecToDegPerHour(x); }

// The misalignment states, held with this prior [arcsec] so that the competing readout jump can
// release them at an onset.
constexpr double kHeldSigmaArcsec = 1e-6;
// The readout-jump alternative (D43) is profiled over at most this many of the step's onsets
// inside its interval, nearest the best first.
constexpr size_t kReadoutOnsets = 8;

// The competing readout jump (D43): the same onsets, the gyro's misalignment states released
// instead of its C1 (a jump of its readings that does not grow). A drift step makes a ramp it
// cannot follow; a readout jump fitted as a drift step leaves the transient it explains.
absl::Status FitReadoutJump(OnsetSearch& search, const OnsetProfile& p,
                            const DiagnoseOptions& opt) {
  CandidateFit& fit = search.fit;
  const double readout_sigma = ArcsecToRad(opt.misalignment_sigma_arcsec);
  std::vector<int> near;
  for (const auto& [f, v] : search.value) {
    const double h = HoursSinceStart(search.frames, f - 1);
    if (h >= p.lower && h <= p.upper) near.push_back(f);
  }
  const int best_frame = search.best_frame;
  std::sort(near.begin(), near.end(),
            [&](int a, int b) { return std::abs(a - best_frame) < std::abs(b - best_frame); });
  if (near.size() > kReadoutOnsets) near.resize(kReadoutOnsets);
  for (int f : near) {
    SessionOptions options = fit.model.options;
    SessionOptions::CoefficientRelease release;
    release.gyro_id = search.candidate.gyro;
    release.time = search.frames[f].time;
    release.sigma = readout_sigma;
    release.misalignment = true;
    options.coefficient_releases.push_back(release);
    ASSIGN_OR_RETURN(ModelRun run, search.RunFrom(f, options));
    const double v = Profile(run).value;
    if (!fit.readout_fitted || v < fit.readout_value) {
      fit.readout_fitted = true;
      fit.readout_value = v;
      fit.readout_onset_hours = HoursSinceStart(search.frames, f - 1);
    }
  }
  if (fit.readout_fitted) {
    const double best = p.points[p.best].second;
    fit.notes.push_back(absl::StrFormat(
        "a jump of the gyro's readings at %.2f h (its misalignment released, prior %.0f "
        "arcsec; %d onsets in the interval) fits -2 log L %.1f %s the drift step's",
        fit.readout_onset_hours, opt.misalignment_sigma_arcsec, near.size(),
        std::abs(fit.readout_value - best), fit.readout_value <= best ? "below" : "above"));
  }
  return absl::OkStatus();
}

// The fit's time behaviour, the step (C1 after it, the run's final estimate, against C1 at the
// onset, the checkpoint's), the onset with its interval and the profile's note; the best onset's
// model and run become the fit's. False when the step does not carry its gain (StepWithoutItsGain).
absl::StatusOr<bool> DescribeStep(OnsetSearch& search, const OnsetProfile& p, double alpha,
                                  double base_value) {
  CandidateFit& fit = search.fit;
  const double onset_hours = p.points[p.best].first;
  DescribeOnset(search, p, fit);

  auto at_onset = EstimationSession::FromCheckpoint(fit.model.config, search.best_options,
                                                    search.checkpoints[search.best_frame]);
  if (!at_onset.ok()) return at_onset.status();
  const std::vector<GyroEstimate> before_all = at_onset->Gyros();
  const GyroEstimate* before = FindEstimate(before_all, search.candidate.gyro);
  const GyroEstimate* after = FindEstimate(search.best_run.gyros, search.candidate.gyro);
  if (before != nullptr && after != nullptr) {
    const Vector3d d = -(after->coefficients.C1 - before->coefficients.C1);
    ASSIGN_OR_RETURN(const std::string refused,
                     StepWithoutItsGain(search, "C1", kThetaC1, -d, fit.time.onset, alpha,
                                        base_value - search.best_value));
    if (!refused.empty()) {
      fit.notes.push_back(refused);
      fit.not_fitted = refused;
      return false;
    }
    const Vector3d d_sigma = after->sigma.C1;
    AddVectorParameters("driftStepDegH", d, d_sigma, DegH(1.0), "deg/h", fit.fitted);
    const double size = d.norm();
    const double size_sigma =
        size > 0 ? std::sqrt((d.cwiseProduct(d_sigma)).squaredNorm()) / size : d_sigma.norm();
    fit.fitted.push_back({"driftStepSizeDegH", DegH(size), DegH(size_sigma), "deg/h"});
  }
  fit.fitted.push_back({"onsetHours", onset_hours, 0.5 * (p.upper - p.lower), "h"});
  fit.fitted.push_back({"onsetLowerHours", p.lower, 0.0, "h"});
  fit.fitted.push_back({"onsetUpperHours", p.upper, 0.0, "h"});
  std::string profile_text;
  for (const auto& [h, v] : p.points) {
    absl::StrAppend(&profile_text, absl::StrFormat(" %.2f:%.1f", h, v - p.points[p.best].second));
  }
  fit.notes.push_back(absl::StrCat(
      "likelihood over the onset (h from the start: -2 log L above the best; ",
      search.value.size(), " onsets, integrated over a uniform prior):", profile_text));
  fit.model.options = search.best_options;
  fit.run = std::move(search.best_run);
  return true;
}

}  // namespace

// The search as a sequence: the gyro's C1 (and misalignment) made releasable, the run without the
// step with checkpoints, the coarse grid, its refinements, the onset's profile, the competing
// readout jump, and the step described.
absl::Status FitDriftStep(const Candidate& candidate, const FitContext& ctx, CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  ASSIGN_OR_RETURN(GyroConfig* g, CandidateGyro(fit.model.config, candidate.gyro));
  // The step d (case axes) enters eq. (10) as C1 -> C1 - d: (h h^T - I)(-d) = d - (h.d) h, the
  // part of d across the spin axis (the part along it moves nothing).
  ReleaseHeldCoefficients(fit.model.config, candidate.gyro, kThetaC1, 3,
                          DegPerHourToRadPerSec(kHeldSigmaDegH));
  // The misalignment states too, held the same way, for the competing readout jump (D43).
  if (!(g->misalignment_sigma > 0.0)) g->misalignment_sigma = ArcsecToRad(kHeldSigmaArcsec);
  OnsetSearch search{candidate, fit,
                     CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction)};
  search.step_sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
  const std::vector<TelemetryFrame>& frames = search.frames;
  fit.parameters = 3;
  fit.time.kind = "step";

  const std::vector<int> grid_frames = GridFrames(frames);
  if (grid_frames.empty()) return absl::OkStatus();  // too short: parameters stay 0
  RETURN_IF_ERROR(RunPrefix(search, grid_frames));
  const double base_value = Profile(*ctx.model_run).value;
  ASSIGN_OR_RETURN(const bool searched,
                   SearchOnsets(search, grid_frames, base_value, opt.alpha));
  if (!searched) {  // nothing to search: no step fitted
    fit.parameters = 0;
    fit.run = *ctx.model_run;
    return absl::OkStatus();
  }
  const OnsetProfile profile = ProfileOnsets(search, fit);
  RETURN_IF_ERROR(FitReadoutJump(search, profile, opt));
  ASSIGN_OR_RETURN(const bool carried, DescribeStep(search, profile, opt.alpha, base_value));
  if (!carried) {  // the gain is not the step's: no step fitted
    fit.parameters = 0;
    fit.prior_points.clear();
    fit.run = *ctx.model_run;
  }
  return absl::OkStatus();
}

}  // namespace esg::estimator::discovery
