// Attitude profiles: analytic rates against finite differences of q_in_b, the paper's calibration
// profile (sun-pointing spin with a 60 min period, orientation changed every 3 h, section 3),
// continuous slews, the orbital period and LVLH axes, named profiles.
#include "estimator/attitude_profile.h"

#include <cmath>
#include <optional>
#include <string>

#include "estimator/rotation.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/quaternion_matchers.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using Eigen::Quaterniond;
using Eigen::Vector3d;
using ::esg::testing::IsNearQuaternion;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;

// Body rate from a central difference of q over +-h, independent of the profile's Rate().
Vector3d FiniteDifferenceRate(const AttitudeProfile& p, double t, double h = 1e-3) {
  return LogQuaternion(p.Attitude(t - h).conjugate() * p.Attitude(t + h)) / (2.0 * h);
}

void ExpectRatesMatchFiniteDifferences(const AttitudeProfile& p, double t_end, double tol) {
  for (double t = 0.0; t <= t_end; t += t_end / 97.0) {
    const Vector3d expected = FiniteDifferenceRate(p, t);
    EXPECT_LT((p.Rate(t) - expected).norm(), tol) << p.Describe() << " at t = " << t;
  }
}

TEST(AttitudeProfile, InertialHoldIsConstant) {
  const Quaterniond q = Quaterniond(0.3, -0.1, 0.9, 0.2).normalized();
  const ProfilePtr p = InertialHold(q);
  EXPECT_THAT(p->Attitude(0.0), IsNearQuaternion(q, 1e-15));
  EXPECT_THAT(p->Attitude(1e5), IsNearQuaternion(q, 1e-15));
  EXPECT_EQ(p->Rate(123.0), Vector3d::Zero());
}

TEST(AttitudeProfile, ConstantSpinRateMatchesFiniteDifferences) {
  auto p = ConstantSpin(Quaterniond(0.5, 0.5, -0.5, 0.5), Vector3d(1, 2, 3), 1e-3);
  ASSERT_THAT(p, IsOk());
  EXPECT_LT(((*p)->Rate(0.0) - 1e-3 * Vector3d(1, 2, 3).normalized()).norm(), 1e-18);
  ExpectRatesMatchFiniteDifferences(**p, 20000.0, 1e-10);
  EXPECT_THAT(ConstantSpin(Quaterniond::Identity(), Vector3d::Zero(), 1.0),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("axis_b")));
}

TEST(AttitudeProfile, OrbitalHasLvlhAxesAndOrbitPeriod) {
  OrbitalOptions o;
  o.inclination = DegToRad(51.6);
  o.period = 5400.0;
  o.raan = DegToRad(100.0);
  o.arg_latitude0 = DegToRad(20.0);
  auto p = Orbital(o);
  ASSERT_THAT(p, IsOk());
  // Periodic with the orbit period, and not with half of it.
  for (double t : {0.0, 1234.5, 4000.0}) {
    EXPECT_THAT((*p)->Attitude(t + o.period), IsNearQuaternion((*p)->Attitude(t), 1e-12));
    EXPECT_THAT((*p)->Attitude(t + 0.5 * o.period),
                ::testing::Not(IsNearQuaternion((*p)->Attitude(t), 1e-3)));
  }
  // Independent construction of the orbit: node direction n, normal w, r(u), v(u).
  const Vector3d node(std::cos(o.raan), std::sin(o.raan), 0.0);
  const Vector3d normal(std::sin(o.raan) * std::sin(o.inclination),
                        -std::cos(o.raan) * std::sin(o.inclination), std::cos(o.inclination));
  const Vector3d in_plane = normal.cross(node);
  for (double t = 0.0; t < 2.0 * o.period; t += 777.0) {
    const double u = o.arg_latitude0 + 2.0 * kPi * t / o.period;
    const Vector3d r = std::cos(u) * node + std::sin(u) * in_plane;
    const Vector3d v = -std::sin(u) * node + std::cos(u) * in_plane;
    const Eigen::Matrix3d C_in_b = (*p)->Attitude(t).toRotationMatrix();
    EXPECT_LT((C_in_b * Vector3d::UnitZ() + r).norm(), 1e-12) << "z to nadir";
    EXPECT_LT((C_in_b * Vector3d::UnitX() - v).norm(), 1e-12) << "x along velocity";
    EXPECT_LT((C_in_b * Vector3d::UnitY() + normal).norm(), 1e-12) << "y along -normal";
  }
  EXPECT_LT(((*p)->Rate(100.0) - Vector3d(0, -2.0 * kPi / o.period, 0)).norm(), 1e-18);
  ExpectRatesMatchFiniteDifferences(**p, o.period, 1e-10);
  EXPECT_THAT(Orbital(0.1, -5.0, 0.0, 0.0),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("period")));
}

TEST(AttitudeProfile, CalibrationSpinsAboutSunPointingAxisWithSixtyMinutePeriod) {
  CalibrationOptions o;  // paper: 60 min spin, 3 h segments
  auto p = Calibration(o, HoursToSeconds(18.0));
  ASSERT_THAT(p, IsOk());
  const Vector3d sun = o.sun_in.normalized();
  const Vector3d axes[] = {Vector3d::UnitZ(), Vector3d::UnitX(), Vector3d::UnitY(),
                           Vector3d(1, 1, 1).normalized()};
  for (int segment = 0; segment < 4; ++segment) {
    const double t0 = HoursToSeconds(3.0 * segment);
    // After the slew: the segment's body axis points at the Sun for the rest of the segment.
    for (double t = t0 + o.slew_duration; t < t0 + HoursToSeconds(3.0); t += 601.0) {
      const Eigen::Matrix3d C_in_b = (*p)->Attitude(t).toRotationMatrix();
      EXPECT_LT((C_in_b * axes[segment] - sun).norm(), 1e-12)
          << "segment " << segment << " t " << t;
      // Spinning about that axis at 2 pi / 60 min.
      // Finite differences right at the slew end: 1e-10 of the 1.7e-3 rad/s rate.
      EXPECT_LT(((*p)->Rate(t) - axes[segment] * 2.0 * kPi / 3600.0).norm(), 1e-10);
    }
    // Period 60 min: the same attitude one hour later, a half turn after 30 min.
    const double t = t0 + o.slew_duration + 100.0;
    EXPECT_THAT((*p)->Attitude(t + 3600.0), IsNearQuaternion((*p)->Attitude(t), 1e-11));
    EXPECT_NEAR(RotationAngle((*p)->Attitude(t + 1800.0), (*p)->Attitude(t)), kPi, 1e-9);
  }
  // The orientation changes every 3 h: another body axis points at the Sun.
  for (int segment = 1; segment < 4; ++segment) {
    const double t = HoursToSeconds(3.0 * segment) + o.slew_duration + 1.0;
    const Eigen::Matrix3d C_in_b = (*p)->Attitude(t).toRotationMatrix();
    EXPECT_GT((C_in_b * axes[segment - 1] - sun).norm(), 0.5) << "segment " << segment;
  }
  ExpectRatesMatchFiniteDifferences(**p, HoursToSeconds(18.0), 1e-8);
}

TEST(AttitudeProfile, SlewsAreContinuousInAttitudeAndRate) {
  CalibrationOptions o;
  auto p = Calibration(o, HoursToSeconds(12.0));
  ASSERT_THAT(p, IsOk());
  for (int boundary = 1; boundary < 4; ++boundary) {
    const double tb = HoursToSeconds(3.0 * boundary);
    // Attitude steps between samples 0.1 s apart stay at the spin/slew rate scale everywhere in
    // and around the slew (no jump), including both ends of the slew.
    double max_step = 0.0;
    for (double t = tb - 5.0; t < tb + o.slew_duration + 5.0; t += 0.1) {
      max_step = std::max(max_step, RotationAngle((*p)->Attitude(t), (*p)->Attitude(t + 0.1)));
    }
    EXPECT_LT(max_step, 0.1 * 0.02) << "boundary " << boundary;  // rate below 0.02 rad/s
    for (double te : {tb, tb + o.slew_duration}) {
      EXPECT_THAT((*p)->Attitude(te - 1e-6), IsNearQuaternion((*p)->Attitude(te + 1e-6), 1e-8));
      EXPECT_LT(((*p)->Rate(te - 0.05) - (*p)->Rate(te + 0.05)).norm(), 1e-6);
    }
    // The slew does move the attitude away from where the outgoing segment would be.
    EXPECT_GT(RotationAngle((*p)->Attitude(tb + o.slew_duration), (*p)->Attitude(tb - 1.0)), 0.1);
  }
}

// A slew whose relative rotation passes through pi while the incoming segment turns: the
// shorter way would flip the eigen axis there (the attitude jumping by about pi at mid-slew);
// the slew keeps its branch and goes on the long way, continuously.
TEST(AttitudeProfile, ASlewThroughPiStaysContinuous) {
  const Vector3d z = Vector3d::UnitZ();
  // Segment B starts at pi - 0.25 rad about z and turns at 0.01 rad/s about z: the relative
  // rotation from the hold passes pi 25 s into the 50 s slew (tau = 1/2).
  auto spin = ConstantSpin(ExpQuaternion((kPi - 0.25) * z), z, 0.01);
  ASSERT_THAT(spin, IsOk());
  auto p = Sequence({{InertialHold(Quaterniond::Identity()), 100.0}, {*spin, 200.0}}, 50.0);
  ASSERT_THAT(p, IsOk());
  double max_step = 0.0;
  for (double t = 95.0; t < 160.0; t += 0.1) {
    max_step = std::max(max_step, RotationAngle((*p)->Attitude(t), (*p)->Attitude(t + 0.1)));
  }
  // The long way turns about 3.6 rad in 50 s: peak rate 30/16 * 3.6 / 50 = 0.135 rad/s.
  EXPECT_LT(max_step, 0.1 * 0.15);
  EXPECT_THAT((*p)->Attitude(150.0), IsNearQuaternion((*spin)->Attitude(50.0), 1e-12));
  ExpectRatesMatchFiniteDifferences(**p, 300.0, 1e-6);
}

// A slew between two spinning segments can pass through pi: the -z to +z turn at 18 h of the
// calibration profile does, with the default spin phases and with those the seeded calibration
// and mixed profiles draw (seed 5024 of the calibration profile at 18 h): the attitude stays
// continuous, at the rates of spins and slews, over every slew of a day.
TEST(AttitudeProfile, SeededProfilesHaveNoAttitudeJumps) {
  for (const char* name : {"calibration", "mixed"}) {
    for (std::optional<uint64_t> seed :
         {std::optional<uint64_t>(), std::optional<uint64_t>(5024), std::optional<uint64_t>(3029),
          std::optional<uint64_t>(1), std::optional<uint64_t>(2), std::optional<uint64_t>(3),
          std::optional<uint64_t>(4), std::optional<uint64_t>(5), std::optional<uint64_t>(6),
          std::optional<uint64_t>(7), std::optional<uint64_t>(8)}) {
      auto p = MakeNamedProfile(name, HoursToSeconds(24.0), seed);
      ASSERT_THAT(p, IsOk());
      double max_step = 0.0;
      for (double t = 0.0; t < HoursToSeconds(24.0); t += 1.0) {
        max_step = std::max(max_step, RotationAngle((*p)->Attitude(t), (*p)->Attitude(t + 1.0)));
      }
      // A slew of at most 2 pi in 600 s peaks at 30/16 * 2 pi / 600 = 0.02 rad/s, plus spins.
      EXPECT_LT(max_step, 0.03) << name << " seed " << (seed ? std::to_string(*seed) : "none");
    }
  }
}

TEST(AttitudeProfile, SequenceBetweenHoldsIsEigenAxisSlew) {
  const Quaterniond qa = Quaterniond::Identity();
  const Vector3d axis = Vector3d(1, -1, 2).normalized();
  const Quaterniond qb = ExpQuaternion(1.0 * axis);
  auto p = Sequence({{InertialHold(qa), 100.0}, {InertialHold(qb), 200.0}}, 50.0);
  ASSERT_THAT(p, IsOk());
  EXPECT_THAT((*p)->Attitude(99.0), IsNearQuaternion(qa, 1e-15));
  EXPECT_THAT((*p)->Attitude(150.0), IsNearQuaternion(qb, 1e-15));
  EXPECT_THAT((*p)->Attitude(1e4), IsNearQuaternion(qb, 1e-15));
  // Mid-slew: half the angle about the same (eigen) axis; quintic law gives s(1/2) = 1/2.
  EXPECT_THAT((*p)->Attitude(125.0), IsNearQuaternion(ExpQuaternion(0.5 * axis), 1e-12));
  const Vector3d w_mid = (*p)->Rate(125.0);
  EXPECT_NEAR(w_mid.normalized().dot(axis), 1.0, 1e-9);
  EXPECT_NEAR(w_mid.norm(), 1.0 * 30.0 / 16.0 / 50.0, 1e-6);  // s'(1/2) = 30/16
  ExpectRatesMatchFiniteDifferences(**p, 300.0, 1e-6);
  EXPECT_THAT(Sequence({}, 1.0),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("no segments")));
  EXPECT_THAT(Sequence({{InertialHold(qa), 10.0}, {InertialHold(qb), 10.0}}, 20.0),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("slew_duration")));
}

TEST(AttitudeProfile, NamedProfiles) {
  for (const std::string& name : NamedProfileNames()) {
    auto p = MakeNamedProfile(name, HoursToSeconds(30.0));
    ASSERT_THAT(p, IsOk()) << name;
    EXPECT_FALSE((*p)->Describe().empty());
    ExpectRatesMatchFiniteDifferences(**p, HoursToSeconds(30.0), 1e-6);
    // Same seed, same profile; different seed, different profile.
    auto a = MakeNamedProfile(name, HoursToSeconds(30.0), 7);
    auto b = MakeNamedProfile(name, HoursToSeconds(30.0), 7);
    auto c = MakeNamedProfile(name, HoursToSeconds(30.0), 8);
    ASSERT_THAT(a, IsOk());
    ASSERT_THAT(c, IsOk());
    for (double t : {0.0, 5000.0, 50000.0}) {
      EXPECT_EQ((*a)->Attitude(t).coeffs(), (*b)->Attitude(t).coeffs()) << name;
    }
    EXPECT_THAT((*a)->Attitude(5000.0),
                ::testing::Not(IsNearQuaternion((*c)->Attitude(5000.0), 1e-6)))
        << name;
  }
  EXPECT_THAT(MakeNamedProfile("tumbling", 100.0),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("inertial, orbital, calibration, mixed")));
  EXPECT_THAT(MakeNamedProfile("orbital", -1.0),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("duration")));
}

TEST(AttitudeProfile, MixedRunsOrbitalCalibrationAndInertialInTurn) {
  ProfileOptions o;
  auto p = MakeNamedProfile("mixed", HoursToSeconds(24.0), std::nullopt, o);
  ASSERT_THAT(p, IsOk());
  const double slew = o.calibration.slew_duration;
  // Orbital part: rate (0, -2 pi / period, 0).
  EXPECT_LT(
      ((*p)->Rate(HoursToSeconds(1.0)) - Vector3d(0, -2.0 * kPi / o.orbital.period, 0)).norm(),
      1e-12);
  // Calibration part: spin at 2 pi / 60 min about the first Sun axis (+z).
  EXPECT_LT(
      ((*p)->Rate(HoursToSeconds(3.0) + slew + 10.0) - Vector3d(0, 0, 2.0 * kPi / 3600.0)).norm(),
      1e-12);
  // Inertial hold, then the orbital part again.
  EXPECT_LT((*p)->Rate(HoursToSeconds(9.0) + slew + 10.0).norm(), 1e-12);
  EXPECT_LT(((*p)->Rate(HoursToSeconds(12.0) + slew + 10.0) -
             Vector3d(0, -2.0 * kPi / o.orbital.period, 0))
                .norm(),
            1e-12);
}

}  // namespace
}  // namespace esg::estimator
