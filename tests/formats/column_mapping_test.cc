// Tests of formats/column_mapping (column mapping version 1, docs/formats.md "Column mapping"):
// a simulated recording exported as a user would (other column names and order, ';' between
// fields, spin axes as azimuth/elevation in degrees, voltages in volts, q_b_in scalar last, a
// text validity flag, Unix seconds) loads through a mapping file equal to 1e-12 to the project's
// own CSV of the same recording; the time formats convert exactly; and every wrong mapping or
// row is refused with an error naming the mapping field, or the CSV line and column.
#include "formats/column_mapping.h"

#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_replace.h"
#include "absl/time/time.h"
#include "estimator/rotation.h"
#include "estimator/simulator.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/paper_setup.h"
#include "tests/testing/run_process.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::StartsWith;

constexpr absl::StatusCode kInvalid = absl::StatusCode::kInvalidArgument;
constexpr double kPi = 3.14159265358979323846;

// The mapping of the user export written by UserExport().
constexpr char kUserMapping[] = R"({
  "format": "esg-column-mapping 1",
  "spacecraftId": "USER-1",
  "delimiter": ";",
  "time": {"column": "UNIX_TIME", "format": "since_epoch", "epoch": "1970-01-01T00:00:00Z", "unit": "s"},
  "gyros": [
    {"id": 1, "spinAxis": {"form": "azimuth_elevation", "columns": ["ESG1_AZ", "ESG1_EL"], "unit": "deg"},
     "voltages": {"columns": ["ESG1_UX", "ESG1_UY", "ESG1_UZ"], "unit": "V"}},
    {"id": 2, "spinAxis": {"form": "azimuth_elevation", "columns": ["ESG2_AZ", "ESG2_EL"], "unit": "deg"},
     "voltages": {"columns": ["ESG2_UX", "ESG2_UY", "ESG2_UZ"], "unit": "V"}},
    {"id": 3, "spinAxis": {"form": "azimuth_elevation", "columns": ["ESG3_AZ", "ESG3_EL"], "unit": "deg"},
     "voltages": {"columns": ["ESG3_UX", "ESG3_UY", "ESG3_UZ"], "unit": "V"}},
    {"id": 4, "spinAxis": {"columns": ["ESG4_H1", "ESG4_H2", "ESG4_H3"]},
     "voltages": {"columns": ["ESG4_UX", "ESG4_UY", "ESG4_UZ"], "unit": "mV"}}
  ],
  "starTracker": {"columns": ["STR_QX", "STR_QY", "STR_QZ", "STR_QW"], "scalar": "last",
                  "rotation": "q_b_in",
                  "valid": {"column": "STR_STATUS", "validValues": ["OK"], "invalidValues": ["BAD", "STALE"]}}
})";

std::string Num(double x) { return absl::StrFormat("%.17g", x); }

// Exact decimal seconds since the Unix epoch.
std::string UnixSeconds(absl::Time t) {
  const int64_t ns = absl::ToUnixNanos(t);
  return absl::StrFormat("%d.%09d", ns / 1000000000, ns % 1000000000);
}

// The recording as a user's export (kUserMapping): columns in another order, an extra column.
std::string UserExport(const estimator::Recording& recording) {
  std::vector<std::string> header = {"STR_STATUS", "STR_QX",    "STR_QY",       "STR_QZ",
                                     "STR_QW",     "UNIX_TIME", "TEMPERATURE_C"};
  for (int g = 1; g <= 3; ++g) {
    for (const char* s : {"AZ", "EL", "UX", "UY", "UZ"})
      header.push_back(absl::StrCat("ESG", g, "_", s));
  }
  for (const char* s : {"H1", "H2", "H3", "UX", "UY", "UZ"})
    header.push_back(absl::StrCat("ESG4_", s));
  std::string out = "# exported from the ground segment\n" + absl::StrJoin(header, ";") + "\n";
  for (const estimator::TelemetryFrame& frame : recording.frames) {
    std::vector<std::string> f;
    if (!frame.star_tracker.has_value()) {
      f = {"", "", "", "", ""};
    } else if (!frame.star_tracker->valid) {
      f = {"STALE", "", "", "", ""};
    } else {
      const estimator::ScalarFirst q = estimator::ToScalarFirst(frame.star_tracker->q_in_b);
      // q_b_in = conj(q_in_b), scalar last.
      f = {"OK", Num(-q[1]), Num(-q[2]), Num(-q[3]), Num(q[0])};
    }
    f.push_back(UnixSeconds(frame.time));
    f.push_back("21.5");
    for (int g = 0; g < 4; ++g) {
      const std::optional<estimator::GyroReading>& r = frame.gyros[g];
      const bool u = r.has_value() && r->u_k_mv.has_value();
      if (g < 3) {
        if (r.has_value()) {
          const Eigen::Vector3d& h = r->h_k;
          f.push_back(Num(std::atan2(h.y(), h.x()) * 180.0 / kPi));
          f.push_back(Num(std::atan2(h.z(), std::hypot(h.x(), h.y())) * 180.0 / kPi));
        } else {
          f.insert(f.end(), {"", ""});
        }
        for (int k = 0; k < 3; ++k) f.push_back(u ? Num((*r->u_k_mv)[k] / 1000.0) : "");
      } else {
        for (int k = 0; k < 3; ++k) f.push_back(r.has_value() ? Num(r->h_k[k]) : "");
        for (int k = 0; k < 3; ++k) f.push_back(u ? Num((*r->u_k_mv)[k]) : "");
      }
    }
    absl::StrAppend(&out, absl::StrJoin(f, ";"), "\n");
  }
  return out;
}

// A short paper flight with every case of a row: invalid and absent star-tracker readings, a
// gyro without voltages, gyro 4 off for a while.
estimator::Recording SimulatedRecording() {
  estimator::SimulationSpec spec = testing::PaperFlight(/*seed=*/7, /*hours=*/1.0);
  absl::StatusOr<estimator::SimulationResult> sim = estimator::Simulate(spec);
  EXPECT_THAT(sim.status(), IsOk());
  estimator::Recording r = sim->recording;
  EXPECT_GE(r.frames.size(), 50u);
  r.frames[5].star_tracker->valid = false;
  for (int i = 10; i < 13; ++i) r.frames[i].star_tracker.reset();
  r.frames[20].gyros[1]->u_k_mv.reset();
  for (int i = 30; i < 40; ++i) r.frames[i].gyros[3].reset();
  return r;
}

void ExpectNear(const Eigen::Vector3d& a, const Eigen::Vector3d& b, double tol,
                const std::string& what) {
  for (int k = 0; k < 3; ++k) EXPECT_NEAR(a[k], b[k], tol) << what << "[" << k << "]";
}

TEST(ColumnMapping, UserExportLoadsEqualToTheProjectCsvOfTheSameRecording) {
  testing::TempDir dir;
  const estimator::Recording simulated = SimulatedRecording();
  // The project's own CSV, through a real file.
  ASSERT_THAT(WriteRecordingCsv(dir.File("own.csv"), simulated), IsOk());
  absl::StatusOr<estimator::Recording> own = ReadRecordingCsv(dir.File("own.csv"));
  ASSERT_THAT(own.status(), IsOk());
  // The user's export and its mapping, through real files.
  testing::WriteFile(dir.File("user.csv"), UserExport(simulated));
  testing::WriteFile(dir.File("columns.json"), kUserMapping);
  absl::StatusOr<estimator::Recording> user =
      ReadRecording(dir.File("user.csv"), dir.File("columns.json"));
  ASSERT_THAT(user.status(), IsOk());

  EXPECT_EQ(user->metadata.at("spacecraft_id"), "USER-1");
  ASSERT_EQ(user->frames.size(), own->frames.size());
  constexpr double kTol = 1e-12;
  double max_h = 0.0, max_u = 0.0, max_q = 0.0;  // largest differences, recorded below
  int quaternions = 0, voltages = 0;
  for (size_t i = 0; i < own->frames.size(); ++i) {
    const estimator::TelemetryFrame& a = own->frames[i];
    const estimator::TelemetryFrame& b = user->frames[i];
    const std::string at = absl::StrCat("frame ", i);
    EXPECT_EQ(a.time, b.time) << at;
    for (int g = 0; g < 4; ++g) {
      ASSERT_EQ(a.gyros[g].has_value(), b.gyros[g].has_value()) << at << " gyro " << g + 1;
      if (!a.gyros[g].has_value()) continue;
      ExpectNear(a.gyros[g]->h_k, b.gyros[g]->h_k, kTol, at + " h_k");
      max_h = std::max(max_h, (a.gyros[g]->h_k - b.gyros[g]->h_k).lpNorm<Eigen::Infinity>());
      ASSERT_EQ(a.gyros[g]->u_k_mv.has_value(), b.gyros[g]->u_k_mv.has_value()) << at;
      if (a.gyros[g]->u_k_mv.has_value()) {
        ExpectNear(*a.gyros[g]->u_k_mv, *b.gyros[g]->u_k_mv, kTol, at + " u_k_mv");
        max_u =
            std::max(max_u, (*a.gyros[g]->u_k_mv - *b.gyros[g]->u_k_mv).lpNorm<Eigen::Infinity>());
        ++voltages;
      }
    }
    ASSERT_EQ(a.star_tracker.has_value(), b.star_tracker.has_value()) << at;
    if (!a.star_tracker.has_value()) continue;
    ASSERT_EQ(a.star_tracker->valid, b.star_tracker->valid) << at;
    if (!a.star_tracker->valid) continue;
    const estimator::ScalarFirst qa = estimator::ToScalarFirst(a.star_tracker->q_in_b);
    const estimator::ScalarFirst qb = estimator::ToScalarFirst(b.star_tracker->q_in_b);
    for (int k = 0; k < 4; ++k) {
      EXPECT_NEAR(qa[k], qb[k], kTol) << at << " q_in_b[" << k << "]";
      max_q = std::max(max_q, std::abs(qa[k] - qb[k]));
    }
    ++quaternions;
  }
  RecordProperty("max_abs_diff_h", absl::StrFormat("%.3g", max_h));
  RecordProperty("max_abs_diff_u_mv", absl::StrFormat("%.3g", max_u));
  RecordProperty("max_abs_diff_q", absl::StrFormat("%.3g", max_q));
  EXPECT_GT(quaternions, 40);
  EXPECT_GT(voltages, 100);
  EXPECT_FALSE(user->frames[5].star_tracker->valid);
  EXPECT_FALSE(user->frames[11].star_tracker.has_value());
  EXPECT_FALSE(user->frames[20].gyros[1]->u_k_mv.has_value());
  EXPECT_FALSE(user->frames[35].gyros[3].has_value());
}

// A small mapping and CSV for the time and error cases; `replace` edits the mapping.
constexpr char kSmallMapping[] = R"({
  "time": {"column": "t", "format": "rfc3339"},
  "gyros": [{"id": 2, "spinAxis": {"columns": ["h1", "h2", "h3"]}}],
  "starTracker": {"columns": ["qw", "qx", "qy", "qz"], "scalar": "first", "rotation": "q_in_b"}
})";
constexpr char kSmallCsv[] =
    "t,h1,h2,h3,qw,qx,qy,qz\n"
    "2019-03-01T00:00:00Z,0.6,0.8,0,1,0,0,0\n"
    "2019-03-01T00:01:00Z,0.6,0.8,0,0.9238795325112867,0,0,0.3826834323650898\n";

absl::StatusOr<ColumnMapping> Mapping(const std::string& from = "", const std::string& to = "") {
  std::string text = kSmallMapping;
  if (!from.empty()) {
    const std::string edited = absl::StrReplaceAll(text, {{from, to}});
    EXPECT_NE(edited, text) << "the test's edit '" << from << "' matches nothing";
    text = edited;
  }
  return ParseColumnMapping(text);
}

TEST(ColumnMapping, SmallMappingReadsQuaternionAndSpinAxisAsGiven) {
  absl::StatusOr<ColumnMapping> m = Mapping();
  ASSERT_THAT(m.status(), IsOk());
  absl::StatusOr<estimator::Recording> r = ParseMappedRecordingCsv(kSmallCsv, *m);
  ASSERT_THAT(r.status(), IsOk());
  ASSERT_EQ(r->frames.size(), 2u);
  EXPECT_FALSE(r->frames[0].gyros[0].has_value());  // gyro 1 not mapped: off
  ASSERT_TRUE(r->frames[1].gyros[1].has_value());
  EXPECT_EQ(r->frames[1].gyros[1]->h_k, Eigen::Vector3d(0.6, 0.8, 0));
  EXPECT_FALSE(r->frames[1].gyros[1]->u_k_mv.has_value());
  ASSERT_TRUE(r->frames[1].star_tracker.has_value());
  EXPECT_TRUE(r->frames[1].star_tracker->valid);
  // The pinning example of docs/conventions.md: +90 deg about z maps body x to inertial y.
  // Here 45 deg: body x to (cos 45, sin 45, 0).
  const Eigen::Vector3d x_in = r->frames[1].star_tracker->q_in_b * Eigen::Vector3d::UnitX();
  EXPECT_NEAR(x_in.y(), std::sqrt(0.5), 1e-15);
  EXPECT_TRUE(r->metadata.empty());
}

TEST(ColumnMapping, InverseScalarLastIsTheConjugate) {
  absl::StatusOr<ColumnMapping> m = Mapping(R"("scalar": "first", "rotation": "q_in_b")",
                                            R"("scalar": "last", "rotation": "q_b_in")");
  ASSERT_THAT(m.status(), IsOk());
  // Columns in file order qw,qx,qy,qz now hold x, y, z, w of q_b_in.
  const std::string csv =
      "t,h1,h2,h3,qw,qx,qy,qz\n"
      "2019-03-01T00:00:00Z,0.6,0.8,0,0,0,-0.3826834323650898,0.9238795325112867\n";
  absl::StatusOr<estimator::Recording> r = ParseMappedRecordingCsv(csv, *m);
  ASSERT_THAT(r.status(), IsOk());
  const estimator::ScalarFirst q = estimator::ToScalarFirst(r->frames[0].star_tracker->q_in_b);
  EXPECT_EQ(q[0], 0.9238795325112867);
  EXPECT_EQ(q[3], 0.3826834323650898);
}

TEST(ColumnMapping, TimeFormatsConvertExactly) {
  // Milliseconds since an epoch, with a fraction: exact to the nanosecond.
  absl::StatusOr<ColumnMapping> m = Mapping(
      R"({"column": "t", "format": "rfc3339"})",
      R"({"column": "t", "format": "since_epoch", "epoch": "2019-03-01T00:00:00Z", "unit": "ms"})");
  ASSERT_THAT(m.status(), IsOk());
  absl::StatusOr<estimator::Recording> r = ParseMappedRecordingCsv(
      "t,h1,h2,h3,qw,qx,qy,qz\n0,0,0,1,,,,\n60000.000125,0,0,1,,,,\n1.2e5,0,0,1,,,,\n", *m);
  ASSERT_THAT(r.status(), IsOk());
  const absl::Time start =
      absl::FromCivil(absl::CivilSecond(2019, 3, 1, 0, 0, 0), absl::UTCTimeZone());
  EXPECT_EQ(r->frames[0].time, start);
  EXPECT_EQ(r->frames[1].time, start + absl::Seconds(60) + absl::Nanoseconds(125));
  EXPECT_EQ(r->frames[2].time, start + absl::Seconds(120));
  EXPECT_FALSE(r->frames[0].star_tracker.has_value());  // all empty: outage

  // GPS week 2042 began 2019-02-24; day 5 at 00:00:00 GPS is 2019-02-28T23:59:42Z (GPS - UTC = 18
  // s).
  m = Mapping(
      R"({"column": "t", "format": "rfc3339"})",
      R"({"format": "gps_week_seconds", "weekColumn": "wk", "secondsColumn": "sow", "gpsMinusUtcS": 18})");
  ASSERT_THAT(m.status(), IsOk());
  r = ParseMappedRecordingCsv("wk,sow,h1,h2,h3,qw,qx,qy,qz\n2042,432000,0,0,1,,,,\n", *m);
  ASSERT_THAT(r.status(), IsOk());
  EXPECT_EQ(r->frames[0].time, start - absl::Seconds(18));
}

// The mapping's own errors: each names its field.
TEST(ColumnMapping, WrongMappingsNameTheField) {
  struct Case {
    std::string from, to, message;
  };
  const std::vector<Case> cases = {
      {R"("format": "rfc3339")",
       R"("format": "since_epoch", "epoch": "2019-03-01T00:00:00Z", "unit": "h")",
       "time.unit: 'h' is not a known unit (s, ms, us)"},
      {R"("format": "rfc3339")", R"("format": "since_epoch", "unit": "s")", "time.epoch: required"},
      {R"("format": "rfc3339")", R"("format": "unix")", "time.format: 'unix' is not rfc3339"},
      {R"("format": "rfc3339")", R"("format": "gps_week_seconds")",
       "time.column: not used with format gps_week_seconds"},
      {R"("columns": ["h1", "h2", "h3"]})",
       R"("columns": ["h1", "h2", "h3"]}, "voltages": {"columns": ["a", "b", "c"], "unit": "kV"})",
       "gyros[0].voltages.unit: 'kV' is not a known unit (V, mV, uV)"},
      {R"("columns": ["h1", "h2", "h3"]})",
       R"("form": "azimuth_elevation", "columns": ["az", "el"], "unit": "grad"})",
       "gyros[0].spinAxis.unit: 'grad' is not a known unit (rad, deg, arcmin, arcsec)"},
      {R"("columns": ["h1", "h2", "h3"]})", R"("columns": ["h1", "h2", "h3"], "unit": "deg"})",
       "gyros[0].spinAxis.unit: direction cosines have no unit"},
      {R"("columns": ["h1", "h2", "h3"]})", R"("columns": ["h1", "h2"]})",
       "gyros[0].spinAxis.columns: must be an array of 3 column names"},
      {R"("id": 2)", R"("id": 5)", "gyros[0].id: must be a gyro id 1..4, got 5"},
      {R"("scalar": "first")", R"("scalar": "front")",
       "starTracker.scalar: 'front' is not first or last"},
      {R"("scalar": "first")", R"("scalarPosition": "first")",
       "starTracker.scalarPosition: unknown field"},
      {R"("rotation": "q_in_b")", R"("rotation": "body_to_inertial")",
       "starTracker.rotation: 'body_to_inertial' is not q_in_b"},
      {R"(, "rotation": "q_in_b")", "", "starTracker.rotation: required"},
      {R"(["qw", "qx", "qy", "qz"])", R"(["qw", "qx", "qy", "h1"])",
       "starTracker.columns[3]: column 'h1' is already mapped by gyros[0].spinAxis.columns[0]"},
      {R"("rotation": "q_in_b")",
       R"("rotation": "q_in_b", "valid": {"column": "v", "validValues": ["1"], "invalidValues": ["1"]})",
       "starTracker.valid.invalidValues: '1' is also in validValues"},
      {R"("time")", R"("times")", "times: unknown field"},
  };
  for (const Case& c : cases) {
    EXPECT_THAT(Mapping(c.from, c.to).status(), StatusIs(kInvalid, HasSubstr(c.message))) << c.to;
  }
  EXPECT_THAT(ParseColumnMapping("{\"time\": ").status(),
              StatusIs(kInvalid, HasSubstr("mapping: not valid JSON")));
  EXPECT_THAT(ParseColumnMapping(R"({"format": "esg-column-mapping 2"})").status(),
              StatusIs(kInvalid, HasSubstr("format: 'esg-column-mapping 2' is not supported")));
}

// nlohmann-json alone keeps the last value of a repeated key (docs/formats.md, "Rules and
// errors"): the mapping reader refuses it with the key's path.
TEST(ColumnMapping, RepeatedKeyIsRefusedWithItsPath) {
  EXPECT_THAT(Mapping(R"("scalar": "first")", R"("scalar": "first", "scalar": "last")").status(),
              StatusIs(kInvalid, StartsWith("starTracker.scalar: duplicate key")));
  EXPECT_THAT(Mapping(R"("format": "rfc3339")", R"("format": "rfc3339", "column": "t")").status(),
              StatusIs(kInvalid, StartsWith("time.column: duplicate key")));
}

// Rows that do not fit the mapping: each names the line, the CSV column and the mapping field.
TEST(ColumnMapping, WrongRowsNameLineColumnAndField) {
  absl::StatusOr<ColumnMapping> m = Mapping();
  ASSERT_THAT(m.status(), IsOk());
  struct Case {
    std::string csv, message;
  };
  const std::vector<Case> cases = {
      {"t,h1,h2,h3,qw,qx,qy\n2019-03-01T00:00:00Z,0,0,1,1,0,0\n",
       "line 1: the header has no column 'qz' (named by the mapping's starTracker.columns[3])"},
      {"t;h1;h2;h3;qw;qx;qy;qz\n", "the header is one field: is the delimiter ',' right?"},
      // A quaternion not of unit length after conversion (here twice the unit one).
      {"t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01T00:00:00Z,0,0,1,2,0,0,0\n",
       "line 2, column qw,qx,qy,qz (starTracker.columns): the quaternion after conversion to "
       "q_in_b has norm 2, not 1 (tolerance 0.001)"},
      {"t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01T00:00:00Z,0,0.5,0.5,1,0,0,0\n",
       "line 2, column h1,h2,h3 (gyros[0].spinAxis): the spin axis has norm 0.707107"},
      {"t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01T00:00:00Z,0,,1,1,0,0,0\n",
       "line 2, column h2 (gyros[0].spinAxis): empty while the rest of gyros[0].spinAxis has "
       "values"},
      {"t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01 00:00,0,0,1,1,0,0,0\n",
       "line 2, column t (time.column): '2019-03-01 00:00' is not an RFC 3339 time"},
      {"t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01T00:01:00Z,0,0,1,1,0,0,0\n2019-03-01T00:00:00Z,0,0,1,1,0,"
       "0,0\n",
       "line 3, column t (time.column): 2019-03-01T00:00:00.000Z is not after 2019-03-01T00:01:00.000Z "
       "of "
       "line 2"},
      {"t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01T00:00:00Z,0,0,one,1,0,0,0\n",
       "line 2, column h3 (gyros[0].spinAxis.columns[2]): 'one' is not a finite number"},
      {"t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01T00:00:00Z,0,0,1,1,0,0\n",
       "line 2: expected 8 fields as in the header (line 1), got 7"},
  };
  for (const Case& c : cases) {
    EXPECT_THAT(ParseMappedRecordingCsv(c.csv, *m).status(),
                StatusIs(kInvalid, HasSubstr(c.message)))
        << c.csv;
  }
  // A validity flag outside both lists.
  m = Mapping(
      R"("rotation": "q_in_b")",
      R"("rotation": "q_in_b", "valid": {"column": "ok", "validValues": ["Y"], "invalidValues": ["N"]})");
  ASSERT_THAT(m.status(), IsOk());
  EXPECT_THAT(ParseMappedRecordingCsv(
                  "t,h1,h2,h3,qw,qx,qy,qz,ok\n2019-03-01T00:00:00Z,0,0,1,1,0,0,0,1\n", *m)
                  .status(),
              StatusIs(kInvalid, HasSubstr("line 2, column ok (starTracker.valid.column): '1' is "
                                           "neither valid (Y) nor invalid (N)")));
  absl::StatusOr<estimator::Recording> r =
      ParseMappedRecordingCsv("t,h1,h2,h3,qw,qx,qy,qz,ok\n2019-03-01T00:00:00Z,0,0,1,,,,,N\n", *m);
  ASSERT_THAT(r.status(), IsOk());
  ASSERT_TRUE(r->frames[0].star_tracker.has_value());
  EXPECT_FALSE(r->frames[0].star_tracker->valid);
}

// Exports from spreadsheets: a UTF-8 byte order mark, quoted names and numbers (RFC 4180, with
// the delimiter and "" inside quotes), and times written "2019-03-01 00:01:00.5" read with a
// pattern.
TEST(ColumnMapping, ByteOrderMarkQuotesAndPatternTimes) {
  absl::StatusOr<ColumnMapping> m =
      Mapping(R"({"column": "t", "format": "rfc3339"})",
              R"({"column": "t", "format": "pattern", "pattern": "%Y-%m-%d %H:%M:%E*S"})");
  ASSERT_THAT(m.status(), IsOk());
  const std::string csv =
      "\xEF\xBB\xBF\"t\",\"h1\",h2,h3,qw,qx,qy,qz,\"note, free\"\n"
      "2019-03-01 00:01:00.5,\"0.6\", \"0.8\" ,0,1,0,0,0,\"said \"\"ok\"\", then left\"\n";
  absl::StatusOr<estimator::Recording> r = ParseMappedRecordingCsv(csv, *m);
  ASSERT_THAT(r.status(), IsOk());
  ASSERT_EQ(r->frames.size(), 1u);
  EXPECT_EQ(r->frames[0].time,
            absl::FromCivil(absl::CivilSecond(2019, 3, 1, 0, 1, 0), absl::UTCTimeZone()) +
                absl::Milliseconds(500));
  EXPECT_EQ(r->frames[0].gyros[1]->h_k, Eigen::Vector3d(0.6, 0.8, 0));

  EXPECT_THAT(
      ParseMappedRecordingCsv("t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01T00:01:00Z,0,0,1,1,0,0,0\n", *m)
          .status(),
      StatusIs(kInvalid, HasSubstr("line 2, column t (time.column): '2019-03-01T00:01:00Z' "
                                   "does not match time.pattern '%Y-%m-%d %H:%M:%E*S'")));
  EXPECT_THAT(
      ParseMappedRecordingCsv("t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01 00:01:00,\"0,0,1,1,0,0,0\n", *m)
          .status(),
      StatusIs(kInvalid, HasSubstr("line 2: field 2: the quote at character 21 is not closed")));
  EXPECT_THAT(ParseMappedRecordingCsv(
                  "t,h1,h2,h3,qw,qx,qy,qz\n2019-03-01 00:01:00,\"0\"x,0,1,1,0,0,0\n", *m)
                  .status(),
              StatusIs(kInvalid, HasSubstr("line 2: field 2: text after its closing quote")));
  // A pattern that loses the date (or anything down to the second) is refused.
  EXPECT_THAT(Mapping(R"({"column": "t", "format": "rfc3339"})",
                      R"({"column": "t", "format": "pattern", "pattern": "%H:%M:%S"})")
                  .status(),
              StatusIs(kInvalid, HasSubstr("time.pattern: '%H:%M:%S' does not determine a date and "
                                           "time to the second")));
  EXPECT_THAT(Mapping(R"({"column": "t", "format": "rfc3339"})",
                      R"({"column": "t", "format": "pattern", "pattern": "%Y-%m-%d %H:%M"})")
                  .status(),
              StatusIs(kInvalid, HasSubstr("time.pattern: '%Y-%m-%d %H:%M' does not determine")));
}

TEST(ColumnMapping, FilesThatCannotBeOpenedAreNamed) {
  testing::TempDir dir;
  EXPECT_THAT(
      ReadRecording(dir.File("rec.csv"), dir.File("none.json")).status(),
      StatusIs(absl::StatusCode::kNotFound, HasSubstr("column mapping " + dir.File("none.json"))));
  testing::WriteFile(dir.File("columns.json"), R"({"time": {"format": "rfc3339"}})");
  EXPECT_THAT(ReadRecording(dir.File("rec.csv"), dir.File("columns.json")).status(),
              StatusIs(kInvalid, AllOf(HasSubstr(dir.File("columns.json")),
                                       HasSubstr("time.column: required"))));
}

// Channels (docs/formats.md "Channels"): a mapped column per channel, an empty cell a frame
// without it.
TEST(ColumnMapping, ChannelColumnsAreReadEmptyCellsMissing) {
  absl::StatusOr<ColumnMapping> m = Mapping(
      R"("rotation": "q_in_b"})",
      R"("rotation": "q_in_b"}, "channels": [{"name": "T_gyro2", "column": "TEMP G2"},
                                             {"name": "heater_1", "column": "HTR1"}])");
  ASSERT_THAT(m.status(), IsOk());
  ASSERT_EQ(m->channels.size(), 2u);
  const std::string csv =
      "t,h1,h2,h3,qw,qx,qy,qz,TEMP G2,HTR1\n"
      "2019-03-01T00:00:00Z,0.6,0.8,0,1,0,0,0,301.5,1\n"
      "2019-03-01T00:01:00Z,0.6,0.8,0,1,0,0,0,,0\n";
  absl::StatusOr<estimator::Recording> r = ParseMappedRecordingCsv(csv, *m);
  ASSERT_THAT(r.status(), IsOk());
  ASSERT_EQ(r->frames.size(), 2u);
  ASSERT_EQ(r->frames[0].channels.size(), 2);
  EXPECT_EQ(*r->frames[0].channels.Find("T_gyro2"), 301.5);
  EXPECT_EQ(*r->frames[0].channels.Find("heater_1"), 1.0);
  EXPECT_EQ(r->frames[1].channels.Find("T_gyro2"), nullptr);
  EXPECT_EQ(*r->frames[1].channels.Find("heater_1"), 0.0);

  const std::string bad =
      "t,h1,h2,h3,qw,qx,qy,qz,TEMP G2,HTR1\n"
      "2019-03-01T00:00:00Z,0.6,0.8,0,1,0,0,0,inf,1\n";
  EXPECT_THAT(ParseMappedRecordingCsv(bad, *m),
              StatusIs(kInvalid, HasSubstr("line 2, column TEMP G2 (channels[0].column): 'inf' is "
                                           "not a finite number")));
  EXPECT_THAT(ParseMappedRecordingCsv(kSmallCsv, *m),
              StatusIs(kInvalid, HasSubstr("the header has no column 'TEMP G2' (named by the "
                                           "mapping's channels[0].column)")));
}

TEST(ColumnMapping, WrongChannelMappingsNameTheField) {
  auto with = [](const std::string& channels) {
    return Mapping(R"("rotation": "q_in_b"})",
                   absl::StrCat(R"("rotation": "q_in_b"}, "channels": )", channels));
  };
  EXPECT_THAT(with(R"([{"name": "T g", "column": "a"}])").status(),
              StatusIs(kInvalid, HasSubstr("channels[0].name: character ' ' at index 1")));
  EXPECT_THAT(with(R"([{"name": "T", "column": "a"}, {"name": "T", "column": "b"}])").status(),
              StatusIs(kInvalid, HasSubstr("channels[1].name: channel 'T' is mapped twice")));
  EXPECT_THAT(with(R"([{"name": "T"}])").status(),
              StatusIs(kInvalid, HasSubstr("channels[0].column: required")));
  EXPECT_THAT(with(R"([{"name": "T", "column": "h1"}])").status(),
              StatusIs(kInvalid, HasSubstr("channels[0].column: column 'h1' is already mapped by "
                                           "gyros[0].spinAxis.columns[0]")));
  EXPECT_THAT(with(R"([{"name": "T", "column": "a", "unit": "K"}])").status(),
              StatusIs(kInvalid, HasSubstr("channels[0].unit: unknown field")));
  EXPECT_THAT(with(R"({"name": "T"})").status(),
              StatusIs(kInvalid, HasSubstr("channels: must be an array")));
}

}  // namespace
}  // namespace esg::storage
