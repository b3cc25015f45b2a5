// Named unit conversions (conventions.h item 8). Every non-SI value crosses into SI here.
#ifndef ESG_ESTIMATOR_UNITS_H_
#define ESG_ESTIMATOR_UNITS_H_

#include <numbers>

namespace esg::estimator {

inline constexpr double kPi = std::numbers::pi;
inline constexpr double kRadPerDeg = kPi / 180.0;
inline constexpr double kRadPerArcmin = kRadPerDeg / 60.0;
inline constexpr double kRadPerArcsec = kRadPerDeg / 3600.0;
inline constexpr double kSecondsPerHour = 3600.0;
inline constexpr double kSecondsPerMinute = 60.0;
inline constexpr double kMetresPerUm = 1e-6;
inline constexpr double kVoltsPerMv = 1e-3;

constexpr double DegToRad(double x_deg) { return x_deg * kRadPerDeg; }
constexpr double RadToDeg(double x) { return x / kRadPerDeg; }
constexpr double ArcsecToRad(double x_arcsec) { return x_arcsec * kRadPerArcsec; }
constexpr double RadToArcsec(double x) { return x / kRadPerArcsec; }
constexpr double ArcminToRad(double x_arcmin) { return x_arcmin * kRadPerArcmin; }
constexpr double RadToArcmin(double x) { return x / kRadPerArcmin; }
// deg/h <-> rad/s.
constexpr double DegPerHourToRadPerSec(double x_deg_h) { return x_deg_h * kRadPerDeg / kSecondsPerHour; }
constexpr double RadPerSecToDegPerHour(double x) { return x * kSecondsPerHour / kRadPerDeg; }
// Random-walk intensity deg/h/sqrt(h) <-> rad/s/sqrt(s) (rad/s^1.5).
constexpr double DegPerHourSqrtHourToSi(double x) { return DegPerHourToRadPerSec(x) / 60.0; }
constexpr double SiToDegPerHourSqrtHour(double x) { return RadPerSecToDegPerHour(x) * 60.0; }
constexpr double HoursToSeconds(double x_hours) { return x_hours * kSecondsPerHour; }
constexpr double SecondsToHours(double x) { return x / kSecondsPerHour; }

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_UNITS_H_
