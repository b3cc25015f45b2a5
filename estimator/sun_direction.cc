#include "estimator/sun_direction.h"

#include <cmath>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "erfa.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

namespace {

// The Earth's heliocentric position in J2000 axes [au] (eraEpv00) at the UTC instant utc.
absl::StatusOr<Eigen::Vector3d> EarthFromSun_in_au(absl::Time utc) {
  if (utc == absl::InfinitePast() || utc == absl::InfiniteFuture()) {
    return absl::InvalidArgumentError(
        absl::StrCat("sun direction: time ", FormatUtc(utc), " is not a finite instant"));
  }
  const absl::TimeZone::CivilInfo civil = absl::UTCTimeZone().At(utc);
  const absl::CivilSecond cs = civil.cs;
  if (cs.year() < kSunFirstYear || cs.year() > kSunLastYear) {
    return absl::InvalidArgumentError(absl::StrCat(
        "sun direction: time ", FormatUtc(utc), " is outside the years ", kSunFirstYear, "-",
        kSunLastYear, " of the solar ephemeris (ERFA eraEpv00)"));
  }
  const double seconds =
      static_cast<double>(cs.second()) + absl::ToDoubleSeconds(civil.subsecond);
  // UTC as ERFA's two-part quasi-Julian date, then TAI and TT. A status of +1 (a year past
  // ERFA's leap-second table, or before 1960) is a warning: TT - UTC is then off by at most
  // seconds, under 0.001 deg of the sun's motion.
  double utc1 = 0.0, utc2 = 0.0, tai1 = 0.0, tai2 = 0.0, tt1 = 0.0, tt2 = 0.0;
  if (eraDtf2d("UTC", static_cast<int>(cs.year()), cs.month(), cs.day(), cs.hour(), cs.minute(),
               seconds, &utc1, &utc2) < 0 ||
      eraUtctai(utc1, utc2, &tai1, &tai2) < 0 || eraTaitt(tai1, tai2, &tt1, &tt2) < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("sun direction: ERFA refused the time ", FormatUtc(utc)));
  }
  // eraEpv00 takes TDB; TDB - TT is under 2 ms, far below what matters here.
  double pvh[2][3], pvb[2][3];
  eraEpv00(tt1, tt2, pvh, pvb);
  const Eigen::Vector3d earth_from_sun_au(pvh[0][0], pvh[0][1], pvh[0][2]);
  return earth_from_sun_au;
}

}  // namespace

absl::StatusOr<Eigen::Vector3d> SunDirection_in(absl::Time utc) {
  absl::StatusOr<Eigen::Vector3d> earth_from_sun_au = EarthFromSun_in_au(utc);
  if (!earth_from_sun_au.ok()) return earth_from_sun_au.status();
  return Eigen::Vector3d(-earth_from_sun_au->normalized());
}

absl::StatusOr<Eigen::Vector3d> SunPosition_in_km(absl::Time utc) {
  absl::StatusOr<Eigen::Vector3d> earth_from_sun_au = EarthFromSun_in_au(utc);
  if (!earth_from_sun_au.ok()) return earth_from_sun_au.status();
  return Eigen::Vector3d(-*earth_from_sun_au * kAstronomicalUnitKm);
}

}  // namespace esg::estimator
