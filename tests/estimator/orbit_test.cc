// The orbit and the Earth's shadow (estimator/orbit.h, estimator/eclipse.h; docs/physics.md "The
// orbit"), against what the geometry gives in closed form: a circular orbit with the sun in its
// plane is in shadow (less than half the sun's disc seen) for 2 asin(R_e / r) of every turn, its
// penumbra lasts 2 a / w (a the sun's apparent radius, w the orbit's rate), and beyond the
// umbra's tip the Earth covers (b / a)^2 of the sun's disc. The Hermite interpolation stays
// within its stated bound of a Keplerian circle, and states too far apart are refused.
#include "estimator/orbit.h"

#include <cmath>
#include <vector>

#include "estimator/eclipse.h"
#include "estimator/sun_direction.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::StatusIs;
using ::testing::HasSubstr;
using Eigen::Vector3d;

constexpr double kMuEarthKm3S2 = 398600.4418;
const absl::Time kT0 = absl::FromCivil(absl::CivilSecond(2019, 3, 1, 0, 0, 0), absl::UTCTimeZone());

// A circular orbit of radius r_km in the x-y plane, angle 0 at kT0.
OrbitState Circular(double r_km, double t_s) {
  const double w = std::sqrt(kMuEarthKm3S2 / (r_km * r_km * r_km));
  OrbitState s;
  s.time = kT0 + absl::Seconds(t_s);
  s.r_in_km = r_km * Vector3d(std::cos(w * t_s), std::sin(w * t_s), 0.0);
  s.v_in_km_s = r_km * w * Vector3d(-std::sin(w * t_s), std::cos(w * t_s), 0.0);
  return s;
}

TEST(Eclipse, ShadowAndPenumbraLastWhatTheGeometryGives) {
  const double r_km = 6878.137;  // 500 km above the equator
  const double w = std::sqrt(kMuEarthKm3S2 / (r_km * r_km * r_km));
  const double period_s = 2.0 * M_PI / w;
  const Vector3d sun_in_km = kAstronomicalUnitKm * Vector3d::UnitX();
  double shadow_s = 0.0, penumbra_s = 0.0;
  const double dt = 0.05;
  for (double t = 0.0; t < period_s; t += dt) {
    const double f = SunlitFraction(Circular(r_km, t).r_in_km, sun_in_km);
    ASSERT_GE(f, 0.0);
    ASSERT_LE(f, 1.0);
    if (f < 0.5) shadow_s += dt;
    if (f > 0.0 && f < 1.0) penumbra_s += dt;
  }
  const double b = std::asin(kEarthEquatorialRadiusKm / r_km);
  const double a = std::asin(kSunRadiusKm / kAstronomicalUnitKm);
  // Less than half the disc while the sun's centre is behind the Earth's limb: 2 b of the turn
  // (the sun's parallax, r / AU = 5e-5 rad, moves that by 0.05 s).
  EXPECT_NEAR(shadow_s, 2.0 * b / w, 0.5) << "period " << period_s << " s";
  EXPECT_NEAR(shadow_s / 60.0, 35.8, 0.2);  // the textbook figure for 500 km, sun in the plane
  // Entry and exit each take the time the limb needs to cross the sun's disc, 2 a / w (8.4 s).
  EXPECT_NEAR(penumbra_s, 2.0 * (2.0 * a / w), 0.5);
}

TEST(Eclipse, SunlitUmbraAndAnnular) {
  const Vector3d sun_in_km = kAstronomicalUnitKm * Vector3d::UnitX();
  EXPECT_EQ(SunlitFraction(Vector3d(7000.0, 0.0, 0.0), sun_in_km), 1.0);
  EXPECT_EQ(SunlitFraction(Vector3d(0.0, 7000.0, 0.0), sun_in_km), 1.0);
  EXPECT_EQ(SunlitFraction(Vector3d(-7000.0, 0.0, 0.0), sun_in_km), 0.0);
  // Beyond the umbra's tip (about 1.38 million km behind the Earth) the Earth's disc lies inside
  // the sun's: the fraction seen is 1 - (b / a)^2.
  const Vector3d far_km(-2.0e6, 0.0, 0.0);
  const double a = std::asin(kSunRadiusKm / (sun_in_km - far_km).norm());
  const double b = std::asin(kEarthEquatorialRadiusKm / far_km.norm());
  EXPECT_NEAR(SunlitFraction(far_km, sun_in_km), 1.0 - (b * b) / (a * a), 1e-12);
}

TEST(SunPosition, IsTheSunDirectionAtTheEarthsDistance) {
  for (int month = 1; month <= 12; ++month) {
    const absl::Time t =
        absl::FromCivil(absl::CivilSecond(2019, month, 1, 0, 0, 0), absl::UTCTimeZone());
    const absl::StatusOr<Vector3d> r_km = SunPosition_in_km(t);
    const absl::StatusOr<Vector3d> s = SunDirection_in(t);
    ASSERT_TRUE(r_km.ok() && s.ok());
    // Perihelion 0.9833 au, aphelion 1.0167 au.
    EXPECT_GT(r_km->norm() / kAstronomicalUnitKm, 0.983) << month;
    EXPECT_LT(r_km->norm() / kAstronomicalUnitKm, 1.017) << month;
    EXPECT_LT((r_km->normalized() - *s).norm(), 1e-12) << month;
  }
}

TEST(Orbit, HermiteInterpolationStaysWithinItsBound) {
  const double r_km = 6878.137;
  for (double step_s : {30.0, 60.0, 120.0, 300.0}) {
    OrbitArc arc;
    for (double t = 0.0; t <= 6000.0; t += step_s) arc.states.push_back(Circular(r_km, t));
    arc.from = arc.states.front().time;
    arc.to = arc.states.back().time;
    const absl::StatusOr<Orbit> orbit = Orbit::FromArcs({arc});
    ASSERT_TRUE(orbit.ok()) << orbit.status();
    const double bound_km = HermiteErrorBoundKm(arc.states[0], arc.states[1]);
    double worst_km = 0.0;
    for (double t = 0.0; t <= 6000.0 - step_s; t += step_s / 7.0) {
      const absl::StatusOr<OrbitState> s = orbit->StateAt(kT0 + absl::Seconds(t));
      ASSERT_TRUE(s.ok());
      worst_km = std::max(worst_km, (s->r_in_km - Circular(r_km, t).r_in_km).norm());
    }
    EXPECT_LE(worst_km, bound_km) << step_s << " s apart";
    EXPECT_GT(worst_km, 0.05 * bound_km) << step_s << " s apart: the bound is not that loose";
  }
}

TEST(Orbit, RefusesStatesTooFarApartOrInsideTheEarth) {
  OrbitArc arc;
  for (double t = 0.0; t <= 6000.0; t += 600.0) arc.states.push_back(Circular(6878.137, t));
  arc.from = arc.states.front().time;
  arc.to = arc.states.back().time;
  EXPECT_THAT(Orbit::FromArcs({arc}),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("arcs[0].states[1].time: states 600 s apart")));
  OrbitArc low = arc;
  low.states.resize(2);
  low.states[1].time = low.states[0].time + absl::Seconds(60);
  low.states[1].r_in_km = Vector3d(6000.0, 0.0, 0.0);
  low.to = low.states[1].time;
  EXPECT_THAT(Orbit::FromArcs({low}), StatusIs(absl::StatusCode::kInvalidArgument,
                                               HasSubstr("states[1].r_in_km: 6000.000 km")));
  EXPECT_THAT(Orbit::FromArcs({}), StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("arcs")));
}

TEST(Orbit, ALaterArcIsUsedWhereArcsOverlapAndGapsAreReported) {
  auto arc_of = [](double from_s, double to_s, double r_km) {
    OrbitArc arc;
    for (double t = from_s; t <= to_s; t += 60.0) arc.states.push_back(Circular(r_km, t));
    arc.from = arc.states.front().time;
    arc.to = arc.states.back().time;
    return arc;
  };
  // Two deliveries overlapping over [1800, 3600] s, then a gap [3600, 5400] s.
  const absl::StatusOr<Orbit> orbit = Orbit::FromArcs(
      {arc_of(0, 3600, 6878.137), arc_of(1800, 3600, 6900.0), arc_of(5400, 7200, 6878.137)});
  ASSERT_TRUE(orbit.ok()) << orbit.status();
  EXPECT_NEAR(orbit->StateAt(kT0 + absl::Seconds(600))->r_in_km.norm(), 6878.137, 1e-3);
  EXPECT_NEAR(orbit->StateAt(kT0 + absl::Seconds(2400))->r_in_km.norm(), 6900.0, 1e-3);
  EXPECT_THAT(orbit->StateAt(kT0 + absl::Seconds(4000)),
              StatusIs(absl::StatusCode::kOutOfRange, HasSubstr("no arc covers 2019-03-01T01:06:40")));
  const std::vector<TimeInterval> gaps =
      orbit->Gaps(kT0 - absl::Seconds(60), kT0 + absl::Seconds(9000));
  ASSERT_EQ(gaps.size(), 3u);
  EXPECT_EQ(gaps[0].from, kT0 - absl::Seconds(60));
  EXPECT_EQ(gaps[0].to, kT0 - absl::Nanoseconds(1));
  EXPECT_EQ(gaps[1].from, kT0 + absl::Seconds(3600) + absl::Nanoseconds(1));
  EXPECT_EQ(gaps[1].to, kT0 + absl::Seconds(5400) - absl::Nanoseconds(1));
  EXPECT_EQ(gaps[2].from, kT0 + absl::Seconds(7200) + absl::Nanoseconds(1));
  EXPECT_TRUE(orbit->Gaps(kT0, kT0 + absl::Seconds(3600)).empty());
}

}  // namespace
}  // namespace esg::estimator
