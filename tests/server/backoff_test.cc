// Tests of server/backoff.h: the waits of the reconnect and retry loops.
#include "server/backoff.h"

#include "gtest/gtest.h"

namespace esg::server {
namespace {

TEST(Backoff, EachFailureDoublesTheWaitUpToTheCapWithJitterInTheUpperHalf) {
  const absl::Duration initial = absl::Milliseconds(50);
  const absl::Duration cap = absl::Seconds(1);
  for (int64_t failures = 1; failures <= 40; ++failures) {
    absl::Duration d = initial;
    for (int64_t i = 1; i < failures && d < cap; ++i) d *= 2;
    d = std::min(d, cap);
    for (int draw = 0; draw < 50; ++draw) {
      const absl::Duration wait = BackoffDelay(failures, initial, cap);
      EXPECT_GE(wait, d / 2) << failures;
      EXPECT_LE(wait, d) << failures;
    }
  }
}

TEST(Backoff, ARunOfFailuresCountsItsAttemptsAndAResetEndsIt) {
  Backoff b(absl::Milliseconds(10), absl::Milliseconds(40));
  EXPECT_EQ(b.failures(), 0);
  EXPECT_LE(b.Failed(), absl::Milliseconds(10));
  EXPECT_LE(b.Failed(), absl::Milliseconds(20));
  EXPECT_GE(b.Failed(), absl::Milliseconds(20));
  for (int i = 0; i < 100; ++i) EXPECT_LE(b.Failed(), absl::Milliseconds(40));
  EXPECT_EQ(b.failures(), 103);
  b.Reset();
  EXPECT_EQ(b.failures(), 0);
  EXPECT_LE(b.Failed(), absl::Milliseconds(10));
}

// Two loops that start failing together do not retry in step.
TEST(Backoff, TheWaitsOfTwoLoopsDiffer) {
  int equal = 0;
  for (int i = 0; i < 100; ++i) {
    equal += BackoffDelay(5, absl::Milliseconds(50), absl::Seconds(1)) ==
                     BackoffDelay(5, absl::Milliseconds(50), absl::Seconds(1))
                 ? 1
                 : 0;
  }
  EXPECT_LT(equal, 5);
}

}  // namespace
}  // namespace esg::server
