// The simulated star tracker (simulator.h, the file comment's "Star tracker"): its readings across
// a run with noise, misalignment, the misalignment cycling with the orbit, the mount following the
// sun, a misalignment jump, latency, outliers (random and a burst), invalid flags, outages and
// frozen windows. Internal to the simulator (simulator.cc). Pure computation.
#ifndef ESG_ESTIMATOR_SIMULATOR_STAR_TRACKER_H_
#define ESG_ESTIMATOR_SIMULATOR_STAR_TRACKER_H_

#include <optional>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "estimator/random.h"
#include "estimator/simulator.h"
#include "estimator/simulator_sun.h"

namespace esg::estimator::simulator_internal {

// Random-stream ids of the star tracker (DeriveSeed); the gyros' streams start at 100.
inline constexpr uint64_t kStarTrackerNoiseStream = 1;
inline constexpr uint64_t kStarTrackerOutlierStream = 2;
inline constexpr uint64_t kStarTrackerInvalidStream = 3;

// Every stream draws the same amount per frame whatever is used. Samples must come in time order
// (the mount's lag is stepped from one to the next).
class StarTrackerSampler {
 public:
  // sun_nodes: required (non-null) when spec.star_tracker.sun_mount is set; kept by pointer.
  StarTrackerSampler(const SimulationSpec& spec, const SunNodes* sun_nodes);

  // The reading at t_m [s since the start] into frame (none in an outage), its outlier and
  // frozen truth into truth (truth.q_in_b: the true attitude at t_m).
  void Sample(double t_m, TelemetryFrame& frame, TruthSample& truth);

 private:
  // The mount's lagged illumination y stepped to t_m (StarTrackerSunMount).
  double MountIllumination(double t_m);
  double FaceIlluminationAt(double t) const;
  // Inside a frozen window: the first reading is held with its outlier truth, later ones repeat
  // it (and are marked frozen in truth).
  void HoldOrRepeat(StarTrackerReading& reading, TruthSample& truth);

  const StarTrackerTruth& st_;
  const AttitudeProfile& profile_;
  const SunNodes* const sun_nodes_;
  const Eigen::Vector3d noise_;
  const Eigen::Quaterniond q_misalignment_;
  const Eigen::Quaterniond q_jump_;
  int burst_left_;
  // The mount's lagged illumination at mount_time_ [s].
  double mount_y_ = 0.0;
  double mount_time_ = 0.0;
  // The sample repeated inside a frozen window, with its outlier truth.
  std::optional<StarTrackerReading> held_;
  bool held_outlier_ = false;
  double held_outlier_angle_ = 0.0;
  Rng noise_rng_;
  Rng outlier_rng_;
  Rng invalid_rng_;
};

}  // namespace esg::estimator::simulator_internal

#endif  // ESG_ESTIMATOR_SIMULATOR_STAR_TRACKER_H_
