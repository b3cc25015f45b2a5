// A scenario's channel drift (docs/scenario.md `channelDrift`; client/scenario.h,
// estimator/simulator.h ChannelDrift): parsed to SI with every bad value named by its key path;
// applied, it declares its channels in the configuration; simulated, the drift follows the
// temperature's value, its lag or the lag's rate of change, a heater steps the temperature while
// it is on and its state is a channel of its own; through the real `esg simulate`, the recording
// carries the `ch:` columns and --write-config the declarations, and `esg diagnose` on that
// recording names the channel and the form.
#include <cmath>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/scenario.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "formats/recording_csv.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "proto/convert.h"
#include "tests/client/cli_test_support.h"
#include "tests/testing/run_process.h"
#include "tests/testing/status_matchers.h"
#include "tests/testing/temp_dir.h"

namespace esg::client {
namespace {

using Eigen::Vector3d;
using ::esg::testing::IsOk;
using ::esg::testing::RunBinary;
using ::esg::testing::RunResult;
using ::esg::testing::StatusIs;
using ::esg::testing::TempDir;
using ::esg::testing::WriteFile;
using ::testing::HasSubstr;
namespace est = ::esg::estimator;

est::SpacecraftConfig Config() {
  est::SpacecraftConfig c;
  c.spacecraft_id = "T";
  for (int id = 1; id <= 3; ++id) {
    est::GyroConfig g;
    g.id = id;
    c.gyros.push_back(g);
  }
  c.readout_noise = est::ArcsecToRad(3.0);
  return c;
}

// `channel_drift` of gyro 2 as a scenario.
std::string ScenarioWith(const std::string& channel_drift) {
  return absl::StrCat(R"({"profile": "calibration", "gyros": [{"id": 2, "channelDrift": )",
                      channel_drift, "}]}");
}

TEST(ChannelScenario, ParsesToSiAndDeclaresItsChannels) {
  auto s = ParseScenarioJson(ScenarioWith(R"({
      "channel": "T_gyro2", "unit": "degC", "mean": 20, "spread": 1.5, "correlationHours": 2,
      "noise": 0.05, "form": "derivative", "timeConstantMinutes": 30,
      "gainDegH": [0.02, -0.01, 0.005], "telemetered": true,
      "heater": {"periodHours": 4, "onFraction": 0.25, "step": 2, "channel": "heater_2"}})"));
  ASSERT_THAT(s, IsOk());
  ASSERT_TRUE(s->gyros[0].channel_drift.has_value());
  const est::ChannelDrift& d = *s->gyros[0].channel_drift;
  EXPECT_EQ(d.channel, "T_gyro2");
  EXPECT_EQ(s->gyros[0].channel_unit, "degC");
  EXPECT_EQ(d.mean, 20.0);
  EXPECT_EQ(d.spread, 1.5);
  EXPECT_EQ(d.correlation_time_s, 7200.0);
  EXPECT_EQ(d.noise, 0.05);
  EXPECT_EQ(d.lag_s, 1800.0);
  EXPECT_TRUE(d.derivative);
  EXPECT_NEAR(d.gain_k_rad_s_per_unit.x(), est::DegPerHourToRadPerSec(0.02), 1e-20);
  ASSERT_TRUE(d.heater.has_value());
  EXPECT_EQ(d.heater->period_s, 4 * 3600.0);
  EXPECT_EQ(d.heater->on_fraction, 0.25);
  EXPECT_EQ(d.heater->step, 2.0);
  EXPECT_EQ(d.heater->channel, "heater_2");

  // Applied: both channels declared (the temperature's range covers 10 spreads, the heater's
  // step and 10 noises, rounded outwards), a declaration the configuration has kept as it is.
  est::SimulationSpec spec;
  spec.config = Config();
  ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
  ASSERT_EQ(spec.config.channels.size(), 2u);
  const est::ChannelConfig& t = spec.config.channels[0];
  EXPECT_EQ(t.name, "T_gyro2");
  EXPECT_EQ(t.unit, "degC");
  EXPECT_EQ(t.valid_min, std::floor(20.0 - 15.0 - 2.0 - 0.5));
  EXPECT_EQ(t.valid_max, std::ceil(20.0 + 15.0 + 2.0 + 0.5));
  EXPECT_EQ(t.max_age, absl::Minutes(10));
  const est::ChannelConfig& h = spec.config.channels[1];
  EXPECT_EQ(h.name, "heater_2");
  EXPECT_EQ(h.unit, "1");
  EXPECT_EQ(h.valid_min, 0.0);
  EXPECT_EQ(h.valid_max, 1.0);
  est::SimulationSpec own;
  own.config = Config();
  est::ChannelConfig declared{"T_gyro2", "K", 0.0, 400.0, absl::Minutes(3)};
  own.config.channels = {declared};
  ASSERT_THAT(ApplyScenario(*s, &own), IsOk());
  ASSERT_EQ(own.config.channels.size(), 2u);
  EXPECT_EQ(own.config.channels[0], declared);

  // Not telemetered: nothing declared.
  auto hidden = ParseScenarioJson(ScenarioWith(
      R"({"channel": "T_gyro2", "gainDegH": [0.01, 0, 0], "telemetered": false})"));
  ASSERT_THAT(hidden, IsOk());
  est::SimulationSpec none;
  none.config = Config();
  ASSERT_THAT(ApplyScenario(*hidden, &none), IsOk());
  EXPECT_TRUE(none.config.channels.empty());
  EXPECT_FALSE(hidden->gyros[0].channel_drift->derivative);
  EXPECT_EQ(hidden->gyros[0].channel_drift->lag_s, 0.0);  // form value by default
}

TEST(ChannelScenario, BadValuesAreRefusedNamingTheKey) {
  const std::vector<std::pair<std::string, std::string>> cases = {
      {R"({"gainDegH": [0.01, 0, 0]})", "gyros[0].channelDrift.channel: required"},
      {R"({"channel": "T"})", "gyros[0].channelDrift.gainDegH: required"},
      {R"({"channel": "T 2", "gainDegH": [0.01, 0, 0]})", "gyros[0].channelDrift.channel:"},
      {R"({"channel": "T", "gainDegH": [0.01, 0]})", "gyros[0].channelDrift.gainDegH: expected"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "form": "rate"})",
       "gyros[0].channelDrift.form: unknown form 'rate'"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "form": "lag"})",
       "gyros[0].channelDrift.timeConstantMinutes: required for form lag"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "timeConstantMinutes": 40})",
       "gyros[0].channelDrift.timeConstantMinutes: not used by form value"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "form": "derivative",
           "timeConstantMinutes": 0.5})",
       "gyros[0].channelDrift.timeConstantMinutes: 0.5 is outside [1, "},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "spread": 0})",
       "gyros[0].channelDrift.spread: must be > 0"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "noise": -1})",
       "gyros[0].channelDrift.noise: -1 is outside"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "unit": ""})",
       "gyros[0].channelDrift.unit: must be 1.."},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "heater": {"step": 1}})",
       "gyros[0].channelDrift.heater.periodHours: required"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0],
           "heater": {"periodHours": 2, "step": 1, "onFraction": 1}})",
       "gyros[0].channelDrift.heater.onFraction: 1: must be strictly between 0 and 1"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0],
           "heater": {"periodHours": 2, "step": 1, "channel": "T"}})",
       "gyros[0].channelDrift.heater.channel: \"T\" is the temperature's channel too"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "heater": {"periodHours": 2, "step": 1,
           "phase": 0}})",
       "gyros[0].channelDrift.heater.phase: unknown key"},
      {R"({"channel": "T", "gainDegH": [0.01, 0, 0], "lagMinutes": 40})",
       "gyros[0].channelDrift.lagMinutes: unknown key"},
  };
  for (const auto& [drift, message] : cases) {
    EXPECT_THAT(ParseScenarioJson(ScenarioWith(drift)),
                StatusIs(absl::StatusCode::kInvalidArgument, HasSubstr(message)))
        << drift;
  }
  // Two drifts writing one channel.
  EXPECT_THAT(ParseScenarioJson(R"({"gyros": [
      {"id": 1, "channelDrift": {"channel": "T", "gainDegH": [0.01, 0, 0],
                                 "heater": {"periodHours": 2, "step": 1, "channel": "H"}}},
      {"id": 2, "channelDrift": {"channel": "H", "gainDegH": [0.01, 0, 0]}}]})"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       HasSubstr("gyros[1].channelDrift.channel: \"H\" is written by "
                                 "gyros[0].channelDrift.heater.channel too")));
}

// A heater of step 1.5 K on for the first 2 h of every 4 h, the temperature's own wander
// negligible (spread 1e-9 K), no channel noise: the drift follows the heater's square wave (value),
// or the lag's rate of change after the heater switches off at 2 h, -step/tau e^(-(t - 2 h)/tau)
// per hour (derivative, tau 40 min; the lag in equilibrium with the heater on at the start).
// The frames carry the temperature and the heater's state.
TEST(ChannelScenario, TheHeaterStepsTheTemperatureAndTheDriftFollowsItsValueOrRateOfChange) {
  for (const std::string form : {"value", "derivative"}) {
    SCOPED_TRACE(form);
    auto s = ParseScenarioJson(ScenarioWith(absl::StrCat(
        R"({"channel": "T_gyro2", "mean": 290, "spread": 1e-9, "noise": 0, "form": ")", form,
        R"(", )", form == "value" ? "" : R"("timeConstantMinutes": 40, )",
        R"("gainDegH": [0.02, -0.01, 0.005],
            "heater": {"periodHours": 4, "onFraction": 0.5, "step": 1.5, "channel": "heater_2"}})")));
    ASSERT_THAT(s, IsOk());
    est::SimulationSpec spec;
    spec.config = Config();
    ASSERT_THAT(ApplyScenario(*s, &spec), IsOk());
    spec.duration = 4.0 * 3600.0;
    auto profile = MakeScenarioProfile(*s, "", spec.duration);
    ASSERT_THAT(profile, IsOk());
    spec.profile = *profile;
    auto result = est::Simulate(spec);
    ASSERT_THAT(result, IsOk());
    ASSERT_TRUE(result->effects[1].channel_drift.has_value());
    const Vector3d gain_deg_h(0.02, -0.01, 0.005);
    int off_checked = 0;
    for (size_t i = 0; i < result->truth.size(); ++i) {
      const est::TruthSample& t = result->truth[i];
      const double t_h = absl::ToDoubleHours(t.time - spec.start);
      const bool on = std::fmod(t_h, 4.0) < 2.0;
      const est::GyroTruthSample& g2 = *t.gyros[1];
      EXPECT_NEAR(g2.channel_value, 290.0 + (on ? 1.5 : 0.0), 1e-6) << t_h;
      const est::TelemetryFrame& frame = result->recording.frames[i];
      ASSERT_NE(frame.channels.Find("T_gyro2"), nullptr) << t_h;
      EXPECT_NEAR(*frame.channels.Find("T_gyro2"), g2.channel_value, 1e-12);
      ASSERT_NE(frame.channels.Find("heater_2"), nullptr) << t_h;
      EXPECT_EQ(*frame.channels.Find("heater_2"), on ? 1.0 : 0.0) << t_h;
      EXPECT_TRUE(t.gyros[0]->dw_channel_k_rad_s.isZero(0.0));
      if (t_h == 0.0 || t_h == 2.0 || t_h == 4.0) continue;  // the switching instants
      const Vector3d dw_deg_h = g2.dw_channel_k_rad_s.unaryExpr(&est::RadPerSecToDegPerHour);
      Vector3d expected_deg_h = Vector3d::Zero();
      if (form == "value") {
        expected_deg_h = (on ? 1.5 : 0.0) * gain_deg_h;
      } else if (!on) {
        const double tau_h = 40.0 / 60.0;
        expected_deg_h = -1.5 / tau_h * std::exp(-(t_h - 2.0) / tau_h) * gain_deg_h;
        ++off_checked;
      }
      EXPECT_LT((dw_deg_h - expected_deg_h).norm(), 1e-4 * gain_deg_h.norm() + 1e-9)
          << t_h << ": " << dw_deg_h.transpose() << " against " << expected_deg_h.transpose();
    }
    if (form == "derivative") EXPECT_GT(off_checked, 100);
  }
}

// Through the CLI: `esg simulate` with a scenario whose gyro 2 follows its temperature through a
// 40 min lag writes the `ch:` column and --write-config declares the channel; `esg diagnose` on
// that recording with that configuration names gyro 2, the channel and the lag (its 95% interval
// holding 40 min, the gain within 3 sigma of the scenario's). A bad channel
// drift exits 2 naming the key.
TEST(ChannelScenario, SimulatedThroughTheCliAndDiagnosedByTheChannel) {
  TempDir dir;
  WriteFile(dir.File("scenario.json"), R"({
    "description": "gyro 2 follows its temperature through a lag",
    "profile": "mixed", "profileSeed": 3,
    "gyros": [{"id": 2, "channelDrift": {"channel": "T_gyro2", "form": "lag",
                                         "timeConstantMinutes": 40,
                                         "gainDegH": [-0.015, 0.015, 0.0125]}}]
  })");
  RunResult r = RunBinary(dir, ESG_BINARY,
                          "simulate --config " + Quote(Rdk1()) + " --scenario " +
                              Quote(dir.File("scenario.json")) + " --hours 10 --seed 5 --out " +
                              Quote(dir.File("rec.csv")) + " --write-config " +
                              Quote(dir.File("config.json")));
  ASSERT_EQ(r.exit_code, 0) << r.err;
  absl::StatusOr<est::Recording> recording = storage::ReadRecordingCsv(dir.File("rec.csv"));
  ASSERT_THAT(recording, IsOk());
  int carried = 0;
  for (const est::TelemetryFrame& f : recording->frames) carried += f.channels.Find("T_gyro2") != nullptr;
  EXPECT_EQ(carried, static_cast<int>(recording->frames.size()));
  absl::StatusOr<est::SpacecraftConfig> config =
      proto_convert::ReadConfigFile(dir.File("config.json"));
  ASSERT_THAT(config, IsOk());
  ASSERT_EQ(config->channels.size(), 1u);
  EXPECT_EQ(config->channels[0].name, "T_gyro2");
  EXPECT_EQ(config->channels[0].unit, "K");

  r = RunBinary(dir, ESG_BINARY,
                "diagnose --config " + Quote(dir.File("config.json")) + " --recording " +
                    Quote(dir.File("rec.csv")) + " --effects channel_drift --max-effects 1 --json");
  ASSERT_EQ(r.exit_code, 0) << r.err;
  const nlohmann::json doc = nlohmann::json::parse(r.out);
  ASSERT_FALSE(doc.at("findings").empty()) << r.out;
  const nlohmann::json& f = doc.at("findings").at(0);
  EXPECT_EQ(f.at("effect"), "basis_term") << r.out;
  EXPECT_EQ(f.at("gyro"), 2) << r.out;
  EXPECT_EQ(f.at("timeBehaviour").at("kind"), "follows_channel") << r.out;
  ASSERT_FALSE(f.at("modelTerms").empty());
  EXPECT_EQ(f.at("modelTerms").at(0).at("channel"), "T_gyro2");
  EXPECT_EQ(f.at("modelTerms").at(0).at("channelForm"), "lag");
  // The lag's 95% interval holds 40 min; each gain component within 3 sigma of the truth.
  double lower = 0.0, upper = 0.0;
  const double truth[3] = {-0.015, 0.015, 0.0125};
  int gains = 0;
  for (const auto& p : f.at("parameters")) {
    if (p.at("name") == "channelLagLowerHours") lower = p.at("value");
    if (p.at("name") == "channelLagUpperHours") upper = p.at("value");
    for (int i = 0; i < 3; ++i) {
      if (p.at("name") != absl::StrCat("channelGainDegH[", i, "]")) continue;
      EXPECT_LE(std::abs(p.at("value").get<double>() - truth[i]),
                3.0 * p.at("sigma").get<double>())
          << p.dump();
      ++gains;
    }
  }
  EXPECT_EQ(gains, 3) << f.at("explanation");
  EXPECT_LE(lower, 40.0 / 60.0) << f.at("explanation");
  EXPECT_GE(upper, 40.0 / 60.0) << f.at("explanation");

  WriteFile(dir.File("bad.json"),
            R"({"gyros": [{"id": 2, "channelDrift": {"channel": "T_gyro2", "form": "lag",
                                                     "gainDegH": [0.01, 0, 0]}}]})");
  r = RunBinary(dir, ESG_BINARY,
                "simulate --config " + Quote(Rdk1()) + " --scenario " + Quote(dir.File("bad.json")) +
                    " --hours 1 --seed 5 --out " + Quote(dir.File("bad.csv")));
  EXPECT_EQ(r.exit_code, 2);
  EXPECT_THAT(r.err, HasSubstr("gyros[0].channelDrift.timeConstantMinutes: required for form lag"));
}

}  // namespace
}  // namespace esg::client
