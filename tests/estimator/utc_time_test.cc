// estimator/utc_time.h: the one text form of an instant (RFC 3339, Z, milliseconds truncated, a
// 4-digit year; docs/formats.md "Time").
#include "estimator/utc_time.h"

#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

const absl::Time kStart = absl::FromUnixSeconds(1551398400);  // 2019-03-01T00:00:00Z

TEST(FormatUtc, WritesMillisecondsTruncatedWithZ) {
  EXPECT_EQ(FormatUtc(kStart), "2019-03-01T00:00:00.000Z");
  EXPECT_EQ(FormatUtc(kStart + absl::Milliseconds(125)), "2019-03-01T00:00:00.125Z");
  EXPECT_EQ(FormatUtc(kStart + absl::Nanoseconds(999999999)), "2019-03-01T00:00:00.999Z")
      << "truncated, not rounded into the next second";
  EXPECT_EQ(FormatUtc(kStart - absl::Nanoseconds(1)), "2019-02-28T23:59:59.999Z");
}

TEST(FormatUtc, YearHasFourDigitsAndOpenEndsHaveNames) {
  EXPECT_EQ(FormatUtc(absl::FromCivil(absl::CivilSecond(1, 1, 1, 0, 0, 0), absl::UTCTimeZone())),
            "0001-01-01T00:00:00.000Z");
  EXPECT_EQ(FormatUtc(absl::InfinitePast()), "infinite-past");
  EXPECT_EQ(FormatUtc(absl::InfiniteFuture()), "infinite-future");
}

}  // namespace
}  // namespace esg::estimator
