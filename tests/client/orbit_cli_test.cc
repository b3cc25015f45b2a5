// The orbit offline, end to end as processes (docs/discovery.md `--orbit`, docs/scenario.md
// `earthShadow`, docs/formats.md "Orbit: CCSDS OEM"): `esg simulate` flies a 24 h inertial hold
// on a 94.6 min orbit whose shadow darkens the face a gyro's drift follows, and writes the orbit
// as an OEM; `esg diagnose --orbit` reads it and names the face with the lag and the size within
// 3 sigma of the truth, saying the shadow was used; without the orbit the drift is unexplained.
// An OEM of another spacecraft, one that does
// not cover the recording, or --orbit with the server's archive exit 2 naming the option.
// On the service (docs/service.md "Orbits"): `esg orbit upload` stores the OEM on a real esgd,
// `esg orbit list` lists it, and `esg diagnose --spacecraft` says it used it; another
// spacecraft's OEM is refused naming its line, exit 1, and a missing file is exit 2.
#include <cmath>
#include <string>

#include "absl/strings/str_replace.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/client/cli_test_support.h"
#include "tests/testing/daemon.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::ReadFile;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;
using ::esg::testing::WriteFile;
using ::testing::HasSubstr;

RunResult RunEsg(const TempDir& dir, const std::string& args) {
  return ::esg::testing::RunBinary(dir, ESG_BINARY, args);
}

// Gyro 2 drifts with the sun on body face -y (lit at 0.94 of full in this hold), 0.15 deg/h at
// full illumination through a 0.3 h thermal lag; the Earth's shadow darkens the face once an
// orbit.
constexpr char kScenario[] = R"({
  "description": "sun on face -y with the Earth's shadow, inertial hold",
  "profile": "inertial", "earthShadow": true,
  "inclinationDeg": 51.6, "orbitPeriodMin": 94.6, "raanDeg": 340,
  "gyros": [{"id": 2, "sunFaceDrift": {"amplitudeDegH": [0.12, 0.0, -0.09], "face": "-y",
                                       "timeConstantHours": 0.3}}]
})";

std::string Config() { return std::string(ESG_SOURCE_DIR) + "/deploy/examples/rdk1.json"; }

// `esg simulate` of the scenario above for `hours` (seed 1) into dir's `recording`, its orbit
// into dir's `oem`; the exit code.
int Simulate(const TempDir& dir, int hours, const std::string& recording, const std::string& oem) {
  WriteFile(dir.File("scenario.json"), kScenario);
  return RunEsg(dir, "simulate --config '" + Config() + "' --scenario '" +
                         dir.File("scenario.json") + "' --hours " + std::to_string(hours) +
                         " --seed 1 --out '" + dir.File(recording) + "' --orbit-out '" +
                         dir.File(oem) + "'")
      .exit_code;
}

// dir's orbit.oem as another spacecraft's (SAT-9) in dir's other.oem.
void WriteOtherSpacecraftsOem(const TempDir& dir) {
  WriteFile(dir.File("other.oem"),
            absl::StrReplaceAll(ReadFile(dir.File("orbit.oem")),
                                {{"OBJECT_NAME = RDK-1", "OBJECT_NAME = SAT-9"},
                                 {"OBJECT_ID = RDK-1", "OBJECT_ID = 2020-007B"}}));
}

double Parameter(const nlohmann::json& finding, const std::string& name, bool sigma = false) {
  for (const auto& p : finding["parameters"]) {
    if (p["name"] == name) return sigma ? p.value("sigma", 0.0) : p["value"].get<double>();
  }
  ADD_FAILURE() << "no parameter " << name << " in " << finding.dump();
  return NAN;
}

TEST(OrbitCli, TheShadowedSunDriftIsNamedWithItsLagFromTheSimulatedOrbit) {
  TempDir dir;
  WriteFile(dir.File("scenario.json"), kScenario);
  RunResult sim = RunEsg(dir, "simulate --config '" + Config() + "' --scenario '" +
                                  dir.File("scenario.json") + "' --hours 24 --seed 3 --out '" +
                                  dir.File("rec.csv") + "' --orbit-out '" + dir.File("orbit.oem") +
                                  "'");
  ASSERT_EQ(sim.exit_code, 0) << sim.err;
  const std::string oem = ReadFile(dir.File("orbit.oem"));
  EXPECT_THAT(oem, HasSubstr("OBJECT_NAME = RDK-1"));
  EXPECT_THAT(oem, HasSubstr("START_TIME = 2019-02-28T23:59:00.000000"));
  EXPECT_THAT(oem, HasSubstr("STOP_TIME = 2019-03-02T00:01:00.000000"));

  RunResult diag = RunEsg(dir, "diagnose --config '" + Config() + "' --recording '" +
                                   dir.File("rec.csv") + "' --orbit '" + dir.File("orbit.oem") +
                                   "' --format json");
  ASSERT_EQ(diag.exit_code, 0) << diag.err;
  const nlohmann::json doc = nlohmann::json::parse(diag.out);
  const nlohmann::json* sun = nullptr;
  for (const auto& f : doc["findings"]) {
    if (f.value("gyro", 0) == 2 &&
        f.value("description", std::string()).find("sun on body face") != std::string::npos) {
      sun = &f;
    }
  }
  ASSERT_NE(sun, nullptr) << doc["findings"].dump(1);
  const std::string words = sun->value("description", std::string());
  EXPECT_THAT(words, HasSubstr("follows the sun on body face -y"));
  EXPECT_THAT(words, HasSubstr("0 in the Earth's shadow"));
  // The lag and the size within 3 sigma of the truth (0.3 h; |(0.12, 0, -0.09)| = 0.15 deg/h).
  const double lag_h = Parameter(*sun, "sunLagHours");
  EXPECT_LE(std::abs(lag_h - 0.3), 3.0 * Parameter(*sun, "sunLagHours", true)) << lag_h;
  const double size = Parameter(*sun, "sunDriftSizeDegH");
  EXPECT_LE(std::abs(size - 0.15), 3.0 * Parameter(*sun, "sunDriftSizeDegH", true)) << size;
  // The held-out drift falls with the finding.
  EXPECT_LT(doc["fit"]["after"]["gapDriftRateDegH"].get<double>(),
            doc["fit"]["before"]["gapDriftRateDegH"].get<double>());

  // Without the orbit the face's illumination is a constant in the hold: the drift is left
  // unexplained in gyro 2, and the diagnosis runs to its end (a body-rate term of the basis,
  // whose regressor is the hold's rate noise, once made it refuse its own model).
  RunResult blind = RunEsg(dir, "diagnose --config '" + Config() + "' --recording '" +
                                    dir.File("rec.csv") + "' --format json");
  ASSERT_EQ(blind.exit_code, 0) << blind.err;
  const nlohmann::json without = nlohmann::json::parse(blind.out);
  EXPECT_EQ(without.value("verdict", std::string()), "unexplained");
  for (const auto& f : without["findings"]) {
    EXPECT_EQ(f.value("description", std::string()).find("follows the sun"), std::string::npos)
        << f.dump();
  }
}

TEST(OrbitCli, AnOrbitThatDoesNotFitTheRecordingExitsTwoNamingIt) {
  TempDir dir;
  ASSERT_EQ(Simulate(dir, 3, "rec.csv", "orbit.oem"), 0);
  ASSERT_EQ(Simulate(dir, 1, "short.csv", "short.oem"), 0);
  const std::string diagnose =
      "diagnose --config '" + Config() + "' --recording '" + dir.File("rec.csv") + "' --orbit ";
  // Another spacecraft's orbit: refused on its OBJECT_NAME line.
  WriteOtherSpacecraftsOem(dir);
  RunResult other = RunEsg(dir, diagnose + "'" + dir.File("other.oem") + "'");
  EXPECT_EQ(other.exit_code, 2);
  EXPECT_THAT(other.err, HasSubstr("--orbit"));
  EXPECT_THAT(other.err, HasSubstr("line 7: OBJECT_NAME: 'SAT-9'"));
  // An orbit of the first hour for a recording of three.
  RunResult short_orbit = RunEsg(dir, diagnose + "'" + dir.File("short.oem") + "'");
  EXPECT_EQ(short_orbit.exit_code, 2);
  EXPECT_THAT(short_orbit.err, HasSubstr("orbit: does not cover the recording"));
  EXPECT_THAT(short_orbit.err, HasSubstr("no state from 2019-03-01T01:01:00.000Z"));
  // A file that is not there.
  RunResult missing = RunEsg(dir, diagnose + "'" + dir.File("absent.oem") + "'");
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_THAT(missing.err, HasSubstr("--orbit"));
  // The server's archive does not take an orbit.
  RunResult server = RunEsg(dir, "diagnose --spacecraft RDK-1 --orbit '" + dir.File("orbit.oem") + "'");
  EXPECT_EQ(server.exit_code, 2);
  EXPECT_THAT(server.err, HasSubstr("--orbit"));
}

TEST(OrbitCli, AnUploadedOrbitIsListedAndTakenByTheServersDiagnosis) {
  TempDir dir;
  ASSERT_EQ(Simulate(dir, 3, "rec.csv", "orbit.oem"), 0);
  ::esg::testing::Daemon daemon(dir.File("esg.db"), dir.File("esgd.log"));
  ASSERT_GT(daemon.port(), 0);
  ASSERT_EQ(Esg(dir, daemon, "configure --config '" + Config() + "'").exit_code, 0);
  RunResult replay = Esg(dir, daemon, "replay --recording '" + dir.File("rec.csv") + "' --wait");
  ASSERT_EQ(replay.exit_code, 0) << replay.err;

  RunResult upload =
      Esg(dir, daemon, "orbit upload --spacecraft RDK-1 --oem '" + dir.File("orbit.oem") + "'");
  ASSERT_EQ(upload.exit_code, 0) << upload.err;
  EXPECT_THAT(upload.out, HasSubstr("stored orbit delivery #1 "));
  RunResult list = Esg(dir, daemon, "orbit list --spacecraft RDK-1 --format json");
  ASSERT_EQ(list.exit_code, 0) << list.err;
  const nlohmann::json listed = nlohmann::json::parse(list.out);
  ASSERT_EQ(listed.size(), 1u);
  EXPECT_EQ(listed[0]["id"], "1");  // int64 in the proto JSON mapping
  EXPECT_GT(std::stoll(listed[0]["states"].get<std::string>()), 100);

  WriteOtherSpacecraftsOem(dir);
  RunResult other =
      Esg(dir, daemon, "orbit upload --spacecraft RDK-1 --oem '" + dir.File("other.oem") + "'");
  EXPECT_EQ(other.exit_code, 1);
  EXPECT_THAT(other.err, HasSubstr("INVALID_ARGUMENT: oem: line 7: OBJECT_NAME: 'SAT-9'"));
  RunResult missing =
      Esg(dir, daemon, "orbit upload --spacecraft RDK-1 --oem '" + dir.File("absent.oem") + "'");
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_THAT(missing.err, HasSubstr("--oem"));
  EXPECT_EQ(nlohmann::json::parse(
                Esg(dir, daemon, "orbit list --spacecraft RDK-1 --format json").out)
                .size(),
            1u);

  RunResult diagnosed = Esg(dir, daemon, "diagnose --spacecraft RDK-1 --format json");
  ASSERT_EQ(diagnosed.exit_code, 0) << diagnosed.err;
  const nlohmann::json result = nlohmann::json::parse(diagnosed.out);
  EXPECT_EQ(result["report"].value("orbit", ""),
            "orbit delivery 1: used (the Earth's shadow in the sun's regressors)");
}

}  // namespace
}  // namespace esg::client
