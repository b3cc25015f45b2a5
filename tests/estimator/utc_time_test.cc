// estimator/utc_time.h: the one text form of an instant (RFC 3339, Z, milliseconds truncated, a
// 4-digit year; docs/formats.md "Time") and the one reader of RFC 3339 text.
#include "estimator/utc_time.h"

#include <string>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"

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

TEST(ParseUtc, ReadsEveryRfc3339FormToTheNanosecond) {
  EXPECT_EQ(*ParseUtc("2019-03-01T00:00:00Z", "--from"), kStart);
  EXPECT_EQ(*ParseUtc("2019-03-01T03:00:00+03:00", "--from"), kStart);
  EXPECT_EQ(*ParseUtc("2019-02-28T23:30:00.5-00:30", "--from"), kStart + absl::Milliseconds(500));
  EXPECT_EQ(*ParseUtc("2019-03-01T00:00:00.123456789Z", ""), kStart + absl::Nanoseconds(123456789));
  EXPECT_EQ(*ParseUtc(" 2019-03-01T00:00:00Z ", "--to"), kStart) << "blanks around are ignored";
  // FormatUtc's text reads back to the millisecond it keeps.
  const absl::Time t = kStart + absl::Milliseconds(125) + absl::Nanoseconds(7);
  EXPECT_EQ(*ParseUtc(FormatUtc(t), "--to"), kStart + absl::Milliseconds(125));
}

TEST(ParseUtc, RefusesAnythingElseNamingWhereItWasGivenWithAnExample) {
  using ::esg::testing::StatusIs;
  const auto refused = [](const std::string& message) {
    return StatusIs(absl::StatusCode::kInvalidArgument, message);
  };
  EXPECT_THAT(ParseUtc("yesterday", "--from"),
              refused("--from: 'yesterday' is not an RFC 3339 time such as 2019-03-01T00:00:00Z"));
  EXPECT_THAT(ParseUtc("2019-03-01 00:00:00Z", "time.epoch"),
              refused("time.epoch: '2019-03-01 00:00:00Z' is not an RFC 3339 time such as "
                      "2019-03-01T00:00:00Z"));
  // Without a name the caller names the place (a CSV problem: line and column).
  EXPECT_THAT(ParseUtc("2019-03-01T00:00:00", ""),
              refused("'2019-03-01T00:00:00' is not an RFC 3339 time such as 2019-03-01T00:00:00Z"))
      << "no offset: not an instant";
  for (const char* bad : {"", "2019-02-30T00:00:00Z", "2019-03-01T00:00:00Zjunk", "infinite-future",
                          "infinite-past", "1551398400"}) {
    EXPECT_THAT(ParseUtc(bad, "--since"),
                StatusIs(absl::StatusCode::kInvalidArgument, ::testing::StartsWith("--since: '")))
        << bad;
  }
  // The text is quoted bounded and escaped: no terminal control reaches a message.
  EXPECT_THAT(ParseUtc("2019\x1b[2J" + std::string(100, 'x'), "--to"),
              refused("--to: '2019\\x1b[2J" + std::string(29, 'x') +
                      "...' is not an RFC 3339 time such as 2019-03-01T00:00:00Z"));
}

}  // namespace
}  // namespace esg::estimator
