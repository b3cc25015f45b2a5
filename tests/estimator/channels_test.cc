// Auxiliary housekeeping channels (estimator/channels.h, docs/formats.md "Channels", D105): the
// frame's container, the declarations' checks, a frame's values against them, and the age rule.
#include "estimator/channels.h"

#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "estimator/spacecraft_config.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/testing/status_matchers.h"

namespace esg::estimator {
namespace {

using ::esg::testing::IsOk;
using ::esg::testing::StatusIs;
using ::testing::HasSubstr;
using ::testing::StartsWith;

ChannelConfig Declared(std::string name, double lo, double hi, absl::Duration max_age,
                       std::string unit = "K") {
  ChannelConfig c;
  c.name = std::move(name);
  c.unit = std::move(unit);
  c.valid_min = lo;
  c.valid_max = hi;
  c.max_age = max_age;
  return c;
}

std::vector<ChannelConfig> TwoChannels() {
  return {Declared("T_gyro2", 250.0, 350.0, absl::Minutes(10)),
          Declared("heater_1", 0.0, 1.0, absl::ZeroDuration(), "1")};
}

TEST(Channels, KeepsNamesSortedAndOnceEach) {
  Channels c;
  EXPECT_TRUE(c.empty());
  c.Set("b", 2.0);
  c.Set("a", 1.0);
  c.Set("b", 3.0);
  ASSERT_EQ(c.size(), 2);
  EXPECT_EQ(c.begin()->name, "a");
  EXPECT_EQ((c.begin() + 1)->name, "b");
  ASSERT_NE(c.Find("b"), nullptr);
  EXPECT_EQ(*c.Find("b"), 3.0);
  EXPECT_EQ(c.Find("c"), nullptr);
}

TEST(Channels, AnEmptyFrameHoldsNoChannelStorage) {
  // The gyro-only hot path: a frame without channels carries one empty vector, no allocation.
  TelemetryFrame frame;
  EXPECT_TRUE(frame.channels.empty());
  EXPECT_EQ(sizeof(Channels), sizeof(std::vector<ChannelValue>));
}

TEST(ChannelConfigs, AcceptsValidDeclarations) {
  EXPECT_THAT(ValidateChannelConfigs(TwoChannels()), IsOk());
  EXPECT_THAT(ValidateChannelConfigs({}), IsOk());
}

TEST(ChannelConfigs, RefusesEachBadFieldNamingIt) {
  auto with = [](auto change) {
    std::vector<ChannelConfig> c = TwoChannels();
    change(c[1]);
    return ValidateChannelConfigs(c);
  };
  EXPECT_THAT(with([](ChannelConfig& c) { c.name = "2hot"; }),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[1].name: ")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.name = "a b"; }),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[1].name: ")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.name = std::string(33, 'x'); }),
              StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr("too long")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.name = "T_gyro2"; }),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       StartsWith("channels[1].name: channel 'T_gyro2' is declared twice")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.unit = ""; }),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[1].unit: ")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.unit = "K\n"; }),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[1].unit: ")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.valid_min = 2.0; }),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[1].validMin: ")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.valid_max = std::numeric_limits<double>::infinity(); }),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[1].validMin: ")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.max_age = absl::Seconds(-1); }),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[1].maxAgeS: ")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.max_age = kMaxChannelAge + absl::Seconds(1); }),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[1].maxAgeS: ")));
  EXPECT_THAT(with([](ChannelConfig& c) { c.max_age = kMaxChannelAge; }), IsOk());
}

TEST(ChannelConfigs, RefusesMoreThanAFrameCanCarry) {
  std::vector<ChannelConfig> many;
  for (int i = 0; i <= kMaxChannels; ++i) {
    many.push_back(Declared(absl::StrCat("c", i), 0.0, 1.0, absl::ZeroDuration()));
  }
  EXPECT_THAT(ValidateChannelConfigs(many),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels: 65 channels")));
  many.pop_back();
  EXPECT_THAT(ValidateChannelConfigs(many), IsOk());
}

TEST(ChannelConfigs, ValidateConfigChecksThem) {
  SpacecraftConfig config;
  config.spacecraft_id = "RDK-1";
  config.gyros.resize(3);
  for (int i = 0; i < 3; ++i) config.gyros[i].id = i + 1;
  ASSERT_THAT(ValidateConfig(config), IsOk());
  config.channels = TwoChannels();
  EXPECT_THAT(ValidateConfig(config), IsOk());
  config.channels[0].valid_min = std::nan("");
  EXPECT_THAT(ValidateConfig(config),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[0].validMin: ")));
}

TEST(FrameChannels, RefusesNonFiniteValuesBadNamesAndTooMany) {
  Channels c;
  c.Set("T_gyro2", 300.0);
  EXPECT_THAT(ValidateFrameChannels(c), IsOk());
  c.Set("T_gyro2", std::nan(""));
  EXPECT_THAT(ValidateFrameChannels(c),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       StartsWith("channels[\"T_gyro2\"]: nan is not finite")));
  Channels bad_name;
  bad_name.Set("x\ny", 1.0);
  EXPECT_THAT(ValidateFrameChannels(bad_name),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels[\"x\\ny\"]: ")));
  Channels many;
  for (int i = 0; i <= kMaxChannels; ++i) many.Set(absl::StrCat("c", i), 0.0);
  EXPECT_THAT(ValidateFrameChannels(many),
              StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("channels: 65 channels")));
}

TEST(FrameChannels, RefusesUndeclaredAndOutOfRangeValuesNamingTheChannel) {
  Channels c;
  c.Set("T_gyro2", 300.0);
  c.Set("heater_1", 1.0);
  EXPECT_THAT(CheckDeclaredChannels(c, TwoChannels()), IsOk());
  c.Set("T_gyro2", 350.5);
  EXPECT_THAT(CheckDeclaredChannels(c, TwoChannels()),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       StartsWith("channels[\"T_gyro2\"]: 350.5 K is outside its valid range "
                                  "[250, 350] K")));
  c.Set("T_gyro2", 350.0);  // the bound itself is valid
  EXPECT_THAT(CheckDeclaredChannels(c, TwoChannels()), IsOk());
  c.Set("T_gyro3", 300.0);
  EXPECT_THAT(CheckDeclaredChannels(c, TwoChannels()),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       StartsWith("channels[\"T_gyro3\"]: not declared in the configuration "
                                  "(declared: T_gyro2, heater_1)")));
}

TEST(FrameChannels, RecordingCheckNamesTheFrame) {
  std::vector<TelemetryFrame> frames(3);
  for (int i = 0; i < 3; ++i) frames[i].time = absl::FromUnixSeconds(60 * i);
  frames[0].channels.Set("T_gyro2", 300.0);
  EXPECT_THAT(CheckRecordingChannels(frames, TwoChannels()), IsOk());
  frames[2].channels.Set("heater_1", 2.0);
  EXPECT_THAT(CheckRecordingChannels(frames, TwoChannels()),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       StartsWith("frame 3 (1970-01-01T00:02:00.000Z): channels[\"heater_1\"]: 2 1 "
                                  "is outside")));
}

TEST(ChannelHold, KeepsTheLastValueUpToItsMaxAge) {
  ChannelHold hold(TwoChannels());
  const absl::Time t0 = absl::FromUnixSeconds(1000);
  TelemetryFrame f;
  f.time = t0;
  EXPECT_FALSE(hold.At("T_gyro2", t0).has_value());  // no value yet
  f.channels.Set("T_gyro2", 300.0);
  f.channels.Set("heater_1", 1.0);
  hold.Update(f);
  TelemetryFrame later;  // carries no channel: T_gyro2 keeps its value with its age
  later.time = t0 + absl::Minutes(5);
  hold.Update(later);
  auto s = hold.At("T_gyro2", t0 + absl::Minutes(5));
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->value, 300.0);
  EXPECT_EQ(s->age, absl::Minutes(5));
  ASSERT_TRUE(hold.At("T_gyro2", t0 + absl::Minutes(10)).has_value());  // the age bound holds
  EXPECT_FALSE(hold.At("T_gyro2", t0 + absl::Minutes(10) + absl::Seconds(1)).has_value());
  // heater_1's max age is 0: only at its own frame.
  ASSERT_TRUE(hold.At("heater_1", t0).has_value());
  EXPECT_FALSE(hold.At("heater_1", t0 + absl::Minutes(5)).has_value());
  EXPECT_FALSE(hold.At("T_gyro2", t0 - absl::Seconds(1)).has_value());  // before its frame
  EXPECT_FALSE(hold.At("undeclared", t0).has_value());
  // A new value replaces the old and restarts its age; an older frame is ignored.
  TelemetryFrame newer;
  newer.time = t0 + absl::Minutes(20);
  newer.channels.Set("T_gyro2", 310.0);
  hold.Update(newer);
  TelemetryFrame stale;
  stale.time = t0 + absl::Minutes(15);
  stale.channels.Set("T_gyro2", 999.0);
  hold.Update(stale);
  s = hold.At("T_gyro2", t0 + absl::Minutes(25));
  ASSERT_TRUE(s.has_value());
  EXPECT_EQ(s->value, 310.0);
  EXPECT_EQ(s->age, absl::Minutes(5));
}

}  // namespace
}  // namespace esg::estimator
