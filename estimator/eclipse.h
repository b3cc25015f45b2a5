// The Earth's shadow (docs/physics.md, "The orbit"): how much of the sun's disc a spacecraft
// sees. A conical shadow of a spherical Earth (equatorial radius) and a spherical sun: seen from
// the spacecraft at r (inertial axes, from the Earth's centre [km]) the sun's disc has the
// apparent radius a = asin(R_sun / |r_sun - r|), the Earth's b = asin(R_earth / |r|), and their
// centres are c apart. The visible fraction of the sun's disc (Montenbruck and Gill, Satellite
// Orbits, 2000, section 3.4.2):
//
//     1                          c >= a + b                  (sunlit)
//     0                          c <= b - a                  (umbra)
//     1 - b^2 / a^2              c <= a - b                  (annular; not from a low orbit)
//     1 - A / (pi a^2)           otherwise (penumbra), A the area of the discs' overlap,
//                                A = a^2 acos(x / a) + b^2 acos((c - x) / b) - c y,
//                                x = (c^2 + a^2 - b^2) / (2 c),  y = sqrt(a^2 - x^2)
//
// The Earth's flattening moves the shadow's edge by up to 21 km (a few seconds of a low orbit's
// eclipse); the atmosphere's refraction and absorption darken the penumbra's outer part a little
// further. Pure computation.
#ifndef ESG_ESTIMATOR_ECLIPSE_H_
#define ESG_ESTIMATOR_ECLIPSE_H_

#include "Eigen/Core"

namespace esg::estimator {

inline constexpr double kEarthEquatorialRadiusKm = 6378.137;  // WGS 84
inline constexpr double kSunRadiusKm = 695700.0;               // IAU 2015 B3 nominal

// The visible fraction of the sun's disc, in [0, 1], from r_in_km with the sun at sun_in_km (both
// from the Earth's centre, inertial axes [km]; sun_direction.h SunPosition_in_km).
double SunlitFraction(const Eigen::Vector3d& r_in_km, const Eigen::Vector3d& sun_in_km);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_ECLIPSE_H_
