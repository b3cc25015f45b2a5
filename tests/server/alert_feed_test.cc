// Tests of server/alert_feed.h: the dedupe rules of a SubscribeAlerts stream and the bound on
// what it remembers of the alerts it sent (no server, no threads: the Feed is plain state).
#include "server/alert_feed.h"

#include <algorithm>
#include <string>

#include "gtest/gtest.h"

namespace esg::server {
namespace {

storage::AlertRecord Alert(int64_t sequence, int64_t repeats = 1, bool acknowledged = false) {
  storage::AlertRecord r;
  r.spacecraft_id = "SC-1";
  r.sequence = sequence;
  r.reason = "GYRO_DATA_REJECTED";
  r.repeat_count = repeats;
  r.acknowledged = acknowledged;
  return r;
}

TEST(AlertFeed, ReplayMergeQueuesOnlyNewerStatesAndLiveQueuesEveryOtherState) {
  AlertFeed feed;
  EXPECT_TRUE(feed.Admit(Alert(1, 3), /*replaying=*/true));
  EXPECT_FALSE(feed.Admit(Alert(1, 2), true));  // older than the replayed state
  EXPECT_TRUE(feed.Admit(Alert(1, 4), true));
  feed.ReplayComplete();
  EXPECT_FALSE(feed.Admit(Alert(1, 4), false));  // the state already sent
  EXPECT_TRUE(feed.Admit(Alert(1, 2), false));   // a re-run set the count back: sent
  EXPECT_TRUE(feed.Admit(Alert(1, 2, true), false));
  EXPECT_FALSE(feed.Admit(Alert(1, 5, false), false));  // an acknowledgement is never undone
}

// A stream that reads for months: after the replay the map keeps the alerts touched last, at
// most 2 kRemembered of them, whatever the number sent; a recent alert's state is still
// deduplicated, a forgotten one's next state is sent again (never lost).
TEST(AlertFeed, WhatAStreamRemembersAfterTheReplayIsBounded) {
  AlertFeed feed;
  const int64_t replayed = 3 * AlertFeed::kRemembered;
  for (int64_t s = 1; s <= replayed; ++s) ASSERT_TRUE(feed.Admit(Alert(s), true));
  // Nothing is forgotten during the replay: the merge needs every replayed state.
  EXPECT_EQ(feed.remembered(), static_cast<size_t>(replayed));
  feed.ReplayComplete();
  EXPECT_EQ(feed.remembered(), AlertFeed::kRemembered);
  const int64_t live = 10 * AlertFeed::kRemembered;
  size_t most = 0;
  for (int64_t s = replayed + 1; s <= replayed + live; ++s) {
    ASSERT_TRUE(feed.Admit(Alert(s), false));
    most = std::max(most, feed.remembered());
  }
  EXPECT_LE(most, 2 * AlertFeed::kRemembered);
  EXPECT_GE(feed.remembered(), AlertFeed::kRemembered);
  const int64_t last = replayed + live;
  EXPECT_FALSE(feed.Admit(Alert(last), false));  // remembered: its state is not sent twice
  EXPECT_TRUE(feed.Admit(Alert(1), false));      // forgotten: sent again
  EXPECT_GT(feed.Forget(), 0);
  EXPECT_EQ(feed.remembered(), 0u);
}

// The alerts touched last are kept, not the ones sent last: an old alert that keeps repeating
// stays remembered while newer, quiet ones are forgotten.
TEST(AlertFeed, AnOldAlertThatKeepsRepeatingStaysRemembered) {
  AlertFeed feed;
  feed.ReplayComplete();
  ASSERT_TRUE(feed.Admit(Alert(1, 1), false));
  int64_t repeats = 1;
  for (int64_t s = 2; s <= 5 * AlertFeed::kRemembered; ++s) {
    ASSERT_TRUE(feed.Admit(Alert(s), false));
    if (s % 1000 == 0) ASSERT_TRUE(feed.Admit(Alert(1, ++repeats), false));
  }
  EXPECT_FALSE(feed.Admit(Alert(1, repeats), false));
  EXPECT_TRUE(feed.Admit(Alert(2), false));  // a quiet one, long forgotten
}

}  // namespace
}  // namespace esg::server
