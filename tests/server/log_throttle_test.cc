// Tests of server/log_throttle.h: lines per key and interval, the summary's count and text, the
// flush of a flood that stopped, the key cap. Pure: the lines are captured from stderr.
#include "server/log_throttle.h"

#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"

namespace esg::server {
namespace {

using ::testing::HasSubstr;

std::vector<std::string> Lines(const std::string& text) {
  return absl::StrSplit(text, '\n', absl::SkipEmpty());
}

const absl::Time kT0 = absl::FromUnixSeconds(1700000000);

TEST(LogThrottle, WritesTheFirstLinesOfAKeyThenCountsTheRestInOneSummary) {
  LogThrottle throttle("test_event");
  ::testing::internal::CaptureStderr();
  int written = 0;
  // 700 lines of one key and 5 of another within one second.
  for (int i = 0; i < 700; ++i) {
    written += throttle.Log("station GS-2", "WARN", absl::StrCat("line ", i), {},
                            kT0 + absl::Milliseconds(i));
  }
  for (int i = 0; i < 5; ++i) written += throttle.Log("station GS-3", "WARN", "other", {}, kT0);
  // The interval is not over: nothing to summarise yet.
  EXPECT_EQ(throttle.Flush(kT0 + absl::Seconds(5)), 0);
  EXPECT_EQ(throttle.Flush(kT0 + absl::Seconds(10)), 1);
  const std::vector<std::string> lines = Lines(::testing::internal::GetCapturedStderr());
  EXPECT_EQ(written, 15);
  ASSERT_EQ(lines.size(), 16u);
  EXPECT_THAT(lines[0], HasSubstr("line 0"));
  EXPECT_THAT(lines[9], HasSubstr("line 9"));
  EXPECT_THAT(lines[15],
              HasSubstr("WARN esgd: 690 more test_event lines for station GS-2 in the last 10 s"));
}

TEST(LogThrottle, ANewIntervalWritesAgainAfterTheSummaryOfTheLastOne) {
  LogThrottle throttle("test_event", {.lines_per_interval = 2, .interval = absl::Seconds(10)});
  ::testing::internal::CaptureStderr();
  for (int i = 0; i < 5; ++i) throttle.Log("k", "WARN", "first", {}, kT0);
  throttle.Log("k", "WARN", "second", {}, kT0 + absl::Seconds(12));
  const std::vector<std::string> lines = Lines(::testing::internal::GetCapturedStderr());
  ASSERT_EQ(lines.size(), 4u);
  EXPECT_THAT(lines[2], HasSubstr("3 more test_event lines for k in the last 10 s"));
  EXPECT_THAT(lines[3], HasSubstr("second"));
}

TEST(LogThrottle, CountedLinesAreSummarisedAndAStoppedFloodIsFlushed) {
  LogThrottle throttle("test_event", {.lines_per_interval = 0});
  ::testing::internal::CaptureStderr();
  for (int i = 0; i < 7; ++i) throttle.CountSuppressed("peer ipv4:10.0.0.5", kT0);
  // FlushThrottledLogs flushes every throttle; InfiniteFuture all pending ones (at a stop).
  EXPECT_GE(FlushThrottledLogs(absl::InfiniteFuture()), 1);
  EXPECT_EQ(throttle.Flush(absl::InfiniteFuture()), 0);
  const std::vector<std::string> lines = Lines(::testing::internal::GetCapturedStderr());
  ASSERT_EQ(lines.size(), 1u);
  EXPECT_THAT(lines[0], HasSubstr("7 more test_event lines for peer ipv4:10.0.0.5"));
}

TEST(LogThrottle, SummaryIsAJsonLineWithTheCountedEvent) {
  SetLogFormat(LogFormat::kJson);
  LogThrottle throttle("frame_conflict", {.lines_per_interval = 1});
  ::testing::internal::CaptureStderr();
  for (int i = 0; i < 4; ++i) {
    throttle.Log("station GS-2 of spacecraft RDK-1", "WARN", "conflict", {{"station", "GS-2"}},
                 kT0);
  }
  throttle.Flush(kT0 + absl::Seconds(10));
  const std::vector<std::string> lines = Lines(::testing::internal::GetCapturedStderr());
  SetLogFormat(LogFormat::kText);
  ASSERT_EQ(lines.size(), 2u);
  const nlohmann::json first = nlohmann::json::parse(lines[0]);
  EXPECT_EQ(first["event"], "frame_conflict");
  EXPECT_EQ(first["station"], "GS-2");
  const nlohmann::json summary = nlohmann::json::parse(lines[1]);
  EXPECT_EQ(summary["event"], "log_suppressed");
  EXPECT_EQ(summary["level"], "WARN");
  EXPECT_EQ(summary["suppressedEvent"], "frame_conflict");
  EXPECT_EQ(summary["key"], "station GS-2 of spacecraft RDK-1");
  EXPECT_EQ(summary["suppressed"], 3);
  EXPECT_EQ(summary["intervalSeconds"], 10);
}

TEST(LogThrottle, KeysBeyondTheCapShareOneKey) {
  LogThrottle throttle("test_event", {.lines_per_interval = 1, .max_keys = 3});
  ::testing::internal::CaptureStderr();
  for (int i = 0; i < 100; ++i) throttle.Log(absl::StrCat("key ", i), "WARN", "x", {}, kT0);
  throttle.Flush(kT0 + absl::Seconds(10));
  const std::vector<std::string> lines = Lines(::testing::internal::GetCapturedStderr());
  // Keys 0 to 2 have a line each; the 97 others share "other keys": one line and a count of 96.
  ASSERT_EQ(lines.size(), 5u) << ::testing::PrintToString(lines);
  EXPECT_THAT(lines[4], HasSubstr("96 more test_event lines for other keys in the last 10 s"));
}

}  // namespace
}  // namespace esg::server
