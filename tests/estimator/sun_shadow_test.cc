// The sun's regressors with the spacecraft's orbit (estimator/discovery/sun_regressors.h,
// docs/discovery.md "A drift that follows the sun"): a face is not lit in the Earth's shadow.
// On a circular 500 km orbit whose plane holds the sun, at the real sun's direction of the date,
// the sunlit fraction along a series is 0 for 2 asin(R_e / r) / w of every turn, and a face
// facing the sun, lagged 0.1 h, cools towards 0 through each eclipse; without the orbit the same
// face stays lit. An orbit that does not cover the series is refused.
#include <cmath>
#include <memory>
#include <vector>

#include "estimator/discovery/sun_regressors.h"
#include "estimator/eclipse.h"
#include "estimator/orbit.h"
#include "estimator/sun_direction.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator::discovery {
namespace {

using ::esg::testing::StatusIs;
using ::testing::HasSubstr;
using Eigen::Vector3d;

const absl::Time kT0 = absl::FromCivil(absl::CivilSecond(2019, 3, 1, 0, 0, 0), absl::UTCTimeZone());
constexpr double kR = 6878.137;  // [km]

// A circular orbit in the plane of the sun's direction at kT0 and a perpendicular axis, states
// every 60 s over [from_s, to_s].
Orbit SunPlaneOrbit(double from_s, double to_s) {
  const Vector3d s = *SunDirection_in(kT0);
  const Vector3d p = s.cross(Vector3d::UnitZ()).normalized();
  const double w = std::sqrt(kEarthGmKm3S2 / (kR * kR * kR));
  OrbitArc arc;
  for (double t = from_s; t <= to_s; t += 60.0) {
    OrbitState st;
    st.time = kT0 + absl::Seconds(t);
    st.r_in_km = kR * (std::cos(w * t) * s + std::sin(w * t) * p);
    st.v_in_km_s = kR * w * (-std::sin(w * t) * s + std::cos(w * t) * p);
    arc.states.push_back(st);
  }
  arc.from = arc.states.front().time;
  arc.to = arc.states.back().time;
  return *Orbit::FromArcs({arc});
}

// A series of 10 s substeps over `hours`, the case axes the inertial ones.
DeviationSeries Series(double hours) {
  DeviationSeries series;
  series.gyro = 1;
  for (double t = 5.0; t < hours * 3600.0; t += 10.0) {
    TrajectoryStep step;
    step.inputs.time = kT0 + absl::Seconds(t);
    step.dt = 10.0;
    series.steps.push_back(step);
  }
  return series;
}

TEST(SunShadow, TheSunlitFractionIsZeroInTheShadowForTheTimeTheGeometryGives) {
  const DeviationSeries series = Series(3.0);
  const absl::StatusOr<std::vector<double>> nu = SunlitAlongSeries(series, SunPlaneOrbit(-60, 3 * 3600 + 60));
  ASSERT_TRUE(nu.ok()) << nu.status();
  double shadow_s = 0.0;
  for (double x : *nu) {
    ASSERT_GE(x, 0.0);
    ASSERT_LE(x, 1.0);
    shadow_s += 10.0 * (1.0 - x);
  }
  // Starting towards the sun, the 3 h (1.9 turns) hold two whole eclipses, centred half a turn
  // and one and a half turns in. The sun moves 0.1 deg out of the orbit's plane over 3 h: each
  // lasts as long to 0.1%.
  const double w = std::sqrt(kEarthGmKm3S2 / (kR * kR * kR));
  EXPECT_NEAR(shadow_s / 2.0, 2.0 * std::asin(kEarthEquatorialRadiusKm / kR) / w, 5.0);
}

TEST(SunShadow, AFaceTowardsTheSunCoolsThroughEachEclipse) {
  const DeviationSeries series = Series(3.0);
  const Orbit orbit = SunPlaneOrbit(-60, 3 * 3600 + 60);
  // The face whose normal is nearest the sun's direction (body = case = inertial axes here).
  const Vector3d s = *SunDirection_in(kT0);
  int face = 0;
  for (int f = 0; f < kSunFaces; ++f) {
    if (SunFaceNormal_b(f).dot(s) > SunFaceNormal_b(face).dot(s)) face = f;
  }
  const absl::StatusOr<SunRegressors> lit = ComputeSunRegressors(series, Eigen::Matrix3d::Identity());
  const absl::StatusOr<SunRegressors> shadowed =
      ComputeSunRegressors(series, Eigen::Matrix3d::Identity(), &orbit);
  ASSERT_TRUE(lit.ok() && shadowed.ok());
  const absl::StatusOr<std::vector<double>> nu = SunlitAlongSeries(series, orbit);
  const std::vector<double>& always = lit->values[face][0];  // lag 0.1 h
  const std::vector<double>& cooled = shadowed->values[face][0];
  const double full = FaceIllumination(s, face);
  double lowest = 1.0;
  int in_umbra = 0;
  for (size_t i = 0; i < series.steps.size(); ++i) {
    EXPECT_NEAR(always[i], full, 0.01);  // the sun moves 0.1 deg in 3 h
    EXPECT_LE(cooled[i], always[i] + 1e-12);
    // 10 min into the umbra a lag of 6 min has fallen below exp(-600 / 360) = 0.19 of full.
    in_umbra = (*nu)[i] == 0.0 ? in_umbra + 1 : 0;
    if (in_umbra == 60) EXPECT_LT(cooled[i], 0.19 * full) << "step " << i;
    lowest = std::min(lowest, cooled[i] / full);
  }
  EXPECT_LT(lowest, 0.01);
}

TEST(SunShadow, TheSunlitFamilyIsTheLaggedSunlitFractionAndOnlyWithTheOrbit) {
  const DeviationSeries series = Series(3.0);
  const Orbit orbit = SunPlaneOrbit(-60, 3 * 3600 + 60);
  const absl::StatusOr<SunRegressors> without = ComputeSunRegressors(series, Eigen::Matrix3d::Identity());
  const absl::StatusOr<SunRegressors> with =
      ComputeSunRegressors(series, Eigen::Matrix3d::Identity(), &orbit);
  ASSERT_TRUE(without.ok() && with.ok());
  EXPECT_EQ(without->values.size(), static_cast<size_t>(kSunFaces));
  ASSERT_EQ(with->values.size(), static_cast<size_t>(kSunFaces + 1));
  EXPECT_EQ(SunFaceName(kSunlitFamily), "sunlit");
  EXPECT_EQ(SunFaceNormal_b(kSunlitFamily), Vector3d::Zero());
  const absl::StatusOr<std::vector<double>> nu = SunlitAlongSeries(series, orbit);
  ASSERT_TRUE(nu.ok());
  std::vector<double> dt(series.steps.size(), 10.0);
  for (size_t lag = 0; lag < with->lag_hours.size(); lag += 10) {
    const std::vector<double> expected = LaggedIllumination(*nu, dt, 3600.0 * with->lag_hours[lag]);
    ASSERT_EQ(with->values[kSunlitFamily][lag].size(), expected.size());
    for (size_t i = 0; i < expected.size(); ++i) {
      ASSERT_DOUBLE_EQ(with->values[kSunlitFamily][lag][i], expected[i]) << "lag " << lag;
    }
  }
}

TEST(SunShadow, AnOrbitThatDoesNotCoverTheSeriesIsRefused) {
  const DeviationSeries series = Series(3.0);
  EXPECT_THAT(SunlitAlongSeries(series, SunPlaneOrbit(0, 3600)),
              StatusIs(absl::StatusCode::kOutOfRange, HasSubstr("orbit: no arc covers")));
}

}  // namespace
}  // namespace esg::estimator::discovery
