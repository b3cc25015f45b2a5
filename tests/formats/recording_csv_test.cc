// Tests of formats/recording_csv (recording CSV version 1, docs/formats.md): bit-exact write/read
// round trip through a real file, absent gyros and star-tracker outages, free column order and
// extra columns, and one test per malformed input asserting line, column and reason.
#include "formats/recording_csv.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <functional>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/time/time.h"
#include "estimator/channels.h"
#include "estimator/rotation.h"
#include "estimator/utc_time.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::storage {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::Not;

constexpr absl::StatusCode kInvalid = absl::StatusCode::kInvalidArgument;

Eigen::Vector3d RandomUnit(std::mt19937_64& rng) {
  std::normal_distribution<double> normal(0.0, 1.0);
  return Eigen::Vector3d(normal(rng), normal(rng), normal(rng)).normalized();
}

// A recording with awkward values: sub-second times down to 1/4 ns, random unit vectors, voltages
// with full 17-digit mantissas, a gyro switched off, outages and invalid star-tracker readings.
estimator::Recording RandomRecording(int num_frames, uint64_t seed) {
  std::mt19937_64 rng(seed);
  std::normal_distribution<double> normal(0.0, 1.0);
  std::uniform_int_distribution<int64_t> jitter_ns(0, 999999999);
  estimator::Recording r;
  r.metadata["spacecraft_id"] = "RDK-1";
  r.metadata["source"] = "simulator seed 7";
  absl::Time t = absl::FromUnixSeconds(1551398400) + absl::Nanoseconds(1) / 4;
  for (int i = 0; i < num_frames; ++i) {
    estimator::TelemetryFrame f;
    f.time = t;
    t += absl::Seconds(60) + absl::Nanoseconds(jitter_ns(rng));
    for (int g = 0; g < estimator::kMaxGyros; ++g) {
      if (g == 3 || (g == 1 && i % 5 == 2)) continue;  // gyro 4 cold spare, gyro 2 drops out
      estimator::GyroReading reading;
      reading.h_k = RandomUnit(rng);
      if (g != 2) reading.u_k_mv = 40.0 * Eigen::Vector3d(normal(rng), normal(rng), normal(rng));
      f.gyros[g] = reading;
    }
    if (i % 7 != 3) {
      estimator::StarTrackerReading st;
      st.valid = i % 11 != 5;
      if (st.valid) {
        st.q_in_b = Eigen::Quaterniond(normal(rng), normal(rng), normal(rng), normal(rng)).normalized();
      }
      f.star_tracker = st;
    }
    r.frames.push_back(f);
  }
  return r;
}

void ExpectRecordingsIdentical(const estimator::Recording& a, const estimator::Recording& b) {
  ASSERT_EQ(a.frames.size(), b.frames.size());
  for (size_t i = 0; i < a.frames.size(); ++i) {
    const estimator::TelemetryFrame& fa = a.frames[i];
    const estimator::TelemetryFrame& fb = b.frames[i];
    SCOPED_TRACE(absl::StrCat("frame ", i));
    EXPECT_EQ(fa.time, fb.time) << absl::FormatTime(fa.time) << " vs " << absl::FormatTime(fb.time);
    for (int g = 0; g < estimator::kMaxGyros; ++g) {
      ASSERT_EQ(fa.gyros[g].has_value(), fb.gyros[g].has_value()) << "gyro " << g + 1;
      if (!fa.gyros[g].has_value()) continue;
      for (int k = 0; k < 3; ++k) {
        EXPECT_EQ(fa.gyros[g]->h_k[k], fb.gyros[g]->h_k[k]) << "gyro " << g + 1;  // bit-exact
      }
      ASSERT_EQ(fa.gyros[g]->u_k_mv.has_value(), fb.gyros[g]->u_k_mv.has_value());
      if (fa.gyros[g]->u_k_mv.has_value()) {
        for (int k = 0; k < 3; ++k) EXPECT_EQ((*fa.gyros[g]->u_k_mv)[k], (*fb.gyros[g]->u_k_mv)[k]);
      }
    }
    ASSERT_EQ(fa.star_tracker.has_value(), fb.star_tracker.has_value());
    if (!fa.star_tracker.has_value()) continue;
    EXPECT_EQ(fa.star_tracker->valid, fb.star_tracker->valid);
    if (fa.star_tracker->valid) {
      EXPECT_EQ(estimator::ToScalarFirst(fa.star_tracker->q_in_b),
                estimator::ToScalarFirst(fb.star_tracker->q_in_b));
    }
  }
}

std::string WriteText(const esg::testing::TempDir& dir, const std::string& name,
                      const std::string& text) {
  const std::string path = dir.File(name);
  std::ofstream(path, std::ios::binary) << text;
  return path;
}

// A small valid file: line 1 format, line 2 spacecraft_id, line 3 header, lines 4.. data rows.
std::string ValidCsv(int num_frames = 3) {
  estimator::Recording r = RandomRecording(num_frames, 11);
  r.metadata.erase("source");
  return FormatRecordingCsv(r);
}

// Replaces the field of `column` on 1-based line `line` (header located by its "time_utc" column).
std::string WithField(const std::string& csv, int line, const std::string& column,
                      const std::string& value) {
  std::vector<std::string> lines = absl::StrSplit(csv, '\n');
  int column_index = -1;
  for (const std::string& l : lines) {
    if (!absl::StartsWith(l, "time_utc")) continue;
    const std::vector<std::string> names = absl::StrSplit(l, ',');
    for (size_t i = 0; i < names.size(); ++i) {
      if (names[i] == column) column_index = static_cast<int>(i);
    }
  }
  EXPECT_GE(column_index, 0) << "test bug: no column " << column;
  std::vector<std::string> fields = absl::StrSplit(lines[line - 1], ',');
  fields[column_index] = value;
  lines[line - 1] = absl::StrJoin(fields, ",");
  return absl::StrJoin(lines, "\n");
}

TEST(RecordingCsv, WriteReadRoundTripIsBitExact) {
  esg::testing::TempDir dir;
  const std::string path = dir.File("rec.csv");
  const estimator::Recording original = RandomRecording(200, 20190301);
  ASSERT_THAT(WriteRecordingCsv(path, original), IsOk());
  absl::StatusOr<estimator::Recording> read = ReadRecordingCsv(path);
  ASSERT_THAT(read, IsOk());
  ExpectRecordingsIdentical(original, *read);
  EXPECT_EQ(read->metadata.at("spacecraft_id"), "RDK-1");
  EXPECT_EQ(read->metadata.at("source"), "simulator seed 7");
  EXPECT_EQ(read->metadata.at("format"), kRecordingCsvFormat);
  // Writing what was read gives the same bytes.
  EXPECT_EQ(FormatRecordingCsv(*read), FormatRecordingCsv(original));
}

TEST(RecordingCsv, FileStartsWithFormatAndSpacecraftThenDesignHeader) {
  const std::string csv = ValidCsv(1);
  const std::vector<std::string> lines = absl::StrSplit(csv, '\n');
  ASSERT_GE(lines.size(), 4u);
  EXPECT_EQ(lines[0], "# format: esg-recording-csv 1");
  EXPECT_EQ(lines[1], "# spacecraft_id: RDK-1");
  EXPECT_THAT(lines[2], AllOf(::testing::StartsWith("time_utc,g1_hx,g1_hy,g1_hz,g1_ux,g1_uy,g1_uz,"
                                                    "g2_hx"),
                              ::testing::EndsWith("g4_uz,st_q0,st_q1,st_q2,st_q3,st_valid")));
  EXPECT_THAT(lines[3], ::testing::StartsWith("2019-03-01T00:00:00.00000000025Z,"));
}

TEST(RecordingCsv, GyroOffAndStarTrackerOutageRoundTrip) {
  estimator::Recording r;
  estimator::TelemetryFrame f;
  f.time = absl::FromUnixSeconds(1551398400);
  estimator::GyroReading g;
  g.h_k = Eigen::Vector3d(0.6, 0.0, 0.8);
  f.gyros[1] = g;  // only gyro 2 on, without voltages; star tracker in outage
  r.frames.push_back(f);
  f.time += absl::Seconds(60);
  f.star_tracker = estimator::StarTrackerReading{};  // present but invalid
  r.frames.push_back(f);

  const std::string csv = FormatRecordingCsv(r);
  EXPECT_THAT(csv, HasSubstr("2019-03-01T00:00:00Z,,,,,,,0.6,0,0.8,,,,,,,,,,,,,,,,,,,,\n"));
  EXPECT_THAT(csv, HasSubstr("2019-03-01T00:01:00Z,,,,,,,0.6,0,0.8,,,,,,,,,,,,,,,,,,,,0\n"));
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(csv);
  ASSERT_THAT(read, IsOk());
  ASSERT_EQ(read->frames.size(), 2u);
  EXPECT_FALSE(read->frames[0].gyros[0].has_value());
  ASSERT_TRUE(read->frames[0].gyros[1].has_value());
  EXPECT_FALSE(read->frames[0].gyros[1]->u_k_mv.has_value());
  EXPECT_FALSE(read->frames[0].star_tracker.has_value());
  ASSERT_TRUE(read->frames[1].star_tracker.has_value());
  EXPECT_FALSE(read->frames[1].star_tracker->valid);
  ExpectRecordingsIdentical(r, *read);
}

TEST(RecordingCsv, InvalidStarTrackerMayCarryAQuaternionThatIsNotKept) {
  const std::string csv = WithField(WithField(ValidCsv(), 4, "st_valid", "0"), 4, "st_q0", "7");
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(csv);
  ASSERT_THAT(read, IsOk());
  ASSERT_TRUE(read->frames[0].star_tracker.has_value());
  EXPECT_FALSE(read->frames[0].star_tracker->valid);
}

// The lines are read as the column-mapping reader reads them (formats/csv_lines.h): a UTF-8 byte
// order mark (a spreadsheet's export) is dropped, CRLF line ends and blank lines change nothing,
// and a problem's line number counts every line of the file.
TEST(RecordingCsv, ByteOrderMarkCrLfAndBlankLinesAreReadAsTheMappedReaderReadsThem) {
  const std::string csv = ValidCsv();
  std::string dos;
  for (char c : csv) {
    if (c == '\n') dos += "\r\n\r\n";
    else dos += c;
  }
  absl::StatusOr<estimator::Recording> plain = ParseRecordingCsv(csv);
  absl::StatusOr<estimator::Recording> bom = ParseRecordingCsv("\xEF\xBB\xBF" + dos);
  ASSERT_THAT(plain, IsOk());
  ASSERT_THAT(bom, IsOk());
  ExpectRecordingsIdentical(*plain, *bom);
  // Line numbers count the blank lines: the 4th line of `csv` is the 7th of `dos`.
  const std::string bad = WithField(csv, 4, "g1_hx", "x");
  std::string bad_dos;
  for (char c : bad) {
    if (c == '\n') bad_dos += "\r\n\r\n";
    else bad_dos += c;
  }
  const absl::StatusOr<estimator::Recording> refused = ParseRecordingCsv(bad_dos);
  ASSERT_FALSE(refused.ok());
  EXPECT_THAT(std::string(refused.status().message()), HasSubstr("line 7"));
}

TEST(RecordingCsv, ExtraColumnsAreIgnored) {
  const std::string text =
      "# spacecraft_id: RDK-2\n"
      "# operator: night shift\n"
      "temperature_c,time_utc,g1_hx,g1_hy,g1_hz,g1_ux,g1_uy,g1_uz,g2_hx,g2_hy,g2_hz,g2_ux,g2_uy,"
      "g2_uz,g3_hx,g3_hy,g3_hz,g3_ux,g3_uy,g3_uz,g4_hx,g4_hy,g4_hz,g4_ux,g4_uy,g4_uz,st_q0,st_q1,"
      "st_q2,st_q3,st_valid,comment\n"
      "21.5,2019-03-01T00:00:00Z,1,0,0,1,2,3,0,1,0,,,,,,,,,,,,,,,,1,0,0,0,1,hello\n"
      "not a number,2019-03-01T00:01:00.5Z,0,0,1,,,,0,1,0,,,,,,,,,,,,,,,,,,,,,\n";
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(text);
  ASSERT_THAT(read, IsOk());
  ASSERT_EQ(read->frames.size(), 2u);
  EXPECT_EQ(read->metadata.at("spacecraft_id"), "RDK-2");
  EXPECT_EQ(read->metadata.at("operator"), "night shift");
  EXPECT_EQ(read->frames[0].gyros[0]->h_k, Eigen::Vector3d(1, 0, 0));
  EXPECT_EQ(*read->frames[0].gyros[0]->u_k_mv, Eigen::Vector3d(1, 2, 3));
  EXPECT_TRUE(read->frames[0].star_tracker->valid);
  EXPECT_EQ(read->frames[1].time, absl::FromUnixSeconds(1551398460) + absl::Milliseconds(500));
  EXPECT_EQ(read->frames[1].gyros[0]->h_k, Eigen::Vector3d(0, 0, 1));
  EXPECT_FALSE(read->frames[1].star_tracker.has_value());
}

TEST(RecordingCsv, ColumnOrderIsFree) {
  // Every line of a valid file with its fields reversed.
  const std::string csv = ValidCsv(4);
  std::vector<std::string> lines = absl::StrSplit(csv, '\n');
  for (std::string& line : lines) {
    if (line.empty() || line[0] == '#') continue;
    std::vector<std::string> fields = absl::StrSplit(line, ',');
    std::reverse(fields.begin(), fields.end());
    line = absl::StrJoin(fields, ",");
  }
  const std::string reversed = absl::StrJoin(lines, "\n");
  ASSERT_NE(reversed, csv);
  absl::StatusOr<estimator::Recording> a = ParseRecordingCsv(csv);
  absl::StatusOr<estimator::Recording> b = ParseRecordingCsv(reversed);
  ASSERT_THAT(a, IsOk());
  ASSERT_THAT(b, IsOk());
  ExpectRecordingsIdentical(*a, *b);
}

TEST(RecordingCsv, CrLfLinesSpacesAndBlankLinesAreAccepted) {
  std::string csv = WithField(ValidCsv(2), 4, "g1_hx", " " + std::string("1") + " ");
  csv = WithField(csv, 4, "g1_hy", "0");
  csv = WithField(csv, 4, "g1_hz", "+0");
  std::string crlf;
  for (char c : csv) {
    if (c == '\n') crlf += "\r\n\r\n";
    else crlf += c;
  }
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(crlf);
  ASSERT_THAT(read, IsOk());
  ASSERT_EQ(read->frames.size(), 2u);
  EXPECT_EQ(read->frames[0].gyros[0]->h_k, Eigen::Vector3d(1, 0, 0));
}

TEST(RecordingCsv, SlightlyNonUnitVectorsAreRenormalised) {
  std::string csv = WithField(ValidCsv(1), 4, "g1_hx", "0.6003");
  csv = WithField(csv, 4, "g1_hy", "0.8");
  csv = WithField(csv, 4, "g1_hz", "0");
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(csv);
  ASSERT_THAT(read, IsOk());
  EXPECT_NEAR(read->frames[0].gyros[0]->h_k.norm(), 1.0, 1e-15);
  EXPECT_NEAR(read->frames[0].gyros[0]->h_k.x(), 0.6003 / std::hypot(0.6003, 0.8), 1e-15);
}

TEST(RecordingCsv, EmptyRecordingHasHeaderOnlyAndReadsBack) {
  estimator::Recording r;
  const std::string csv = FormatRecordingCsv(r);
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(csv);
  ASSERT_THAT(read, IsOk());
  EXPECT_TRUE(read->frames.empty());
  EXPECT_EQ(read->metadata.count("spacecraft_id"), 0u);
}

// Keys are cleaned before they are ordered: a key with a line break sorts before "a b!" but is
// written as "a b" after it, two keys that clean to the same are written once (the first in key
// order), one that cleans to "format" is dropped and one that cleans to "spacecraft_id" leads;
// the written text is what the reader reads back and writes again (found by fuzz_recording_csv).
TEST(RecordingCsv, MetadataIsWrittenInTheOrderOfItsCleanedKeys) {
  estimator::Recording recording;
  recording.metadata = {{"a b!", "1"},   {"a\rb", "2"},     {"x", "first"},
                        {"x\n", "second"}, {"\rformat", "9"}, {"spacecraft_id\r", "SC-9"}};
  const std::string text = FormatRecordingCsv(recording);
  EXPECT_EQ(text.substr(0, text.find("time_utc")),
            "# format: esg-recording-csv 1\n# spacecraft_id: SC-9\n# a b: 2\n# a b!: 1\n"
            "# x: first\n");
  absl::StatusOr<estimator::Recording> back = ParseRecordingCsv(text);
  ASSERT_TRUE(back.ok()) << back.status();
  EXPECT_EQ(FormatRecordingCsv(*back), text);
}

TEST(RecordingCsv, MissingFileIsNotFound) {
  esg::testing::TempDir dir;
  EXPECT_THAT(ReadRecordingCsv(dir.File("nope.csv")),
              StatusIs(absl::StatusCode::kNotFound, HasSubstr("nope.csv")));
}

// ---------------------------------------------------------------------------------------------
// Malformed input: each case names the line, the column and the reason.

struct MalformedCase {
  std::string name;
  std::function<std::string()> make;
  std::string expected;  // substring of the message
};

void PrintTo(const MalformedCase& c, std::ostream* os) { *os << c.name; }

class MalformedRecording : public ::testing::TestWithParam<MalformedCase> {};

TEST_P(MalformedRecording, IsInvalidArgumentWithLineColumnAndReason) {
  esg::testing::TempDir dir;
  const std::string path = WriteText(dir, "bad.csv", GetParam().make());
  EXPECT_THAT(ReadRecordingCsv(path),
              StatusIs(kInvalid, AllOf(HasSubstr("bad.csv"), HasSubstr("1 problem\n"),
                                       HasSubstr(GetParam().expected))));
}

INSTANTIATE_TEST_SUITE_P(
    RecordingCsv, MalformedRecording,
    ::testing::Values(
        MalformedCase{"NonUnitDirectionCosines",
                      [] {
                        std::string c = WithField(ValidCsv(), 5, "g2_hx", "0.9");
                        c = WithField(c, 5, "g2_hy", "0.9");
                        return WithField(c, 5, "g2_hz", "0");
                      },
                      "line 5, column g2_hx..g2_hz: norm 1.27279 is not 1 (tolerance 0.001)"},
        MalformedCase{"NonUnitQuaternion",
                      [] {
                        std::string c = WithField(ValidCsv(), 6, "st_q0", "0.5");
                        c = WithField(c, 6, "st_q1", "0");
                        c = WithField(c, 6, "st_q2", "0");
                        return WithField(c, 6, "st_q3", "0");
                      },
                      "line 6, column st_q0..st_q3: norm 0.5 is not 1 (tolerance 0.001)"},
        MalformedCase{"NaN", [] { return WithField(ValidCsv(), 4, "g3_hy", "nan"); },
                      "line 4, column g3_hy: 'nan' is not finite"},
        MalformedCase{"Infinity", [] { return WithField(ValidCsv(), 5, "g1_uz", "-inf"); },
                      "line 5, column g1_uz: '-inf' is not finite"},
        MalformedCase{"NonNumeric", [] { return WithField(ValidCsv(), 6, "g1_ux", "12.5mV"); },
                      "line 6, column g1_ux: '12.5mV' is not a number"},
        MalformedCase{"NonIncreasingTime",
                      [] { return WithField(ValidCsv(), 6, "time_utc", "2019-03-01T00:00:30Z"); },
                      "line 6, column time_utc: 2019-03-01T00:00:30Z is not after"},
        MalformedCase{"RepeatedTime",
                      [] {
                        std::string c = WithField(ValidCsv(), 4, "time_utc", "2019-03-01T00:00:00Z");
                        return WithField(c, 5, "time_utc", "2019-03-01T00:00:00Z");
                      },
                      "line 5, column time_utc: 2019-03-01T00:00:00Z is not after "
                      "2019-03-01T00:00:00.000Z of line 4"},
        MalformedCase{"BadTimestamp",
                      [] { return WithField(ValidCsv(), 5, "time_utc", "2019-03-01 00:01:00"); },
                      "line 5, column time_utc: '2019-03-01 00:01:00' is not an RFC 3339 time"},
        MalformedCase{"EmptyTime", [] { return WithField(ValidCsv(), 5, "time_utc", ""); },
                      "line 5, column time_utc: empty"},
        MalformedCase{"WrongFieldCount",
                      [] {
                        std::string c = ValidCsv();
                        const size_t line5 = c.find('\n', c.find('\n', c.find('\n', c.find('\n') + 1) + 1) + 1);
                        return c.insert(line5, ",");  // one field too many at the end of line 4
                      },
                      "line 4: expected 30 fields as in the header (line 3), got 31"},
        MalformedCase{"MissingHeaderColumns",
                      [] {
                        std::string c = ValidCsv();
                        for (const std::string name : {"g3_uy", "st_valid"}) {
                          const size_t at = c.find("," + name);
                          c.replace(at, name.size() + 1, ",x_" + name);
                        }
                        return c;
                      },
                      "line 3: header lacks required columns g3_uy, st_valid"},
        MalformedCase{"StValidNotZeroOrOne", [] { return WithField(ValidCsv(), 4, "st_valid", "2"); },
                      "line 4, column st_valid: '2' is not 0 or 1"},
        MalformedCase{"StValidEmptyWithQuaternion",
                      [] { return WithField(ValidCsv(), 4, "st_valid", ""); },
                      "line 4, column st_valid: empty while st_q0..st_q3 have values"},
        MalformedCase{"ValidStarTrackerWithoutQuaternion",
                      [] {
                        std::string c = ValidCsv();
                        for (const char* q : {"st_q0", "st_q1", "st_q2", "st_q3"}) c = WithField(c, 4, q, "");
                        return c;
                      },
                      "line 4, column st_q0..st_q3: empty while st_valid is 1"},
        MalformedCase{"PartlyEmptyGyroGroup", [] { return WithField(ValidCsv(), 5, "g3_hz", ""); },
                      "line 5, column g3_hz: empty while the rest of its group g3_hx..g3_hz has values"},
        MalformedCase{"PartlyEmptyVoltageGroup",
                      [] { return WithField(ValidCsv(), 4, "g1_uy", ""); },
                      "line 4, column g1_uy: empty while the rest of its group g1_ux..g1_uz has values"},
        MalformedCase{"VoltagesWithoutSpinAxis",
                      [] {
                        std::string c = ValidCsv();
                        for (const char* h : {"g4_hx", "g4_hy", "g4_hz"}) c = WithField(c, 4, h, "");
                        return WithField(WithField(WithField(c, 4, "g4_ux", "1"), 4, "g4_uy", "2"), 4,
                                         "g4_uz", "3");
                      },
                      "line 4, column g4_ux..g4_uz: voltages given while gyro 4 has no spin-axis"},
        MalformedCase{"UnsupportedFormat",
                      [] {
                        std::string c = ValidCsv();
                        return c.replace(0, c.find('\n'), "# format: esg-recording-csv 2");
                      },
                      "line 1: unsupported format 'esg-recording-csv 2'"},
        MalformedCase{"CommentAfterHeader",
                      [] {
                        std::string c = ValidCsv();
                        return c + "# late note: x\n";
                      },
                      "line 7: comment or metadata line after the header"},
        MalformedCase{"NoHeader", [] { return std::string("# spacecraft_id: X\n"); },
                      "line 2: no header line"}),
    [](const ::testing::TestParamInfo<MalformedCase>& info) { return info.param.name; });

TEST(RecordingCsv, EveryProblemOfAFileIsReported) {
  std::string csv = ValidCsv(6);
  csv = WithField(csv, 4, "g1_hx", "abc");
  csv = WithField(csv, 6, "st_valid", "yes");
  csv = WithField(csv, 7, "time_utc", "yesterday");
  csv = WithField(csv, 9, "g2_ux", "inf");
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(csv);
  EXPECT_THAT(read, StatusIs(kInvalid, AllOf(HasSubstr("4 problems"),
                                            HasSubstr("line 4, column g1_hx: 'abc' is not a number"),
                                            HasSubstr("line 6, column st_valid: 'yes' is not 0 or 1"),
                                            HasSubstr("line 7, column time_utc: 'yesterday'"),
                                            HasSubstr("line 9, column g2_ux: 'inf' is not finite"))));
  // No problem on the untouched lines.
  EXPECT_THAT(read.status().message(), AllOf(Not(HasSubstr("line 5")), Not(HasSubstr("line 8"))));
}

// The offline verbs read with max_row_gap = 7 days, the limit of esgd's ingest (docs/formats.md,
// "Validation"): a row exactly 7 days after the previous one is read, one a nanosecond later
// is a problem naming both lines' times; without the option the reader takes any gap.
TEST(RecordingCsv, RowMoreThanTheGapLimitAfterThePreviousIsAProblemWhenAsked) {
  const std::string csv = ValidCsv(3);
  absl::StatusOr<estimator::Recording> plain = ParseRecordingCsv(csv);
  ASSERT_THAT(plain, IsOk());
  const absl::Time previous = plain->frames[1].time;  // line 5
  RecordingReadOptions options;
  options.max_row_gap = absl::Hours(24 * 7);
  auto at = [&](absl::Duration after) {
    return WithField(csv, 6, "time_utc",
                     absl::FormatTime(absl::RFC3339_full, previous + after, absl::UTCTimeZone()));
  };
  EXPECT_THAT(ParseRecordingCsv(at(absl::Hours(24 * 7)), options), IsOk());
  EXPECT_THAT(
      ParseRecordingCsv(at(absl::Hours(24 * 7) + absl::Nanoseconds(1)), options),
      StatusIs(kInvalid, AllOf(HasSubstr("1 problem"),
                               HasSubstr("line 6, column time_utc: " +
                                         estimator::FormatUtc(previous + absl::Hours(24 * 7) +
                                                              absl::Nanoseconds(1)) +
                                         " is more than 7 days after the previous row (line 5, " +
                                         estimator::FormatUtc(previous) + ")"))));
  EXPECT_THAT(ParseRecordingCsv(at(absl::Hours(24 * 365 * 5))), IsOk());
}

TEST(RecordingCsv, ProblemListIsCappedWithACount) {
  std::string csv = ValidCsv(kMaxReportedProblems + 10);
  for (int i = 0; i < kMaxReportedProblems + 10; ++i) csv = WithField(csv, 4 + i, "st_valid", "x");
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(csv);
  EXPECT_THAT(read, StatusIs(kInvalid, AllOf(HasSubstr("60 problems"), HasSubstr("line 53, column"),
                                            Not(HasSubstr("line 54, column")),
                                            HasSubstr("... and 10 more"))));
}

// ---------------------------------------------------------------------------------------------
// Channel columns `ch:NAME` (docs/formats.md "Channels").

TEST(RecordingCsv, ChannelsRoundTripAsChColumnsWithEmptyCellsWhereMissing) {
  estimator::Recording r = RandomRecording(4, 38);
  r.metadata.erase("source");  // line 3 is the header
  r.frames[0].channels.Set("T_gyro2", 301.25);
  r.frames[0].channels.Set("heater_1", 1.0);
  r.frames[1].channels.Set("heater_1", 0.0);  // T_gyro2 has its own, slower cadence
  r.frames[3].channels.Set("T_gyro2", -1.0 / 3.0);
  const std::string csv = FormatRecordingCsv(r);
  const std::vector<std::string> lines = absl::StrSplit(csv, '\n');
  EXPECT_THAT(lines[2], ::testing::EndsWith(",st_valid,ch:T_gyro2,ch:heater_1"));
  EXPECT_THAT(lines[3], ::testing::EndsWith(",301.25,1"));
  EXPECT_THAT(lines[4], ::testing::EndsWith(",,0"));
  EXPECT_THAT(lines[5], ::testing::EndsWith(",,"));
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(csv);
  ASSERT_THAT(read, IsOk());
  ExpectRecordingsIdentical(r, *read);
  for (size_t i = 0; i < r.frames.size(); ++i) {
    EXPECT_EQ(read->frames[i].channels, r.frames[i].channels) << "frame " << i;
  }
  EXPECT_EQ(FormatRecordingCsv(*read), csv);
}

TEST(RecordingCsv, ARecordingWithoutChannelsIsWrittenAsBefore) {
  const std::string csv = ValidCsv(2);
  EXPECT_THAT(csv, Not(HasSubstr("ch:")));
  absl::StatusOr<estimator::Recording> read = ParseRecordingCsv(csv);
  ASSERT_THAT(read, IsOk());
  for (const estimator::TelemetryFrame& f : read->frames) EXPECT_TRUE(f.channels.empty());
}

TEST(RecordingCsv, BadChannelColumnsAndValuesAreProblemsNamingTheColumn) {
  estimator::Recording r = RandomRecording(2, 39);
  r.metadata.erase("source");  // line 3 is the header
  r.frames[0].channels.Set("T_gyro2", 300.0);
  const std::string csv = FormatRecordingCsv(r);
  EXPECT_THAT(ParseRecordingCsv(WithField(csv, 4, "ch:T_gyro2", "warm")),
              StatusIs(kInvalid, HasSubstr("line 4, column ch:T_gyro2: 'warm' is not a number")));
  EXPECT_THAT(ParseRecordingCsv(WithField(csv, 5, "ch:T_gyro2", "nan")),
              StatusIs(kInvalid, HasSubstr("line 5, column ch:T_gyro2: 'nan' is not finite")));
  EXPECT_THAT(ParseRecordingCsv(WithField(csv, 3, "ch:T_gyro2", "ch:2hot")),
              StatusIs(kInvalid, HasSubstr("line 3, column ch:2hot: name: character '2' at index "
                                           "0 is not allowed")));
  EXPECT_THAT(ParseRecordingCsv(WithField(csv, 3, "ch:T_gyro2", "ch:")),
              StatusIs(kInvalid, HasSubstr("line 3, column ch:: name: empty name")));
}

TEST(RecordingCsv, MoreChannelsInARowThanAFrameCarriesIsAProblem) {
  estimator::Recording r = RandomRecording(1, 40);
  r.metadata.erase("source");  // line 3 is the header
  for (int i = 0; i <= estimator::kMaxChannels; ++i) {
    r.frames[0].channels.Set(absl::StrCat("c", i), i);
  }
  EXPECT_THAT(ParseRecordingCsv(FormatRecordingCsv(r)),
              StatusIs(kInvalid, HasSubstr("line 4: 65 channels, at most 64 in a frame")));
}

}  // namespace
}  // namespace esg::storage
