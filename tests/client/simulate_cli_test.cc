// `esg simulate` run as a real process (the built binary, ESG_BINARY) into a temporary
// directory: reproducible bytes, the documented examples, and exit code 2 with a message naming
// the problem for bad arguments.
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>
#include <vector>

#include "estimator/units.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "proto/convert.h"
#include "tests/client/cli_test_support.h"
#include "tests/testing/run_process.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;

using ::esg::testing::ReadFile;
using ::esg::testing::RunResult;
using ::esg::testing::WriteFile;

RunResult RunEsg(const TempDir& dir, const std::string& args) {
  return ::esg::testing::RunBinary(dir, ESG_BINARY, args);
}

TEST(SimulateCli, SameSeedGivesSameFileBytesAndAReadableRecording) {
  TempDir dir;
  const std::string base = "simulate --config '" + Rdk1() + "' --hours 2 ";
  RunResult a = RunEsg(dir, base + "--seed 7 --out '" + dir.File("a.csv") + "'");
  ASSERT_EQ(a.exit_code, 0) << a.err;
  EXPECT_THAT(a.out, HasSubstr("121 frames"));
  RunResult b = RunEsg(dir, base + "--seed 7 --out '" + dir.File("b.csv") + "'");
  ASSERT_EQ(b.exit_code, 0) << b.err;
  RunResult c = RunEsg(dir, base + "--seed 8 --out '" + dir.File("c.csv") + "'");
  ASSERT_EQ(c.exit_code, 0) << c.err;
  const std::string bytes_a = ReadFile(dir.File("a.csv"));
  EXPECT_GT(bytes_a.size(), 10000u);
  EXPECT_EQ(bytes_a, ReadFile(dir.File("b.csv")));
  EXPECT_NE(bytes_a, ReadFile(dir.File("c.csv")));

  auto recording = storage::ReadRecordingCsv(dir.File("a.csv"));
  ASSERT_THAT(recording, IsOk());
  EXPECT_EQ(recording->metadata.at("spacecraft_id"), "RDK-1");
  EXPECT_EQ(recording->metadata.at("seed"), "7");
  ASSERT_EQ(recording->frames.size(), 121u);
  for (const auto& frame : recording->frames) {
    EXPECT_TRUE(frame.gyros[0] && frame.gyros[1] && frame.gyros[2]);
    EXPECT_FALSE(frame.gyros[3].has_value());  // the cold spare
    EXPECT_TRUE(frame.star_tracker.has_value());
  }
}

TEST(SimulateCli, WritesConfigAndTruthWhenAsked) {
  TempDir dir;
  RunResult r = RunEsg(dir, "simulate --config '" + Rdk1() +
                                "' --hours 1 --seed 3 --telemetry-step 30 --integration-rate 4"
                                " --start 2020-06-01T12:00:00Z --json --out '" +
                                dir.File("rec.csv") + "' --write-config '" + dir.File("used.json") +
                                "' --truth '" + dir.File("truth.csv") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("\"frames\": 121"));
  auto original = proto_convert::ReadConfigFile(Rdk1());
  auto used = proto_convert::ReadConfigFile(dir.File("used.json"));
  ASSERT_THAT(original, IsOk());
  ASSERT_THAT(used, IsOk());
  EXPECT_EQ(proto_convert::ConfigToJson(*original), proto_convert::ConfigToJson(*used));
  auto recording = storage::ReadRecordingCsv(dir.File("rec.csv"));
  ASSERT_THAT(recording, IsOk());
  EXPECT_EQ(recording->frames.front().time,
            absl::FromCivil(absl::CivilSecond(2020, 6, 1, 12, 0, 0), absl::UTCTimeZone()));
  const std::string truth = ReadFile(dir.File("truth.csv"));
  EXPECT_THAT(truth, HasSubstr("# g1_true_k0_deg_h: 0.25\n"));
  EXPECT_THAT(truth, HasSubstr("time_utc,q0,q1,q2,q3,g1_hin_x"));
  EXPECT_THAT(truth, HasSubstr("\n2020-06-01T12:00:30Z,"));
}

// The truth file's rows are the recording's rows: the same times in the same text, to the
// digit the instant needs (formats/recording_csv.h FormatRecordingTime), here a 0.2505 s step
// that the millisecond form of messages would cut to .250.
TEST(SimulateCli, TruthRowsHaveTheRecordingsTimesExactly) {
  TempDir dir;
  RunResult r = RunEsg(dir, "simulate --config '" + Rdk1() +
                                "' --hours 0.002 --telemetry-step 0.2505 --integration-rate 4000"
                                " --seed 1 --out '" + dir.File("rec.csv") + "' --truth '" +
                                dir.File("truth.csv") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  auto times = [](const std::string& text) {
    std::vector<std::string> out;
    std::istringstream lines(text);
    std::string line;
    while (std::getline(lines, line)) {
      if (line.empty() || line[0] == '#' || line.rfind("time_utc", 0) == 0) continue;
      out.push_back(line.substr(0, line.find(',')));
    }
    return out;
  };
  const std::vector<std::string> recording = times(ReadFile(dir.File("rec.csv")));
  ASSERT_EQ(recording.size(), 29u);
  EXPECT_EQ(recording[1], "2019-03-01T00:00:00.2505Z");
  EXPECT_EQ(times(ReadFile(dir.File("truth.csv"))), recording);
}

// The drift effects beyond the paper's models are recorded in the truth file: their settings
// (with the orbital period taken from the profile) and switch times as metadata, their time
// histories as columns after st_outlier_arcsec; an orbital drift without a period on a profile
// without an orbit is refused naming the JSON key.
TEST(SimulateCli, TruthFileRecordsTheDriftEffects) {
  TempDir dir;
  const std::string scenario = std::string(ESG_SOURCE_DIR) +
                               "/deploy/examples/scenarios/drift_behaviours.json";
  RunResult r = RunEsg(dir, "simulate --config '" + Rdk1() + "' --scenario '" + scenario +
                                "' --hours 6 --seed 5 --out '" + dir.File("rec.csv") +
                                "' --truth '" + dir.File("truth.csv") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string truth = ReadFile(dir.File("truth.csv"));
  EXPECT_THAT(truth, HasSubstr("# g1_orbital_drift_amplitude_deg_h: [0.02, 0, -0.01]\n"));
  EXPECT_THAT(truth, HasSubstr("# g1_orbital_drift_period_min: 94\n"));  // the mixed profile's
  EXPECT_THAT(truth, HasSubstr("# g1_orbital_drift_phase_deg: 30\n"));
  EXPECT_THAT(truth, HasSubstr("# g1_rotor_displacement_rate_um_h: [0.05, 0, 0]\n"));
  EXPECT_THAT(truth, HasSubstr("# g2_readout_distortion_ppm: [200, -100, 0, 50, 0, 0]\n"));
  EXPECT_THAT(truth, HasSubstr("# g2_switching_drift_mean_dwell_h: 4\n"));
  EXPECT_THAT(truth, HasSubstr("# g2_switch_times_h: ["));
  EXPECT_THAT(truth, HasSubstr("# g3_hidden_driver_correlation_h: 2\n"));
  EXPECT_THAT(truth,
              HasSubstr("st_outlier,st_outlier_arcsec,g1_displacement_x_um,g1_displacement_y_um,"
                        "g1_displacement_z_um,g1_orbital_dw_x_deg_h,g1_orbital_dw_y_deg_h,"
                        "g1_orbital_dw_z_deg_h,g2_switching_level,g3_hidden_driver,"
                        "g3_hidden_dw_x_deg_h,g3_hidden_dw_y_deg_h,g3_hidden_dw_z_deg_h\n"));
  // At the start: displacement 0.5 um, orbital drift A cos(30 deg), level +-1.
  EXPECT_THAT(truth, ::testing::ContainsRegex(
                         "\n2019-03-01T00:00:00Z,[^\n]*,0,0,0\\.5,0,0,0\\.0173[0-9]*,0,"
                         "-0\\.00866[0-9]*,[+-]1,[^,\n]+,[^,\n]+,[^,\n]+,-?0\n"));

  WriteFile(dir.File("no_period.json"),
            R"({"profile": "calibration",
                "gyros": [{"id": 1, "orbitalDrift": {"amplitudeDegH": [0, 0, 0.01]}}]})");
  RunResult bad = RunEsg(dir, "simulate --config '" + Rdk1() + "' --scenario '" +
                                  dir.File("no_period.json") + "' --hours 1 --seed 1 --out '" +
                                  dir.File("x.csv") + "'");
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_THAT(bad.err, HasSubstr("gyros[0].orbitalDrift.periodMin: required"));
}

// A rotor displacement turning about a case axis is recorded in the truth file: the axis
// (normalised) and the period as metadata, and the displacement columns turning with it, a quarter
// turn at 6 h of a 24 h period taking (1.4, 0, 0) um to (0, 1.4, 0) um; a turn without a
// displacement is refused naming the JSON key.
TEST(SimulateCli, TruthFileRecordsTheDisplacementTurn) {
  TempDir dir;
  WriteFile(dir.File("turn.json"),
            R"({"profile": "calibration",
                "gyros": [{"id": 1, "rotorDisplacementUm": [1.4, 0, 0],
                           "rotorDisplacementTurn": {"axis": [0, 0, 2], "periodH": 24}}]})");
  RunResult r = RunEsg(dir, "simulate --config '" + Rdk1() + "' --scenario '" +
                                dir.File("turn.json") + "' --hours 6 --seed 5 --out '" +
                                dir.File("rec.csv") + "' --truth '" + dir.File("truth.csv") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::string truth = ReadFile(dir.File("truth.csv"));
  EXPECT_THAT(truth, HasSubstr("# g1_rotor_displacement_turn_axis: [0, 0, 1]\n"));
  EXPECT_THAT(truth, HasSubstr("# g1_rotor_displacement_turn_period_h: 24\n"));
  EXPECT_THAT(truth, ::testing::Not(HasSubstr("rotor_displacement_rate_um_h")));
  EXPECT_THAT(truth, HasSubstr("st_outlier,st_outlier_arcsec,g1_displacement_x_um,"
                               "g1_displacement_y_um,g1_displacement_z_um\n"));
  // The last row (6 h): its last three fields are the displacement [um].
  std::vector<std::string> rows;
  std::istringstream lines(truth);
  for (std::string line; std::getline(lines, line);) {
    if (!line.empty() && line[0] != '#') rows.push_back(line);
  }
  ASSERT_EQ(rows.size(), 362u);  // the header and 361 frames
  ASSERT_EQ(rows.back().rfind("2019-03-01T06:00:00Z,", 0), 0u) << rows.back();
  std::vector<std::string> fields;
  std::istringstream row(rows.back());
  for (std::string field; std::getline(row, field, ',');) fields.push_back(field);
  ASSERT_GE(fields.size(), 3u);
  const size_t n = fields.size();
  EXPECT_NEAR(std::stod(fields[n - 3]), 0.0, 1e-12);
  EXPECT_NEAR(std::stod(fields[n - 2]), 1.4, 1e-12);
  EXPECT_NEAR(std::stod(fields[n - 1]), 0.0, 1e-12);

  WriteFile(
      dir.File("no_displacement.json"),
      R"({"gyros": [{"id": 1, "rotorDisplacementTurn": {"axis": [0, 0, 1], "periodH": 24}}]})");
  RunResult bad = RunEsg(dir, "simulate --config '" + Rdk1() + "' --scenario '" +
                                  dir.File("no_displacement.json") +
                                  "' --hours 1 --seed 1 --out '" + dir.File("x.csv") + "'");
  EXPECT_EQ(bad.exit_code, 2);
  EXPECT_THAT(bad.err,
              HasSubstr("gyros[0].rotorDisplacementTurn: needs a non-zero rotorDisplacementUm"));
}

TEST(SimulateCli, DocumentedScenarioExamplesRun) {
  const std::filesystem::path scenarios =
      std::filesystem::path(ESG_SOURCE_DIR) / "deploy/examples/scenarios";
  int count = 0;
  for (const auto& entry : std::filesystem::directory_iterator(scenarios)) {
    if (entry.path().extension() != ".json") continue;
    ++count;
    TempDir dir;
    RunResult r =
        RunEsg(dir, "simulate --config '" + Rdk1() + "' --scenario '" + entry.path().string() +
                        "' --hours 1 --seed 1 --out '" + dir.File("rec.csv") + "'");
    EXPECT_EQ(r.exit_code, 0) << entry.path() << ": " << r.err;
    EXPECT_THAT(storage::ReadRecordingCsv(dir.File("rec.csv")), IsOk()) << entry.path();
  }
  EXPECT_GE(count, 3);
}

TEST(SimulateCli, BadArgumentsExitTwoNamingTheProblem) {
  TempDir dir;
  const std::string out = " --out '" + dir.File("x.csv") + "'";
  const std::string config = " --config '" + Rdk1() + "'";
  struct Case {
    std::string args;
    std::string message;
  };
  WriteFile(dir.File("unknown_key.json"),
            R"({"gyros": [{"id": 2, "rotorDisplacmentUm": [1, 0, 0]}]})");
  WriteFile(dir.File("out_of_range.json"), R"({"starTracker": {"outlierRate": 1.5}})");
  WriteFile(dir.File("malformed.json"), R"({"gyros": [)");
  WriteFile(dir.File("bad_config.json"), R"({"spacecraftId": "X", "gyros": []})");
  const Case cases[] = {
      {"simulate --config '" + dir.File("missing.json") + "' --hours 1 --seed 1" + out,
       "missing.json"},
      {"simulate" + config + " --hours 0 --seed 1" + out, "--hours"},
      {"simulate" + config + " --hours -3 --seed 1" + out, "--hours"},
      {"simulate" + config + " --hours 1" + out, "--seed"},
      {"simulate" + config + " --hours 1 --seed 1 --profile tumbling" + out,
       "inertial, orbital, calibration, mixed"},
      {"simulate" + config + " --hours 1 --seed 1 --start yesterday" + out, "--start"},
      {"simulate" + config + " --hours 1 --seed 1 --telemetry-step 0" + out, "--telemetry-step"},
      {"simulate" + config + " --hours 1 --seed 1 --scenario '" + dir.File("unknown_key.json") +
           "'" + out,
       "gyros[0].rotorDisplacmentUm: unknown key"},
      {"simulate" + config + " --hours 1 --seed 1 --scenario '" + dir.File("out_of_range.json") +
           "'" + out,
       "starTracker.outlierRate: 1.5 is outside [0, 1]"},
      {"simulate" + config + " --hours 1 --seed 1 --scenario '" + dir.File("malformed.json") + "'" +
           out,
       "malformed JSON"},
      {"simulate" + config + " --hours 1 --seed 1 --scenario '" + dir.File("nope.json") + "'" + out,
       "nope.json"},
      {"simulate --config '" + dir.File("bad_config.json") + "' --hours 1 --seed 1" + out,
       "bad_config.json: workingPair"},
  };
  for (const Case& c : cases) {
    RunResult r = RunEsg(dir, c.args);
    EXPECT_EQ(r.exit_code, 2) << c.args << "\n" << r.err;
    EXPECT_THAT(r.err, HasSubstr(c.message)) << c.args;
  }
  EXPECT_FALSE(std::filesystem::exists(dir.File("x.csv")));
}

TEST(SimulateCli, UnwritableOutputIsARuntimeFailure) {
  TempDir dir;
  RunResult r = RunEsg(dir, "simulate --config '" + Rdk1() + "' --hours 0.1 --seed 1 --out '" +
                                dir.File("no/such/dir/x.csv") + "'");
  EXPECT_EQ(r.exit_code, 1) << r.err;
  EXPECT_THAT(r.err, HasSubstr("--out"));
}

}  // namespace
}  // namespace esg::client
