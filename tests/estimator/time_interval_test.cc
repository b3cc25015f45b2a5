// estimator/time_interval.h: the one interval convention of every from/to, [from, to] with both
// ends inclusive (docs/service.md "Time intervals").
#include "estimator/time_interval.h"

#include "gtest/gtest.h"

namespace esg::estimator {
namespace {

const absl::Time kStart = absl::FromUnixSeconds(1551398400);  // 2019-03-01T00:00:00Z

TEST(TimeInterval, BothEndsAreInside) {
  const TimeInterval span{kStart, kStart + absl::Minutes(1)};
  EXPECT_TRUE(span.Contains(kStart));
  EXPECT_TRUE(span.Contains(kStart + absl::Minutes(1)));
  EXPECT_FALSE(span.Contains(kStart - absl::Nanoseconds(1)));
  EXPECT_FALSE(span.Contains(kStart + absl::Minutes(1) + absl::Nanoseconds(1)));
  // The half-open form of a storage query: [from, End()) holds the same instants.
  EXPECT_EQ(span.End(), kStart + absl::Minutes(1) + absl::Nanoseconds(1));
  const TimeInterval instant{kStart, kStart};
  EXPECT_TRUE(instant.Contains(kStart));
  EXPECT_EQ(instant.End(), kStart + absl::Nanoseconds(1));
}

TEST(TimeInterval, AbsentEndsAreOpen) {
  const TimeInterval all;
  EXPECT_TRUE(all.Contains(absl::UnixEpoch()));
  EXPECT_TRUE(all.Contains(absl::InfiniteFuture()));
  EXPECT_EQ(all.End(), absl::InfiniteFuture());
}

}  // namespace
}  // namespace esg::estimator
