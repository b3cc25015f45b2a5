// estimator/sun_direction.h: the sun's direction in inertial (J2000) axes from UTC (ERFA),
// checked against physics stated without it: the equinox and the solstice of 2024, and the
// Astronomical Almanac's low-precision solar formula (section C, "Sun", good to 0.01 deg over
// 1950-2050) coded here on its own.
#include "estimator/sun_direction.h"

#include <cmath>

#include "Eigen/Geometry"
#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

constexpr double kPi = 3.14159265358979323846;
constexpr double kDeg = kPi / 180.0;
constexpr double kObliquityJ2000Deg = 23.4392911;  // mean obliquity at J2000 (IAU 1976)
constexpr double kAberrationDeg = 20.496 / 3600.0;  // constant of annual aberration

absl::Time Utc(int y, int mo, int d, int h, int mi) {
  return absl::FromCivil(absl::CivilSecond(y, mo, d, h, mi, 0), absl::UTCTimeZone());
}

// Days since J2000.0 (2000-01-01 12:00); the almanac's n, UTC for TT (69 s, 0.00003 deg).
double DaysSinceJ2000(absl::Time utc) {
  return absl::ToDoubleSeconds(utc - Utc(2000, 1, 1, 12, 0)) / 86400.0;
}

// General precession in longitude from J2000 to the date (IAU 1976, Lieske) [deg].
double PrecessionInLongitudeDeg(double n_days) {
  const double T = n_days / 36525.0;
  return (5029.0966 * T + 1.11113 * T * T) / 3600.0;
}

// J2000 equatorial axes -> J2000 ecliptic axes (the axes turned by the obliquity about x).
Eigen::Vector3d EclipticJ2000(const Eigen::Vector3d& v_in) {
  return Eigen::AngleAxisd(-kObliquityJ2000Deg * kDeg, Eigen::Vector3d::UnitX()) * v_in;
}

// Ecliptic axes -> equatorial axes.
Eigen::Vector3d Equatorial(const Eigen::Vector3d& v_ecl) {
  return Eigen::AngleAxisd(kObliquityJ2000Deg * kDeg, Eigen::Vector3d::UnitX()) * v_ecl;
}

// The almanac's sun: apparent ecliptic longitude of the mean equinox of date [deg].
double AlmanacLongitudeOfDateDeg(double n) {
  const double L = 280.460 + 0.9856474 * n;
  const double g = (357.528 + 0.9856003 * n) * kDeg;
  return L + 1.915 * std::sin(g) + 0.020 * std::sin(2.0 * g);
}

// The almanac's sun as a geometric direction in J2000 axes: the aberration its mean longitude
// carries taken out, the longitude turned back to the J2000 equinox, latitude 0 (the ecliptic's
// own motion, 47 arcsec per century, leaves under 0.003 deg by 2040).
Eigen::Vector3d AlmanacSun_in(absl::Time utc) {
  const double n = DaysSinceJ2000(utc);
  const double lambda =
      (AlmanacLongitudeOfDateDeg(n) + kAberrationDeg - PrecessionInLongitudeDeg(n)) * kDeg;
  const Eigen::Vector3d ecliptic(std::cos(lambda), std::sin(lambda), 0.0);
  return Equatorial(ecliptic);
}

double AngleDeg(const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  return std::atan2(a.cross(b).norm(), a.dot(b)) / kDeg;
}

TEST(SunDirection, IsAUnitVector) {
  for (int day = 0; day < 366; day += 5) {
    const auto s = SunDirection_in(Utc(2024, 1, 1, 0, 0) + absl::Hours(24 * day));
    ASSERT_TRUE(s.ok()) << s.status();
    EXPECT_NEAR(s->norm(), 1.0, 1e-14);
  }
}

// 2024-03-20 03:06 UTC: the sun's apparent longitude of date is 0. In axes of the equinox of
// date (J2000 axes turned by the precession since) its right ascension and declination are 0 to
// the 20 arcsec of aberration and nutation; in J2000 axes the equinox is 0.338 deg of precession
// behind, at right ascension -0.31 deg and declination -0.13 deg.
TEST(SunDirection, MarchEquinox2024HasRightAscensionAndDeclinationZeroOfDate) {
  const absl::Time t = Utc(2024, 3, 20, 3, 6);
  const auto s_in = SunDirection_in(t);
  ASSERT_TRUE(s_in.ok()) << s_in.status();
  const double p = PrecessionInLongitudeDeg(DaysSinceJ2000(t));
  EXPECT_NEAR(p, 0.338, 0.001);
  // To axes of the equinox of date: the longitude grows by the precession about the ecliptic
  // pole; back to equatorial axes (the obliquity's change since J2000, 0.003 deg, moves nothing
  // at the equinox).
  const Eigen::Vector3d ecl_date =
      Eigen::AngleAxisd(p * kDeg, Eigen::Vector3d::UnitZ()) * EclipticJ2000(*s_in);
  const Eigen::Vector3d eq_date = Equatorial(ecl_date);
  EXPECT_NEAR(std::atan2(eq_date.y(), eq_date.x()) / kDeg, 0.0, 0.01);
  EXPECT_NEAR(std::asin(eq_date.z()) / kDeg, 0.0, 0.01);
  // In J2000 axes.
  const double lambda = -p * kDeg;
  const double eps = kObliquityJ2000Deg * kDeg;
  EXPECT_NEAR(std::atan2(s_in->y(), s_in->x()) / kDeg,
              std::atan2(std::cos(eps) * std::sin(lambda), std::cos(lambda)) / kDeg, 0.01);
  EXPECT_NEAR(std::asin(s_in->z()) / kDeg, std::asin(std::sin(eps) * std::sin(lambda)) / kDeg,
              0.01);
}

// 2024-06-20 20:51 UTC: the sun's declination is the obliquity, 23.44 deg (23.436 of date; in
// J2000 axes 23.439 less 0.0004 deg for the 0.338 deg the equinox has moved and 0.003 deg for the
// ecliptic's own motion since 2000, 47 arcsec per century: 23.436).
TEST(SunDirection, JuneSolstice2024HasDeclinationOfTheObliquity) {
  const auto s_in = SunDirection_in(Utc(2024, 6, 20, 20, 51));
  ASSERT_TRUE(s_in.ok()) << s_in.status();
  EXPECT_NEAR(std::asin(s_in->z()) / kDeg, 23.44, 0.005);
  // And the right ascension 90 deg less the precession's 0.338 deg / cos(obliquity) (0.37 deg).
  EXPECT_NEAR(std::atan2(s_in->y(), s_in->x()) / kDeg, 90.0 - 0.369, 0.01);
}

// The almanac's formula (0.01 deg), with the ecliptic's motion it leaves out (0.003 deg): within
// 0.015 deg every 3.7 days from 2000 to 2040.
TEST(SunDirection, AgreesWithTheAlmanacsLowPrecisionFormula) {
  double worst_deg = 0.0;
  for (absl::Time t = Utc(2000, 1, 1, 0, 0); t < Utc(2040, 1, 1, 0, 0);
       t += absl::Hours(24 * 3 + 17)) {
    const auto s_in = SunDirection_in(t);
    ASSERT_TRUE(s_in.ok()) << s_in.status();
    const double angle = AngleDeg(*s_in, AlmanacSun_in(t));
    worst_deg = std::max(worst_deg, angle);
    ASSERT_LT(angle, 0.015) << absl::FormatTime(t, absl::UTCTimeZone());
  }
  // The two are independent: agreement to the formula's accuracy, not exact.
  EXPECT_GT(worst_deg, 1e-4);
}

TEST(SunDirection, RefusesTimesOutsideTheEphemerisNamingTheTime) {
  const auto early = SunDirection_in(Utc(1899, 12, 31, 23, 0));
  ASSERT_FALSE(early.ok());
  EXPECT_EQ(early.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_NE(early.status().message().find("1899-12-31T23:00:00.000Z"), std::string::npos)
      << early.status();
  EXPECT_FALSE(SunDirection_in(Utc(2101, 1, 1, 0, 0)).ok());
  EXPECT_FALSE(SunDirection_in(absl::InfiniteFuture()).ok());
  EXPECT_TRUE(SunDirection_in(Utc(1900, 1, 1, 0, 0)).ok());
}

}  // namespace
}  // namespace esg::estimator
