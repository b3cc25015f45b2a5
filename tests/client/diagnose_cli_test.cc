// `esg diagnose` run as a real process (ESG_BINARY) on a recording written by `esg simulate`
// through the formats of docs/formats.md: the JSON document names the effect and the gyro and shows
// the held-out drift rate falling; --out writes the Markdown report and the gnuplot plots (each
// referenced from the report, time in hours from the start, the residual's predicted sigma in its
// data), onset.png for a drift step and trend.png for a rotor displacement with voltages; progress
// goes to stderr; bad arguments exit 2 naming the option.
#include <sys/wait.h>

#include <algorithm>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::TempDir;
using ::testing::HasSubstr;
using ::testing::Not;

using ::esg::testing::ReadFile;
using ::esg::testing::RunResult;
using ::esg::testing::WriteFile;

RunResult RunEsg(const TempDir& dir, const std::string& args) {
  return ::esg::testing::RunBinary(dir, ESG_BINARY, args);
}

bool GnuplotInstalled() { return std::system("gnuplot --version > /dev/null 2>&1") == 0; }

// The PNG files a Markdown report references as images, "![...](name.png)".
std::set<std::string> ReferencedPngs(const std::string& md) {
  std::set<std::string> out;
  for (size_t at = md.find("]("); at != std::string::npos; at = md.find("](", at + 2)) {
    const size_t end = md.find(')', at);
    const std::string name = md.substr(at + 2, end - at - 2);
    if (name.size() > 4 && name.substr(name.size() - 4) == ".png") out.insert(name);
  }
  return out;
}

// Every plot of the report directory: referenced from report.md with a sentence after it, drawn
// (non-empty) when gnuplot is installed, its time axis hours from the start with the UTC start
// in its title.
void ExpectPlotsReferencedAndDrawn(const TempDir& dir, const std::vector<std::string>& pngs) {
  const std::string md = ReadFile(dir.File("report/report.md"));
  const std::set<std::string> referenced = ReferencedPngs(md);
  for (const std::string& png : pngs) {
    EXPECT_TRUE(referenced.count(png)) << png << " not referenced from report.md";
    const size_t at = md.find("](" + png + ")\n\n");
    ASSERT_NE(at, std::string::npos) << png;
    EXPECT_GT(md.find(". ", at), at) << png << ": no sentence after the image";
    if (GnuplotInstalled()) {
      const std::string path = dir.File("report/" + png);
      ASSERT_TRUE(std::filesystem::exists(path))
          << png << "; " << ReadFile(dir.File("report/gnuplot.log"));
      EXPECT_GT(std::filesystem::file_size(path), 1000u) << png;
    }
  }
  const std::string gp = ReadFile(dir.File("report/plots.gp"));
  EXPECT_THAT(gp, HasSubstr("hours from the start"));
  EXPECT_THAT(gp, HasSubstr("(start 2019-03-01T00:00:00.000Z)"));
  EXPECT_THAT(gp, Not(HasSubstr("set xlabel 'time, h'")));
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
  // The simulator writes suspension voltages: the displacement's trend is plotted too.
  ASSERT_TRUE(finding.contains("displacementTrend"));
  ExpectPlotsReferencedAndDrawn(dir, {"residuals.png", "held_out.png", "regimes.png", "trend.png"});
  EXPECT_THAT(md, Not(HasSubstr("onset.png")));  // no drift step found
  // The residual data carry the filter's predicted sigma beside each |difference|.
  std::istringstream data(ReadFile(dir.File("report/residuals_before.dat")));
  int rows = 0;
  for (std::string line; std::getline(data, line);) {
    if (line.empty() || line[0] == '#') continue;
    std::istringstream row(line);
    double hours = -1, residual = -1, sigma = -1;
    ASSERT_TRUE(row >> hours >> residual >> sigma) << line;
    EXPECT_GT(sigma, 0.0) << line;
    ++rows;
  }
  EXPECT_GT(rows, 100);
  const nlohmann::json saved = nlohmann::json::parse(ReadFile(dir.File("report/diagnosis.json")));
  EXPECT_EQ(saved.at("verdict"), "rotor_displacement");
  ASSERT_TRUE(saved.contains("series"));
  const auto& point = saved.at("series").at("residualsBefore").at(0);
  ASSERT_EQ(point.size(), 4u);  // hours, gyro, |difference|, sigma
  EXPECT_GT(point.at(3).get<double>(), 0.0);
}

// The shipped example of drift behaviours beyond the library (docs/scenario.md,
// drift_behaviours.json, 30 h, seed 5): gyro 1 drifts with the orbit and with a growing rotor
// displacement, gyro 2 switches at random and has a distorted readout, gyro 3 follows a quantity
// the telemetry does not carry (0.014 deg/h). The open-ended stage's regression also selects
// terms for gyro 2; a drift that returns to its mean describes them better (docs/discovery.md,
// "The open-ended stage"), so they are not taken: gyro 2 keeps only its readout distortion, and
// its drift is its own unexplained finding, described in time. Gyro 3 gets no term; since the
// simulated slews no longer jump (docs/scenario.md) its small drift is not found at all, and
// when a finding names gyro 3 it is an unexplained one described as a wandering drift. No
// finding makes the held-out gap drift worse (docs/discovery.md, "A verdict no stronger than its
// evidence"), and the model with the findings still fails its own consistency tests: the
// verdict is partly_explained, never the readout distortion alone.
TEST(DiagnoseCli, TheDriftBehavioursExampleTakesNoTermsForDriftsThatReturnToTheirMeanAndNamesEach) {
  TempDir dir;
  const std::string examples = std::string(ESG_SOURCE_DIR) + "/deploy/examples/";
  RunResult sim = RunEsg(dir, "simulate --config '" + examples + "rdk1.json' --scenario '" +
                                  examples + "scenarios/drift_behaviours.json' --hours 30 --seed 5" +
                                  " --out '" + dir.File("rec.csv") + "' --write-config '" +
                                  dir.File("config.json") + "'");
  ASSERT_EQ(sim.exit_code, 0) << sim.err;
  RunResult r = RunEsg(dir, "diagnose --config '" + dir.File("config.json") + "' --recording '" +
                                dir.File("rec.csv") + "' --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json doc = nlohmann::json::parse(r.out);
  bool left_out = false, gyro2_unexplained = false;
  for (const auto& f : doc.at("findings")) {
    const std::string effect = f.at("effect");
    const int gyro = f.at("gyro");
    if (gyro == 3) {
      // Gyro 3's drift is never named as physics; found, it is described in time.
      EXPECT_EQ(effect, "unexplained") << f.at("explanation");
      const std::string text = f.at("explanation");
      EXPECT_TRUE(text.find("the drift of gyro 3 returns to its mean") != std::string::npos ||
                  text.find("the drift of gyro 3 wanders beyond the configured random walk") !=
                      std::string::npos)
          << text;
    }
    gyro2_unexplained |= effect == "unexplained" && gyro == 2;
    if (effect == "basis_term" && gyro == 2) {
      EXPECT_TRUE(f.contains("readoutDistortion")) << f.at("explanation");
    }
    for (const auto& note : f.at("evidence").at("notes")) {
      const std::string text = note;
      left_out |= text.find("the basis's terms for gyro 2") != std::string::npos &&
                  text.find("less well than a drift that returns to its mean") != std::string::npos;
    }
  }
  EXPECT_TRUE(left_out) << r.out;
  EXPECT_TRUE(gyro2_unexplained) << r.out;
  // What the findings take is never a worse point prediction, and the model with them is tested.
  const double before = doc.at("fit").at("before").at("gapDriftRateDegH");
  const double after = doc.at("fit").at("after").at("gapDriftRateDegH");
  EXPECT_LE(after, 1.05 * before) << r.out;
  EXPECT_EQ(doc.at("verdict"), "partly_explained") << r.out;
  EXPECT_FALSE(doc.at("consistency").at("passed").get<bool>()) << r.out;
}

// A large drift step in gyro 3 of a short recording: onset.png shows the likelihood over the
// onset and the residual at it.
TEST(DiagnoseCli, DriftStepReportPlotsTheOnset) {
  TempDir dir;
  WriteFile(dir.File("config.json"), kConfig);
  WriteFile(dir.File("scenario.json"), R"({
    "description": "gyro 3 drift steps at 3 h",
    "profile": "mixed", "profileSeed": 3,
    "gyros": [{"id": 3, "fault": {"timeHours": 3, "kind": "drift_step", "degH": [0.3, 0.3, 0.3]}}]
  })");
  RunResult sim = RunEsg(dir, "simulate --config '" + dir.File("config.json") + "' --scenario '" +
                                  dir.File("scenario.json") + "' --hours 6 --seed 5 --out '" +
                                  dir.File("rec.csv") + "'");
  ASSERT_EQ(sim.exit_code, 0) << sim.err;
  RunResult r = RunEsg(dir, "diagnose --config '" + dir.File("config.json") + "' --recording '" +
                                dir.File("rec.csv") +
                                "' --effects drift_step --max-effects 1 "
                                "--json --out '" +
                                dir.File("report") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json doc = nlohmann::json::parse(r.out);
  ASSERT_EQ(doc.at("verdict"), "drift_step") << r.out;
  const auto& time = doc.at("findings").at(0).at("timeBehaviour");
  EXPECT_NEAR(time.at("onsetHours").get<double>(), 3.0, 0.2);
  ASSERT_FALSE(time.at("onsetProfile").empty());
  double best = 1e300;
  for (const auto& p : time.at("onsetProfile")) best = std::min(best, p.at(1).get<double>());
  EXPECT_EQ(best, 0.0);  // -2 log L above the best
  ExpectPlotsReferencedAndDrawn(dir, {"residuals.png", "held_out.png", "regimes.png", "onset.png"});
  EXPECT_TRUE(std::filesystem::exists(dir.File("report/onset_profile.dat")));
}

// A warm-up of gyro 2 (the scenario's transientDrift, docs/scenario.md: 0.15 deg/h decaying with
// tau = 3 h from the start) is found with --effects warm_up as three exponential_decay terms of
// gyro 2, tau's 95% interval holding 3 h; model.json carries them (timeConstantS) and esg
// calibrate reads it: the kind round-trips through the diagnosis's JSON and the configuration's.
TEST(DiagnoseCli, WarmUpIsWrittenToTheModelAsExponentialDecayTerms) {
  TempDir dir;
  WriteFile(dir.File("config.json"), kConfig);
  WriteFile(dir.File("scenario.json"), R"({
    "description": "gyro 2 warms up",
    "profile": "mixed", "profileSeed": 3,
    "gyros": [{"id": 2, "transientDrift": {"amplitudeDegH": [0.09, -0.09, 0.08],
                                           "timeConstantHours": 3}}]
  })");
  RunResult sim = RunEsg(dir, "simulate --config '" + dir.File("config.json") + "' --scenario '" +
                                  dir.File("scenario.json") + "' --hours 12 --seed 5 --out '" +
                                  dir.File("rec.csv") + "'");
  ASSERT_EQ(sim.exit_code, 0) << sim.err;
  RunResult r = RunEsg(dir, "diagnose --config '" + dir.File("config.json") + "' --recording '" +
                                dir.File("rec.csv") +
                                "' --effects warm_up --max-effects 1 --json --out '" +
                                dir.File("report") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json doc = nlohmann::json::parse(r.out);
  ASSERT_EQ(doc.at("verdict"), "basis_term") << r.out;
  const auto& f = doc.at("findings").at(0);
  EXPECT_EQ(f.at("gyro"), 2);
  EXPECT_EQ(f.at("timeBehaviour").at("kind"), "warm_up");
  double lower = 0.0, upper = 0.0;
  for (const auto& p : f.at("parameters")) {
    if (p.at("name") == "tauLowerHours") lower = p.at("value");
    if (p.at("name") == "tauUpperHours") upper = p.at("value");
  }
  EXPECT_LE(lower, 3.0) << f.at("explanation");
  EXPECT_GE(upper, 3.0) << f.at("explanation");
  ASSERT_EQ(f.at("modelTerms").size(), 3u);
  for (const auto& t : f.at("modelTerms")) {
    EXPECT_EQ(t.at("kind"), "exponential_decay");
    EXPECT_GT(t.at("timeConstantS").get<double>(), 0.0);
  }
  const nlohmann::json model = nlohmann::json::parse(ReadFile(dir.File("report/model.json")));
  int decays = 0;
  for (const auto& g : model.at("gyros")) {
    if (!g.contains("basisTerms")) continue;
    for (const auto& t : g.at("basisTerms")) decays += t.at("kind") == "exponential_decay";
  }
  EXPECT_EQ(decays, 3);
  RunResult cal = RunEsg(dir, "calibrate --config '" + dir.File("report/model.json") +
                                  "' --recording '" + dir.File("rec.csv") + "' --json");
  EXPECT_EQ(cal.exit_code, 0) << cal.err;
}

// A step of gyro 2's k0 (the scenario's coefficientStep, docs/scenario.md: +0.1 deg/h at 5 h of
// 12 h) is found with --effects coefficient_step as a step of k0 at an onset whose 95% interval
// holds 5 h; model.json carries it as three spin_axis_harmonic terms switched on at the onset
// (their epoch, D110) and esg calibrate reads it.
TEST(DiagnoseCli, CoefficientStepIsWrittenToTheModelAsSwitchedOnHarmonics) {
  TempDir dir;
  WriteFile(dir.File("config.json"), kConfig);
  WriteFile(dir.File("scenario.json"), R"({
    "description": "gyro 2's k0 steps",
    "profile": "mixed", "profileSeed": 3,
    "gyros": [{"id": 2, "coefficientStep": {"startHours": 5, "k0DegH": 0.1}}]
  })");
  RunResult sim = RunEsg(dir, "simulate --config '" + dir.File("config.json") + "' --scenario '" +
                                  dir.File("scenario.json") + "' --hours 12 --seed 5 --out '" +
                                  dir.File("rec.csv") + "'");
  ASSERT_EQ(sim.exit_code, 0) << sim.err;
  RunResult r = RunEsg(dir, "diagnose --config '" + dir.File("config.json") + "' --recording '" +
                                dir.File("rec.csv") +
                                "' --effects coefficient_step --max-effects 1 --json --out '" +
                                dir.File("report") + "'");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json doc = nlohmann::json::parse(r.out);
  ASSERT_EQ(doc.at("verdict"), "basis_term") << r.out;
  const auto& f = doc.at("findings").at(0);
  EXPECT_EQ(f.at("gyro"), 2);
  const auto& time = f.at("timeBehaviour");
  EXPECT_EQ(time.at("kind"), "coefficient_step");
  EXPECT_LE(time.at("onsetLowerHours").get<double>(), 5.0) << f.at("explanation");
  EXPECT_GE(time.at("onsetUpperHours").get<double>(), 5.0) << f.at("explanation");
  bool k0 = false;
  for (const auto& p : f.at("parameters")) k0 = k0 || p.at("name") == "k0StepDegH";
  EXPECT_TRUE(k0) << f.at("explanation");
  ASSERT_EQ(f.at("modelTerms").size(), 3u);
  const auto& epoch = f.at("modelTerms").at(0).at("epoch");
  EXPECT_NE(epoch, "1970-01-01T00:00:00Z");  // switched on at the onset, not always on
  for (const auto& t : f.at("modelTerms")) {
    EXPECT_EQ(t.at("kind"), "spin_axis_harmonic");
    EXPECT_EQ(t.at("epoch"), epoch);
  }
  const nlohmann::json model = nlohmann::json::parse(ReadFile(dir.File("report/model.json")));
  int switched = 0;
  for (const auto& g : model.at("gyros")) {
    if (!g.contains("basisTerms")) continue;
    for (const auto& t : g.at("basisTerms")) {
      switched += t.at("kind") == "spin_axis_harmonic" && t.at("epoch") == epoch;
    }
  }
  EXPECT_EQ(switched, 3);
  ExpectPlotsReferencedAndDrawn(dir, {"onset.png"});
  RunResult cal = RunEsg(dir, "calibrate --config '" + dir.File("report/model.json") +
                                  "' --recording '" + dir.File("rec.csv") + "' --json");
  EXPECT_EQ(cal.exit_code, 0) << cal.err;
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
  // The message lists every effect the diagnosis tries, the sun's, the readout group's and the
  // warm-up's too.
  for (const char* id : {"rotor_displacement", "fourth_harmonic", "unequal_stiffness",
                         "gyro_misalignment", "star_tracker_misalignment", "star_tracker_latency",
                         "random_walk_drift", "drift_step", "readout_distortion", "sun_drift",
                         "warm_up", "coefficient_step", "transient"}) {
    EXPECT_THAT(effect.err, HasSubstr(id));
  }
  RunResult no_config = RunEsg(dir, "diagnose --recording '" + dir.File("rec.csv") + "'");
  EXPECT_EQ(no_config.exit_code, 2);
  EXPECT_THAT(no_config.err, HasSubstr("--config"));
}

}  // namespace
}  // namespace esg::client
