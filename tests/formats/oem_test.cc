// The CCSDS OEM reader and writer (formats/oem.h, docs/formats.md "Orbit: CCSDS OEM"): the writer's
// file reads back as the orbit it wrote; the reader takes what the standard allows (comments,
// several segments, accelerations, covariance blocks, TAI epochs) and refuses, on its line, what
// this project cannot use: another centre, a frame not aligned with J2000, a time system other
// than UTC or TAI, another spacecraft's orbit, malformed data or covariance.
#include "formats/oem.h"

#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_replace.h"
#include "absl/time/time.h"
#include "formats/ccsds_kvn.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::testing::StatusIs;
using ::testing::HasSubstr;
using estimator::OrbitState;

constexpr absl::StatusCode kInvalid = absl::StatusCode::kInvalidArgument;
const absl::Time kT0 = absl::FromCivil(absl::CivilSecond(2019, 3, 1, 0, 0, 0), absl::UTCTimeZone());

std::vector<OrbitState> CircularStates(double from_s, double to_s, double step_s) {
  const double r_km = 6878.137;
  const double w = std::sqrt(398600.4418 / (r_km * r_km * r_km));
  std::vector<OrbitState> states;
  for (double t = from_s; t <= to_s; t += step_s) {
    OrbitState s;
    s.time = kT0 + absl::Seconds(t);
    s.r_in_km = r_km * Eigen::Vector3d(std::cos(w * t), 0.0, std::sin(w * t));
    s.v_in_km_s = r_km * w * Eigen::Vector3d(-std::sin(w * t), 0.0, std::cos(w * t));
    states.push_back(s);
  }
  return states;
}

std::string Written(const std::vector<OrbitState>& states) {
  OemHeader header;
  header.object_name = "RDK-1";
  header.object_id = "2019-001A";
  header.creation_date = kT0;
  header.comments = {"simulated"};
  absl::StatusOr<std::string> text = WriteOem(header, states);
  EXPECT_TRUE(text.ok()) << text.status();
  return text.ok() ? *text : std::string();
}

// The written file with one line replaced (the header and metadata lines are unique).
std::string With(const std::string& from, const std::string& to) {
  const std::string text = Written(CircularStates(0, 3600, 60));
  EXPECT_NE(text.find(from), std::string::npos) << from;
  return absl::StrReplaceAll(text, {{from, to}});
}

TEST(Oem, WrittenOrbitReadsBack) {
  const std::vector<OrbitState> states = CircularStates(0, 3600, 60);
  const std::string text = Written(states);
  const absl::StatusOr<OemFile> file = ParseOem(text);
  ASSERT_TRUE(file.ok()) << file.status();
  EXPECT_EQ(file->version, "2.0");
  ASSERT_EQ(file->segments.size(), 1u);
  EXPECT_EQ(file->segments[0].metadata.at("REF_FRAME"), "EME2000");
  EXPECT_EQ(file->segments[0].comments, std::vector<std::string>{"simulated"});
  ASSERT_EQ(file->segments[0].states.size(), states.size());
  for (size_t i = 0; i < states.size(); ++i) {
    EXPECT_EQ(file->segments[0].states[i].time, states[i].time);
    EXPECT_LT((file->segments[0].states[i].r_in_km - states[i].r_in_km).norm(), 1e-6);
    EXPECT_LT((file->segments[0].states[i].v_in_km_s - states[i].v_in_km_s).norm(), 1e-9);
  }
  const absl::StatusOr<estimator::Orbit> orbit = ParseOemOrbit(text, "RDK-1");
  ASSERT_TRUE(orbit.ok()) << orbit.status();
  EXPECT_TRUE(orbit->Gaps(kT0, kT0 + absl::Seconds(3600)).empty());
  EXPECT_TRUE(ParseOemOrbit(text, "2019-001A").ok());  // OBJECT_ID names it too
}

TEST(Oem, ReadsWhatTheStandardAllows) {
  // Version 1.0, comments in the header, the metadata and the data section's start, two segments
  // (a gap between them), accelerations, TAI epochs, a covariance block.
  std::string text =
      "CCSDS_OEM_VERS = 1.0\n"
      "COMMENT delivered by flight dynamics\n"
      "CREATION_DATE = 2019-060T00:00:00\n"
      "ORIGINATOR = FDS\n";
  for (int segment = 0; segment < 2; ++segment) {
    const std::vector<OrbitState> states =
        CircularStates(segment * 7200, segment * 7200 + 3600, 60);
    text += absl::StrCat("META_START\nCOMMENT arc ", segment + 1,
                         "\nOBJECT_NAME = RDK-1\nOBJECT_ID = 2019-001A\nCENTER_NAME = EARTH\n"
                         "REF_FRAME = GCRF\nTIME_SYSTEM = TAI\nSTART_TIME = ",
                         FormatCcsdsTime(states.front().time + absl::Seconds(37)),
                         "\nSTOP_TIME = ", FormatCcsdsTime(states.back().time + absl::Seconds(37)),
                         "\nINTERPOLATION = HERMITE\nINTERPOLATION_DEGREE = 3\nMETA_STOP\n"
                         "COMMENT states in km and km/s\n");
    for (const OrbitState& s : states) {
      text += absl::StrFormat("%s %.6f %.6f %.6f %.9f %.9f %.9f 0 0 0\n",
                              FormatCcsdsTime(s.time + absl::Seconds(37)), s.r_in_km.x(),
                              s.r_in_km.y(), s.r_in_km.z(), s.v_in_km_s.x(), s.v_in_km_s.y(),
                              s.v_in_km_s.z());
    }
    text +=
        "COVARIANCE_START\nEPOCH = 2019-03-01T00:00:37\nCOV_REF_FRAME = RTN\n1e-3\n0 1e-3\n"
        "0 0 1e-3\n0 0 0 1e-9\n0 0 0 0 1e-9\n0 0 0 0 0 1e-9\nCOVARIANCE_STOP\n";
  }
  const absl::StatusOr<OemFile> file = ParseOem(text);
  ASSERT_TRUE(file.ok()) << file.status();
  ASSERT_EQ(file->segments.size(), 2u);
  EXPECT_EQ(file->segments[0].covariance_blocks, 1);
  // TAI 37 s ahead of UTC in 2019.
  EXPECT_EQ(file->segments[1].states.front().time, kT0 + absl::Seconds(7200));
  const absl::StatusOr<estimator::Orbit> orbit = ParseOemOrbit(text, "RDK-1");
  ASSERT_TRUE(orbit.ok()) << orbit.status();
  const std::vector<estimator::TimeInterval> gaps = orbit->Gaps(kT0, kT0 + absl::Seconds(10800));
  ASSERT_EQ(gaps.size(), 1u);
  EXPECT_EQ(gaps[0].from, kT0 + absl::Seconds(3600) + absl::Nanoseconds(1));
  EXPECT_EQ(gaps[0].to, kT0 + absl::Seconds(7200) - absl::Nanoseconds(1));
}

TEST(Oem, RefusesWhatItCannotUseOnItsLine) {
  // The written file: header lines 1-3, META_START on 5, OBJECT_NAME 7, CENTER_NAME 9,
  // REF_FRAME 10, TIME_SYSTEM 11, the first data line 18.
  EXPECT_THAT(ParseOem(With("CENTER_NAME = EARTH", "CENTER_NAME = MARS")),
              StatusIs(kInvalid, HasSubstr("line 9: CENTER_NAME: 'MARS' is not read")));
  EXPECT_THAT(ParseOem(With("REF_FRAME = EME2000", "REF_FRAME = ITRF2000")),
              StatusIs(kInvalid, HasSubstr("line 10: REF_FRAME: 'ITRF2000' is not read")));
  EXPECT_THAT(ParseOem(With("REF_FRAME = EME2000", "REF_FRAME = TEME")),
              StatusIs(kInvalid, HasSubstr("inertial frame aligned with J2000")));
  EXPECT_THAT(ParseOem(With("TIME_SYSTEM = UTC", "TIME_SYSTEM = TT")),
              StatusIs(kInvalid, HasSubstr("line 11: TIME_SYSTEM: TT is not read")));
  EXPECT_THAT(ParseOem(With("TIME_SYSTEM = UTC", "TIME_SYSTEM = MARS_TIME")),
              StatusIs(kInvalid, HasSubstr("line 11: TIME_SYSTEM: unknown value")));
  EXPECT_THAT(ParseOem(With("CCSDS_OEM_VERS = 2.0", "CCSDS_OEM_VERS = 4.0")),
              StatusIs(kInvalid, HasSubstr("line 1: CCSDS_OEM_VERS: unsupported version 4.0")));
  EXPECT_THAT(ParseOem(With("CENTER_NAME = EARTH\n", "")),
              StatusIs(kInvalid, HasSubstr("CENTER_NAME: required metadata keyword missing")));
  EXPECT_THAT(ParseOemOrbit(Written(CircularStates(0, 3600, 60)), "RDK-2"),
              StatusIs(kInvalid, HasSubstr("line 7: OBJECT_NAME: 'RDK-1' (OBJECT_ID '2019-001A') "
                                           "is not spacecraft 'RDK-2'")));
  const std::string good = Written(CircularStates(0, 3600, 60));
  const std::string first_line = FormatCcsdsTime(kT0);
  const size_t at = good.find("\n" + first_line) + 1;
  const size_t end = good.find('\n', at);
  const std::string data = good.substr(at, end - at);
  auto replaced = [&](const std::string& line) {
    return good.substr(0, at) + line + good.substr(end);
  };
  EXPECT_THAT(ParseOem(replaced(data + " 1")),
              StatusIs(kInvalid, HasSubstr("line 18: data: expected an epoch and 6 numbers")));
  EXPECT_THAT(ParseOem(replaced(absl::StrReplaceAll(data, {{" 0.000000 ", " nan "}}))),
              StatusIs(kInvalid, HasSubstr("line 18: Y: 'nan' is not a number")));
  EXPECT_THAT(ParseOem(replaced(absl::StrReplaceAll(
                  data, {{first_line, FormatCcsdsTime(kT0 + absl::Seconds(60))}}))),
              StatusIs(kInvalid, HasSubstr("line 19: epoch: 2019-03-01T00:01:00.000000 is not after the previous epoch")));
  EXPECT_THAT(ParseOem(good + "COVARIANCE_START\nEPOCH = 2019-03-01T00:00:00\n1\n0 1\n0 0\n"),
              StatusIs(kInvalid, HasSubstr("row 3 of the lower triangle needs 3 numbers, got 2")));
  EXPECT_THAT(ParseOem(good + "COVARIANCE_START\nEPOCH = 2019-03-01T00:00:00\n1\nCOVARIANCE_STOP\n"),
              StatusIs(kInvalid, HasSubstr("the matrix before it has 1 of 6 rows")));
  // States 600 s apart: the orbit cannot be interpolated to 1 km.
  EXPECT_THAT(ParseOemOrbit(Written(CircularStates(0, 6000, 600)), "RDK-1"),
              StatusIs(kInvalid, HasSubstr("segment 1 (line 7): states[1].time: states 600 s apart")));
}

}  // namespace
}  // namespace esg::storage
