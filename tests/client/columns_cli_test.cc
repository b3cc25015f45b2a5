// `esg calibrate`, `esg diagnose` and `esg replay` with `--columns FILE` (docs/formats.md,
// "Column mapping"), run as real processes: a recording simulated by `esg simulate` and exported
// as a user's telemetry would be (deploy/examples/columns_user_export.json: other column names,
// ';' between fields, spin axes as azimuth/elevation in degrees, voltages in volts, q_b_in scalar
// last, Unix seconds) calibrates to the same coefficients as the original CSV, diagnoses to the
// same verdict, and replays to a real esgd on loopback with every frame acknowledged and applied;
// the identity mapping (deploy/examples/columns_esg_recording.json) reads the project's CSV bit for
// bit; a wrong mapping or a CSV that does not fit it exits 2 naming the mapping field or the
// column and line; the worked examples of docs/formats.md load and agree.
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/time/time.h"
#include "estimator/rotation.h"
#include "formats/column_mapping.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/client/cli_test_support.h"
#include "tests/testing/run_process.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

#define ESGD_PATH ESGD_BINARY
#include "tests/testing/daemon.h"

namespace esg::client {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::ReadFile;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;
using ::esg::testing::WriteFile;
using ::testing::HasSubstr;
using Json = nlohmann::json;

constexpr double kPi = 3.14159265358979323846;

std::string Example(const std::string& name) {
  return std::string(ESG_SOURCE_DIR) + "/deploy/examples/" + name;
}

RunResult RunEsg(const TempDir& dir, const std::string& args) {
  return ::esg::testing::RunBinary(dir, ESG_BINARY, args + " < /dev/null");
}

std::string Num(double x) { return absl::StrFormat("%.17g", x); }

// The recording in the layout of deploy/examples/columns_user_export.json, columns in another
// order than the mapping's and one the mapping does not name.
std::string UserExport(const estimator::Recording& recording) {
  std::vector<std::string> header = {"UNIX_TIME", "STR_STATUS", "STR_QX", "STR_QY",
                                     "STR_QZ",    "STR_QW",     "BUS_V"};
  for (int g = 1; g <= 4; ++g) {
    for (const char* s : {"AZ", "EL", "UX", "UY", "UZ"}) {
      header.push_back(absl::StrCat("ESG", g, "_", s));
    }
  }
  std::string out = absl::StrJoin(header, ";") + "\n";
  for (const estimator::TelemetryFrame& frame : recording.frames) {
    const int64_t ns = absl::ToUnixNanos(frame.time);
    std::vector<std::string> f = {absl::StrFormat("%d.%09d", ns / 1000000000, ns % 1000000000)};
    if (!frame.star_tracker.has_value()) {
      f.insert(f.end(), {"", "", "", "", ""});
    } else if (!frame.star_tracker->valid) {
      f.insert(f.end(), {"BAD", "", "", "", ""});
    } else {
      const estimator::ScalarFirst q = estimator::ToScalarFirst(frame.star_tracker->q_in_b);
      f.insert(f.end(), {"OK", Num(-q[1]), Num(-q[2]), Num(-q[3]), Num(q[0])});  // q_b_in
    }
    f.push_back("28.1");
    for (int g = 0; g < 4; ++g) {
      const std::optional<estimator::GyroReading>& r = frame.gyros[g];
      if (r.has_value()) {
        const Eigen::Vector3d& h = r->h_k;
        f.push_back(Num(std::atan2(h.y(), h.x()) * 180.0 / kPi));
        f.push_back(Num(std::atan2(h.z(), std::hypot(h.x(), h.y())) * 180.0 / kPi));
      } else {
        f.insert(f.end(), {"", ""});
      }
      const bool u = r.has_value() && r->u_k_mv.has_value();
      for (int k = 0; k < 3; ++k) f.push_back(u ? Num((*r->u_k_mv)[k] / 1000.0) : "");
    }
    absl::StrAppend(&out, absl::StrJoin(f, ";"), "\n");
  }
  return out;
}

// Two JSON documents equal but for numbers, which agree to `rel` relative or 1e-10 absolute (in
// the document's units: deg/h, arcsec; values near zero differ relatively more).
void ExpectSameJson(const Json& a, const Json& b, const std::string& path, double rel) {
  if (a.is_number_float() || b.is_number_float()) {
    ASSERT_TRUE(a.is_number() && b.is_number()) << path;
    const double x = a.get<double>(), y = b.get<double>();
    EXPECT_NEAR(x, y, std::max(1e-10, rel * std::abs(x))) << path;
    return;
  }
  ASSERT_EQ(a.type(), b.type()) << path;
  if (a.is_object()) {
    ASSERT_EQ(a.size(), b.size()) << path;
    for (auto it = a.begin(); it != a.end(); ++it) {
      ASSERT_TRUE(b.contains(it.key())) << path << "." << it.key();
      ExpectSameJson(it.value(), b.at(it.key()), path + "." + it.key(), rel);
    }
  } else if (a.is_array()) {
    ASSERT_EQ(a.size(), b.size()) << path;
    for (size_t i = 0; i < a.size(); ++i) {
      ExpectSameJson(a[i], b[i], absl::StrCat(path, "[", i, "]"), rel);
    }
  } else {
    EXPECT_EQ(a, b) << path;
  }
}

// One simulated 6 h recording of deploy/examples/rdk1.json with star-tracker defects (outliers,
// an outage, two samples flagged invalid), and its user export.
class ColumnsCli : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = new TempDir;
    const RunResult r =
        RunEsg(*dir_, "simulate --config " + Quote(Example("rdk1.json")) + " --scenario " +
                          Quote(Example("scenarios/star_tracker_defects.json")) +
                          " --hours 6 --seed 11 --out " + Quote(dir_->File("rec.csv")));
    ASSERT_EQ(r.exit_code, 0) << r.err;
    absl::StatusOr<estimator::Recording> recording =
        storage::ReadRecordingCsv(dir_->File("rec.csv"));
    ASSERT_THAT(recording.status(), IsOk());
    rows_ = static_cast<int64_t>(recording->frames.size());
    // Two samples flagged invalid by the star tracker (the scenario's 0.5% may give none).
    for (int i : {40, 41}) {
      ASSERT_TRUE(recording->frames[i].star_tracker.has_value());
      recording->frames[i].star_tracker->valid = false;
    }
    ASSERT_THAT(storage::WriteRecordingCsv(dir_->File("rec.csv"), *recording), IsOk());
    int invalid = 0, outage = 0;
    for (const auto& frame : recording->frames) {
      invalid += frame.star_tracker.has_value() && !frame.star_tracker->valid;
      outage += !frame.star_tracker.has_value();
    }
    ASSERT_GT(invalid, 0);
    ASSERT_GT(outage, 0);
    WriteFile(dir_->File("user.csv"), UserExport(*recording));
  }
  static void TearDownTestSuite() { delete dir_; }

  static std::string Rec() { return Quote(dir_->File("rec.csv")); }
  static std::string User() { return Quote(dir_->File("user.csv")); }

  static TempDir* dir_;
  static int64_t rows_;
};
TempDir* ColumnsCli::dir_ = nullptr;
int64_t ColumnsCli::rows_ = 0;

TEST_F(ColumnsCli, CalibrateOnTheUserExportGivesTheSameCoefficients) {
  TempDir dir;
  const std::string config = " --config " + Quote(Example("rdk1.json"));
  RunResult own = RunEsg(dir, "calibrate" + config + " --recording " + Rec() + " --json");
  ASSERT_EQ(own.exit_code, 0) << own.err;
  RunResult user = RunEsg(dir, "calibrate" + config + " --recording " + User() + " --columns " +
                                   Quote(Example("columns_user_export.json")) + " --json");
  ASSERT_EQ(user.exit_code, 0) << user.err;
  const Json a = Json::parse(own.out), b = Json::parse(user.out);
  ASSERT_TRUE(a.contains("gyros")) << own.out;
  EXPECT_EQ(a.at("gyros").size(), 3u);
  // Inputs equal to ~1e-16 (degrees and volts converted back) give coefficients equal to 1e-9
  // relative or 1e-10 deg/h (measured: 4.3e-13 deg/h at most); counts, states and events exactly.
  ExpectSameJson(a, b, "calibrate", 1e-9);

  // The identity mapping reads the project's own CSV bit for bit: the same document exactly.
  RunResult identity = RunEsg(dir, "calibrate" + config + " --recording " + Rec() + " --columns " +
                                       Quote(Example("columns_esg_recording.json")) + " --json");
  ASSERT_EQ(identity.exit_code, 0) << identity.err;
  EXPECT_EQ(Json::parse(identity.out), a);
}

TEST_F(ColumnsCli, DiagnoseOnTheUserExportGivesTheSameReport) {
  TempDir dir;
  const std::string common =
      "diagnose --config " + Quote(Example("rdk1.json")) + " --max-effects 1 --json --recording ";
  RunResult own = RunEsg(dir, common + Rec());
  ASSERT_EQ(own.exit_code, 0) << own.err;
  RunResult user =
      RunEsg(dir, common + User() + " --columns " + Quote(Example("columns_user_export.json")));
  ASSERT_EQ(user.exit_code, 0) << user.err;
  const Json a = Json::parse(own.out), b = Json::parse(user.out);
  ASSERT_TRUE(a.contains("verdict")) << own.out;
  ASSERT_FALSE(a.at("candidates").empty());
  // The whole report: verdict, candidates and their statistics, fit, regimes.
  ExpectSameJson(a, b, "diagnose", 1e-6);
}

TEST_F(ColumnsCli, ReplayOfTheUserExportToEsgdAcknowledgesEveryFrame) {
  TempDir dir;
  ::esg::testing::Daemon esgd(dir.File("esg.db"), dir.File("esgd.log"));
  ASSERT_GT(esgd.port(), 0) << ReadFile(dir.File("esgd.log"));
  const std::string at = absl::StrCat("--server 127.0.0.1:", esgd.port(), " ");
  RunResult r = RunEsg(dir, at + "configure --config " + Quote(Example("rdk1.json")));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  // The spacecraft comes from the mapping's spacecraftId (the export has no metadata lines).
  r = RunEsg(dir, at + "replay --recording " + User() + " --columns " +
                      Quote(Example("columns_user_export.json")) + " --wait --json");
  ASSERT_EQ(r.exit_code, 0) << r.err << ReadFile(dir.File("esgd.log"));
  const Json replay = Json::parse(r.out);
  auto i64 = [](const Json& v) {
    return v.is_string() ? std::stoll(v.get<std::string>()) : v.get<int64_t>();
  };
  EXPECT_EQ(replay.at("spacecraftId"), "RDK-1");
  EXPECT_EQ(i64(replay.at("sent")), rows_);
  EXPECT_EQ(i64(replay.at("acked")), rows_);
  EXPECT_EQ(i64(replay.at("accepted")), rows_);
  EXPECT_EQ(i64(replay.at("rejected")), 0);
  EXPECT_EQ(i64(replay.at("highestAppliedSequence")), rows_);
}

TEST_F(ColumnsCli, WrongMappingOrCsvExitsTwoNamingFieldColumnAndLine) {
  TempDir dir;
  const std::string calibrate =
      "calibrate --config " + Quote(Example("rdk1.json")) + " --recording ";
  // A unit that is not known: the mapping field.
  std::string mapping = ReadFile(Example("columns_user_export.json"));
  WriteFile(dir.File("bad_unit.json"),
            std::string(mapping).replace(mapping.find("\"V\""), 3, "\"kV\""));
  RunResult r = RunEsg(dir, calibrate + User() + " --columns " + Quote(dir.File("bad_unit.json")));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("gyros[0].voltages.unit: 'kV' is not a known unit (V, mV, uV)"));
  // The project's CSV through the user mapping: its columns are missing, each named.
  r = RunEsg(dir, calibrate + Rec() + " --columns " + Quote(Example("columns_user_export.json")));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("the header has no column 'UNIX_TIME' (named by the mapping's "
                               "time.column)"));
  // A quaternion that is not unit length after conversion: line and columns. The first valid
  // reading from line 4 on gets STR_QW = 2.
  std::vector<std::string> lines = absl::StrSplit(ReadFile(dir_->File("user.csv")), '\n');
  int bad_line = 0;
  for (size_t i = 3; i < lines.size() && bad_line == 0; ++i) {
    std::vector<std::string> f = absl::StrSplit(lines[i], ';');
    if (f.size() > 5 && f[1] == "OK") {
      f[5] = "2";
      lines[i] = absl::StrJoin(f, ";");
      bad_line = static_cast<int>(i) + 1;
    }
  }
  ASSERT_GT(bad_line, 0);
  WriteFile(dir.File("bad_row.csv"), absl::StrJoin(lines, "\n"));
  r = RunEsg(dir, calibrate + Quote(dir.File("bad_row.csv")) + " --columns " +
                      Quote(Example("columns_user_export.json")));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr(absl::StrCat(
                         "line ", bad_line,
                         ", column STR_QX,STR_QY,STR_QZ,STR_QW (starTracker.columns): the "
                         "quaternion after conversion to q_in_b has norm")));
  // Replay refuses it before connecting (no server needed for exit 2).
  r = RunEsg(dir, "--server 127.0.0.1:1 replay --recording " + Quote(dir.File("bad_row.csv")) +
                      " --columns " + Quote(Example("columns_user_export.json")));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err,
              HasSubstr(absl::StrCat("line ", bad_line, ", column STR_QX,STR_QY,STR_QZ,STR_QW")));
  // Without spacecraftId in the mapping (an export has no metadata lines) replay needs
  // --spacecraft, and says where the id could have come from.
  const size_t id_at = mapping.find("  \"spacecraftId\": \"RDK-1\",\n");
  ASSERT_NE(id_at, std::string::npos);
  WriteFile(dir.File("no_id.json"), std::string(mapping).erase(id_at, 27));
  r = RunEsg(dir, "--server 127.0.0.1:1 replay --recording " + User() + " --columns " +
                      Quote(dir.File("no_id.json")));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--columns mapping (spacecraftId)"));
  // Each verb documents the option.
  for (const char* verb : {"calibrate", "gap", "diagnose", "replay"}) {
    r = RunEsg(dir, std::string(verb) + " --help");
    EXPECT_THAT(r.out, HasSubstr("--columns")) << verb;
  }
}

// The text of the code block after "<!-- example: NAME -->" in a Markdown file.
std::string DocExample(const std::string& markdown, const std::string& name) {
  const size_t anchor = markdown.find("<!-- example: " + name + " -->");
  if (anchor == std::string::npos) return "";
  const size_t start = markdown.find('\n', markdown.find("```", anchor)) + 1;
  return markdown.substr(start, markdown.find("\n```", start) + 1 - start);
}

// The worked examples of docs/formats.md: the project's CSV and a user export with its mapping
// (the same as deploy/examples/columns_user_export.json) give the same frames.
TEST(ColumnsDocs, DocsWorkedExamplesLoadEqual) {
  const std::string doc = ReadFile(std::string(ESG_SOURCE_DIR) + "/docs/formats.md");
  const std::string own_csv = DocExample(doc, "recording.csv");
  const std::string user_csv = DocExample(doc, "user-export.csv");
  const std::string mapping_json = DocExample(doc, "columns_user_export.json");
  ASSERT_FALSE(own_csv.empty() || user_csv.empty() || mapping_json.empty());
  EXPECT_EQ(Json::parse(mapping_json), Json::parse(ReadFile(Example("columns_user_export.json"))));
  absl::StatusOr<estimator::Recording> own = storage::ParseRecordingCsv(own_csv);
  ASSERT_THAT(own.status(), IsOk());
  absl::StatusOr<storage::ColumnMapping> mapping = storage::ParseColumnMapping(mapping_json);
  ASSERT_THAT(mapping.status(), IsOk());
  absl::StatusOr<estimator::Recording> user = storage::ParseMappedRecordingCsv(user_csv, *mapping);
  ASSERT_THAT(user.status(), IsOk());
  EXPECT_EQ(own->metadata.at("spacecraft_id"), user->metadata.at("spacecraft_id"));
  ASSERT_EQ(own->frames.size(), 4u);
  ASSERT_EQ(user->frames.size(), 4u);
  for (size_t i = 0; i < 4; ++i) {
    const estimator::TelemetryFrame& a = own->frames[i];
    const estimator::TelemetryFrame& b = user->frames[i];
    EXPECT_EQ(a.time, b.time) << i;
    for (int g = 0; g < 4; ++g) {
      ASSERT_EQ(a.gyros[g].has_value(), b.gyros[g].has_value()) << i << " gyro " << g + 1;
      if (!a.gyros[g].has_value()) continue;
      EXPECT_LT((a.gyros[g]->h_k - b.gyros[g]->h_k).norm(), 1e-6) << i << " gyro " << g + 1;
      ASSERT_EQ(a.gyros[g]->u_k_mv.has_value(), b.gyros[g]->u_k_mv.has_value()) << i;
      if (a.gyros[g]->u_k_mv.has_value()) {
        EXPECT_LT((*a.gyros[g]->u_k_mv - *b.gyros[g]->u_k_mv).norm(), 1e-9) << i;
      }
    }
    ASSERT_EQ(a.star_tracker.has_value(), b.star_tracker.has_value()) << i;
    if (!a.star_tracker.has_value()) continue;
    ASSERT_EQ(a.star_tracker->valid, b.star_tracker->valid) << i;
    if (a.star_tracker->valid) {
      EXPECT_LT(a.star_tracker->q_in_b.angularDistance(b.star_tracker->q_in_b), 1e-9) << i;
    }
  }
}

}  // namespace
}  // namespace esg::client
