// `esg diagnose` run as a real process (ESG_BINARY) on a recording written by `esg simulate`
// through the formats of docs/formats.md: the JSON document names the effect and the gyro and shows
// the held-out drift rate falling; --out writes the Markdown report and the gnuplot plots; progress
// goes to stderr; bad arguments exit 2 naming the option.
#include <sys/wait.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::TempDir;
using ::testing::HasSubstr;

using ::esg::testing::ReadFile;
using ::esg::testing::RunResult;
using ::esg::testing::WriteFile;

RunResult RunEsg(const TempDir& dir, const std::string& args) {
  return ::esg::testing::RunBinary(dir, ESG_BINARY, args);
}

// The user's model: paper model (1) (k0 free, no C1/C2, exact mountings).
constexpr char kConfig[] = R"({
  "spacecraftId": "DISC-CLI",
  "gyros": [
    {"id": 1, "caseToBody": [1,0,0, 0,1,0, 0,0,1], "model": {"k0DegH": 0.25}, "modelSigma": {"k0DegH": 0.3}},
    {"id": 2, "caseToBody": [0,0,-1, 0,1,0, 1,0,0], "model": {"k0DegH": -0.18}, "modelSigma": {"k0DegH": 0.3}},
    {"id": 3, "caseToBody": [0,-1,0, 1,0,0, 0,0,1], "model": {"k0DegH": 0.31}, "modelSigma": {"k0DegH": 0.3}},
    {"id": 4, "caseToBody": [0,0,1, 1,0,0, 0,1,0], "model": {"k0DegH": 0.2}, "modelSigma": {"k0DegH": 0.3}}
  ],
  "workingPair": [1, 2], "reservePair": [1, 3],
  "starTracker": {"noiseArcsec": [5, 5, 30]},
  "readoutNoiseArcsec": 3,
  "randomWalkDegHSqrtH": 0.0015
})";

// Gyro 2's rotor displaced 1.4 um (C ~ 0.1 deg/h), varied orientations, outliers and an outage.
constexpr char kScenario[] = R"({
  "description": "gyro 2 rotor displaced",
  "profile": "mixed", "profileSeed": 3,
  "gyros": [{"id": 2, "rotorDisplacementUm": [0.8, -1.0, 0.6]}],
  "starTracker": {"outlierRate": 0.01, "outlierArcmin": 1, "outages": [{"startHours": 5, "endHours": 6}]}
})";

TEST(DiagnoseCli, NamesTheMissingEffectAndWritesTheReport) {
  TempDir dir;
  WriteFile(dir.File("config.json"), kConfig);
  WriteFile(dir.File("scenario.json"), kScenario);
  RunResult sim = RunEsg(dir, "simulate --config '" + dir.File("config.json") + "' --scenario '" +
                                  dir.File("scenario.json") + "' --hours 24 --seed 3 --out '" +
                                  dir.File("rec.csv") + "'");
  ASSERT_EQ(sim.exit_code, 0) << sim.err;
  RunResult r =
      RunEsg(dir, "diagnose --config '" + dir.File("config.json") + "' --recording '" +
                      dir.File("rec.csv") + "' --json --out '" + dir.File("report") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("diagnose:"));
  EXPECT_THAT(r.err, HasSubstr("round 1"));
  const nlohmann::json doc = nlohmann::json::parse(r.out);
  EXPECT_EQ(doc.at("verdict"), "rotor_displacement");
  ASSERT_FALSE(doc.at("findings").empty());
  const auto& finding = doc.at("findings").at(0);
  EXPECT_EQ(finding.at("effect"), "rotor_displacement");
  EXPECT_EQ(finding.at("gyro"), 2);
  EXPECT_THAT(finding.at("explanation").get<std::string>(), HasSubstr("C1"));
  bool has_c1 = false;
  for (const auto& p : finding.at("parameters"))
    has_c1 |= p.at("name") == "c1DegH[0]" && p.at("unit") == "deg/h";
  EXPECT_TRUE(has_c1);
  EXPECT_TRUE(finding.at("evidence").contains("pValue"));
  EXPECT_EQ(doc.at("mismatch").at("gyro"), 2);
  EXPECT_TRUE(doc.at("mismatch").contains("regime"));
  const double before = doc.at("fit").at("before").at("gapDriftRateDegH");
  const double after = doc.at("fit").at("after").at("gapDriftRateDegH");
  EXPECT_GT(before, 0.0);
  EXPECT_LT(after, 0.5 * before);
  EXPECT_LT(doc.at("fit").at("after").at("residualRmsArcsec").get<double>(),
            doc.at("fit").at("before").at("residualRmsArcsec").get<double>());
  // The report: Markdown with the plots beside it.
  const std::string md = ReadFile(dir.File("report/report.md"));
  EXPECT_THAT(md, HasSubstr("# Diagnosis: rotor_displacement"));
  EXPECT_THAT(md, HasSubstr("![held-out error](held_out.png)"));
  for (const char* png : {"residuals.png", "held_out.png", "regimes.png"}) {
    EXPECT_GT(std::filesystem::file_size(dir.File(std::string("report/") + png)), 1000u) << png;
  }
  const nlohmann::json saved = nlohmann::json::parse(ReadFile(dir.File("report/diagnosis.json")));
  EXPECT_EQ(saved.at("verdict"), "rotor_displacement");
  EXPECT_TRUE(saved.contains("series"));
}

TEST(DiagnoseCli, BadArgumentsExitTwoNamingTheOption) {
  TempDir dir;
  WriteFile(dir.File("config.json"), kConfig);
  RunResult missing = RunEsg(dir, "diagnose --config '" + dir.File("config.json") +
                                      "' --recording '" + dir.File("absent.csv") + "'");
  EXPECT_EQ(missing.exit_code, 2);
  EXPECT_THAT(missing.err, HasSubstr("--recording"));
  WriteFile(dir.File("rec.csv"), "time_utc,st_q0,st_q1,st_q2,st_q3,st_valid\n");
  RunResult effect =
      RunEsg(dir, "diagnose --config '" + dir.File("config.json") + "' --recording '" +
                      dir.File("rec.csv") + "' --effects rotor_displacment");
  EXPECT_EQ(effect.exit_code, 2);
  EXPECT_THAT(effect.err, HasSubstr("--effects"));
  RunResult no_config = RunEsg(dir, "diagnose --recording '" + dir.File("rec.csv") + "'");
  EXPECT_EQ(no_config.exit_code, 2);
  EXPECT_THAT(no_config.err, HasSubstr("--config"));
}

}  // namespace
}  // namespace esg::client
