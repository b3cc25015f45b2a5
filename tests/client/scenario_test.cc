// Scenario JSON (client/scenario.h, docs/scenario.md): units converted to SI, unknown keys and
// out-of-range values named, changes applied on top of the configuration's model.
#include "client/scenario.h"

#include <algorithm>
#include <cmath>
#include <string>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/model_terms.h"
#include "estimator/simulator.h"
#include "estimator/rotation.h"
#include "estimator/sun_direction.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"

namespace esg::client {
namespace {

using Eigen::Vector3d;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;
namespace est = ::esg::estimator;

est::SpacecraftConfig Config() {
  est::SpacecraftConfig c;
  c.spacecraft_id = "T";
  for (int id = 1; id <= 3; ++id) {
    est::GyroConfig g;
    g.id = id;
    g.model.k0 = est::DegPerHourToRadPerSec(0.1 * id);
    g.model.C1 = est::DegPerHourToRadPerSec(0.01) * Vector3d(1, 2, 3);
    c.gyros.push_back(g);
  }
  c.readout_noise = est::ArcsecToRad(3.0);
  return c;
}

constexpr char kFull[] = R"({
  "description": "displaced rotor on gyro 2, star tracker with defects",
  "gyros": [{"id": 2, "rotorDisplacementUm": [0.5, -1.0, 0.3], "c10DegHPerUm": 0.05,
             "c20DegHPerUm": 0.015, "k0DegH": 0.2, "c2DegH": [0.1, 0, -0.1],
             "misalignmentArcsec": [10, -20, 30], "randomWalkDegHSqrtH": 0.002,
             "running": true, "fault": {"timeHours": 5, "kind": "drift_step", "degH": [0, 0, 0.05]}},
            {"id": 1, "fault": {"timeHours": 2.5, "kind": "readout_jump", "arcsec": [0, 60, 0]}}],
  "starTracker": {"noiseArcsec": [4, 4, 25], "latencyMs": 300, "misalignmentArcsec": [5, 0, 0],
                  "outlierRate": 0.01, "outlierArcmin": 2,
                  "outages": [{"startHours": 3, "endHours": 4}], "invalidRate": 0.005},
  "readoutNoiseArcsec": 2,
  "profile": "orbital", "inclinationDeg": 51.6, "orbitPeriodMin": 92, "profileSeed": 9
})";

TEST(Scenario, ParsesEveryFieldIntoSi) {
  auto s = ParseScenarioJson(kFull);
  ASSERT_THAT(s, IsOk());
  EXPECT_EQ(s->profile, "orbital");
  EXPECT_EQ(s->profile_seed, 9u);
  EXPECT_NEAR(s->profile_options.orbital.inclination, est::DegToRad(51.6), 1e-15);
  EXPECT_NEAR(s->profile_options.orbital.period, 92 * 60.0, 1e-9);
  ASSERT_EQ(s->gyros.size(), 2u);
  const ScenarioGyro& g2 = s->gyros[0];
  EXPECT_EQ(g2.id, 2);
  EXPECT_LT((*g2.rotor_displacement_k - 1e-6 * Vector3d(0.5, -1.0, 0.3)).norm(), 1e-20);
  EXPECT_NEAR(*g2.c10_per_m, est::DegPerHourToRadPerSec(0.05) / 1e-6, 1e-12);
  EXPECT_NEAR(*g2.drift_coefficients[est::kThetaK0], est::DegPerHourToRadPerSec(0.2), 1e-20);
  EXPECT_LT((*g2.misalignment_b - est::ArcsecToRad(1.0) * Vector3d(10, -20, 30)).norm(), 1e-20);
  ASSERT_TRUE(g2.fault.has_value());
  EXPECT_EQ(g2.fault->kind, est::GyroFault::Kind::kDriftStep);
  EXPECT_EQ(g2.fault->time, 5 * 3600.0);
  EXPECT_EQ(s->gyros[1].fault->kind, est::GyroFault::Kind::kReadoutJump);
  EXPECT_NEAR(s->star_tracker.latency, 0.3, 1e-15);
  EXPECT_NEAR(s->star_tracker.outlier_size, est::ArcminToRad(2.0), 1e-18);
  ASSERT_EQ(s->star_tracker.outages.size(), 1u);
  EXPECT_EQ(s->star_tracker.outages[0].first, 3 * 3600.0);
  EXPECT_NEAR(*s->readout_noise, est::ArcsecToRad(2.0), 1e-20);
}

TEST(Scenario, ApplyMergesCoefficientsWithTheModelAndSetsTruth) {
  auto s = ParseScenarioJson(kFull);
  ASSERT_THAT(s, IsOk());
  est::SimulationSpec spec;
  spec.config = Config();
  ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
  const est::GyroTruth& g2 = spec.gyros[1];
  ASSERT_TRUE(g2.drift.has_value());
  EXPECT_NEAR(g2.drift->k0, est::DegPerHourToRadPerSec(0.2), 1e-20);      // replaced
  EXPECT_EQ(g2.drift->C1, spec.config.gyros[1].model.C1);                 // kept from the model
  EXPECT_NEAR(g2.drift->C2.x(), est::DegPerHourToRadPerSec(0.1), 1e-20);  // replaced
  EXPECT_EQ(g2.running, true);
  EXPECT_NEAR(*g2.readout_noise, est::ArcsecToRad(2.0), 1e-20);  // top-level value, all gyros
  EXPECT_NEAR(*spec.gyros[2].readout_noise, est::ArcsecToRad(2.0), 1e-20);
  EXPECT_FALSE(spec.gyros[0].drift.has_value());
  EXPECT_TRUE(spec.gyros[0].fault.has_value());
  EXPECT_EQ(spec.star_tracker.outages.size(), 1u);
  EXPECT_TRUE(spec.star_tracker.noise.has_value());
  // The merged spec simulates.
  auto profile = MakeScenarioProfile(*s, "", 3600.0);
  ASSERT_THAT(profile, IsOk());
  EXPECT_THAT((*profile)->Describe(), HasSubstr("orbital"));
  spec.profile = *profile;
  spec.duration = 3600.0;
  EXPECT_THAT(est::Simulate(spec), IsOk());
  // The command-line name wins over the scenario's.
  auto inertial = MakeScenarioProfile(*s, "inertial", 3600.0);
  ASSERT_THAT(inertial, IsOk());
  EXPECT_THAT((*inertial)->Describe(), HasSubstr("inertial"));
}

// The faults of the fault matrix (issue 9): frozen and missing gyro readings, the cold spare
// switched on, and the star tracker's outlier burst, frozen output and misalignment jump.
TEST(Scenario, ParsesAndAppliesTheFaultMatrixFaults) {
  auto s = ParseScenarioJson(R"({
    "gyros": [{"id": 1, "fault": {"timeHours": 2, "kind": "reading_frozen", "endHours": 2.25}},
              {"id": 2, "fault": {"timeHours": 3, "kind": "readings_missing", "endHours": 3.5}},
              {"id": 3, "switchOnHours": 6}],
    "starTracker": {"outlierBurst": {"timeHours": 4, "count": 5, "arcmin": 3},
                    "frozen": [{"startHours": 5, "endHours": 5.5}],
                    "misalignmentJump": {"timeHours": 7, "arcsec": [120, 0, -60]},
                    "misalignmentCycle": {"arcsec": [18, -15, 19], "periodMin": 94,
                                          "phaseDeg": 30},
                    "sunMount": {"arcsec": [20, -10, 5], "face": "-y",
                                 "timeConstantHours": 1.5}}
  })");
  ASSERT_THAT(s, IsOk());
  est::SimulationSpec spec;
  spec.config = Config();
  ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
  const est::GyroFault& frozen = *spec.gyros[0].fault;
  EXPECT_EQ(frozen.kind, est::GyroFault::Kind::kReadingFrozen);
  EXPECT_EQ(frozen.time, 2 * 3600.0);
  EXPECT_EQ(frozen.end, 2.25 * 3600.0);
  const est::GyroFault& missing = *spec.gyros[1].fault;
  EXPECT_EQ(missing.kind, est::GyroFault::Kind::kReadingsMissing);
  EXPECT_EQ(missing.time, 3 * 3600.0);
  EXPECT_EQ(missing.end, 3.5 * 3600.0);
  EXPECT_EQ(spec.gyros[2].switch_on_time, 6 * 3600.0);
  const est::StarTrackerTruth& st = spec.star_tracker;
  ASSERT_TRUE(st.outlier_burst.has_value());
  EXPECT_EQ(st.outlier_burst->time, 4 * 3600.0);
  EXPECT_EQ(st.outlier_burst->count, 5);
  EXPECT_NEAR(st.outlier_burst->angle, est::ArcminToRad(3.0), 1e-18);
  ASSERT_EQ(st.frozen.size(), 1u);
  EXPECT_EQ(st.frozen[0], std::make_pair(5 * 3600.0, 5.5 * 3600.0));
  ASSERT_TRUE(st.misalignment_jump.has_value());
  EXPECT_EQ(st.misalignment_jump->time, 7 * 3600.0);
  EXPECT_LT((st.misalignment_jump->rotation_b - est::ArcsecToRad(1.0) * Vector3d(120, 0, -60)).norm(),
            1e-20);
  ASSERT_TRUE(st.misalignment_cycle.has_value());
  EXPECT_LT((st.misalignment_cycle->amplitude_b - est::ArcsecToRad(1.0) * Vector3d(18, -15, 19))
                .norm(),
            1e-20);
  EXPECT_EQ(st.misalignment_cycle->period_s, 94 * 60.0);
  EXPECT_NEAR(st.misalignment_cycle->phase_rad, est::DegToRad(30.0), 1e-15);
  ASSERT_TRUE(st.sun_mount.has_value());
  EXPECT_LT((st.sun_mount->rotation_b - est::ArcsecToRad(1.0) * Vector3d(20, -10, 5)).norm(),
            1e-20);
  EXPECT_EQ(st.sun_mount->face_axis, 1);
  EXPECT_EQ(st.sun_mount->face_sign, -1);
  EXPECT_EQ(st.sun_mount->time_constant_s, 1.5 * 3600.0);
  // The spec simulates with every one of them.
  spec.profile = *MakeScenarioProfile(*s, "", 8 * 3600.0);
  spec.duration = 8 * 3600.0;
  EXPECT_THAT(est::Simulate(spec), IsOk());
}

// A rate-dependent drift and a warm-up transient: parsed into SI, applied, and simulated as
// their formulas say (each truth sample's part: G C_k_b w_b for the body rate of the profile at
// that time, A exp(-(t - t0) / tau) from t0 and zero before), both included in the total drift.
TEST(Scenario, ParsesAndSimulatesTheRateDependentDriftAndTheWarmUpTransient) {
  auto s = ParseScenarioJson(R"({
    "profile": "calibration",
    "gyros": [{"id": 1, "rateDrift": {"degHPerDegS": [0.7, 0, 0, 0, 0, -0.3, 0.1, 0.2, 0]}},
              {"id": 2, "transientDrift": {"amplitudeDegH": [0.1, -0.05, 0],
                                           "timeConstantHours": 0.5, "startHours": 0.25}}]
  })");
  ASSERT_THAT(s, IsOk());
  ASSERT_EQ(s->gyros.size(), 2u);
  ASSERT_TRUE(s->gyros[0].rate_drift.has_value());
  EXPECT_NEAR(s->gyros[0].rate_drift->gain_k(0, 0), 0.7 / 3600.0, 1e-18);
  EXPECT_NEAR(s->gyros[0].rate_drift->gain_k(1, 2), -0.3 / 3600.0, 1e-18);
  EXPECT_NEAR(s->gyros[0].rate_drift->gain_k(2, 1), 0.2 / 3600.0, 1e-18);
  ASSERT_TRUE(s->gyros[1].transient_drift.has_value());
  EXPECT_EQ(s->gyros[1].transient_drift->time_constant_s, 1800.0);
  EXPECT_EQ(s->gyros[1].transient_drift->start_s, 900.0);

  est::SimulationSpec spec;
  spec.config = Config();
  ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
  auto profile = MakeScenarioProfile(*s, "", 3600.0);
  ASSERT_THAT(profile, IsOk());
  spec.profile = *profile;
  spec.duration = 3600.0;
  auto result = est::Simulate(spec);
  ASSERT_THAT(result, IsOk());
  ASSERT_TRUE(result->effects[0].rate_drift.has_value());
  ASSERT_TRUE(result->effects[1].transient_drift.has_value());
  const Eigen::Matrix3d gain = s->gyros[0].rate_drift->gain_k;
  const Vector3d amplitude = s->gyros[1].transient_drift->amplitude_k_rad_s;
  double largest_rate_drift = 0.0;
  for (const est::TruthSample& t : result->truth) {
    const double t_s = absl::ToDoubleSeconds(t.time - spec.start);
    const est::GyroTruthSample& g1 = *t.gyros[0];
    const Vector3d w_k = g1.C_b_k.transpose() * spec.profile->Rate(t_s);
    EXPECT_LT((g1.dw_rate_k_rad_s - gain * w_k).norm(), 1e-15) << t_s;
    largest_rate_drift = std::max(largest_rate_drift, g1.dw_rate_k_rad_s.norm());
    const est::GyroTruthSample& g2 = *t.gyros[1];
    const Vector3d expected =
        t_s < 900.0 ? Vector3d::Zero() : Vector3d(amplitude * std::exp(-(t_s - 900.0) / 1800.0));
    EXPECT_LT((g2.dw_transient_k_rad_s - expected).norm(), 1e-15) << t_s;
    // Gyro 2 has no other effect beyond the model: its total drift includes the transient.
    EXPECT_TRUE(g2.dw_rate_k_rad_s.isZero(0.0));
    EXPECT_TRUE(t.gyros[2]->dw_transient_k_rad_s.isZero(0.0));
  }
  // The calibration profile turns at about 0.1 deg/s: a drift of a few hundredths of a deg/h.
  EXPECT_GT(est::RadPerSecToDegPerHour(largest_rate_drift), 0.01);
}

// A step of the drift coefficients (docs/scenario.md coefficientStep): its time and each
// coefficient's step parsed into SI in theta layout, the others 0, and carried into the
// simulation's truth.
TEST(Scenario, ParsesAndAppliesTheCoefficientStep) {
  auto s = ParseScenarioJson(R"({
    "gyros": [{"id": 2, "coefficientStep": {"startHours": 0.25, "k0DegH": 0.1,
                                            "nuDegH": [0.01, -0.02, 0.03]}}]
  })");
  ASSERT_THAT(s, IsOk());
  ASSERT_EQ(s->gyros.size(), 1u);
  ASSERT_TRUE(s->gyros[0].coefficient_step.has_value());
  const est::CoefficientStep& c = *s->gyros[0].coefficient_step;
  EXPECT_EQ(c.time_s, 900.0);
  EXPECT_NEAR(c.delta.k0, est::DegPerHourToRadPerSec(0.1), 1e-18);
  EXPECT_NEAR(c.delta.nu(1), est::DegPerHourToRadPerSec(-0.02), 1e-18);
  EXPECT_TRUE(c.delta.C1.isZero(0.0));
  EXPECT_TRUE(c.delta.C2.isZero(0.0));
  EXPECT_TRUE(c.delta.mu.isZero(0.0));
  est::SimulationSpec spec;
  spec.config = Config();
  ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
  ASSERT_TRUE(spec.gyros[1].coefficient_step.has_value());
  EXPECT_EQ(spec.gyros[1].coefficient_step->time_s, 900.0);
  EXPECT_FALSE(spec.gyros[0].coefficient_step.has_value());
}

// A sun-driven thermal drift: parsed into SI and a face, and simulated as its formula says. The
// face's illumination u = max(0, s_b[x]) is recomputed here from each truth sample's attitude and
// the sun's direction at its time, and its lag tau dy/dt = u - y, y(0) = u(0), integrated on the
// truth samples alone (60 s apart, exact for u linear between them). The simulator steps the lag
// at 8 Hz, so the two differ by the lag of u's departure from a line over 60 s: under
// |u''| (60 s)^2 / 8 = 6e-4 for the orbital profile's 1.1e-3 rad/s, and under 4e-4 where u meets
// its kink at 0 (a slope change of at most 1.1e-3 /s, lagged over 60 s of tau = 0.5 h): 2e-3
// allowed.
// "earthShadow" with a "sunlit" drift: the truth's illumination is the fraction of the sun's disc
// seen from the circular orbit of the scenario's elements, so it is 0 in the Earth's shadow for
// the fraction of each orbit the geometry gives: (1 / pi) acos(sqrt(h^2 + 2 R h) / (r cos beta)),
// h the height above the equatorial radius R and beta the sun's angle above the orbit's plane.
TEST(Scenario, TheSunlitDriftIsDarkInTheEarthsShadowForTheTimeTheGeometryGives) {
  auto s = ParseScenarioJson(R"({
    "profile": "inertial", "earthShadow": true,
    "inclinationDeg": 51.6, "orbitPeriodMin": 94.6, "raanDeg": 340,
    "gyros": [{"id": 2, "sunFaceDrift": {"amplitudeDegH": [0, 0.1, 0], "face": "sunlit",
                                        "timeConstantHours": 0.5}}]
  })");
  ASSERT_THAT(s, IsOk());
  ASSERT_TRUE(s->earth_shadow);
  EXPECT_EQ(s->gyros[0].sun_face_drift->face_axis, est::kSunlitFaceAxis);
  est::SimulationSpec spec;
  spec.config = Config();
  ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
  ASSERT_TRUE(spec.earth_shadow.has_value());
  // Four whole orbits: as many eclipses as the fraction counts.
  spec.duration = 4.0 * spec.earth_shadow->period;
  spec.telemetry_step = 10.0;
  auto profile = MakeScenarioProfile(*s, "", spec.duration);
  ASSERT_THAT(profile, IsOk());
  spec.profile = *profile;
  auto result = est::Simulate(spec);
  ASSERT_THAT(result, IsOk());
  int dark = 0, lit = 0;
  for (const est::TruthSample& t : result->truth) {
    const double u = t.gyros[1]->sun_illumination;
    ASSERT_GE(u, 0.0);
    ASSERT_LE(u, 1.0);
    dark += u < 0.5;
    lit += u == 1.0;
  }
  // The orbit's normal and the sun at the run's middle give beta.
  const est::OrbitalOptions& o = *spec.earth_shadow;
  const Vector3d normal(std::sin(o.raan) * std::sin(o.inclination),
                       -std::cos(o.raan) * std::sin(o.inclination), std::cos(o.inclination));
  const Vector3d sun = *est::SunDirection_in(spec.start + absl::Seconds(spec.duration / 2));
  const double beta = std::asin(normal.dot(sun));
  const double n = 2.0 * M_PI / o.period;
  const double r = std::cbrt(398600.4418 / (n * n)), R = 6378.137, h = r - R;
  const double expected = std::acos(std::sqrt(h * h + 2.0 * R * h) / (r * std::cos(beta))) / M_PI;
  const double frames = static_cast<double>(result->truth.size());
  EXPECT_NEAR(dark / frames, expected, 0.01) << "beta " << beta * 180.0 / M_PI << " deg";
  EXPECT_GT(lit / frames, 1.0 - expected - 0.02);
}

TEST(Scenario, ParsesAndSimulatesTheSunDrivenThermalDrift) {
  auto s = ParseScenarioJson(R"({
    "profile": "orbital", "orbitPeriodMin": 95,
    "gyros": [{"id": 2, "sunFaceDrift": {"amplitudeDegH": [0.09, 0, -0.03], "face": "+x",
                                        "timeConstantHours": 0.5}}]
  })");
  ASSERT_THAT(s, IsOk());
  ASSERT_EQ(s->gyros.size(), 1u);
  ASSERT_TRUE(s->gyros[0].sun_face_drift.has_value());
  const est::SunFaceDrift& d = *s->gyros[0].sun_face_drift;
  EXPECT_EQ(d.face_axis, 0);
  EXPECT_EQ(d.face_sign, 1);
  auto minus_y = ParseScenarioJson(R"({"gyros": [{"id": 1, "sunFaceDrift":
      {"amplitudeDegH": [0, 0, 0.1], "face": "-y", "timeConstantHours": 2}}]})");
  ASSERT_THAT(minus_y, IsOk());
  EXPECT_EQ(minus_y->gyros[0].sun_face_drift->face_axis, 1);
  EXPECT_EQ(minus_y->gyros[0].sun_face_drift->face_sign, -1);
  EXPECT_EQ(d.time_constant_s, 1800.0);
  EXPECT_LT((d.amplitude_k_rad_s - est::DegPerHourToRadPerSec(1.0) * Vector3d(0.09, 0, -0.03))
                .norm(),
            1e-20);

  est::SimulationSpec spec;
  spec.config = Config();
  ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
  spec.start = absl::FromCivil(absl::CivilSecond(2024, 6, 20, 0, 0, 0), absl::UTCTimeZone());
  spec.duration = 6 * 3600.0;
  auto profile = MakeScenarioProfile(*s, "", spec.duration);
  ASSERT_THAT(profile, IsOk());
  spec.profile = *profile;
  auto result = est::Simulate(spec);
  ASSERT_THAT(result, IsOk());
  ASSERT_TRUE(result->effects[1].sun_face_drift.has_value());
  EXPECT_FALSE(result->effects[0].sun_face_drift.has_value());

  const double tau = 1800.0;
  double y = 0.0, u_prev = 0.0, t_prev = 0.0;
  double u_min = 1.0, u_max = 0.0, worst = 0.0;
  for (size_t m = 0; m < result->truth.size(); ++m) {
    const est::TruthSample& t = result->truth[m];
    const double t_s = absl::ToDoubleSeconds(t.time - spec.start);
    auto s_in = est::SunDirection_in(t.time);
    ASSERT_THAT(s_in.status(), IsOk());
    const Vector3d s_b = t.q_in_b.toRotationMatrix().transpose() * *s_in;
    const double u = std::max(0.0, s_b.x());
    if (m == 0) {
      y = u;
    } else {
      // Exact for u linear over [t_prev, t_s].
      const double h = t_s - t_prev, a = std::exp(-h / tau);
      y = u + (y - u_prev) * a - (u - u_prev) * (tau / h) * (1.0 - a);
    }
    u_prev = u;
    t_prev = t_s;
    u_min = std::min(u_min, u);
    u_max = std::max(u_max, u);
    const est::GyroTruthSample& g2 = *t.gyros[1];
    EXPECT_NEAR(g2.sun_illumination, u, 1e-7) << t_s;
    EXPECT_NEAR(g2.sun_lagged_illumination, y, 2e-3) << t_s;
    worst = std::max(worst, std::abs(g2.sun_lagged_illumination - y));
    EXPECT_LT((g2.dw_sun_k_rad_s - g2.sun_lagged_illumination * d.amplitude_k_rad_s).norm(),
              1e-20)
        << t_s;
    EXPECT_TRUE(t.gyros[0]->dw_sun_k_rad_s.isZero(0.0));
    EXPECT_EQ(t.gyros[0]->sun_lagged_illumination, 0.0);
  }
  // The orbital profile carries the face in and out of the sun, so the lag matters.
  EXPECT_LT(u_min, 0.05);
  EXPECT_GT(u_max, 0.5);
  RecordProperty("worst_lag_difference", std::to_string(worst));

  // Where the sun is not known (past ERFA's ephemeris), the run is refused naming the effect.
  spec.start = absl::FromCivil(absl::CivilSecond(2150, 1, 1, 0, 0, 0), absl::UTCTimeZone());
  EXPECT_THAT(est::Simulate(spec),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("sun_face_drift: the run (start and duration) must lie where "
                                 "the sun is known")));
}

// The drift effects beyond the paper's models: each key parsed into SI, applied to the truth, and
// the orbital drift's period taken from the profile when absent (and required without an orbit).
TEST(Scenario, ParsesAndAppliesTheDriftEffects) {
  auto s = ParseScenarioJson(R"({
    "profile": "orbital", "orbitPeriodMin": 92,
    "gyros": [{"id": 1, "orbitalDrift": {"amplitudeDegH": [0.02, 0, -0.01], "phaseDeg": 30},
               "rotorDisplacementUm": [0.5, 0, 0], "rotorDisplacementRateUmH": [0.05, -0.1, 0]},
              {"id": 2, "orbitalDrift": {"amplitudeDegH": [0, 0.01, 0], "periodMin": 100},
               "switchingDrift": {"amplitudeDegH": [0, 0.03, 0], "meanDwellHours": 4},
               "readoutDistortionPpm": [200, -100, 0, 50, 10, -30]},
              {"id": 3, "hiddenDriverDrift": {"amplitudeDegH": [0.01, 0.02, 0],
                                              "correlationHours": 2}}]
  })");
  ASSERT_THAT(s, IsOk());
  ASSERT_EQ(s->gyros.size(), 3u);
  const ScenarioGyro& g1 = s->gyros[0];
  ASSERT_TRUE(g1.orbital_drift.has_value());
  EXPECT_LT((g1.orbital_drift->amplitude_k_rad_s -
             est::DegPerHourToRadPerSec(1.0) * Vector3d(0.02, 0, -0.01))
                .norm(),
            1e-20);
  EXPECT_FALSE(g1.orbital_drift->period_s.has_value());
  EXPECT_NEAR(g1.orbital_drift->phase_rad, est::DegToRad(30.0), 1e-15);
  EXPECT_LT((*g1.rotor_displacement_rate_k_m_s - 1e-6 / 3600.0 * Vector3d(0.05, -0.1, 0)).norm(),
            1e-24);
  const ScenarioGyro& g2 = s->gyros[1];
  EXPECT_EQ(g2.orbital_drift->period_s, 6000.0);
  EXPECT_EQ(g2.orbital_drift->phase_rad, 0.0);
  ASSERT_TRUE(g2.switching_drift.has_value());
  EXPECT_EQ(g2.switching_drift->mean_dwell_s, 4 * 3600.0);
  EXPECT_NEAR(g2.switching_drift->amplitude_k_rad_s.y(), est::DegPerHourToRadPerSec(0.03), 1e-20);
  ASSERT_TRUE(g2.readout_distortion_k.has_value());
  Eigen::Matrix3d D;
  D << 200, 50, -30,  //
      50, -100, 10,   //
      -30, 10, 0;
  EXPECT_LT((*g2.readout_distortion_k - 1e-6 * D).norm(), 1e-18);
  EXPECT_EQ(*g2.readout_distortion_k, g2.readout_distortion_k->transpose());
  const ScenarioGyro& g3 = s->gyros[2];
  ASSERT_TRUE(g3.hidden_driver_drift.has_value());
  EXPECT_EQ(g3.hidden_driver_drift->correlation_time_s, 2 * 3600.0);
  EXPECT_NEAR(g3.hidden_driver_drift->amplitude_k_rad_s.y(), est::DegPerHourToRadPerSec(0.02),
              1e-20);

  est::SimulationSpec spec;
  spec.config = Config();
  ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
  EXPECT_EQ(spec.gyros[0].rotor_displacement_rate_k_m_s, *g1.rotor_displacement_rate_k_m_s);
  EXPECT_EQ(spec.gyros[0].orbital_drift->phase_rad, g1.orbital_drift->phase_rad);
  EXPECT_EQ(spec.gyros[1].readout_distortion_k, *g2.readout_distortion_k);
  EXPECT_EQ(spec.gyros[1].switching_drift->mean_dwell_s, 4 * 3600.0);
  EXPECT_EQ(spec.gyros[2].hidden_driver_drift->correlation_time_s, 2 * 3600.0);
  EXPECT_FALSE(spec.gyros[2].orbital_drift.has_value());
  // The orbital profile supplies gyro 1's period (92 min); the spec simulates.
  auto profile = MakeScenarioProfile(*s, "", 3600.0);
  ASSERT_THAT(profile, IsOk());
  EXPECT_THAT(CheckScenarioAgainstProfile(*s, **profile), IsOk());
  spec.profile = *profile;
  spec.duration = 3600.0;
  auto result = est::Simulate(spec);
  ASSERT_THAT(result, IsOk());
  EXPECT_EQ(result->effects[0].orbital_drift->period_s, 92 * 60.0);
  EXPECT_EQ(result->effects[1].orbital_drift->period_s, 6000.0);
  // The calibration profile has no orbit: gyro 1's orbitalDrift then needs periodMin.
  auto calibration = MakeScenarioProfile(*s, "calibration", 3600.0);
  ASSERT_THAT(calibration, IsOk());
  EXPECT_THAT(CheckScenarioAgainstProfile(*s, **calibration),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[0].orbitalDrift.periodMin: required")));
}

// rotorDisplacementTurn: the axis normalised whatever its length (before or after
// rotorDisplacementUm in the object), the period in hours to seconds, copied into the truth with
// the rate beside it; the simulated displacement turns right-handed about it (a quarter turn of
// (1, 0, 0) um about case z is (0, 1, 0) um).
TEST(Scenario, ParsesAndAppliesTheRotorDisplacementTurn) {
  auto s = ParseScenarioJson(R"({
    "gyros": [{"id": 2, "rotorDisplacementTurn": {"axis": [0, 0, 4], "periodH": 4},
               "rotorDisplacementUm": [1, 0, 0]},
              {"id": 3, "rotorDisplacementUm": [0, 0.5, 0], "rotorDisplacementRateUmH": [0, 0.1, 0],
               "rotorDisplacementTurn": {"axis": [1, -1, 0.5], "periodH": 8784}}]
  })");
  ASSERT_THAT(s, IsOk());
  ASSERT_EQ(s->gyros.size(), 2u);
  ASSERT_TRUE(s->gyros[0].rotor_displacement_turn.has_value());
  EXPECT_EQ(s->gyros[0].rotor_displacement_turn->axis_k, Vector3d::UnitZ());
  EXPECT_EQ(s->gyros[0].rotor_displacement_turn->period_s, 4 * 3600.0);
  const Vector3d axis3 = s->gyros[1].rotor_displacement_turn->axis_k;
  EXPECT_NEAR(axis3.norm(), 1.0, 1e-15);
  EXPECT_LT((axis3 - Vector3d(1, -1, 0.5) / 1.5).norm(), 1e-15);
  EXPECT_EQ(s->gyros[1].rotor_displacement_turn->period_s, 8784 * 3600.0);

  est::SimulationSpec spec;
  spec.config = Config();
  ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
  EXPECT_FALSE(spec.gyros[0].rotor_displacement_turn.has_value());
  ASSERT_TRUE(spec.gyros[1].rotor_displacement_turn.has_value());
  EXPECT_EQ(spec.gyros[1].rotor_displacement_turn->axis_k, Vector3d::UnitZ());
  EXPECT_EQ(spec.gyros[1].rotor_displacement_turn->period_s, 4 * 3600.0);
  EXPECT_EQ(spec.gyros[2].rotor_displacement_turn->axis_k, axis3);
  EXPECT_EQ(spec.gyros[2].rotor_displacement_rate_k_m_s, 1e-6 / 3600.0 * Vector3d(0, 0.1, 0));
  auto profile = MakeScenarioProfile(*s, "calibration", 3600.0);
  ASSERT_THAT(profile, IsOk());
  spec.profile = *profile;
  spec.duration = 3600.0;
  auto result = est::Simulate(spec);
  ASSERT_THAT(result, IsOk());
  ASSERT_TRUE(result->truth.back().gyros[1].has_value());
  EXPECT_LT(
      (result->truth.back().gyros[1]->rotor_displacement_k_m - 1e-6 * Vector3d(0, 1, 0)).norm(),
      1e-18);
}

TEST(Scenario, GyroNotInConfigurationIsAnError) {
  auto s = ParseScenarioJson(R"({"gyros": [{"id": 4, "running": true}]})");
  ASSERT_THAT(s, IsOk());
  est::SimulationSpec spec;
  spec.config = Config();
  EXPECT_THAT(ApplyScenario(*s, &spec),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("gyros[0].id: gyro 4")));
}

// Every fixed term of the drift model is a scenario key with the shape the term table gives it
// (estimator/model_terms.h FixedTermKeys()): one number, or an array of its component count, each
// number landing in its own theta slot; an array one longer is refused naming that count.
TEST(Scenario, FixedTermKeysTakeTheComponentCountOfTheTermTable) {
  for (const est::FixedTermKey& key : est::FixedTermKeys()) {
    SCOPED_TRACE(std::string(key.json_key));
    const int n = key.components == 0 ? 1 : key.components;
    std::string numbers;
    for (int i = 0; i < n; ++i) {
      numbers += absl::StrFormat("%s%g", i == 0 ? "" : ", ", 0.01 * (i + 1));
    }
    const std::string value = key.components == 0 ? numbers : absl::StrCat("[", numbers, "]");
    absl::StatusOr<Scenario> s = ParseScenarioJson(
        absl::StrCat(R"({"gyros": [{"id": 1, ")", key.json_key, R"(": )", value, "}]}"));
    ASSERT_THAT(s, IsOk());
    ASSERT_EQ(s->gyros.size(), 1u);
    for (int t = 0; t < est::kNumDriftCoefficients; ++t) {
      const bool in_key = t >= key.first_theta_index && t < key.first_theta_index + n;
      ASSERT_EQ(s->gyros[0].drift_coefficients[t].has_value(), in_key) << t;
      if (in_key) {
        EXPECT_DOUBLE_EQ(*s->gyros[0].drift_coefficients[t],
                         est::DegPerHourToRadPerSec(0.01 * (t - key.first_theta_index + 1)))
            << t;
      }
    }
    if (key.components == 0) continue;
    EXPECT_THAT(
        ParseScenarioJson(absl::StrCat(R"({"gyros": [{"id": 1, ")", key.json_key, R"(": [)",
                                       numbers, ", 0]}]}")),
        StatusIs(absl::StatusCode::kInvalidArgument,
                 HasSubstr(absl::StrCat("gyros[0].", key.json_key, ": expected an array of ", n,
                                        " numbers, got ", n + 1, " values"))));
  }
}

TEST(Scenario, ErrorsNameTheKey) {
  const std::pair<const char*, const char*> cases[] = {
      {R"({"gyro": []})", "gyro: unknown key"},
      {R"({"gyros": [{"id": 1, "k0": 0.2}]})", "gyros[0].k0: unknown key"},
      {R"({"gyros": [{"k0DegH": 0.2}]})", "gyros[0].id: required"},
      {R"({"gyros": [{"id": 5}]})", "gyros[0].id: 5 is outside 1..4"},
      {R"({"gyros": [{"id": 1}, {"id": 1}]})", "gyros[1].id: gyro 1 appears twice"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [0, 50, 0]}]})",
       "gyros[0].rotorDisplacementUm[1]: 50 is outside [-20, 20]"},
      {R"({"gyros": [{"id": 1, "c1DegH": [0, 0]}]})",
       "gyros[0].c1DegH: expected an array of 3 numbers, got 2 values"},
      {R"({"gyros": [{"id": 1, "running": "yes"}]})", "gyros[0].running: expected true or false"},
      {R"({"gyros": [{"id": 1, "fault": {"timeHours": 1, "kind": "explode"}}]})",
       "gyros[0].fault.kind: unknown kind 'explode'"},
      {R"({"gyros": [{"id": 1, "fault": {"timeHours": 1, "kind": "drift_step", "arcsec": [1, 2, 3]}}]})",
       "gyros[0].fault.arcsec: not used by kind drift_step"},
      {R"({"gyros": [{"id": 1, "randomWalkDegHSqrtH": -0.1}]})",
       "gyros[0].randomWalkDegHSqrtH: -0.1 is outside [0, 1]"},
      {R"({"starTracker": {"outages": [{"startHours": 4, "endHours": 3}]}})",
       "starTracker.outages[0].endHours: 3 must be after startHours 4"},
      {R"({"starTracker": {"latencyMs": "300"}})", "starTracker.latencyMs: expected a number"},
      {R"({"gyros": [{"id": 1, "fault": {"timeHours": 1, "kind": "reading_frozen"}}]})",
       "gyros[0].fault.endHours: required for kind reading_frozen"},
      {R"({"gyros": [{"id": 1, "fault": {"timeHours": 2, "kind": "readings_missing", "endHours": 1}}]})",
       "gyros[0].fault.endHours: 1 must be after timeHours 2"},
      {R"({"gyros": [{"id": 1, "fault": {"timeHours": 1, "kind": "readings_missing", "endHours": 2, "arcsec": [1, 0, 0]}}]})",
       "gyros[0].fault.arcsec: not used by kind readings_missing"},
      {R"({"gyros": [{"id": 1, "fault": {"timeHours": 1, "kind": "readout_jump", "endHours": 2, "arcsec": [1, 0, 0]}}]})",
       "gyros[0].fault.endHours: not used by kind readout_jump"},
      {R"({"gyros": [{"id": 4, "switchOnHours": -1}]})",
       "gyros[0].switchOnHours: -1 is outside [0, 100000]"},
      {R"({"starTracker": {"outlierBurst": {"timeHours": 1, "count": 0, "arcmin": 2}}})",
       "starTracker.outlierBurst.count: expected an integer in 1..100000, got 0"},
      {R"({"starTracker": {"outlierBurst": {"timeHours": 1, "count": 2.5, "arcmin": 2}}})",
       "starTracker.outlierBurst.count: expected an integer"},
      {R"({"starTracker": {"outlierBurst": {"timeHours": 1, "count": 5}}})",
       "starTracker.outlierBurst.arcmin: required"},
      {R"({"starTracker": {"outlierBurst": {"timeHours": 1, "count": 5, "arcmin": 0}}})",
       "starTracker.outlierBurst.arcmin: must be > 0"},
      {R"({"starTracker": {"frozen": [{"startHours": 2, "endHours": 2}]}})",
       "starTracker.frozen[0].endHours: 2 must be after startHours 2"},
      {R"({"starTracker": {"frozen": {"startHours": 2, "endHours": 3}}})",
       "starTracker.frozen: expected an array"},
      {R"({"starTracker": {"misalignmentJump": {"timeHours": 1, "arcsec": [1, 2]}}})",
       "starTracker.misalignmentJump.arcsec: expected an array of 3 numbers, got 2 values"},
      {R"({"starTracker": {"misalignmentJump": {"arcsec": [1, 2, 3]}}})",
       "starTracker.misalignmentJump.timeHours: required"},
      {R"({"starTracker": {"misalignmentCycle": {"arcsec": [1, 2, 3]}}})",
       "starTracker.misalignmentCycle.periodMin: required"},
      {R"({"starTracker": {"misalignmentCycle": {"arcsec": [1, 2, 3], "periodMin": 0}}})",
       "starTracker.misalignmentCycle.periodMin: must be > 0"},
      {R"({"starTracker": {"misalignmentCycle": {"arcsec": [1, 2, 3], "periodMin": 90, "phase": 1}}})",
       "starTracker.misalignmentCycle.phase: unknown key"},
      {R"({"starTracker": {"sunMount": {"arcsec": [1, 2, 3], "face": "+x"}}})",
       "starTracker.sunMount.timeConstantHours: required"},
      {R"({"starTracker": {"sunMount": {"arcsec": [1, 2, 3], "timeConstantHours": 1}}})",
       "starTracker.sunMount.face: required"},
      {R"({"starTracker": {"sunMount": {"arcsec": [1, 2, 3], "face": "x", "timeConstantHours": 1}}})",
       "starTracker.sunMount.face: expected one of +x"},
      {R"({"gyros": [{"id": 1, "orbitalDrift": {"periodMin": 90}}]})",
       "gyros[0].orbitalDrift.amplitudeDegH: required"},
      {R"({"gyros": [{"id": 1, "orbitalDrift": {"amplitudeDegH": [0, 0, 0.01], "periodMin": 0}}]})",
       "gyros[0].orbitalDrift.periodMin: 0 is outside [1, 100000]"},
      {R"({"gyros": [{"id": 1, "orbitalDrift": {"amplitudeDegH": [0, 0, 0.01], "phase": 3}}]})",
       "gyros[0].orbitalDrift.phase: unknown key"},
      {R"({"gyros": [{"id": 1, "orbitalDrift": {"amplitudeDegH": [0, 500, 0]}}]})",
       "gyros[0].orbitalDrift.amplitudeDegH[1]: 500 is outside [-100, 100]"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementRateUmH": [0, 0, 30]}]})",
       "gyros[0].rotorDisplacementRateUmH[2]: 30 is outside [-20, 20]"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementRateUmH": 0.1}]})",
       "gyros[0].rotorDisplacementRateUmH: expected an array of 3 numbers"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [1, 0, 0],
                      "rotorDisplacementTurn": {"axis": [0, 0, 0], "periodH": 24}}]})",
       "gyros[0].rotorDisplacementTurn.axis: must not be the zero vector"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [1, 0, 0],
                      "rotorDisplacementTurn": {"axis": [0, 0, 1], "periodH": 0}}]})",
       "gyros[0].rotorDisplacementTurn.periodH: must be > 0"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [1, 0, 0],
                      "rotorDisplacementTurn": {"axis": [0, 0, 1], "periodH": -2}}]})",
       "gyros[0].rotorDisplacementTurn.periodH: -2 is outside [0, 8784]"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [1, 0, 0],
                      "rotorDisplacementTurn": {"axis": [0, 0, 1], "periodH": 9000}}]})",
       "gyros[0].rotorDisplacementTurn.periodH: 9000 is outside [0, 8784]"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [1, 0, 0],
                      "rotorDisplacementTurn": {"axis": [0, 0, 1], "periodH": 24, "phaseDeg": 3}}]})",
       "gyros[0].rotorDisplacementTurn.phaseDeg: unknown key"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [1, 0, 0],
                      "rotorDisplacementTurn": {"axis": [0, 0, 1]}}]})",
       "gyros[0].rotorDisplacementTurn.periodH: required"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [1, 0, 0],
                      "rotorDisplacementTurn": {"periodH": 24}}]})",
       "gyros[0].rotorDisplacementTurn.axis: required"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [1, 0, 0],
                      "rotorDisplacementTurn": {"axis": [0, 1], "periodH": 24}}]})",
       "gyros[0].rotorDisplacementTurn.axis: expected an array of 3 numbers"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [1, 0, 0], "rotorDisplacementTurn": 24}]})",
       "gyros[0].rotorDisplacementTurn: expected an object"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementTurn": {"axis": [0, 0, 1], "periodH": 24}}]})",
       "gyros[0].rotorDisplacementTurn: needs a non-zero rotorDisplacementUm"},
      {R"({"gyros": [{"id": 1, "rotorDisplacementUm": [0, 0, 0],
                      "rotorDisplacementTurn": {"axis": [0, 0, 1], "periodH": 24}}]})",
       "gyros[0].rotorDisplacementTurn: needs a non-zero rotorDisplacementUm"},
      {R"({"gyros": [{"id": 1, "readoutDistortionPpm": [1, 2, 3]}]})",
       "gyros[0].readoutDistortionPpm: expected an array of 6 numbers"},
      {R"({"gyros": [{"id": 1, "readoutDistortionPpm": [1, 2, 3, 4, 5, 2e5]}]})",
       "gyros[0].readoutDistortionPpm[5]: 200000 is outside [-100000, 100000]"},
      {R"({"gyros": [{"id": 1, "switchingDrift": {"amplitudeDegH": [0, 0, 0.01]}}]})",
       "gyros[0].switchingDrift.meanDwellHours: required"},
      {R"({"gyros": [{"id": 1, "switchingDrift": {"amplitudeDegH": [0, 0, 0.01], "meanDwellHours": 0}}]})",
       "gyros[0].switchingDrift.meanDwellHours: 0 is outside [0.001, 100000]"},
      {R"({"gyros": [{"id": 1, "switchingDrift": {"amplitudeDegH": [0, 0, 0.01], "meanDwellHours": 1, "tau": 1}}]})",
       "gyros[0].switchingDrift.tau: unknown key"},
      {R"({"gyros": [{"id": 1, "hiddenDriverDrift": {"correlationHours": 2}}]})",
       "gyros[0].hiddenDriverDrift.amplitudeDegH: required"},
      {R"({"gyros": [{"id": 1, "hiddenDriverDrift": {"amplitudeDegH": [0, 0, 0.01], "correlationHours": -2}}]})",
       "gyros[0].hiddenDriverDrift.correlationHours: -2 is outside [0.001, 100000]"},
      {R"({"gyros": [{"id": 1, "hiddenDriverDrift": [0, 0, 0.01]}]})",
       "gyros[0].hiddenDriverDrift: expected an object"},
      {R"({"gyros": [{"id": 1, "rateDrift": {"degHPerDegS": [1, 0, 0, 0, 1, 0]}}]})",
       "gyros[0].rateDrift.degHPerDegS: expected an array of 9 numbers"},
      {R"({"gyros": [{"id": 1, "rateDrift": {"degHPerDegS": [1, 0, 0, 0, 1, 0, 0, 0, 500]}}]})",
       "gyros[0].rateDrift.degHPerDegS[8]: 500 is outside [-100, 100]"},
      {R"({"gyros": [{"id": 1, "rateDrift": {}}]})", "gyros[0].rateDrift.degHPerDegS: required"},
      {R"({"gyros": [{"id": 1, "transientDrift": {"amplitudeDegH": [0, 0, 0.1]}}]})",
       "gyros[0].transientDrift.timeConstantHours: required"},
      {R"({"gyros": [{"id": 1, "sunFaceDrift": {"amplitudeDegH": [0, 0, 0.1], "timeConstantHours": 1}}]})",
       "gyros[0].sunFaceDrift.face: required (+x, -x, +y, -y, +z, -z or sunlit)"},
      {R"({"gyros": [{"id": 1, "sunFaceDrift": {"amplitudeDegH": [0, 0, 0.1], "timeConstantHours": 1, "face": "sunlit"}}]})",
       "gyros[0].sunFaceDrift.face: sunlit needs \"earthShadow\": true (the orbit whose shadow it follows)"},
      {R"({"earthShadow": 1})", "earthShadow: expected true or false, got number"},
      {R"({"gyros": [{"id": 1, "sunFaceDrift": {"amplitudeDegH": [0, 0, 0.1], "timeConstantHours": 1, "face": "y"}}]})",
       "gyros[0].sunFaceDrift.face: expected one of +x, -x, +y, -y, +z, -z (the body face whose outward normal is that axis) or sunlit (the fraction of the sun's disc seen from the orbit, with earthShadow), got 'y'"},
      {R"({"gyros": [{"id": 1, "sunFaceDrift": {"amplitudeDegH": [0, 0, 0.1], "timeConstantHours": 1, "face": 2}}]})",
       "gyros[0].sunFaceDrift.face: expected one of +x, -x, +y, -y, +z, -z (the body face whose outward normal is that axis) or sunlit (the fraction of the sun's disc seen from the orbit, with earthShadow), got 2"},
      {R"({"gyros": [{"id": 1, "sunFaceDrift": {"amplitudeDegH": [0, 0, 0.1], "face": "+x"}}]})",
       "gyros[0].sunFaceDrift.timeConstantHours: required"},
      {R"({"gyros": [{"id": 1, "sunFaceDrift": {"amplitudeDegH": [0, 0, 0.1], "face": "+x", "timeConstantHours": 0}}]})",
       "gyros[0].sunFaceDrift.timeConstantHours: 0 is outside [0.001, 100000]"},
      {R"({"gyros": [{"id": 1, "sunFaceDrift": {"amplitudeDegH": [0, 0, 0.1], "face": "+x", "timeConstantHours": 1, "lag": 1}}]})",
       "gyros[0].sunFaceDrift.lag: unknown key"},
      {R"({"gyros": [{"id": 1, "transientDrift": {"amplitudeDegH": [0, 0, 0.1], "timeConstantHours": 3, "startHours": -1}}]})",
       "gyros[0].transientDrift.startHours: -1 is outside [0, 100000]"},
      {R"({"gyros": [{"id": 1, "transientDrift": {"amplitudeDegH": [0, 0, 0.1], "timeConstantHours": 3, "tau": 3}}]})",
       "gyros[0].transientDrift.tau: unknown key"},
      {R"({"gyros": [{"id": 1, "coefficientStep": {"k0DegH": 0.1}}]})",
       "gyros[0].coefficientStep.startHours: required"},
      {R"({"gyros": [{"id": 1, "coefficientStep": {"startHours": 3}}]})",
       "gyros[0].coefficientStep: names no coefficient"},
      {R"({"gyros": [{"id": 1, "coefficientStep": {"startHours": 3, "c2DegH": [0.1, 0.2]}}]})",
       "gyros[0].coefficientStep.c2DegH"},
      {R"({"gyros": [{"id": 1, "coefficientStep": {"startHours": 3, "k0": 0.1}}]})",
       "gyros[0].coefficientStep.k0: unknown key"},
      {R"({"profile": "tumbling"})", "profile: unknown profile 'tumbling'"},
      {R"({"inclinationDeg": 200})", "inclinationDeg: 200 is outside [0, 180]"},
      {R"({"segmentHours": 0.1, "slewMin": 10})", "slewMin: 10 min is longer than segmentHours"},
      {R"({"profileSeed": -1})", "profileSeed: expected a non-negative integer"},
      {R"([1, 2])", "scenario: expected an object"},
      {R"({"gyros": [)", "scenario: malformed JSON"},
  };
  for (const auto& [json, message] : cases) {
    EXPECT_THAT(ParseScenarioJson(json),
                StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr(message)))
        << json;
  }
}

// nlohmann-json alone keeps the last value of a repeated key: refused with the key's path.
TEST(Scenario, RepeatedKeyIsRefusedWithItsPath) {
  EXPECT_THAT(
      ParseScenarioJson(
          R"({"gyros": [{"id": 1}, {"id": 2, "randomWalkDegHSqrtH": 0.001, "randomWalkDegHSqrtH": 0.5}]})"),
      StatusIs(absl::StatusCode::kInvalidArgument,
               ::testing::StartsWith("gyros[1].randomWalkDegHSqrtH: duplicate key")));
  EXPECT_THAT(ParseScenarioJson(R"({"profile": "inertial", "profile": "orbital"})"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       ::testing::StartsWith("profile: duplicate key")));
}

TEST(Scenario, MissingFileIsNotFound) {
  EXPECT_THAT(ReadScenarioFile("/nonexistent/scenario.json"),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("/nonexistent/scenario.json")));
}

}  // namespace
}  // namespace esg::client
