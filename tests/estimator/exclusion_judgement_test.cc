// The session's judgement between an incomplete model and a broken gyro (docs/decisions.md D94,
// estimator/reading_fault_monitor.h), run end to end through EstimationSession on simulated
// flights of deploy/examples/rdk1.json:
// - a drift change of 0.9 deg/h (below the 1 deg/h limit) is a DRIFT_CHANGED of that gyro, no
//   exclusion; 1.2 deg/h excludes it (DRIFT_CHANGE_BEYOND_LIMIT or READING_BEYOND_ANY_DRIFT),
//   the session degraded with a valid output, not FAULTED;
// - model (1) on the paper's displaced rotors, the calibration profile (the model lacks C1, C2
//   in every gyro): no gyro excluded;
// - model (10)+(11) on a gyro with an unconfigured misalignment of 80 arcsec (no misalignment
//   states), on the calibration profile: no gyro excluded.
#include <cstdio>
#include <optional>
#include <string>

#include "absl/strings/str_cat.h"
#include "estimator/attitude_profile.h"
#include "estimator/calibration_model.h"
#include "estimator/rotation.h"
#include "estimator/session.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/example_config.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using Eigen::Vector3d;
using ::esg::testing::IsOk;

SpacecraftConfig Rdk1() { return testing::ExampleConfig("rdk1.json"); }

// A fault-free flight of `hours` on the named profile.
SimulationSpec FlightSpec(const SpacecraftConfig& config, const char* profile, double hours,
                          uint64_t seed) {
  SimulationSpec spec;
  spec.config = config;
  spec.duration = HoursToSeconds(hours);
  spec.seed = seed;
  spec.profile = *MakeNamedProfile(profile, spec.duration, seed);
  return spec;
}

struct Flight {
  std::vector<Event> events;
  std::vector<GyroEstimate> gyros;
  SessionState state = SessionState::kNoData;
  bool degraded = false;
  AttitudeEstimate attitude;
};

Flight RunSession(const SpacecraftConfig& config, const SimulationSpec& spec, const std::string& model) {
  Flight run;
  auto sim = Simulate(spec);
  EXPECT_THAT(sim, IsOk());
  if (!sim.ok()) return run;
  SessionOptions options;
  options.model = *ParseModel(model);
  auto session = EstimationSession::Create(config, options);
  EXPECT_THAT(session, IsOk());
  if (!session.ok()) return run;
  for (const TelemetryFrame& frame : sim->recording.frames) {
    auto report = session->AddFrame(frame);
    EXPECT_THAT(report, IsOk());
    if (!report.ok()) return run;
    run.events.insert(run.events.end(), report->events.begin(), report->events.end());
    run.attitude = report->attitude;
  }
  run.gyros = session->Gyros();
  run.state = session->state();
  run.degraded = session->degraded();
  return run;
}

std::string Excluded(const Flight& run) {
  std::string out;
  for (const GyroEstimate& g : run.gyros) {
    if (g.faulty) absl::StrAppend(&out, " gyro ", g.id, ": ", g.exclusion.Describe());
  }
  return out;
}

// A drift step of `deg_h` in gyro 2 at 5 h, perpendicular to its spin axis, on an inertial hold
// (the body does not turn, so no allowance for slow reading errors widens the bound).
SimulationSpec DriftStep(const SpacecraftConfig& config, double deg_h, uint64_t seed) {
  SimulationSpec spec = FlightSpec(config, "inertial", 8.0, seed);
  GyroFault fault;
  fault.time = HoursToSeconds(5.0) + 30.0;
  fault.kind = GyroFault::Kind::kDriftStep;
  const Vector3d h0 = DefaultInitialSpinAxis(2);
  fault.value = DegPerHourToRadPerSec(deg_h) * AnyPerpendicular(h0);
  spec.gyros[1].fault = fault;
  return spec;
}

TEST(ExclusionJudgement, ADriftChangeBelowTheLimitIsAlertedAndRecalibratedNotExcluded) {
  const SpacecraftConfig config = Rdk1();
  for (uint64_t seed : {1, 2}) {
    SCOPED_TRACE(absl::StrCat("seed ", seed));
    const Flight run = RunSession(config, DriftStep(config, 0.9, seed), "10+11");
    EXPECT_FALSE(run.degraded) << Excluded(run);
    EXPECT_NE(run.state, SessionState::kFaulted);
    std::optional<Event> changed;
    for (const Event& e : run.events) {
      if (e.kind == Event::Kind::kDriftChanged && e.subsystem == "gyro 2" && !changed) changed = e;
    }
    ASSERT_TRUE(changed.has_value()) << "no DRIFT_CHANGED of gyro 2";
    // "drift of gyro 2 changed by X +- S deg/h": X within 3 S of the step.
    double x = 0.0, sigma = 0.0;
    ASSERT_EQ(std::sscanf(changed->message.c_str(), "drift of gyro 2 changed by %lf +- %lf", &x, &sigma), 2)
        << changed->message;
    EXPECT_NEAR(x, 0.9, 3.0 * sigma) << changed->message;
    EXPECT_NEAR(changed->value, x, 5e-4);  // the message rounds to 3 decimals
  }
}

TEST(ExclusionJudgement, ADriftChangeBeyondTheLimitExcludesTheGyroAndTheOutputStaysValid) {
  const SpacecraftConfig config = Rdk1();
  for (uint64_t seed : {1, 2}) {
    SCOPED_TRACE(absl::StrCat("seed ", seed));
    const Flight run = RunSession(config, DriftStep(config, 1.2, seed), "10+11");
    ASSERT_TRUE(run.degraded);
    for (const GyroEstimate& g : run.gyros) {
      EXPECT_EQ(g.faulty, g.id == 2) << Excluded(run);
      if (g.id == 2) {
        EXPECT_TRUE(g.exclusion.reason == ExclusionReason::kDriftBeyondLimit ||
                    g.exclusion.reason == ExclusionReason::kBeyondAnyDrift)
            << Excluded(run);
        EXPECT_GE(g.exclusion.time, absl::FromUnixSeconds(0));
      }
    }
    EXPECT_NE(run.state, SessionState::kFaulted);
    EXPECT_TRUE(run.attitude.valid) << run.attitude.invalid_reason;
    EXPECT_EQ(run.attitude.pair, (std::array<int, 2>{1, 3}));
  }
}

TEST(ExclusionJudgement, ModelOneOnDisplacedRotorsExcludesNoGyro) {
  // The paper's calibration flight: every rotor displaced, the model of eq. (1) only.
  const SpacecraftConfig config = Rdk1();
  for (uint64_t seed : {1, 2}) {
    SCOPED_TRACE(absl::StrCat("seed ", seed));
    SimulationSpec spec = FlightSpec(config, "calibration", 12.0, seed);
    spec.gyros[0].rotor_displacement_k = Vector3d(1.0e-6, -1.5e-6, 0.8e-6);
    spec.gyros[1].rotor_displacement_k = Vector3d(-0.7e-6, 0.5e-6, 1.2e-6);
    spec.gyros[2].rotor_displacement_k = Vector3d(0.5e-6, 1.0e-6, -1.0e-6);
    const Flight run = RunSession(config, spec, "1+11");
    EXPECT_FALSE(run.degraded) << Excluded(run);
    EXPECT_NE(run.state, SessionState::kFaulted);
  }
}

TEST(ExclusionJudgement, AnUnconfiguredMisalignmentExcludesNoGyro) {
  // Misalignments are not filter states here (no prior), and gyro 3's case is off by 80 arcsec.
  SpacecraftConfig config = Rdk1();
  for (GyroConfig& g : config.gyros) g.misalignment_sigma = 0.0;
  for (uint64_t seed : {1, 2}) {
    SCOPED_TRACE(absl::StrCat("seed ", seed));
    SimulationSpec spec = FlightSpec(config, "calibration", 8.0, seed);
    spec.gyros[2].misalignment_b = Vector3d(ArcsecToRad(60), ArcsecToRad(-50), ArcsecToRad(20));
    const Flight run = RunSession(config, spec, "10+11");
    EXPECT_FALSE(run.degraded) << Excluded(run);
  }
}

}  // namespace
}  // namespace esg::estimator
