// The sun's direction seen from the Earth, a function of time alone (docs/physics.md "The sun";
// decision in docs/decisions.md). Computed with ERFA (Debian liberfa-dev): the instant's UTC
// becomes TT through ERFA's leap-second table (eraUtctai, eraTaitt), eraEpv00 gives the Earth's
// heliocentric position in ICRS-aligned axes (the BCRS axes of the IAU, which are the J2000 axes
// `in` of docs/conventions.md to 0.02 arcsec, the frame bias), and the sun's direction is the
// opposite of it, normalised.
//
// It is the geometric direction from the Earth's centre: no annual aberration (up to 20.5 arcsec)
// and no parallax of a spacecraft in orbit (under 10 arcsec below 7000 km from the centre), so it
// is within 0.01 deg of the direction in which a spacecraft sees the sun; eraEpv00 itself is good
// to a few km of the Earth's position (far under 0.001 arcsec) over 1900-2100.
#ifndef ESG_ESTIMATOR_SUN_DIRECTION_H_
#define ESG_ESTIMATOR_SUN_DIRECTION_H_

#include "Eigen/Core"
#include "absl/status/statusor.h"
#include "absl/time/time.h"

namespace esg::estimator {

// First and last years of eraEpv00's stated accuracy; a time outside [kSunFirstYear,
// kSunLastYear] is refused.
inline constexpr int kSunFirstYear = 1900;
inline constexpr int kSunLastYear = 2100;

// Unit vector from the Earth's centre to the sun in inertial (J2000) axes at the UTC instant
// utc [1]. InvalidArgument naming the time when it is infinite or outside kSunFirstYear..
// kSunLastYear.
absl::StatusOr<Eigen::Vector3d> SunDirection_in(absl::Time utc);

// The astronomical unit [km] (IAU 2012 B2, exact).
inline constexpr double kAstronomicalUnitKm = 149597870.7;

// The sun's position from the Earth's centre in inertial (J2000) axes at the UTC instant utc
// [km]: the opposite of eraEpv00's heliocentric Earth, geometric (no light time: the sun moves
// 0.0057 deg in the 8.3 min light takes, which does not change an eclipse's geometry by more than
// a second). The same errors as SunDirection_in.
absl::StatusOr<Eigen::Vector3d> SunPosition_in_km(absl::Time utc);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_SUN_DIRECTION_H_
