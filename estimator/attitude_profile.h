// Attitude profiles: the body attitude q_in_b(t) and body rate w_b_in_b(t) of a spacecraft as
// functions of time, for the simulator and for the planned-attitude input of gap prediction
// (docs/physics.md, "Prediction"). Includes the calibration profile of the paper's flight test
// (section 3 of the paper; docs/physics.md, "The paper's flight test"): solar orientation, rotation
// about one body axis with a 60 min period, the orientation changed every 3 h. Conventions of
// conventions.h (q_in_b maps body to inertial).
//
// Time t is in seconds since the profile's start. Every profile is defined for all real t
// (before its start and after its nominal end it continues analytically), so latency and
// extrapolation never fall off an edge.
#ifndef ESG_ESTIMATOR_ATTITUDE_PROFILE_H_
#define ESG_ESTIMATOR_ATTITUDE_PROFILE_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/statusor.h"
#include "estimator/units.h"

namespace esg::estimator {

class AttitudeProfile {
 public:
  virtual ~AttitudeProfile() = default;

  // q_in_b at t [s], unit norm.
  virtual Eigen::Quaterniond Attitude(double t) const = 0;

  // w_b_in_b at t [rad/s]: angular velocity of b relative to in, in body axes, so that
  // dq_in_b/dt = 0.5 q_in_b (x) [0; w_b_in_b]. Default: central finite difference of Attitude
  // over +-kRateStep.
  virtual Eigen::Vector3d Rate(double t) const;

  // Short human-readable description, e.g. for recording metadata.
  virtual std::string Describe() const = 0;

  // The period [s] of the orbit the spacecraft flies, when the profile models one (orbital, and
  // a sequence with an orbital segment: the first such segment's); nullopt otherwise. The
  // simulator's orbital drift cycles with it by default.
  virtual std::optional<double> OrbitalPeriod() const { return std::nullopt; }

  static constexpr double kRateStep = 0.01;  // [s]
};

using ProfilePtr = std::shared_ptr<const AttitudeProfile>;

// Constant attitude, zero rate.
ProfilePtr InertialHold(const Eigen::Quaterniond& q_in_b);

// Rotation at a constant rate about a body-fixed axis:
//   q_in_b(t) = q_in_b0 (x) Exp(axis_b * rate * t),   w_b_in_b = axis_b * rate.
// axis_b is normalised; InvalidArgument for a zero axis or non-finite values.
absl::StatusOr<ProfilePtr> ConstantSpin(const Eigen::Quaterniond& q_in_b0,
                                        const Eigen::Vector3d& axis_b, double rate);

// Circular orbit, body axes held LVLH-like (local vertical, local horizontal):
//   body z toward nadir (-r), body x along the velocity, body y along minus the orbit normal
//   (y = -unit(r x v)), so x = y x z.
// The orbit plane is J2000-referred: right ascension of the ascending node raan [rad],
// inclination [rad]; arg_latitude0 [rad] is the argument of latitude at t = 0 (0 at the ascending
// node); the argument of latitude grows at 2 pi / period. The body rotates about body -y at the
// orbit rate: w_b_in_b = (0, -2 pi / period, 0). InvalidArgument unless period > 0 and values
// finite.
struct OrbitalOptions {
  double inclination = DegToRad(97.5);  // [rad]; sun-synchronous-like
  double period = 5640.0;               // [s] (94 min)
  double raan = DegToRad(30.0);         // [rad]
  double arg_latitude0 = 0.0;           // [rad]
};
absl::StatusOr<ProfilePtr> Orbital(const OrbitalOptions& options);
absl::StatusOr<ProfilePtr> Orbital(double inclination, double period, double raan,
                                   double arg_latitude0);

// One segment of a Sequence: a profile whose own time starts at the segment's start.
struct ProfileSegment {
  ProfilePtr profile;
  double duration = 0.0;  // [s], > 0
};

// Segments one after the other; segment i runs for its duration with local time t - T_i
// (T_i = sum of the earlier durations); the last segment continues after its nominal end and the
// first one before t = 0. Each change of segment (at T_i, i >= 1) begins a slew of length
// slew_duration [s] (<= the segment's duration) that takes the attitude smoothly from the
// outgoing segment to the incoming one:
//   q(t) = q_prev(t) (x) Exp(s(tau) * Log(conj(q_prev(t)) (x) q_next(t))),
//   tau = (t - T_i) / slew_duration,  s(tau) = 10 tau^3 - 15 tau^4 + 6 tau^5 (quintic),
// where q_prev and q_next are the two segments' attitudes at t. Between two inertial holds this is
// the classic eigen-axis slew with a quintic time law (zero rate and acceleration at both ends);
// in general attitude and rate are continuous at both ends of the slew. Log takes the shorter way
// at the slew's start and follows the same branch continuously after it: a relative rotation
// that passes through pi while both segments move goes on the long way instead of flipping the
// eigen axis (attitude and rate stay continuous). slew_duration = 0 switches instantly. Rates come from finite differences
// during slews and from the segment otherwise.
// InvalidArgument for an empty list, a null profile, a non-positive duration, a negative slew or a
// slew longer than a segment.
absl::StatusOr<ProfilePtr> Sequence(std::vector<ProfileSegment> segments, double slew_duration,
                                    std::string description = "sequence");

// The paper's calibration profile (section 3): solar orientation with rotation about the
// sun-pointing body axis at a 60 min period; every segment_duration (3 h) another body axis is
// pointed at the Sun (cycling through sun_axes_b), the segments joined by Sequence slews.
// Segment i: q_in_b(tau) = q_i (x) Exp(a_i * 2 pi / spin_period * tau), where q_i is the
// smallest rotation that takes body axis a_i onto sun_in, followed by a rotation by phase_i about
// sun_in. So body axis a_i points at the Sun throughout the segment and the body spins about it.
struct CalibrationOptions {
  // Fixed inertial direction of the Sun (normalised by the builder). Default: right ascension
  // 30 deg, declination 12 deg (the Sun in late April): (cos 12 cos 30, cos 12 sin 30, sin 12).
  Eigen::Vector3d sun_in = Eigen::Vector3d(0.847101, 0.489074, 0.207912);
  double spin_period = 3600.0;        // [s], the paper's 60 min
  double segment_duration = 10800.0;  // [s], the paper's 3 h
  double slew_duration = 600.0;       // [s], part of each new segment
  // Body axes pointed at the Sun in turn (normalised); default +z, +x, +y, unit(1,1,1),
  // unit(-1,1,-1), -z: the principal axes first, then oblique ones so that every gyro's spin axis
  // sweeps cones of different opening in its case frame.
  std::vector<Eigen::Vector3d> sun_axes_b;
  // Spin phase about the Sun line at each segment start [rad], cycling; default 0, 2.1, 4.2 ...
  // (i * 2.1 rad). MakeNamedProfile with a seed draws them uniformly instead.
  std::vector<double> phases;
  // Number of segments; 0 = enough to cover the duration passed to the builder.
  int num_segments = 0;
};
// duration [s]: how long the profile must cover (used when num_segments == 0).
absl::StatusOr<ProfilePtr> Calibration(const CalibrationOptions& options, double duration);

// Options of the named profiles (the CLI and scenario files set them).
struct ProfileOptions {
  OrbitalOptions orbital;
  CalibrationOptions calibration;
  // Attitude of `inertial` (and of the inertial holds in `mixed` before any seed is applied).
  Eigen::Quaterniond inertial_q_in_b = Eigen::Quaterniond(0.8, 0.2, -0.4, 0.4).normalized();
  // `mixed`: durations of its orbital, calibration and inertial parts [s], repeated in this order
  // until the duration is covered; slews of calibration.slew_duration join them.
  double mixed_orbital_duration = 10800.0;
  double mixed_calibration_duration = 21600.0;
  double mixed_inertial_duration = 10800.0;
};

// Names accepted by MakeNamedProfile: inertial, orbital, calibration, mixed.
std::vector<std::string> NamedProfileNames();

// Builds a named profile covering at least `duration` [s]:
//   inertial    InertialHold(options.inertial_q_in_b)
//   orbital     Orbital(options.orbital)
//   calibration Calibration(options.calibration, duration)
//   mixed       orbital, calibration, inertial hold in sequence, repeating.
// With a seed, the free choices are drawn from it (spin phases of the calibration segments, the
// attitude of each inertial hold, the orbit's initial argument of latitude); without one the
// profile is the documented default. The same (name, duration, seed, options) give the same
// profile. InvalidArgument for an unknown name (the message lists the valid names), a
// non-positive or non-finite duration, or bad options.
absl::StatusOr<ProfilePtr> MakeNamedProfile(std::string_view name, double duration,
                                            std::optional<uint64_t> seed = std::nullopt,
                                            const ProfileOptions& options = {});

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_ATTITUDE_PROFILE_H_
