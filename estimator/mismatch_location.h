// Where a failing model-consistency test's mismatch sits (issue 35, item 1): one gyro, two, the
// star tracker's side, or all gyros. Pure computation over the reading-fault monitor's tracks
// (reading_fault_monitor.h), which the session keeps at every measurement step.
//
// EVIDENCE
//   Each running gyro has a track per source: its star-tracker rebuild (eq. (13)) and its
//   rebuild from the pair of the two other gyros (no star tracker in it), each minus the spin
//   axis its model carries, measured against the model as it was when the track started. The
//   filter's own state errors cancel exactly, so a gyro's track moves only with what its own
//   model lacks (and with the rebuild's source), never with another gyro's. Under the model the
//   track over its window (W + 1 samples, 21 by default) is an offset, plus a rate drawn from
//   the model's own rate uncertainty, plus white noise of the configured covariance; its misfit
//   (ReadingFaultMonitor::ModelMisfit) is chi-square with 2 W degrees of freedom. A track is
//   implicated when its misfit exceeds chi2inv(1 - alpha, 2 W), alpha = kMismatchLocationAlpha:
//   a track the model fits is implicated with probability 0.001 at a located alert.
//
// LOCATION (G: the gyros whose star-tracker track is implicated)
//   G one gyro, not all       that gyro's drift: something the model lacks in it
//                             ("model:gyro_N").
//   G two gyros, not all      those two ("model:gyros_N_M").
//   G every running gyro (at  the star tracker's side when no pair track is implicated (the
//   least two)                gyros agree with one another: its latency, mount or noise;
//                             "model:star_tracker"); a drift of every gyro when some pair track
//                             is ("model:all_gyros"); either when the pair tracks are not
//                             available (fewer than three gyros, "model:common").
//   G empty, or fewer than    not located ("model"): the windows do not show it (a mismatch
//   two star-tracker tracks   that the last W steps no longer carry, or a track restarted).
//   The pair rebuild's noise is bounded isotropically (a test never stronger than the exact one),
//   so a drift of every gyro can be read as the star tracker's side, never the reverse.
#ifndef ESG_ESTIMATOR_MISMATCH_LOCATION_H_
#define ESG_ESTIMATOR_MISMATCH_LOCATION_H_

#include <optional>
#include <string>
#include <vector>

#include "estimator/reading_fault_monitor.h"

namespace esg::estimator {

inline constexpr double kMismatchLocationAlpha = 1e-3;

// One running gyro's evidence: the misfit of its star-tracker track and of its pair track.
struct TrackMisfit {
  int gyro_id = 0;
  std::optional<ReadingFaultMonitor::Misfit> star_tracker;
  std::optional<ReadingFaultMonitor::Misfit> pair;
};

struct MismatchLocation {
  enum class Where { kNotLocated, kGyro, kGyros, kStarTracker, kAllGyros, kCommon };
  Where where = Where::kNotLocated;
  std::vector<int> gyro_ids;  // the gyros whose star-tracker track is implicated
  std::vector<TrackMisfit> evidence;

  // The alert's subsystem: "model" or "model:<where>" (table above).
  std::string Subsystem() const;
  // One sentence for the alert's message: "located: gyro 2 (...)" with the misfits.
  std::string Describe() const;
};

// Whether a misfit exceeds chi2inv(1 - kMismatchLocationAlpha, dof).
bool Implicated(const ReadingFaultMonitor::Misfit& m);

MismatchLocation LocateMismatch(const std::vector<TrackMisfit>& gyros);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_MISMATCH_LOCATION_H_
