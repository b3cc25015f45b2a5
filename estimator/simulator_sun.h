// The sun as the simulator's sun-driven effects see it (simulator.h SunFaceDrift,
// StarTrackerSunMount): its direction at nodes from the run's start, interpolated, scaled by the
// sunlit fraction when the spacecraft flies an Earth-shadow orbit, and a body face's illumination.
// Internal to the simulator (simulator.cc, simulator_star_tracker.cc). Pure computation.
#ifndef ESG_ESTIMATOR_SIMULATOR_SUN_H_
#define ESG_ESTIMATOR_SIMULATOR_SUN_H_

#include <optional>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/attitude_profile.h"

namespace esg::estimator::simulator_internal {

// Spacing of the sun directions the simulator computes and interpolates between [s].
inline constexpr double kSunNodeSpacingS = 600.0;

// The sun's direction in inertial axes at nodes kSunNodeSpacingS apart from the simulation start,
// interpolated linearly between them and normalised (the sun moves 0.007 deg in 600 s: the
// interpolation is off by under 1e-8 rad). With an Earth-shadow orbit, the sun's position [km] at
// the same nodes gives the fraction of its disc seen from the orbit, which scales the direction:
// the illumination max(0, n . s_b) is linear in it.
class SunNodes {
 public:
  // Errors: those of SunDirection_in and SunPosition_in_km (a time outside the sun's table).
  static absl::StatusOr<SunNodes> Make(absl::Time start, double duration_s,
                                       const std::optional<OrbitalOptions>& earth_shadow);

  // [1], inertial axes, at t seconds since the start (0 <= t <= duration; clamped outside): the
  // unit vector to the sun, times the fraction of the sun's disc seen from the Earth-shadow orbit
  // when there is one.
  Eigen::Vector3d At(double t) const;

 private:
  absl::Time start_;
  std::optional<OrbitalOptions> earth_shadow_;
  std::vector<Eigen::Vector3d> s_in_;
  std::vector<Eigen::Vector3d> sun_in_km_;
};

// A body face's illumination by the sun s_b (body axes, as SunNodes::At gives it carried by the
// attitude) [1]: max(0, face_sign s_b[face_axis]) for face_axis 0, 1, 2 (x, y, z); for
// simulator.h kSunlitFaceAxis no face: the sunlit fraction |s_b| (at most 1).
double FaceIllumination(const Eigen::Vector3d& s_b, int face_axis, double face_sign);

}  // namespace esg::estimator::simulator_internal

#endif  // ESG_ESTIMATOR_SIMULATOR_SUN_H_
