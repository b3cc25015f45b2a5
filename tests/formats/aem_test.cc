// The AEM reader's time systems and the spacecraft check of a plan (formats/aem.h,
// docs/formats.md "Attitude product: CCSDS AEM"): TAI epochs are converted to UTC with ERFA's
// leap seconds, SCLK and the other time systems are refused naming the TIME_SYSTEM line, and a
// plan whose OBJECT_NAME and OBJECT_ID name another spacecraft is refused naming OBJECT_NAME's
// line. (The writer and the structural rules are tested in tests/server/aem_test.cc.)
#include "formats/aem.h"

#include <string>
#include <vector>

#include "absl/strings/str_replace.h"
#include "absl/time/time.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/quaternion_matchers.h"
#include "tests/testing/status_matchers.h"

namespace esg::storage {
namespace {

using ::esg::testing::IsNearQuaternion;
using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::StartsWith;

constexpr absl::StatusCode kInvalid = absl::StatusCode::kInvalidArgument;

absl::Time Utc(int y, int mo, int d, int h, int mi, int s) {
  return absl::FromCivil(absl::CivilSecond(y, mo, d, h, mi, s), absl::UTCTimeZone());
}

// One segment of spacecraft RDK-1 (OBJECT_NAME on line 6, TIME_SYSTEM on line 10), epochs
// written as given, in the time system given.
std::string Aem(const std::string& time_system, const std::vector<std::string>& epochs,
                const std::string& object_name = "RDK-1", const std::string& object_id = "2019-001A") {
  std::string text =
      "CCSDS_AEM_VERS = 2.0\n"
      "CREATION_DATE = 2019-03-01T00:00:00\n"
      "ORIGINATOR = FDS\n"
      "\n"
      "META_START\n"
      "OBJECT_NAME = " + object_name + "\n"
      "OBJECT_ID = " + object_id + "\n"
      "REF_FRAME_A = EME2000\n"
      "REF_FRAME_B = SC_BODY_1\n"
      "TIME_SYSTEM = " + time_system + "\n"
      "START_TIME = " + epochs.front() + "\n"
      "STOP_TIME = " + epochs.back() + "\n"
      "ATTITUDE_TYPE = QUATERNION\n"
      "META_STOP\n"
      "\n"
      "DATA_START\n";
  for (const std::string& e : epochs) text += e + " 0 0 0.382683432365090 0.923879532511287\n";
  text += "DATA_STOP\n";
  return text;
}

TEST(AemTimeSystem, UtcEpochsAreReadAsWritten) {
  absl::StatusOr<AemFile> f = ParseAem(Aem("UTC", {"2019-03-01T00:00:00.000000"}));
  ASSERT_THAT(f, IsOk());
  EXPECT_EQ(f->segments[0].samples[0].epoch, Utc(2019, 3, 1, 0, 0, 0));
}

TEST(AemTimeSystem, TaiEpochsAreConvertedToUtcWithTheLeapSeconds) {
  // TAI - UTC = 37 s since 2017-01-01 (IERS Bulletin C), 36 s in the second half of 2016.
  absl::StatusOr<AemFile> f = ParseAem(
      Aem("TAI", {"2019-03-01T00:00:37.000000", "2019-03-01T00:01:37.123456"}));
  ASSERT_THAT(f, IsOk());
  const AemSegment& s = f->segments[0];
  EXPECT_EQ(s.start_time, Utc(2019, 3, 1, 0, 0, 0));
  EXPECT_EQ(s.stop_time, Utc(2019, 3, 1, 0, 1, 0) + absl::Microseconds(123456));
  EXPECT_EQ(s.samples[0].epoch, Utc(2019, 3, 1, 0, 0, 0));
  EXPECT_EQ(s.samples[1].epoch, Utc(2019, 3, 1, 0, 1, 0) + absl::Microseconds(123456));
  EXPECT_THAT(s.samples[1].q_in_b,
              IsNearQuaternion(Eigen::Quaterniond(0.923879532511287, 0, 0, 0.382683432365090), 1e-12));

  // Across the leap second at the end of 2016.
  f = ParseAem(Aem("TAI", {"2016-12-31T23:59:00.000000", "2017-01-01T00:01:00.000000"}));
  ASSERT_THAT(f, IsOk());
  EXPECT_EQ(f->segments[0].samples[0].epoch, Utc(2016, 12, 31, 23, 58, 24));
  EXPECT_EQ(f->segments[0].samples[1].epoch, Utc(2017, 1, 1, 0, 0, 23));
  // Before 1972 TAI - UTC is not a whole number of seconds and drifts by 0.002592 s a day: at
  // 1971-06-01T00:00:00Z it is 9.337554 s, so the TAI reading 00:00:09.337554 is that instant to
  // the drift over the 0.34 s the whole-second part is evaluated before it (10 ns).
  f = ParseAem(Aem("TAI", {"1971-06-01T00:00:09.337554"}));
  ASSERT_THAT(f, IsOk());
  EXPECT_LT(absl::AbsDuration(f->segments[0].samples[0].epoch - Utc(1971, 6, 1, 0, 0, 0)),
            absl::Nanoseconds(20));
}

TEST(AemTimeSystem, SclkAndTheOtherTimeSystemsAreRefusedOnTheirLine) {
  for (const std::string system : {"SCLK", "MET", "GPS", "TT", "UT1", "TDB"}) {
    EXPECT_THAT(ParseAem(Aem(system, {"2019-03-01T00:00:00.000000"})),
                StatusIs(kInvalid, AllOf(StartsWith("line 10: TIME_SYSTEM: " + system +
                                                    " is not read"),
                                         HasSubstr("UTC, or TAI"))))
        << system;
  }
  EXPECT_THAT(ParseAem(Aem("MARS", {"2019-03-01T00:00:00.000000"})),
              StatusIs(kInvalid, StartsWith("line 10: TIME_SYSTEM: unknown value MARS")));
}

TEST(AemTimeSystem, TaiWithoutUtcOrWithSecond60IsRefused) {
  EXPECT_THAT(ParseAem(Aem("TAI", {"2016-12-31T23:59:60.000000"})),
              StatusIs(kInvalid, AllOf(HasSubstr("START_TIME"), HasSubstr("second 60"))));
  EXPECT_THAT(ParseAem(Aem("TAI", {"1955-01-01T00:00:00.000000"})),
              StatusIs(kInvalid, HasSubstr("TAI before 1960 has no UTC")));
}

TEST(AemPlan, PlanOfTheSpacecraftIsRead) {
  absl::StatusOr<std::vector<AemSample>> plan =
      ParseAemPlan(Aem("UTC", {"2019-03-01T00:00:00", "2019-03-01T00:01:00"}), "RDK-1");
  ASSERT_THAT(plan, IsOk());
  EXPECT_EQ(plan->size(), 2u);
  // OBJECT_ID may carry the spacecraft id instead (OBJECT_NAME a longer name).
  EXPECT_THAT(ParseAemPlan(Aem("UTC", {"2019-03-01T00:00:00"}, "Resurs-DK 1", "RDK-1"), "RDK-1"),
              IsOk());
}

TEST(AemPlan, PlanOfAnotherSpacecraftIsRefusedNamingObjectName) {
  EXPECT_THAT(ParseAemPlan(Aem("UTC", {"2019-03-01T00:00:00"}, "SAT-9", "2020-007B"), "RDK-1"),
              StatusIs(kInvalid, StartsWith("line 6: OBJECT_NAME: 'SAT-9' (OBJECT_ID '2020-007B') "
                                            "is not spacecraft 'RDK-1'")));
  // The id is compared exactly.
  EXPECT_THAT(ParseAemPlan(Aem("UTC", {"2019-03-01T00:00:00"}, "rdk-1", "rdk-1"), "RDK-1"),
              StatusIs(kInvalid, HasSubstr("OBJECT_NAME: 'rdk-1'")));
  // The file's own errors come first.
  EXPECT_THAT(ParseAemPlan(Aem("SCLK", {"2019-03-01T00:00:00"}, "SAT-9"), "RDK-1"),
              StatusIs(kInvalid, StartsWith("line 10: TIME_SYSTEM")));
}

}  // namespace
}  // namespace esg::storage
