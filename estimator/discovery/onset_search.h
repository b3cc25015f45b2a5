// The onset search that the time behaviours switched on during a recording share
// (docs/discovery.md, "Time behaviour"): a drift step (drift_step.h), a coefficient step
// (coefficient_step.h) and a transient from an onset (transient.h). One run of the model without
// the change, with checkpoints at the onsets of two grids; each onset a run continued from its
// checkpoint with the change released (or switched on) there, so an onset costs the part of a run
// after it; the likelihood profiled over the onset on a coarse grid, refined near its best while
// the change is significant. Pure computation.
#ifndef ESG_ESTIMATOR_DISCOVERY_ONSET_SEARCH_H_
#define ESG_ESTIMATOR_DISCOVERY_ONSET_SEARCH_H_

#include <functional>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/discovery/candidate.h"
#include "estimator/discovery/model_run.h"
#include "estimator/drift_model.h"
#include "estimator/session.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"

namespace esg::estimator::discovery {

// A coefficient the model holds is put in the filter's layout with this prior [deg/h] so that it
// can be released at the onset; before it the filter keeps it at its configured value.
inline constexpr double kHeldSigmaDegH = 1e-6;

// Hours from the first of `frames` to frame f.
double HoursSinceStart(const std::vector<TelemetryFrame>& frames, int f);

// The part of an onset search that every onset shares: the recording (its star tracker corrected
// as the model corrects it), the run without the change with checkpoints at the onsets of the
// grids, and each onset's profiled -2 log L with the best so far. `candidate` and `fit` outlive
// the search; every run adds one to fit.runs.
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

  // The run with `options` from onset frame f (a frame with a checkpoint): the prefix's steps
  // before f, then a run continued from the checkpoint at f. Errors: those of RunModel.
  absl::StatusOr<ModelRun> RunFrom(int f, const SessionOptions& options);

  // One onset: continue from the checkpoint with the released states (C1 for a drift step)
  // released at the onset frame; keeps the best. An onset evaluated already, or without a
  // checkpoint, is skipped. Errors: those of RunModel.
  absl::Status Evaluate(int f);

  // Further refinements, each finer within one `spacing` of the best onset so far, down to one
  // frame, while the change is significant against `base_value` (the model's -2 log L without
  // it) at level `alpha`. Errors: those of RunModel.
  absl::Status Refine(absl::Duration spacing, double base_value, double alpha);
};

// The likelihood over the onset, in hours from the start, and what it gives: the best onset and
// its 95% interval [h].
struct OnsetProfile {
  std::vector<std::pair<double, double>> points;  // hours, value
  size_t best = 0;
  double lower = 0.0, upper = 0.0;  // [h]
};

// The onset interval: where -2 log L stays within kProfileIntervalDrop of its minimum, linear
// between evaluated onsets, clipped to the onsets searched. Also the evidence's prior points in
// `fit` (and fit.onset_profile): the onset integrated over a prior uniform across the span
// searched, by the trapezoid rule on the onsets evaluated; each onset's run is already the
// change's marginal likelihood (its size integrated over its prior). Precondition: at least one
// onset evaluated.
OnsetProfile ProfileOnsets(const OnsetSearch& search, CandidateFit& fit);

// The fit's onset with its interval (fit.time: onset, onset_hours and its bounds, onsets
// searched) from the search's best onset and its profile `p`.
void DescribeOnset(const OnsetSearch& search, const OnsetProfile& p, CandidateFit& fit);

// The onsets of the first two grids, k D / 48, k = 1 .. before the last frame (D the recording's
// length); empty for a recording too short for them.
std::vector<int> GridFrames(const std::vector<TelemetryFrame>& frames);

// The prefix run without the change (search.BaseConfig()), with checkpoints before the onsets of
// `grid_frames`. Errors: those of RunModel.
absl::Status RunPrefix(OnsetSearch& search, const std::vector<int>& grid_frames);

// The coarse grid, the finer grid within one coarse spacing of its best onset, and the
// refinements while the change is significant (`base_value` the model's -2 log L without it).
// False when no onset could be searched. Errors: those of RunModel.
absl::StatusOr<bool> SearchOnsets(OnsetSearch& search, const std::vector<int>& grid_frames,
                                  double base_value, double alpha);

}  // namespace esg::estimator::discovery

#endif  // ESG_ESTIMATOR_DISCOVERY_ONSET_SEARCH_H_
