#include "estimator/discovery/onset_search.h"

#include <algorithm>
#include <cmath>
#include <iterator>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_format.h"
#include "estimator/discovery/profile_interval.h"
#include "estimator/statistics.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"

namespace esg::estimator::discovery {

namespace {

// The onset grids (docs/discovery.md, "Time behaviour"): coarse onsets at
// k D / kOnsetCoarse (D the recording's length, k = 1 .. kOnsetCoarse - 1), then twice a grid
// kOnsetRefine times finer within one spacing of the best onset so far.
constexpr int kOnsetCoarse = 12;
constexpr int kOnsetRefine = 4;

// The first frame at or after `t`.
int FrameAtOrAfter(const std::vector<TelemetryFrame>& frames, absl::Time t) {
  auto it = std::lower_bound(frames.begin(), frames.end(), t,
                             [](const TelemetryFrame& f, absl::Time x) { return f.time < x; });
  return static_cast<int>(it - frames.begin());
}

}  // namespace

double HoursSinceStart(const std::vector<TelemetryFrame>& frames, int f) {
  return HoursSince(frames[f].time, frames.front().time);
}

absl::StatusOr<ModelRun> OnsetSearch::RunFrom(int f, const SessionOptions& options) {
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

absl::Status OnsetSearch::Evaluate(int f) {
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
absl::Status OnsetSearch::Refine(absl::Duration spacing, double base_value, double alpha) {
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

// The onset interval: where -2 log L stays within kProfileIntervalDrop of its minimum, linear
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
    const std::vector<double> weights =
        TrapezoidWeights(profile, profile.back().first - profile.front().first);
    for (size_t j = 0; j < profile.size(); ++j) {
      fit.prior_points.emplace_back(weights[j], profile[j].second);
    }
  }
  for (size_t j = 0; j < profile.size(); ++j) {
    if (profile[j].second < profile[p.best].second) p.best = j;
  }
  const LevelInterval in =
      IntervalAtLevel(profile, p.best, profile[p.best].second + kProfileIntervalDrop);
  p.lower = in.lower;
  p.upper = in.upper;
  return p;
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

}  // namespace esg::estimator::discovery
