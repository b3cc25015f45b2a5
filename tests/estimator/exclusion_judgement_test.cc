// The session's judgement between an incomplete model and a broken gyro (docs/decisions.md D94,
// estimator/reading_fault_monitor.h), run end to end through EstimationSession on simulated
// flights of deploy/examples/rdk1.json:
// - a drift change of 0.9 deg/h (below the 1 deg/h limit) is a DRIFT_CHANGED of that gyro, no
//   exclusion; 1.2 deg/h excludes it (DRIFT_CHANGE_BEYOND_LIMIT or READING_BEYOND_ANY_DRIFT),
//   the session degraded with a valid output, not FAULTED;
// - model (1) on the paper's displaced rotors, the calibration profile (the model lacks C1, C2
//   in every gyro): no gyro excluded;
// - model (10)+(11) on a gyro with an unconfigured misalignment of 80 arcsec (no misalignment
//   states), on the calibration profile: no gyro excluded;
// - a drift proportional to the body rate through a slew of 180 deg: no gyro excluded;
// - a gyro excluded by a frozen reading and readmitted by the operator (ReadmitGyro) rejoins as
//   a switched-on spare and runs to the end.
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

// A cycling drift the model lacks, in one gyro (scripts/false_exclusions.sh's orbital_drift class,
// seeds 4, 49 and 79: 0.12-0.13 deg/h at the orbital period, 12 h): MODEL_INCONSISTENT located at
// that gyro is what such a drift gives, so it is no drift change: no DRIFT_CHANGED (D21's hold on
// the accumulated test, D33; lifting it when the located alert names the gyro alone gave a
// DRIFT_CHANGED on each of these three flights, docs/decisions.md D103), and nothing excluded.
TEST(ExclusionJudgement, ACyclingDriftTheModelLacksInOneGyroIsNoDriftChange) {
  const SpacecraftConfig config = Rdk1();
  struct Case {
    uint64_t seed;
    const char* profile;
    int gyro;
    Vector3d amplitude_deg_h;
    double phase_deg;
  };
  for (const Case& c : {Case{4, "mixed", 1, Vector3d(0.0707, -0.1011, -0.0051), 231.58},
                        Case{49, "orbital", 1, Vector3d(-0.1223, -0.0385, -0.0017), 203.06},
                        Case{79, "calibration", 3, Vector3d(0.0525, -0.1106, -0.0251), 163.90}}) {
    SCOPED_TRACE(absl::StrCat("seed ", c.seed, ", ", c.profile, ", gyro ", c.gyro));
    SimulationSpec spec = FlightSpec(config, c.profile, 12.0, c.seed);
    OrbitalDrift drift;
    drift.amplitude_k_rad_s = DegPerHourToRadPerSec(1.0) * c.amplitude_deg_h;
    drift.period_s = 94.0 * 60.0;
    drift.phase_rad = c.phase_deg * kRadPerDeg;
    spec.gyros[c.gyro - 1].orbital_drift = drift;
    const Flight run = RunSession(config, spec, "10+11");
    EXPECT_FALSE(run.degraded) << Excluded(run);
    for (const Event& e : run.events) {
      EXPECT_NE(e.kind, Event::Kind::kDriftChanged)
          << e.subsystem << " at " << e.time << ": " << e.message;
    }
  }
}

// A drift proportional to the body rate, which the model lacks (scripts/false_exclusions.sh's
// rate_drift class, seed 5024: 0.076 deg/h at 0.1 deg/s in gyro 2, 19 h of the seeded calibration
// profile): the slew at 18 h turns the body from -z to +z at the Sun, through 180 deg, where the
// simulated attitude had jumped and the drift with the rate (gyro 2 was excluded at 18:03); a
// slew turns it at up to 1 deg/s, a drift of a few tenths of a deg/h the model lacks for ten
// minutes: nothing excluded.
TEST(ExclusionJudgement, ARateDependentDriftThroughAHalfTurnSlewExcludesNoGyro) {
  const SpacecraftConfig config = Rdk1();
  SimulationSpec spec = FlightSpec(config, "calibration", 19.0, 5024);
  RateDrift drift;
  const double gain[9] = {-0.40112157851880037, -0.525216642908976,  0.09906942242487568,
                          -0.2040746590254603,  -0.26720927782528303, 0.05040257040237541,
                          -0.07267671481154743, -0.09516072486532892, 0.017949770208585146};
  for (int i = 0; i < 9; ++i) drift.gain_k(i / 3, i % 3) = gain[i] / kSecondsPerHour;
  spec.gyros[1].rate_drift = drift;
  const Flight run = RunSession(config, spec, "10+11");
  EXPECT_FALSE(run.degraded) << Excluded(run);
  EXPECT_NE(run.state, SessionState::kFaulted);
}

// An excluded gyro readmitted on an operator's word (EstimationSession::ReadmitGyro): gyro 3's
// reading frozen for 15 min at 2 h while the spacecraft turns excludes it; readmitted at 4 h, its
// block leaves the state at once and it rejoins at the next measurement step as a switched-on
// spare (GYRO_STARTED), running and not excluded to the end; the session restores from a
// checkpoint taken between the two. Refused: a gyro not configured (NotFound), one running or
// not running (FailedPrecondition), each naming gyro_id.
TEST(ExclusionJudgement, AReadmittedGyroRejoinsAtTheNextMeasurementStepAsASwitchedOnSpare) {
  const SpacecraftConfig config = Rdk1();
  SimulationSpec spec = FlightSpec(config, "calibration", 6.0, 5);
  GyroFault fault;
  fault.time = HoursToSeconds(2.0);
  fault.kind = GyroFault::Kind::kReadingFrozen;
  fault.end = HoursToSeconds(2.25);
  spec.gyros[2].fault = fault;
  auto sim = Simulate(spec);
  ASSERT_THAT(sim, IsOk());
  SessionOptions options;
  options.model = *ParseModel("10+11");
  auto session = EstimationSession::Create(config, options);
  ASSERT_THAT(session, IsOk());
  const absl::Time readmit_at = sim->recording.frames.front().time + absl::Hours(4);
  std::vector<Event> after;
  bool readmitted = false;
  for (const TelemetryFrame& frame : sim->recording.frames) {
    if (!readmitted && frame.time > readmit_at) {
      const std::vector<GyroEstimate> before = session->Gyros();
      ASSERT_EQ(before.size(), 3u);
      ASSERT_TRUE(before[2].id == 3 && before[2].faulty) << "gyro 3 was not excluded";
      EXPECT_TRUE(session->degraded());
      EXPECT_EQ(session->ReadmitGyro(5).code(), absl::StatusCode::kNotFound);
      const absl::Status running = session->ReadmitGyro(1);
      EXPECT_EQ(running.code(), absl::StatusCode::kFailedPrecondition);
      EXPECT_THAT(std::string(running.message()), ::testing::HasSubstr("gyro_id: gyro 1 is not excluded"));
      const int size_before = session->state_size();
      ASSERT_THAT(session->ReadmitGyro(3), IsOk());
      EXPECT_LT(session->state_size(), size_before);
      EXPECT_EQ(session->Gyros().size(), 2u);
      EXPECT_FALSE(session->degraded());
      EXPECT_EQ(session->ReadmitGyro(3).code(), absl::StatusCode::kFailedPrecondition);
      // A checkpoint taken before it rejoins restores.
      auto restored = EstimationSession::FromCheckpoint(config, options, session->ExportCheckpoint());
      ASSERT_THAT(restored, IsOk());
      EXPECT_EQ(restored->state_size(), session->state_size());
      readmitted = true;
    }
    auto report = session->AddFrame(frame);
    ASSERT_THAT(report, IsOk());
    if (readmitted) after.insert(after.end(), report->events.begin(), report->events.end());
  }
  ASSERT_TRUE(readmitted);
  bool started = false;
  for (const Event& e : after) started = started || (e.kind == Event::Kind::kGyroStarted && e.subsystem == "gyro 3");
  EXPECT_TRUE(started) << "no GYRO_STARTED of gyro 3 after the readmission";
  const std::vector<GyroEstimate> gyros = session->Gyros();
  ASSERT_EQ(gyros.size(), 3u);
  for (const GyroEstimate& g : gyros) EXPECT_FALSE(g.faulty) << "gyro " << g.id << ": " << g.exclusion.Describe();
  EXPECT_FALSE(session->degraded());
  EXPECT_NE(session->state(), SessionState::kFaulted);
  const Eigen::MatrixXd& P = session->covariance();
  EXPECT_LE((P - P.transpose()).cwiseAbs().maxCoeff(), 1e-12 * P.cwiseAbs().maxCoeff());
}

}  // namespace
}  // namespace esg::estimator
