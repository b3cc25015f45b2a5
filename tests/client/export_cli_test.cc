// `esg export telemetry|history` as real processes against a real esgd child process on
// 127.0.0.1 (docs/cli.md "export"): a simulated recording replayed into esgd and exported again
// is the same recording (every frame, every value, compared as read back by the recording
// reader) and `esg calibrate --recording` gives the same result on both; a span exports its
// frames only; the history export has one row per stored snapshot, each value equal to the
// stored one; bad arguments exit 2 naming the option, server refusals exit 1.
#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <string>
#include <vector>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "estimator/rotation.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/client/cli_test_support.h"
#include "tests/testing/run_process.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using ::esg::testing::RunBinary;
using ::esg::testing::RunResult;
using ::esg::testing::TempDir;
using ::testing::HasSubstr;
using Json = nlohmann::json;

// A coefficient of a drift model in esg's JSON by its term's key (keyed, docs/formats.md).
double KeyedDegH(const Json& model, const std::string& term) {
  for (const Json& c : model.at("coefficients")) {
    if (c.at("term") == term) return c.at("valueDegH").get<double>();
  }
  ADD_FAILURE() << "no keyed coefficient " << term << " in " << model.dump();
  return 0.0;
}

// Largest absolute difference between two frames' values; +inf when their shapes differ (a gyro,
// a voltage or the star tracker present in one only, a validity flag or a time that differs).
double MaxDifference(const estimator::TelemetryFrame& a, const estimator::TelemetryFrame& b) {
  constexpr double kShape = INFINITY;
  if (a.time != b.time) return kShape;
  double worst = 0.0;
  for (size_t g = 0; g < a.gyros.size(); ++g) {
    if (a.gyros[g].has_value() != b.gyros[g].has_value()) return kShape;
    if (!a.gyros[g].has_value()) continue;
    worst = std::max(worst, (a.gyros[g]->h_k - b.gyros[g]->h_k).cwiseAbs().maxCoeff());
    if (a.gyros[g]->u_k_mv.has_value() != b.gyros[g]->u_k_mv.has_value()) return kShape;
    if (a.gyros[g]->u_k_mv.has_value()) {
      worst = std::max(worst, (*a.gyros[g]->u_k_mv - *b.gyros[g]->u_k_mv).cwiseAbs().maxCoeff());
    }
  }
  if (a.star_tracker.has_value() != b.star_tracker.has_value()) return kShape;
  if (a.star_tracker.has_value()) {
    if (a.star_tracker->valid != b.star_tracker->valid) return kShape;
    if (a.star_tracker->valid) {
      worst = std::max(worst, (a.star_tracker->q_in_b.coeffs() - b.star_tracker->q_in_b.coeffs())
                                  .cwiseAbs()
                                  .maxCoeff());
    }
  }
  return worst;
}

// One esgd with RDK-1 configured and a 6 h simulated recording replayed (361 frames).
class ExportCli : public ReplayedRdk1Suite<ExportCli> {
 protected:
  static RunResult Run(const std::string& args) { return RunBinary(*dir_, ESG_BINARY, args); }
  static RunResult Esg(const TempDir& dir, const std::string& args) {
    return client::Esg(dir, *daemon_, args);
  }
};

TEST_F(ExportCli, TelemetryExportIsTheReplayedRecordingAndCalibratesTheSame) {
  TempDir dir;
  const std::string exported = dir.File("export.csv");
  RunResult r = Esg(dir, "export telemetry --spacecraft RDK-1 --out " + Quote(exported));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("RDK-1: 361 frames (2019-03-01T00:00:00.000Z .. "));
  EXPECT_FALSE(std::ifstream(exported + ".tmp").good()) << "the temporary file is renamed";

  absl::StatusOr<estimator::Recording> replayed = storage::ReadRecordingCsv(recording_);
  absl::StatusOr<estimator::Recording> back = storage::ReadRecordingCsv(exported);
  ASSERT_TRUE(replayed.ok()) << replayed.status();
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(back->metadata.at("spacecraft_id"), "RDK-1");
  ASSERT_EQ(back->frames.size(), replayed->frames.size());
  ASSERT_EQ(back->frames.size(), 361u);
  double worst = 0.0;
  for (size_t i = 0; i < back->frames.size(); ++i) {
    const double d = MaxDifference(back->frames[i], replayed->frames[i]);
    ASSERT_TRUE(std::isfinite(d)) << "frame " << i << " differs in shape or time";
    worst = std::max(worst, d);
  }
  RecordProperty("max_abs_difference", absl::StrCat(worst));
  // The writer keeps every double (shortest round-trip form): measured 0.
  EXPECT_EQ(worst, 0.0);

  // The offline calibration reads the export as it reads the recording: the same result.
  r = Run("calibrate --config " + Quote(Rdk1()) + " --recording " + Quote(recording_) +
          " --format json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  Json original = Json::parse(r.out);
  r = Run("calibrate --config " + Quote(Rdk1()) + " --recording " + Quote(exported) +
          " --format json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  Json again = Json::parse(r.out);
  ASSERT_TRUE(original.contains("gyros")) << original.dump();
  EXPECT_EQ(again["gyros"], original["gyros"]);
}

TEST_F(ExportCli, TelemetrySpanExportsItsFramesOnly) {
  TempDir dir;
  const std::string exported = dir.File("span.csv");
  // [01:00, 02:00], both ends inclusive: frames at 01:00, 01:01, ..., 02:00.
  RunResult r = Esg(dir,
                    "export telemetry --spacecraft RDK-1 --from 2019-03-01T01:00:00Z "
                    "--to 2019-03-01T02:00:00Z --out " +
                        Quote(exported));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  absl::StatusOr<estimator::Recording> back = storage::ReadRecordingCsv(exported);
  ASSERT_TRUE(back.ok()) << back.status();
  ASSERT_EQ(back->frames.size(), 61u);
  const absl::Time start = absl::FromUnixSeconds(1551398400);  // 2019-03-01T00:00:00Z
  EXPECT_EQ(back->frames.front().time, start + absl::Hours(1));
  EXPECT_EQ(back->frames.back().time, start + absl::Hours(2));

  // No frame in the span: exit 1, nothing written.
  const std::string empty = dir.File("empty.csv");
  r = Esg(dir,
          "export telemetry --spacecraft RDK-1 --from 2020-01-01T00:00:00Z --out " + Quote(empty));
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("no archived frame of RDK-1"));
  EXPECT_FALSE(std::ifstream(empty).good());
  EXPECT_FALSE(std::ifstream(empty + ".tmp").good());
}

// Values of a history CSV row by column name.
std::vector<std::vector<std::string>> CsvRows(const std::string& text) {
  std::vector<std::vector<std::string>> rows;
  for (absl::string_view line : absl::StrSplit(text, '\n', absl::SkipEmpty())) {
    rows.push_back(absl::StrSplit(line, ','));
  }
  return rows;
}

// Every verb with --from/--to reads the span one way, [--from, --to] with both ends inclusive
// (docs/cli.md "Time spans"): the records measured exactly at --to are printed or written, none
// after it. The replay has a frame, an estimate and a snapshot per gyro every 60 s.
TEST_F(ExportCli, EveryVerbsSpanIncludesTheRecordsAtTo) {
  TempDir dir;
  const std::string span = " --from 2019-03-01T01:00:00Z --to 2019-03-01T02:00:00Z";
  const std::string at_to = "\n2019-03-01T02:00:00.000Z,";
  const std::string after_to = "\n2019-03-01T02:01:00.000Z,";
  // esg estimates --csv: a row per step, 01:00 .. 02:00.
  RunResult r = Esg(dir, "estimates --spacecraft RDK-1 --csv" + span);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(CsvRows(r.out).size(), 1u + 61u) << "header and 61 steps";
  EXPECT_THAT(r.out, HasSubstr(at_to));
  EXPECT_THAT(r.out, ::testing::Not(HasSubstr(after_to)));
  // esg history --csv and esg export history: a row per gyro and step, the last at 02:00.
  for (const std::string verb : {"history --csv", "export history"}) {
    r = Esg(dir, verb + " --spacecraft RDK-1" + span);
    ASSERT_EQ(r.exit_code, 0) << verb << ": " << r.err;
    EXPECT_THAT(r.out, HasSubstr(at_to)) << verb;
    EXPECT_THAT(r.out, ::testing::Not(HasSubstr(after_to))) << verb;
    const std::vector<std::vector<std::string>> rows = CsvRows(r.out);
    ASSERT_GE(rows.size(), 2u) << verb;
    EXPECT_EQ(rows.back()[0], "2019-03-01T02:00:00.000Z") << verb;
  }
  // esg export telemetry (TelemetrySpanExportsItsFramesOnly reads the file back): 61 frames.
  r = Esg(dir, "export telemetry --spacecraft RDK-1 --out " + Quote(dir.File("t.csv")) + span);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr("RDK-1: 61 frames (2019-03-01T01:00:00.000Z .. "
                               "2019-03-01T02:00:00.000Z)"));
  // esg diagnose --spacecraft: the stored diagnosis ran on the 61 frames, the last at 02:00.
  r = Esg(dir, "diagnose --spacecraft RDK-1" + span);
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.out, HasSubstr("2019-03-01T01:00:00.000Z .. 2019-03-01T02:00:00.000Z, 61 frames"));
  // --from = --to: the one instant.
  r = Esg(dir, "estimates --spacecraft RDK-1 --csv --from 2019-03-01T02:00:00Z "
               "--to 2019-03-01T02:00:00Z");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_EQ(CsvRows(r.out).size(), 2u) << r.out;
  EXPECT_THAT(r.out, HasSubstr(at_to));
}

TEST_F(ExportCli, HistoryExportHasEveryStoredSnapshotWithItsValues) {
  TempDir dir;
  // The stored history, through GetCoefficientHistory's pages.
  RunResult r = Esg(dir, "history --spacecraft RDK-1 --format json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json stored = Json::parse(r.out);
  const size_t count = stored["snapshots"].size();
  ASSERT_GT(count, 700u) << "6 h of 60 s steps, one snapshot per running gyro";

  const std::string csv = dir.File("history.csv");
  r = Esg(dir, "export history --spacecraft RDK-1 --out " + Quote(csv));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  EXPECT_THAT(r.err, HasSubstr(absl::StrCat("RDK-1: ", count, " coefficient snapshots written")));
  const std::vector<std::vector<std::string>> rows = CsvRows(testing::ReadFile(csv));
  ASSERT_EQ(rows.size(), count + 1) << "a header and one row per stored snapshot";
  // The same columns as `esg history --csv`.
  r = Esg(dir, "history --spacecraft RDK-1 --csv");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const std::vector<std::vector<std::string>> history_csv = CsvRows(r.out);
  ASSERT_EQ(history_csv.size(), rows.size());
  EXPECT_EQ(rows[0], history_csv[0]);
  const std::vector<std::string>& header = rows[0];
  const size_t k0 = std::find(header.begin(), header.end(), "k0_deg_h") - header.begin();
  const size_t k0_sigma =
      std::find(header.begin(), header.end(), "k0_sigma_deg_h") - header.begin();
  ASSERT_LT(k0_sigma, header.size());
  // Every k0 and its sigma read back as the stored double (17 significant digits).
  for (size_t i = 0; i < count; ++i) {
    const Json& s = stored["snapshots"][i];
    double value = 0.0, sigma = 0.0;
    ASSERT_TRUE(absl::SimpleAtod(rows[i + 1][k0], &value)) << rows[i + 1][k0];
    ASSERT_TRUE(absl::SimpleAtod(rows[i + 1][k0_sigma], &sigma));
    EXPECT_EQ(value, KeyedDegH(s["model"], "k0")) << "row " << i + 1;
    EXPECT_EQ(sigma, KeyedDegH(s["sigma"], "k0")) << "row " << i + 1;
    EXPECT_EQ(std::stoi(rows[i + 1][1]), s["gyroId"].get<int>());
  }

  // JSON: the snapshots in the proto JSON mapping, on stdout without --out.
  r = Esg(dir, "export history --spacecraft RDK-1 --gyro 2 --format json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const Json doc = Json::parse(r.out);
  size_t gyro2 = 0;
  for (const Json& s : stored["snapshots"]) gyro2 += s["gyroId"] == 2;
  ASSERT_EQ(doc["snapshots"].size(), gyro2);
  EXPECT_EQ(doc["snapshots"][0]["gyroId"], 2);
}

TEST_F(ExportCli, BadArgumentsExitTwoNamingTheOptionAndRefusalsExitOne) {
  TempDir dir;
  RunResult r = Esg(dir, "export telemetry --spacecraft RDK-1");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--out"));
  r = Esg(dir, "export telemetry --spacecraft RDK-1 --from yesterday --out x.csv");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("esg export telemetry: --from: 'yesterday' is not an RFC 3339 time "
                               "such as 2019-03-01T00:00:00Z"));
  r = Esg(dir,
          "export telemetry --spacecraft RDK-1 --from 2019-03-01T02:00:00Z "
          "--to 2019-03-01T01:00:00Z --out x.csv");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--to '2019-03-01T01:00:00Z': is before --from"));
  r = Esg(dir, "export telemetry --spacecraft RDK-1 --out /nonexistent-dir/x.csv");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--out /nonexistent-dir/x.csv: cannot create"));
  r = Esg(dir, "export history --spacecraft RDK-1 --format table");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("esg export history: --format table: must be csv or json"));
  r = Esg(dir, "export history --spacecraft RDK-1 --gyro 7");
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("--gyro 7"));
  r = Esg(dir, "export");
  EXPECT_EQ(r.exit_code, 2);
  // The server's refusal: exit 1 with its code, no file left behind.
  const std::string out = dir.File("none.csv");
  r = Esg(dir, "export telemetry --spacecraft RDK-9 --out " + Quote(out));
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("esg export telemetry: NOT_FOUND: spacecraft_id: 'RDK-9'"));
  EXPECT_FALSE(std::ifstream(out).good());
  EXPECT_FALSE(std::ifstream(out + ".tmp").good());
  r = Esg(dir, "export history --spacecraft RDK-9");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("esg export history: NOT_FOUND: "));
  r = RunBinary(dir, ESG_BINARY, "--server 127.0.0.1:1 export history --spacecraft RDK-1");
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_THAT(r.err, HasSubstr("UNAVAILABLE: server not reachable at 127.0.0.1:1"));
}

}  // namespace
}  // namespace esg::client
