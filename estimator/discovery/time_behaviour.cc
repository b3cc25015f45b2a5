#include "estimator/discovery/time_behaviour.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <functional>
#include <optional>
#include <iterator>
#include <map>
#include <vector>
#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/discovery/profile_interval.h"
#include "estimator/statistics.h"
#include "estimator/drift_model.h"
#include "estimator/model_terms.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

namespace {

using Eigen::Vector3d;

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

}  // namespace

namespace {

// The onset search of a drift step (docs/discovery.md, "Time behaviour"): coarse onsets at
// k D / kOnsetCoarse (D the recording's length, k = 1 .. kOnsetCoarse - 1), then twice a grid
// kOnsetRefine times finer within one spacing of the best onset so far.
constexpr int kOnsetCoarse = 12;
constexpr int kOnsetRefine = 4;
// A coefficient the model holds is put in the filter's layout with this prior so that it can be
// released at the onset; before it the filter keeps it at its configured value.
constexpr double kHeldSigmaDegH = 1e-6;
constexpr double kHeldSigmaArcsec = 1e-6;
// chi-square(1) 95% quantile: the onset interval is where -2 log L stays within it of its minimum.
constexpr double kOnsetIntervalDrop = kProfileIntervalDrop;
// The readout-jump alternative (D43) is profiled over at most this many of the step's onsets
// inside its interval, nearest the best first.
constexpr size_t kReadoutOnsets = 8;

// The first frame at or after `t`.
int FrameAtOrAfter(const std::vector<TelemetryFrame>& frames, absl::Time t) {
  auto it = std::lower_bound(frames.begin(), frames.end(), t,
                             [](const TelemetryFrame& f, absl::Time x) { return f.time < x; });
  return static_cast<int>(it - frames.begin());
}

// The part of a drift step's search that every onset shares: the recording (its star tracker
// corrected as the model corrects it), the run without the step with checkpoints at the onsets
// of the grids, and each onset's profiled -2 log L with the best so far.
struct OnsetSearch {
  const Candidate& candidate;
  CandidateFit& fit;
  std::vector<TelemetryFrame> frames;
  double step_sigma = 0.0;  // the step's prior 1-sigma [rad/s]
  // The coefficients released at the onset (drift_model.h theta): C1 for a drift step.
  int first = kThetaC1;
  int count = 3;
  // A transient from an onset (FitTransient) releases nothing: the run from onset frame f has
  // the configuration this gives (its terms switched on at the onset), and the run without it
  // `base_config` (the same terms, inert); unset, both are the model's.
  std::function<SpacecraftConfig(int f)> config_at;
  std::optional<SpacecraftConfig> base_config;

  const SpacecraftConfig& BaseConfig() const {
    return base_config.has_value() ? *base_config : fit.model.config;
  }
  ModelRun prefix;
  std::map<int, SessionCheckpoint> checkpoints;
  std::map<int, double> value;  // onset frame -> profiled -2 log L
  int best_frame = -1;
  double best_value = 0.0;
  ModelRun best_run;
  SessionOptions best_options;

  // The run with `options` from onset frame f: the prefix's steps before f, then a run continued
  // from the checkpoint at f.
  absl::StatusOr<ModelRun> RunFrom(int f, const SessionOptions& options) {
    ModelRunOptions ro;
    ro.start = &checkpoints[f];
    ro.start_frame = f;
    auto tail = config_at ? RunModel(config_at(f), options, frames, ro)
                          : RunModel(fit.model.config, options, frames, ro);
    ++fit.runs;
    if (!tail.ok()) return tail.status();
    ModelRun run;
    for (const StepRecord& s : prefix.steps) {
      if (s.frame < f) run.steps.push_back(s);
    }
    run.steps.insert(run.steps.end(), std::make_move_iterator(tail->steps.begin()),
                     std::make_move_iterator(tail->steps.end()));
    run.gyros = std::move(tail->gyros);
    run.resets = tail->resets;
    run.rejections = tail->rejections;
    return run;
  }

  // One onset: continue from the checkpoint with the released states (C1 for a drift step)
  // released at the onset frame.
  absl::Status Evaluate(int f) {
    if (value.count(f) || !checkpoints.count(f)) return absl::OkStatus();
    SessionOptions options = fit.model.options;
    if (!config_at) {
      options.coefficient_releases.push_back(
          {candidate.gyro, first, count, frames[f].time, step_sigma});
    }
    ASSIGN_OR_RETURN(ModelRun run, RunFrom(f, options));
    const double v = Profile(run).value;
    value[f] = v;
    if (best_frame < 0 || v < best_value) {
      best_frame = f;
      best_value = v;
      best_run = std::move(run);
      best_options = options;
    }
    return absl::OkStatus();
  }

  // Further refinements, each kOnsetRefine times finer within one spacing of the best onset so
  // far, down to one frame, while the step is significant at the onsets searched so far (else
  // the onset does not matter: the candidate is not taken): the profile of a real step is
  // sharp, a few minutes wide for 0.04 deg/h against 5 arcsec star-tracker noise. The
  // checkpoints of a level come from a short run continued from the nearest earlier one.
  absl::Status Refine(absl::Duration spacing, double base_value, double alpha) {
    const int n = static_cast<int>(frames.size());
    const absl::Duration frame_step =
        (frames.back().time - frames.front().time) / std::max(1, n - 1);
    while (spacing > frame_step) {
      // The evidence integrated over the onsets is at most the best onset's (an average): below
      // the threshold of a single comparison the step cannot be taken.
      if (!(base_value - best_value > EvidenceThreshold(alpha, 1))) break;
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
      auto more = RunModel(BaseConfig(), fit.model.options, frames, ro);
      ++fit.runs;
      if (!more.ok()) return more.status();
      for (size_t j = 0; j < more->checkpoints.size(); ++j) {
        checkpoints[new_frames[j]] = std::move(more->checkpoints[j]);
      }
      for (int f : new_frames) RETURN_IF_ERROR(Evaluate(f));
    }
    return absl::OkStatus();
  }
};

// The likelihood over the onset, in hours from the start, and what it gives: the prior weights
// of the evidence, the best onset and its interval.
struct OnsetProfile {
  std::vector<std::pair<double, double>> points;  // hours, value
  size_t best = 0;
  double lower = 0.0, upper = 0.0;  // [h]
};

// The onset interval: where -2 log L stays within kOnsetIntervalDrop of its minimum, linear
// between evaluated onsets, clipped to the onsets searched. Also the evidence's prior points in
// `fit`: the onset integrated over a prior uniform across the span searched, by the trapezoid
// rule on the onsets evaluated (refined to one frame near the best); each onset's run is already
// the step's marginal likelihood (its size integrated over its prior).
OnsetProfile ProfileOnsets(const OnsetSearch& search, CandidateFit& fit) {
  OnsetProfile p;
  // A release at frame f widens the coefficients before the propagation from frame f - 1: the
  // modelled drift changes from frames[f - 1].time on, the onset reported.
  for (const auto& [f, v] : search.value) {
    p.points.emplace_back(HoursSinceStart(search.frames, f - 1), v);
  }
  const std::vector<std::pair<double, double>>& profile = p.points;
  fit.onset_profile = profile;
  if (profile.size() == 1) {
    fit.prior_points.emplace_back(1.0, profile.front().second);
  } else {
    const double span_h = profile.back().first - profile.front().first;
    for (size_t j = 0; j < profile.size(); ++j) {
      const double left = j > 0 ? profile[j].first - profile[j - 1].first : 0.0;
      const double right = j + 1 < profile.size() ? profile[j + 1].first - profile[j].first : 0.0;
      fit.prior_points.emplace_back(0.5 * (left + right) / span_h, profile[j].second);
    }
  }
  for (size_t j = 0; j < profile.size(); ++j) {
    if (profile[j].second < profile[p.best].second) p.best = j;
  }
  const LevelInterval in =
      IntervalAtLevel(profile, p.best, profile[p.best].second + kOnsetIntervalDrop);
  p.lower = in.lower;
  p.upper = in.upper;
  return p;
}

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

// Whether a step found by releasing coefficients at its onset carries its likelihood gain
// (docs/discovery.md, "A step must carry its gain"). Releasing a state's variance at T does two
// things: it lets the filter estimate a step, and it widens the covariance at T. Where the
// model's covariance is too small there (after a star-tracker outage, say), the widening alone
// lowers -2 log L, with no coefficient changed. So the step found must carry the gain itself: a
// run of the model without any release, the step `step_rad_s` (the group's estimate after the
// onset less the one at it) held at that value from the onset as switched-on basis terms
// (CoefficientStepTerms, sigma 0), must improve -2 log L on the run without the step by at least
// the chi-square bound of `count` degrees of freedom at level alpha (a likelihood ratio with the
// group's coefficients estimated). One run more per step found. Returns an empty string when it
// does (or when the gyro's basis has no room for the terms: the evidence alone decides), else
// the note that says why nothing was fitted.
absl::StatusOr<std::string> StepWithoutItsGain(OnsetSearch& search, const std::string& name,
                                               int first, const Eigen::VectorXd& step_rad_s,
                                               absl::Time onset, double alpha, double gain) {
  SpacecraftConfig held = search.BaseConfig();
  ASSIGN_OR_RETURN(GyroConfig * g, CandidateGyro(held, search.candidate.gyro));
  const std::vector<BasisTerm> terms = CoefficientStepTerms(first, step_rad_s, onset, 0.0);
  if (g->basis_terms.size() + terms.size() > static_cast<size_t>(kMaxBasisTermsPerGyro)) {
    return std::string();
  }
  g->basis_terms.insert(g->basis_terms.end(), terms.begin(), terms.end());
  auto run = RunModel(held, search.fit.model.options, search.frames);
  ++search.fit.runs;
  if (!run.ok()) return run.status();
  const double held_gain = Profile(search.prefix).value - Profile(*run).value;
  const int count = static_cast<int>(step_rad_s.size());
  const double bound = ChiSquareQuantile(1.0 - alpha, static_cast<double>(count));
  if (held_gain >= bound) {
    search.fit.notes.push_back(absl::StrFormat(
        "held from its onset without the release, the step of %s improves -2 log L by %.1f (the "
        "%.0f%% chi-square bound %.2f for %d parameter%s): it carries its gain",
        name, held_gain, 100.0 * (1.0 - alpha), bound, count, count == 1 ? "" : "s"));
    return std::string();
  }
  return absl::StrFormat(
      "a step of %s not fitted: -2 log L improves by %.1f with the coefficient%s released at the "
      "best onset, but by %.1f with the step found held from it (below the %.0f%% chi-square bound "
      "%.2f for %d parameter%s): the gain comes from the variance released at the onset (the "
      "model's covariance too small there), not from a change of the coefficient%s",
      name, gain, count == 1 ? "" : "s", held_gain, 100.0 * (1.0 - alpha), bound, count,
      count == 1 ? "" : "s", count == 1 ? "" : "s");
}

// The fit's onset with its interval (TimeBehaviour of a step).
void DescribeOnset(const OnsetSearch& search, const OnsetProfile& p, CandidateFit& fit) {
  const std::vector<TelemetryFrame>& frames = search.frames;
  const absl::Time t0 = frames.front().time;
  fit.time.onset = frames[search.best_frame - 1].time;
  fit.time.onset_hours = p.points[p.best].first;
  fit.time.onset_lower_hours = p.lower;
  fit.time.onset_upper_hours = p.upper;
  fit.time.onset_lower = t0 + absl::Hours(p.lower);
  fit.time.onset_upper = t0 + absl::Hours(p.upper);
  fit.time.onsets_searched = static_cast<int>(search.value.size());
}

// The fit's time behaviour, the step (C1 after it, the run's final estimate, against C1 at the
// onset, the checkpoint's), the onset with its interval and the profile's note; the best onset's
// model and run become the fit's.
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

// The onsets of the first two grids, k D / (kOnsetCoarse kOnsetRefine), k = 1 .. before the
// last frame (D the recording's length); empty for a recording too short for them.
std::vector<int> GridFrames(const std::vector<TelemetryFrame>& frames) {
  const int n = static_cast<int>(frames.size());
  std::vector<int> grid_frames;
  if (n < 2) return grid_frames;
  const absl::Time t0 = frames.front().time;
  const absl::Duration length = frames.back().time - t0;
  const int fine = kOnsetCoarse * kOnsetRefine;
  for (int k = 1; k < fine; ++k)
    grid_frames.push_back(FrameAtOrAfter(frames, t0 + length * k / fine));
  grid_frames.erase(std::unique(grid_frames.begin(), grid_frames.end()), grid_frames.end());
  while (!grid_frames.empty() && grid_frames.back() >= n - 1) grid_frames.pop_back();
  return grid_frames;
}

// The prefix run without the step, with checkpoints before the onsets of `grid_frames`.
absl::Status RunPrefix(OnsetSearch& search, const std::vector<int>& grid_frames) {
  CandidateFit& fit = search.fit;
  ModelRunOptions prefix_options;
  prefix_options.checkpoint_frames = grid_frames;
  auto prefix = RunModel(search.BaseConfig(), fit.model.options, search.frames, prefix_options);
  ++fit.runs;
  if (!prefix.ok()) return prefix.status();
  for (size_t j = 0; j < prefix->checkpoints.size(); ++j) {
    search.checkpoints[grid_frames[j]] = std::move(prefix->checkpoints[j]);
  }
  search.prefix = *std::move(prefix);
  return absl::OkStatus();
}

// The coarse grid, the finer grid within one coarse spacing of its best onset, and the
// refinements while the step is significant (`base_value` the model's -2 log L without it).
// False when no onset could be searched.
absl::StatusOr<bool> SearchOnsets(OnsetSearch& search, const std::vector<int>& grid_frames,
                                  double base_value, double alpha) {
  const std::vector<TelemetryFrame>& frames = search.frames;
  const absl::Duration length = frames.back().time - frames.front().time;
  for (size_t j = kOnsetRefine - 1; j < grid_frames.size(); j += kOnsetRefine) {
    RETURN_IF_ERROR(search.Evaluate(grid_frames[j]));
  }
  // A recording too short for the coarse grid: every onset of the finer.
  if (search.best_frame < 0) {
    for (int f : grid_frames) RETURN_IF_ERROR(search.Evaluate(f));
  }
  if (search.best_frame < 1) return false;
  // Refinement 1: the finer grid within one coarse spacing of the best coarse onset.
  const absl::Duration spacing = length / kOnsetCoarse;
  for (int f : grid_frames) {
    if (absl::AbsDuration(frames[f].time - frames[search.best_frame].time) <= spacing) {
      RETURN_IF_ERROR(search.Evaluate(f));
    }
  }
  RETURN_IF_ERROR(search.Refine(length / (kOnsetCoarse * kOnsetRefine), base_value, alpha));
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

std::vector<BasisTerm> CoefficientStepTerms(int first, const Eigen::VectorXd& step_rad_s,
                                            absl::Time onset, double sigma) {
  // Each coefficient's regressor of eq. (1), (10) as monomials (drift_model.h
  // CoefficientMonomials).
  std::vector<BasisTerm> terms;
  for (int j = 0; j < step_rad_s.size(); ++j) {
    for (const CoefficientMonomial& m : CoefficientMonomials(first + j)) {
      BasisTerm t;
      t.kind = BasisKind::kSpinAxisHarmonic;
      t.axis = m.axis;
      t.exponents = m.exponents;
      t.epoch = onset;
      t.value = m.sign * step_rad_s(j);
      t.sigma = sigma;
      terms.push_back(t);
    }
  }
  return terms;
}

std::vector<CoefficientGroup> StepGroupsInUse(const GyroConfig& gyro) {
  const DriftVector value = gyro.model.AsVector(), sigma = gyro.model_sigma.AsVector();
  auto in_use = [&](int first, int count) {
    for (int i = first; i < first + count; ++i) {
      if (value(i) != 0.0 || sigma(i) > 0.0) return true;
    }
    return false;
  };
  // The fixed terms' table (model_terms.h), in theta order: k0 every model's; C1 is the drift
  // step's; the others where in use. The step's name is the key's with "Step" before its unit.
  std::vector<CoefficientGroup> out;
  for (const FixedTermKey& key : FixedTermKeys()) {
    if (key.first_theta_index == kThetaC1) continue;
    const int count = std::max(key.components, 1);  // a scalar key has no components
    if (key.first_theta_index != kThetaK0 && !in_use(key.first_theta_index, count)) continue;
    std::string json_name(key.json_key);
    const size_t unit_at = json_name.find("DegH");
    json_name.insert(unit_at == std::string::npos ? json_name.size() : unit_at, "Step");
    out.push_back({std::string(key.symbol), json_name, key.first_theta_index, count});
  }
  return out;
}

namespace {

// One group's search and what it gives: the onset profile (its prior points and interval), the
// best onset's run and options, the step with its 1-sigma, and the evidence integrated over the
// onsets against the model without the step.
struct GroupStep {
  CoefficientGroup group;
  CandidateFit scratch;  // the profile's prior points and onset profile
  OnsetProfile profile;
  int best_frame = -1;
  ModelRun run;
  SessionOptions options;
  Eigen::VectorXd step, step_sigma;  // [rad/s]
  double evidence = 0.0;             // 2 ln B over the onsets
  absl::Time onset_time;
};

// The step of the group at the best onset: the estimate after it (the run's final) less the
// one at the onset (the checkpoint's); its 1-sigma combines both estimates' sigmas (the
// estimate before the onset enters the one after it through the prior only).
absl::Status StepOf(OnsetSearch& search, GroupStep& g) {
  auto at_onset = EstimationSession::FromCheckpoint(search.fit.model.config, search.best_options,
                                                    search.checkpoints[search.best_frame]);
  if (!at_onset.ok()) return at_onset.status();
  const std::vector<GyroEstimate> before_all = at_onset->Gyros();
  const GyroEstimate* before = FindEstimate(before_all, search.candidate.gyro);
  const GyroEstimate* after = FindEstimate(search.best_run.gyros, search.candidate.gyro);
  g.step = Eigen::VectorXd::Zero(g.group.count);
  g.step_sigma = Eigen::VectorXd::Zero(g.group.count);
  if (before == nullptr || after == nullptr) return absl::OkStatus();
  const DriftVector b = before->coefficients.AsVector(), a = after->coefficients.AsVector();
  const DriftVector sb = before->sigma.AsVector(), sa = after->sigma.AsVector();
  for (int j = 0; j < g.group.count; ++j) {
    const int i = g.group.first + j;
    g.step(j) = a(i) - b(i);
    g.step_sigma(j) = std::hypot(sa(i), sb(i));
  }
  return absl::OkStatus();
}

}  // namespace

// The search as a sequence: the groups of the model in use made releasable, one run without the
// step with checkpoints shared by the groups, each group's onset search and profile, the group
// of the largest evidence, its step described and its basis terms.
absl::Status FitCoefficientStep(const Candidate& candidate, const FitContext& ctx,
                                CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  ASSIGN_OR_RETURN(const GyroConfig* g, CandidateGyro(fit.model.config, candidate.gyro));
  const std::vector<CoefficientGroup> groups = StepGroupsInUse(*g);
  for (const CoefficientGroup& group : groups) {
    ReleaseHeldCoefficients(fit.model.config, candidate.gyro, group.first, group.count,
                            DegPerHourToRadPerSec(kHeldSigmaDegH));
  }
  fit.time.kind = kTimeCoefficientStep;
  fit.parameters = 0;
  fit.run = *ctx.model_run;
  const std::vector<TelemetryFrame> frames =
      CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction);
  const std::vector<int> grid_frames = GridFrames(frames);
  if (grid_frames.empty()) return absl::OkStatus();  // too short: no step fitted
  const double base_value = Profile(*ctx.model_run).value;

  std::vector<GroupStep> steps;
  std::vector<std::string> refused_notes;  // groups whose step does not carry its gain
  std::map<int, SessionCheckpoint> checkpoints;
  ModelRun prefix;
  for (const CoefficientGroup& group : groups) {
    OnsetSearch search{candidate, fit, frames};
    search.step_sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
    search.first = group.first;
    search.count = group.count;
    if (checkpoints.empty()) {
      RETURN_IF_ERROR(RunPrefix(search, grid_frames));
    } else {  // the run without the step is the same for every group
      search.checkpoints = checkpoints;
      search.prefix = prefix;
    }
    ASSIGN_OR_RETURN(const bool searched,
                     SearchOnsets(search, grid_frames, base_value, opt.alpha));
    checkpoints = search.checkpoints;
    prefix = search.prefix;
    if (!searched) continue;
    GroupStep step;
    step.group = group;
    step.profile = ProfileOnsets(search, step.scratch);
    std::vector<std::pair<double, double>> points;
    for (const auto& [w, v] : step.scratch.prior_points) points.emplace_back(w, base_value - v);
    step.evidence = EvidenceOverPrior(points);
    RETURN_IF_ERROR(StepOf(search, step));
    ASSIGN_OR_RETURN(const std::string refused,
                     StepWithoutItsGain(search, group.name, group.first, step.step,
                                        frames[search.best_frame - 1].time, opt.alpha,
                                        base_value - search.best_value));
    if (!refused.empty()) {
      refused_notes.push_back(refused);
      continue;
    }
    step.best_frame = search.best_frame;
    step.onset_time = frames[search.best_frame - 1].time;
    DescribeOnset(search, step.profile, step.scratch);
    step.run = std::move(search.best_run);
    step.options = search.best_options;
    steps.push_back(std::move(step));
  }
  fit.notes.insert(fit.notes.end(), refused_notes.begin(), refused_notes.end());
  if (steps.empty()) {
    fit.not_fitted = absl::StrJoin(refused_notes, "; ");
    return absl::OkStatus();
  }

  // The evidence: the groups equally likely a priori, each one's onsets integrated over the
  // uniform prior (its prior points weighted by 1 / the number of groups); the finding is the
  // group of the largest evidence.
  size_t best = 0;
  for (size_t k = 0; k < steps.size(); ++k) {
    for (const auto& [w, v] : steps[k].scratch.prior_points) {
      fit.prior_points.emplace_back(w / static_cast<double>(groups.size()), v);
    }
    if (steps[k].evidence > steps[best].evidence) best = k;
  }
  GroupStep& s = steps[best];
  fit.parameters = s.group.count;
  fit.time = s.scratch.time;
  fit.time.kind = kTimeCoefficientStep;
  fit.onset_profile = s.scratch.onset_profile;
  fit.model.options = s.options;
  fit.run = std::move(s.run);

  const double deg_h = DegH(1.0);
  std::string sizes;
  for (int j = 0; j < s.group.count; ++j) {
    const std::string name = s.group.count == 1 ? std::string(s.group.json_name)
                                                : absl::StrFormat("%s[%d]", s.group.json_name, j);
    fit.fitted.push_back({name, s.step(j) * deg_h, s.step_sigma(j) * deg_h, "deg/h"});
    absl::StrAppend(&sizes, j == 0 ? "" : ", ",
                    absl::StrFormat("%+.4f +- %.4f", s.step(j) * deg_h, s.step_sigma(j) * deg_h));
  }
  const OnsetProfile& p = s.profile;
  const double onset_hours = p.points[p.best].first;
  fit.fitted.push_back({"onsetHours", onset_hours, 0.5 * (p.upper - p.lower), "h"});
  fit.fitted.push_back({"onsetLowerHours", p.lower, 0.0, "h"});
  fit.fitted.push_back({"onsetUpperHours", p.upper, 0.0, "h"});

  const double sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
  const std::vector<BasisTerm> terms = CoefficientStepTerms(s.group.first, s.step, s.onset_time,
                                                            sigma);
  const int held = static_cast<int>(g->basis_terms.size());
  if (held + static_cast<int>(terms.size()) <= kMaxBasisTermsPerGyro) {
    fit.basis_terms = terms;
  } else {
    fit.notes.push_back(absl::StrFormat(
        "no basis terms for the step: gyro %d's basis holds %d terms, at most %d (%d more needed)",
        candidate.gyro, held, kMaxBasisTermsPerGyro, terms.size()));
  }
  fit.description = absl::StrFormat(
      "a step of %s of gyro %d (eq. %s) at %.2f h from the start (95%% %.2f-%.2f h): %s%s deg/h "
      "(%s after the step less before it)",
      s.group.name, candidate.gyro, s.group.first == kThetaK0 || s.group.first >= kThetaMu
                                        ? "(1)"
                                        : "(10)",
      onset_hours, p.lower, p.upper, s.group.count == 1 ? "" : "(",
      absl::StrCat(sizes, s.group.count == 1 ? "" : ")"), s.group.name);
  for (const GroupStep& other : steps) {
    std::string profile_text;
    for (const auto& [h, v] : other.profile.points) {
      absl::StrAppend(&profile_text,
                      absl::StrFormat(" %.2f:%.1f", h, v - other.profile.points[other.profile.best].second));
    }
    fit.notes.push_back(absl::StrFormat(
        "a step of %s: 2 ln B = %.1f integrated over %d onsets, the best at %.2f h; likelihood "
        "over the onset (h from the start: -2 log L above the best):%s",
        other.group.name, other.evidence, other.profile.points.size(),
        other.profile.points[other.profile.best].first, profile_text));
  }
  fit.notes.push_back(absl::StrFormat(
      "%d filter runs for %d group%s: one without the step, the others continued from its "
      "checkpoints (each the part of a run after its onset)",
      fit.runs, groups.size(), groups.size() == 1 ? "" : "s"));
  return absl::OkStatus();
}

namespace {

// The warm-up's search over tau (docs/discovery.md, "Time behaviour"): kTauCoarse time constants
// equally spaced in ln tau across [kWarmUpMinTauHours, kWarmUpMaxTauHours] (factors of 1.9), then
// kTauRefine times the two points half a spacing either side of the best so far.
constexpr int kTauCoarse = 7;
constexpr int kTauRefine = 2;
// While the warm-up is significant at the time constants searched (as the step's onset search
// goes on only then), the two time constants that bracket each end of the interval are bisected
// in ln tau down to kTauResolution apart, at most kTauIntervalRuns runs: linear interpolation
// between points further apart puts the end inside a convex profile, the interval too narrow.
constexpr double kTauResolution = 0.02;  // in ln tau: 2% of tau
constexpr int kTauIntervalRuns = 10;
constexpr int kWarmUpTerms = 3;  // one exponential_decay term per case axis

// The model with the warm-up's three terms (time constant tau_h, epoch t0) appended to the gyro's
// basis, freed with the prior sigma [rad/s].
ModelState WithWarmUp(const ModelState& model, int gyro, absl::Time t0, double tau_h,
                      double sigma) {
  ModelState m = model;
  GyroConfig* g = FindGyroMutable(m.config, gyro);
  for (int axis = 1; axis <= kWarmUpTerms; ++axis) {
    BasisTerm t;
    t.kind = BasisKind::kExponentialDecay;
    t.axis = axis;
    t.time_constant = tau_h * kSecondsPerHour;
    t.epoch = t0;
    t.value = 0.0;
    t.sigma = sigma;
    g->basis_terms.push_back(t);
  }
  return m;
}

}  // namespace

// The search as a sequence: the coarse grid of time constants, its refinements, the profile's
// prior weights and interval, and the best run's amplitude described.
absl::Status FitWarmUp(const Candidate& candidate, const FitContext& ctx, CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  ASSIGN_OR_RETURN(const GyroConfig* g, CandidateGyro(fit.model.config, candidate.gyro));
  fit.time.kind = kTimeWarmUp;
  const int first_term = static_cast<int>(g->basis_terms.size());
  if (first_term + kWarmUpTerms > kMaxBasisTermsPerGyro || ctx.frames->size() < 2) {
    fit.parameters = 0;
    fit.run = *ctx.model_run;
    fit.notes.push_back(absl::StrFormat(
        "no warm-up fitted: gyro %d's basis holds %d terms, at most %d (three more needed)",
        candidate.gyro, first_term, kMaxBasisTermsPerGyro));
    return absl::OkStatus();
  }
  const std::vector<TelemetryFrame> frames =
      CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction);
  const absl::Time t0 = frames.front().time;
  const double sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
  const double log_min = std::log(kWarmUpMinTauHours), log_max = std::log(kWarmUpMaxTauHours);
  const double spacing = (log_max - log_min) / (kTauCoarse - 1);

  std::map<double, double> value;  // ln(tau / h) -> profiled -2 log L
  std::map<double, Vector3d> amplitude;  // ln(tau / h) -> the run's final A [rad/s, case axes]
  double best_log = 0.0, best_value = 0.0;
  bool any = false;
  ModelRun best_run;
  auto evaluate = [&](double log_tau) -> absl::Status {
    log_tau = std::clamp(log_tau, log_min, log_max);
    for (const auto& [x, v] : value) {
      if (std::abs(x - log_tau) < 1e-9) return absl::OkStatus();
    }
    const ModelState m =
        WithWarmUp(fit.model, candidate.gyro, t0, std::exp(log_tau), sigma);
    auto run = RunModel(m.config, m.options, frames);
    ++fit.runs;
    if (!run.ok()) return run.status();
    const double v = Profile(*run).value;
    value[log_tau] = v;
    Vector3d a_k = Vector3d::Zero();
    if (const GyroEstimate* e = FindEstimate(run->gyros, candidate.gyro);
        e != nullptr && static_cast<int>(e->basis_terms.size()) >= first_term + kWarmUpTerms) {
      for (int i = 0; i < kWarmUpTerms; ++i) a_k(i) = e->basis_terms[first_term + i].value;
    }
    amplitude[log_tau] = a_k;
    if (!any || v < best_value) {
      any = true;
      best_value = v;
      best_log = log_tau;
      best_run = *std::move(run);
    }
    return absl::OkStatus();
  };
  for (int k = 0; k < kTauCoarse; ++k) RETURN_IF_ERROR(evaluate(log_min + k * spacing));
  for (int r = 1; r <= kTauRefine; ++r) {
    const double half = spacing / std::pow(2.0, r);
    const double centre = best_log;
    if (centre - half >= log_min - 1e-12) RETURN_IF_ERROR(evaluate(centre - half));
    if (centre + half <= log_max + 1e-12) RETURN_IF_ERROR(evaluate(centre + half));
  }
  // The interval's ends resolved (kTauResolution) while the warm-up is significant.
  if (Profile(*ctx.model_run).value - best_value > EvidenceThreshold(opt.alpha, 1)) {
    for (int extra = 0; extra < kTauIntervalRuns; ++extra) {
      const std::optional<double> middle = WidestEndBracketMiddle(
          ProfilePoints(value.begin(), value.end()), kOnsetIntervalDrop, kTauResolution);
      if (!middle.has_value()) break;
      RETURN_IF_ERROR(evaluate(*middle));
    }
  }

  // The evidence's prior points: tau integrated over a prior uniform in ln tau across the span
  // searched, by the trapezoid rule on the time constants evaluated (each run is already the
  // amplitude's marginal likelihood, freed with its prior).
  std::vector<std::pair<double, double>> profile(value.begin(), value.end());
  const double span = log_max - log_min;
  size_t best = 0;
  for (size_t j = 0; j < profile.size(); ++j) {
    const double left = j > 0 ? profile[j].first - profile[j - 1].first : 0.0;
    const double right = j + 1 < profile.size() ? profile[j + 1].first - profile[j].first : 0.0;
    fit.prior_points.emplace_back(0.5 * (left + right) / span, profile[j].second);
    if (profile[j].second < profile[best].second) best = j;
  }
  // The interval: where -2 log L stays within the chi-square(1) 95% quantile of its minimum,
  // linear in ln tau between the time constants evaluated, clipped to the span searched.
  const LevelInterval in =
      IntervalAtLevel(profile, best, profile[best].second + kOnsetIntervalDrop);
  const double lower = in.lower, upper = in.upper;
  const bool lower_open = in.lower_open, upper_open = in.upper_open;
  const double tau_h = std::exp(profile[best].first);
  const double lower_h = std::exp(lower), upper_h = std::exp(upper);

  fit.model = WithWarmUp(fit.model, candidate.gyro, t0, tau_h, sigma);
  fit.run = std::move(best_run);
  fit.parameters = kWarmUpTerms;
  fit.time.onset = t0;
  const GyroEstimate* e = FindEstimate(fit.run.gyros, candidate.gyro);
  Vector3d a = Vector3d::Zero(), a_sigma = Vector3d::Zero();
  if (e != nullptr && static_cast<int>(e->basis_terms.size()) >= first_term + kWarmUpTerms &&
      static_cast<int>(e->basis_sigma.size()) >= first_term + kWarmUpTerms) {
    for (int i = 0; i < kWarmUpTerms; ++i) {
      a(i) = e->basis_terms[first_term + i].value;
      a_sigma(i) = e->basis_sigma[first_term + i];
    }
  }
  const GyroConfig* gw = FindGyroMutable(fit.model.config, candidate.gyro);
  for (int i = 0; i < kWarmUpTerms; ++i) {
    BasisTerm t = gw->basis_terms[first_term + i];
    t.value = a(i);
    fit.basis_terms.push_back(t);
  }
  // The filter's sigma of A is at the best tau; A moves with tau, so its sigma adds the spread
  // tau's uncertainty gives (the delta method on the profile: dA/d ln tau from the time constants
  // evaluated at the interval's ends, times the 1-sigma of ln tau, the 95% half-width / 1.96).
  {
    auto inside = [&](const auto& point) {
      return point.first >= lower - 1e-12 && point.first <= upper + 1e-12;
    };
    auto lo = std::find_if(amplitude.begin(), amplitude.end(), inside);
    auto hi = std::find_if(amplitude.rbegin(), amplitude.rend(), inside);
    if (lo != amplitude.end() && hi != amplitude.rend() && hi->first > lo->first) {
      const Vector3d slope = (hi->second - lo->second) / (hi->first - lo->first);
      const double sigma_log_tau = 0.5 * (upper - lower) / 1.959963984540054;
      const Vector3d from_tau = slope.cwiseAbs() * sigma_log_tau;
      a_sigma = (a_sigma.cwiseAbs2() + from_tau.cwiseAbs2()).cwiseSqrt();
      fit.notes.push_back(absl::StrFormat(
          "the amplitude's 1-sigma includes tau's uncertainty: dA/d ln tau = %s deg/h (from "
          "tau = %.2f h to %.2f h), times the 1-sigma of ln tau %.3f, adds %s deg/h",
          absl::StrFormat("(%.4f, %.4f, %.4f)", DegH(slope.x()), DegH(slope.y()),
                          DegH(slope.z())),
          std::exp(lo->first), std::exp(hi->first), sigma_log_tau,
          absl::StrFormat("(%.4f, %.4f, %.4f)", DegH(from_tau.x()), DegH(from_tau.y()),
                          DegH(from_tau.z()))));
    }
  }
  AddVectorParameters("warmUpDegH", a, a_sigma, DegH(1.0), "deg/h", fit.fitted);
  const double size = a.norm();
  const double size_sigma =
      size > 0 ? std::sqrt((a.cwiseProduct(a_sigma)).squaredNorm()) / size : a_sigma.norm();
  fit.fitted.push_back({"warmUpSizeDegH", DegH(size), DegH(size_sigma), "deg/h"});
  fit.fitted.push_back({"tauHours", tau_h, 0.5 * (upper_h - lower_h), "h"});
  fit.fitted.push_back({"tauLowerHours", lower_h, 0.0, "h"});
  fit.fitted.push_back({"tauUpperHours", upper_h, 0.0, "h"});
  const Vector3d direction = size > 0 ? Vector3d(a / size) : Vector3d::Zero();
  fit.description = absl::StrFormat(
      "warm-up of gyro %d: a case-fixed drift along (%.2f, %.2f, %.2f) (case axes), %.3f +- "
      "%.3f deg/h at the recording's start, decaying with tau = %.1f h (95%% %.1f-%.1f h%s; "
      "an exponential transient from the start, tau searched over %.1f-%.0f h)",
      candidate.gyro, direction.x(), direction.y(), direction.z(), DegH(size), DegH(size_sigma),
      tau_h, lower_h, upper_h,
      lower_open || upper_open ? ", clipped: the interval reaches an end of the span searched"
                               : "",
      kWarmUpMinTauHours, kWarmUpMaxTauHours);
  std::string profile_text;
  for (const auto& [x, v] : profile) {
    absl::StrAppend(&profile_text, absl::StrFormat(" %.2f:%.1f", std::exp(x), v - best_value));
  }
  fit.notes.push_back(absl::StrCat(
      "likelihood over the time constant (h: -2 log L above the best; ", profile.size(),
      " time constants, integrated over a prior uniform in ln tau):", profile_text));
  return absl::OkStatus();
}

// The search as a sequence: the gyro's basis with three inert exponential_decay terms for the
// run without the transient and its checkpoints, the onset searched at the middle time constant,
// the time constant searched at the best onset, the evidence, and the transient described.
absl::Status FitTransient(const Candidate& candidate, const FitContext& ctx, CandidateFit& fit) {
  const DiagnoseOptions& opt = *ctx.options;
  ASSIGN_OR_RETURN(const GyroConfig* g, CandidateGyro(fit.model.config, candidate.gyro));
  fit.time.kind = kTimeTransient;
  fit.parameters = 0;
  fit.run = *ctx.model_run;
  const int first_term = static_cast<int>(g->basis_terms.size());
  if (first_term + kWarmUpTerms > kMaxBasisTermsPerGyro) {
    fit.notes.push_back(absl::StrFormat(
        "no transient fitted: gyro %d's basis holds %d terms, at most %d (three more needed)",
        candidate.gyro, first_term, kMaxBasisTermsPerGyro));
    return absl::OkStatus();
  }
  const double sigma = DegPerHourToRadPerSec(opt.c_sigma_deg_h);
  const double log_min = std::log(kWarmUpMinTauHours), log_max = std::log(kWarmUpMaxTauHours);
  const double spacing = (log_max - log_min) / (kTauCoarse - 1);
  const double log_tau0 = log_min + spacing * (kTauCoarse / 2);  // the grid's middle, 3.5 h
  double log_tau = log_tau0;

  OnsetSearch search{candidate, fit,
                     CorrectStarTracker(*ctx.frames, *ctx.rates, fit.model.correction)};
  const std::vector<TelemetryFrame>& frames = search.frames;
  const std::vector<int> grid_frames = GridFrames(frames);
  if (grid_frames.empty()) return absl::OkStatus();  // too short: no transient fitted
  const ModelState model = fit.model;
  // Before its onset a term is 0: the terms switched on after the last frame leave the run
  // without the transient as it is, and give its checkpoints the layout of the runs with it.
  search.base_config =
      WithWarmUp(model, candidate.gyro, frames.back().time + absl::Hours(1),
                 std::exp(log_tau0), sigma)
          .config;
  // The modelled drift changes from frames[f - 1].time on, as a release at frame f's does.
  search.config_at = [&](int f) {
    return WithWarmUp(model, candidate.gyro, frames[f - 1].time, std::exp(log_tau), sigma).config;
  };
  RETURN_IF_ERROR(RunPrefix(search, grid_frames));
  ASSIGN_OR_RETURN(const bool searched, SearchOnsets(search, grid_frames,
                                                     Profile(*ctx.model_run).value, opt.alpha));
  if (!searched) return absl::OkStatus();
  CandidateFit onsets;
  const OnsetProfile p = ProfileOnsets(search, onsets);
  const int onset_frame = search.best_frame;

  // The time constant at the best onset, on the warm-up's grid refined twice near its best.
  std::map<double, double> value;  // ln(tau / h) -> -2 log L
  std::map<double, Vector3d> amplitude, amplitude_sigma;
  auto amplitude_of = [&](const ModelRun& run, double lt) {
    const GyroEstimate* e = FindEstimate(run.gyros, candidate.gyro);
    Vector3d a = Vector3d::Zero(), s = Vector3d::Zero();
    if (e != nullptr && static_cast<int>(e->basis_terms.size()) >= first_term + kWarmUpTerms &&
        static_cast<int>(e->basis_sigma.size()) >= first_term + kWarmUpTerms) {
      for (int i = 0; i < kWarmUpTerms; ++i) {
        a(i) = e->basis_terms[first_term + i].value;
        s(i) = e->basis_sigma[first_term + i];
      }
    }
    amplitude[lt] = a;
    amplitude_sigma[lt] = s;
  };
  value[log_tau0] = search.value[onset_frame];
  amplitude_of(search.best_run, log_tau0);
  double best_log = log_tau0;
  ModelRun best_run = std::move(search.best_run);
  auto evaluate = [&](double lt) -> absl::Status {
    lt = std::clamp(lt, log_min, log_max);
    for (const auto& [x, v] : value) {
      if (std::abs(x - lt) < 1e-9) return absl::OkStatus();
    }
    log_tau = lt;
    ASSIGN_OR_RETURN(ModelRun run, search.RunFrom(onset_frame, fit.model.options));
    const double v = Profile(run).value;
    value[lt] = v;
    amplitude_of(run, lt);
    if (v < value[best_log]) {
      best_log = lt;
      best_run = std::move(run);
    }
    return absl::OkStatus();
  };
  for (int k = 0; k < kTauCoarse; ++k) RETURN_IF_ERROR(evaluate(log_min + k * spacing));
  for (int r = 1; r <= kTauRefine; ++r) {
    const double half = spacing / std::pow(2.0, r);
    const double centre = best_log;
    if (centre - half >= log_min - 1e-12) RETURN_IF_ERROR(evaluate(centre - half));
    if (centre + half <= log_max + 1e-12) RETURN_IF_ERROR(evaluate(centre + half));
  }
  // The interval's ends resolved as the warm-up's (kTauResolution, at most kTauIntervalRuns
  // more runs) while the transient is significant: the chord between coarse points lies above
  // the convex profile.
  if (Profile(*ctx.model_run).value - value[best_log] > EvidenceThreshold(opt.alpha, 1)) {
    for (int extra = 0; extra < kTauIntervalRuns; ++extra) {
      const std::optional<double> middle = WidestEndBracketMiddle(
          ProfilePoints(value.begin(), value.end()), kOnsetIntervalDrop, kTauResolution);
      if (!middle.has_value()) break;
      RETURN_IF_ERROR(evaluate(*middle));
    }
  }
  log_tau = best_log;

  // tau's interval: -2 log L within 3.84 of its minimum, linear in ln tau between the time
  // constants evaluated, clipped to the span searched.
  const ProfilePoints tau_profile(value.begin(), value.end());
  const size_t best = ProfileMinimum(tau_profile);
  const LevelInterval in =
      IntervalAtLevel(tau_profile, best, tau_profile[best].second + kOnsetIntervalDrop);
  const double lower = in.lower, upper = in.upper;

  // The evidence over onset and tau, separated: the onset's prior points (at the middle time
  // constant) each shifted by -2 ln R, R the likelihood integrated over a prior uniform in ln tau
  // at the best onset relative to its value at the middle time constant (exact when the
  // likelihood is a product of a function of the onset and one of tau).
  double min_value = tau_profile[best].second;
  double sum = 0.0;
  const double span = log_max - log_min;
  for (size_t j = 0; j < tau_profile.size(); ++j) {
    const double left = j > 0 ? tau_profile[j].first - tau_profile[j - 1].first : 0.0;
    const double right =
        j + 1 < tau_profile.size() ? tau_profile[j + 1].first - tau_profile[j].first : 0.0;
    sum += 0.5 * (left + right) / span * std::exp(-0.5 * (tau_profile[j].second - min_value));
  }
  const double log_r = -0.5 * (min_value - value[log_tau0]) + std::log(sum);
  for (const auto& [w, v] : onsets.prior_points) fit.prior_points.emplace_back(w, v - 2.0 * log_r);

  const double tau_h = std::exp(best_log);
  const double lower_h = std::exp(lower), upper_h = std::exp(upper);
  fit.parameters = kWarmUpTerms;
  DescribeOnset(search, p, fit);
  fit.time.kind = kTimeTransient;
  fit.onset_profile = onsets.onset_profile;
  fit.model = WithWarmUp(model, candidate.gyro, frames[onset_frame - 1].time, tau_h, sigma);
  fit.run = std::move(best_run);
  // A's sigma: the filter's at the best tau, and the spread tau's uncertainty gives (the delta
  // method: dA / d ln tau between the time constants beside the best, times the 95% half-width
  // of ln tau / 1.96), as the warm-up's.
  const Vector3d a = amplitude[best_log];
  Vector3d a_sigma = amplitude_sigma[best_log];
  {
    auto at = value.find(best_log);
    auto lo = at == value.begin() ? at : std::prev(at);
    auto hi = std::next(at) == value.end() ? at : std::next(at);
    if (hi->first > lo->first) {
      const Vector3d slope = (amplitude[hi->first] - amplitude[lo->first]) / (hi->first - lo->first);
      const double s_log_tau = 0.5 * (upper - lower) / 1.96;
      for (int i = 0; i < 3; ++i) a_sigma(i) = std::hypot(a_sigma(i), slope(i) * s_log_tau);
    }
  }
  const GyroConfig* gw = FindGyroMutable(fit.model.config, candidate.gyro);
  for (int i = 0; i < kWarmUpTerms; ++i) {
    BasisTerm t = gw->basis_terms[first_term + i];
    t.value = a(i);
    fit.basis_terms.push_back(t);
  }
  AddVectorParameters("transientDegH", a, a_sigma, DegH(1.0), "deg/h", fit.fitted);
  const double size = a.norm();
  const double size_sigma =
      size > 0 ? std::sqrt((a.cwiseProduct(a_sigma)).squaredNorm()) / size : a_sigma.norm();
  fit.fitted.push_back({"transientSizeDegH", DegH(size), DegH(size_sigma), "deg/h"});
  fit.fitted.push_back({"tauHours", tau_h, 0.5 * (upper_h - lower_h), "h"});
  fit.fitted.push_back({"tauLowerHours", lower_h, 0.0, "h"});
  fit.fitted.push_back({"tauUpperHours", upper_h, 0.0, "h"});
  const double onset_hours = p.points[p.best].first;
  fit.fitted.push_back({"onsetHours", onset_hours, 0.5 * (p.upper - p.lower), "h"});
  fit.fitted.push_back({"onsetLowerHours", p.lower, 0.0, "h"});
  fit.fitted.push_back({"onsetUpperHours", p.upper, 0.0, "h"});
  const Vector3d direction = size > 0 ? Vector3d(a / size) : Vector3d::Zero();
  fit.description = absl::StrFormat(
      "transient of gyro %d: a case-fixed drift along (%.2f, %.2f, %.2f) (case axes), %.3f +- "
      "%.3f deg/h at its onset %.2f h from the start (95%% %.2f-%.2f h), decaying with tau = "
      "%.1f h (95%% %.1f-%.1f h; an exponential transient from an onset, tau searched over "
      "%.1f-%.0f h)",
      candidate.gyro, direction.x(), direction.y(), direction.z(), DegH(size), DegH(size_sigma),
      onset_hours, p.lower, p.upper, tau_h, lower_h, upper_h, kWarmUpMinTauHours,
      kWarmUpMaxTauHours);
  std::string onset_text, tau_text;
  for (const auto& [h, v] : p.points) {
    absl::StrAppend(&onset_text, absl::StrFormat(" %.2f:%.1f", h, v - p.points[p.best].second));
  }
  for (const auto& [x, v] : tau_profile) {
    absl::StrAppend(&tau_text, absl::StrFormat(" %.2f:%.1f", std::exp(x), v - min_value));
  }
  fit.notes.push_back(absl::StrFormat(
      "likelihood over the onset at tau = %.2f h (h from the start: -2 log L above the best; %d "
      "onsets):%s",
      std::exp(log_tau0), p.points.size(), onset_text));
  fit.notes.push_back(absl::StrFormat(
      "likelihood over the time constant at the best onset (h: -2 log L above the best; %d time "
      "constants, integrated over a prior uniform in ln tau, 2 ln R = %.1f against %.2f h):%s",
      tau_profile.size(), 2.0 * log_r, std::exp(log_tau0), tau_text));
  fit.notes.push_back(absl::StrFormat(
      "%d filter runs: one without the transient, the others continued from its checkpoints",
      fit.runs));
  return absl::OkStatus();
}

void DescribeVoltageTrend(const SpacecraftConfig& config, const std::vector<TelemetryFrame>& frames,
                          int gyro, CandidateFit& fit) {
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
  std::array<RobustLine, 3> lines;
  for (int i = 0; i < 3; ++i) {
    const RobustLine& line = lines[i] = FitRobustLine(hours, u_mv[i]);
    const double sigma_mv_h =
        line.residual_sigma / std::sqrt(var_t * line.used / static_cast<double>(hours.size()));
    slope_mv_h(i) = line.slope;
    rate_um_h(i) = um(line.slope);
    rate_sigma_um_h(i) = std::abs(um(sigma_mv_h));
    if (sigma_mv_h > 0) chi2 += std::pow(line.slope / sigma_mv_h, 2);
  }
  // The series of the report's trend plot: the implied displacement, averaged over bins.
  DisplacementTrend& trend = fit.displacement_trend;
  const size_t n = hours.size();
  const size_t bins = std::min<size_t>(n, DisplacementTrend::kMaxSamples);
  for (size_t b = 0; b < bins; ++b) {
    const size_t first = b * n / bins, last = (b + 1) * n / bins;
    DisplacementTrend::Sample sample;
    for (size_t j = first; j < last; ++j) {
      sample.hours += hours[j];
      for (int i = 0; i < 3; ++i) sample.displacement_um[i] += um(u_mv[i][j]);
    }
    sample.hours /= static_cast<double>(last - first);
    for (double& d : sample.displacement_um) d /= static_cast<double>(last - first);
    trend.samples.push_back(sample);
  }
  for (int i = 0; i < 3; ++i) {
    trend.intercept_um[i] = um(lines[i].intercept);
    trend.rate_um_h[i] = rate_um_h(i);
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

}  // namespace esg::estimator::discovery
