// A drift that follows a housekeeping channel as a candidate (estimator/discovery/
// channel_candidate.h): one per gyro and declared channel, none without channels (so a recording
// without channels is diagnosed as before), and no fit for a channel the recording does not vary.
// The classes found end to end are measured by the confusion bench (docs/discovery.md).
#include "estimator/discovery/channel_candidate.h"

#include <algorithm>
#include <string>
#include <vector>

#include "estimator/discovery/candidates.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/discovery_scenarios.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator::discovery {
namespace {

using ::esg::testing::IsOk;

ChannelConfig Temperature(const std::string& name) {
  ChannelConfig c;
  c.name = name;
  c.unit = "K";
  c.valid_min = 250;
  c.valid_max = 350;
  c.max_age = absl::Minutes(10);
  return c;
}

TEST(ChannelCandidate, NoneWithoutChannelsAndOnePerGyroAndDeclaredChannelOtherwise) {
  ModelState without;
  without.config = ::esg::testing::DiscoveryConfig();
  const std::vector<Candidate> before = ListCandidates(without, {1, 2, 3}, {}, false);
  EXPECT_TRUE(std::none_of(before.begin(), before.end(), [](const Candidate& c) {
    return c.effect == Effect::kChannelDrift;
  }));
  ModelState with = without;
  with.config.channels = {Temperature("T_gyro2"), Temperature("heater_1")};
  const std::vector<Candidate> after = ListCandidates(with, {1, 2, 3}, {}, false);
  std::vector<std::string> names, others;
  for (const Candidate& c : after) {
    if (c.effect == Effect::kChannelDrift) {
      names.push_back(CandidateName(c));
    } else {
      others.push_back(CandidateName(c));
    }
  }
  EXPECT_THAT(names, ::testing::UnorderedElementsAre(
                         "channel_drift[1:T_gyro2]", "channel_drift[1:heater_1]",
                         "channel_drift[2:T_gyro2]", "channel_drift[2:heater_1]",
                         "channel_drift[3:T_gyro2]", "channel_drift[3:heater_1]"));
  std::vector<std::string> before_names;
  for (const Candidate& c : before) before_names.push_back(CandidateName(c));
  EXPECT_EQ(others, before_names);
  // Once taken, a gyro's channel is not offered again; --effects without it offers none.
  with.added.push_back("channel_drift[2:T_gyro2]");
  int offered = 0;
  for (const Candidate& c : ListCandidates(with, {1, 2, 3}, {}, false)) {
    offered += CandidateName(c) == "channel_drift[2:T_gyro2]" ? 1 : 0;
  }
  EXPECT_EQ(offered, 0);
  for (const Candidate& c : ListCandidates(with, {1, 2, 3}, {Effect::kRotorDisplacement}, false)) {
    EXPECT_NE(c.effect, Effect::kChannelDrift);
  }
  EXPECT_EQ(EffectFromId("channel_drift"), Effect::kChannelDrift);
}

// A channel constant over the recording (or absent from it) explains nothing: no parameter, no
// filter run, a note saying why.
TEST(ChannelCandidate, AChannelThatDoesNotChangeIsNotFitted) {
  ModelState model;
  model.config = ::esg::testing::DiscoveryConfig();
  model.config.channels = {Temperature("T_gyro2")};
  std::vector<TelemetryFrame> frames(5);
  for (int i = 0; i < 5; ++i) {
    frames[i].time = absl::FromUnixSeconds(1551398400 + 60 * i);
    frames[i].channels.Set("T_gyro2", 293.0);
  }
  const ModelRun run;
  const DiagnoseOptions options;
  FitContext ctx;
  ctx.frames = &frames;
  ctx.model = &model;
  ctx.model_run = &run;
  ctx.options = &options;
  absl::StatusOr<CandidateFit> fit = FitCandidate({Effect::kChannelDrift, 2, "T_gyro2"}, ctx);
  ASSERT_THAT(fit, IsOk());
  EXPECT_EQ(fit->parameters, 0);
  EXPECT_EQ(fit->runs, 0);
  ASSERT_FALSE(fit->notes.empty());
  EXPECT_THAT(fit->notes.front(), ::testing::HasSubstr("does not change over the recording"));
  frames.resize(1);
  fit = FitCandidate({Effect::kChannelDrift, 2, "T_gyro2"}, ctx);
  ASSERT_THAT(fit, IsOk());
  EXPECT_THAT(fit->notes.front(), ::testing::HasSubstr("fewer than two of its values"));
}

}  // namespace
}  // namespace esg::estimator::discovery
