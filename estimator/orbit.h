// A spacecraft's orbit as flight dynamics delivers it (docs/physics.md, "The orbit"; the file is
// a CCSDS OEM, formats/oem.h): arcs of states (position and velocity in inertial J2000 axes from
// the Earth's centre, [km] and [km/s]), each valid over the span it covers, interpolated between
// states by the cubic Hermite polynomial of the two neighbouring positions and velocities.
//
// The interpolation's error between states h apart is at most |d^4 r/dt^4| h^4 / 384; on a near-
// circular orbit |d^4 r/dt^4| = |r| w^4 with w = |v| / |r|, so an arc is refused where that bound
// exceeds kMaxInterpolationErrorKm (a low orbit's states may then be up to about 420 s apart:
// 1 km is 0.13 s of the shadow's edge passing). Pure computation.
#ifndef ESG_ESTIMATOR_ORBIT_H_
#define ESG_ESTIMATOR_ORBIT_H_

#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/time_interval.h"

namespace esg::estimator {

inline constexpr double kMaxInterpolationErrorKm = 1.0;
// A position closer to the Earth's centre than this is refused (the polar radius, WGS 84) [km].
inline constexpr double kEarthPolarRadiusKm = 6356.752;

struct OrbitState {
  absl::Time time;
  Eigen::Vector3d r_in_km = Eigen::Vector3d::Zero();
  Eigen::Vector3d v_in_km_s = Eigen::Vector3d::Zero();
};

// States in time order, valid over [from, to] (inside the states' span).
struct OrbitArc {
  std::vector<OrbitState> states;
  absl::Time from;
  absl::Time to;
};

class Orbit {
 public:
  // InvalidArgument naming the field ("arcs[1].states[4].r_in_km: ...") for an arc with fewer
  // than 2 states, times not strictly increasing, a number not finite, a position inside the
  // Earth, [from, to] empty or outside its states, or states too far apart for the interpolation
  // (the bound above, with the interval and the bound in the message); "arcs" when there are
  // none. Where arcs overlap, a later one is used (a newer delivery replaces an older
  // prediction). `arc_names[i]`, when given, replaces "arcs[i]." at the head of an error about
  // arc i (a file's reader names its segment and line).
  static absl::StatusOr<Orbit> FromArcs(std::vector<OrbitArc> arcs,
                                        const std::vector<std::string>& arc_names = {});

  // The interpolated state at t; OutOfRange naming t and the coverage when no arc covers it.
  absl::StatusOr<OrbitState> StateAt(absl::Time t) const;

  // The parts of [from, to] that no arc covers, in time order.
  std::vector<TimeInterval> Gaps(absl::Time from, absl::Time to) const;

  const std::vector<OrbitArc>& arcs() const { return arcs_; }

 private:
  explicit Orbit(std::vector<OrbitArc> arcs) : arcs_(std::move(arcs)) {}
  std::vector<OrbitArc> arcs_;
};

// The cubic Hermite interpolation between states a and b at t (a.time <= t <= b.time).
OrbitState InterpolateHermite(const OrbitState& a, const OrbitState& b, absl::Time t);

// The bound above on the interpolation error between a and b [km].
double HermiteErrorBoundKm(const OrbitState& a, const OrbitState& b);

// The Earth's gravitational parameter GM [km^3/s^2] (WGS 84).
inline constexpr double kEarthGmKm3S2 = 398600.4418;

// The state t_s seconds after `epoch` on a circular orbit (the simulator's, docs/scenario.md):
// radius from the period by Kepler's third law, r = (GM (period / 2 pi)^2)^(1/3); position
// r (cos u x_p + sin u y_p) with x_p = Rz(raan) x (towards the ascending node) and
// y_p = Rz(raan) Rx(inclination) y, u = arg_latitude0 + 2 pi t_s / period; the velocity its
// derivative. The orbit the orbital attitude profile points at (attitude_profile.h Orbital:
// its body z axis is -r).
OrbitState CircularOrbitState(double inclination_rad, double raan_rad, double period_s,
                              double arg_latitude0_rad, absl::Time epoch, double t_s);
// The period of the Keplerian ellipse through `state` [s]: 2 pi sqrt(a^3 / GM), the semi-major
// axis a from the vis-viva equation 1 / a = 2 / |r| - |v|^2 / GM. Infinite when the state is not
// bound (|v|^2 >= 2 GM / |r|).
double KeplerPeriodS(const OrbitState& state);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_ORBIT_H_
