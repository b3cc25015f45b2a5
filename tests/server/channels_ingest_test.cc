// Housekeeping channels at ingest (docs/formats.md "Channels", docs/service.md "Ingest contract")
// against a real esgd on loopback, on SQLite and on PostgreSQL: a frame with a value out of its
// declared range, an undeclared channel, a non-finite value or too many channels is refused
// INVALID_ARGUMENT naming the channel; the accepted frames are archived with their channels, and
// stay so (read back, re-run, exported) after a reconfiguration that no longer declares them.
#include <cmath>
#include <limits>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/time/time.h"
#include "estimator/channels.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/postgres_server.h"
#include "tests/testing/status_matchers.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::IsOk;
using ::esg::testing::LoopbackServer;
using ::esg::testing::PostgresServer;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StreamFrames;
using ::testing::HasSubstr;

constexpr int kInvalidArgument = 3;  // grpc::StatusCode::INVALID_ARGUMENT

const SimulatedRun& RunC() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("CHAN-1", 0.5, 38));
  return *run;
}

estimator::SpacecraftConfig WithChannels(estimator::SpacecraftConfig config) {
  estimator::ChannelConfig t;
  t.name = "T_gyro2";
  t.unit = "K";
  t.valid_min = 250.0;
  t.valid_max = 350.0;
  t.max_age = absl::Minutes(10);
  estimator::ChannelConfig heater;
  heater.name = "heater_1";
  heater.unit = "1";
  heater.valid_min = 0.0;
  heater.valid_max = 1.0;
  config.channels = {t, heater};
  return config;
}

void Configure(esg::v1::EstimationService::Stub& stub, const estimator::SpacecraftConfig& config,
               bool replace) {
  grpc::ClientContext ctx;
  esg::v1::ConfigureRequest request = ConfigureRequestFor(config);
  request.set_replace(replace);
  esg::v1::ConfigureResponse r;
  const grpc::Status status = stub.ConfigureSpacecraft(&ctx, request, &r);
  ASSERT_TRUE(status.ok()) << status.error_message();
}

std::vector<esg::v1::TelemetryFrame> Export(esg::v1::EstimationService::Stub& stub) {
  grpc::ClientContext ctx;
  esg::v1::ExportTelemetryRequest request;
  request.set_spacecraft_id("CHAN-1");
  auto reader = stub.ExportTelemetry(&ctx, request);
  std::vector<esg::v1::TelemetryFrame> frames;
  esg::v1::ExportTelemetryResponse chunk;
  while (reader->Read(&chunk)) {
    frames.insert(frames.end(), chunk.frames().begin(), chunk.frames().end());
  }
  const grpc::Status status = reader->Finish();
  EXPECT_TRUE(status.ok()) << status.error_message();
  return frames;
}

void RefusesBadChannelsAndKeepsTheAcceptedOnes(LoopbackServer& server) {
  ASSERT_NE(server.get(), nullptr);
  auto stub = server.Stub();
  Configure(*stub, WithChannels(RunC().config), /*replace=*/false);
  std::vector<esg::v1::TelemetryFrame> frames(RunC().frames.begin(), RunC().frames.begin() + 10);
  auto set = [&](int i, const std::string& name, double value) {
    (*frames[i].mutable_channels())[name] = value;
  };
  set(0, "T_gyro2", 301.5);
  set(0, "heater_1", 1.0);
  set(1, "T_gyro2", 350.5);  // out of range
  set(2, "T_gyro3", 300.0);  // undeclared
  set(3, "T_gyro2", std::numeric_limits<double>::quiet_NaN());
  for (int k = 0; k <= estimator::kMaxChannels; ++k) set(4, absl::StrCat("c", k), 0.0);
  set(5, "heater_1", 0.0);  // T_gyro2 absent: its own cadence
  set(7, "T_gyro2", 350.0);  // the bound itself
  const auto result = StreamFrames(*stub, frames);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), frames.size());
  struct Refusal {
    int frame;
    std::string field;
    std::string reason;
  };
  const std::vector<Refusal> refusals = {
      {1, "channels[\"T_gyro2\"]", "350.5 K is outside its valid range [250, 350] K"},
      {2, "channels[\"T_gyro3\"]",
       "not declared in the configuration (declared: T_gyro2, heater_1)"},
      {3, "channels[\"T_gyro2\"]", "nan is not finite"},
      {4, "channels", "65 channels, at most 64 in a frame"}};
  for (const Refusal& r : refusals) {
    const esg::v1::TelemetryAck& ack = result.acks[r.frame];
    EXPECT_FALSE(ack.accepted()) << r.frame;
    EXPECT_EQ(ack.rejection().code(), kInvalidArgument) << r.frame;
    EXPECT_EQ(ack.rejection().field(), r.field) << r.frame;
    EXPECT_THAT(ack.rejection().reason(), HasSubstr(r.reason)) << r.frame;
  }
  for (int i : {0, 5, 6, 7, 8, 9}) {
    EXPECT_TRUE(result.acks[i].accepted()) << i << ": " << result.acks[i].rejection().reason();
  }
  ASSERT_THAT(server.core().WaitApplied("CHAN-1", absl::Seconds(60)), IsOk());

  // Archived with their channels; read back again after a reconfiguration that declares none
  // (the filter re-runs over the archive: accepted data is never lost).
  for (bool reconfigured : {false, true}) {
    SCOPED_TRACE(reconfigured ? "after the reconfiguration" : "as accepted");
    if (reconfigured) {
      Configure(*stub, RunC().config, /*replace=*/true);
      ASSERT_THAT(server.core().WaitApplied("CHAN-1", absl::Seconds(60)), IsOk());
      grpc::ClientContext ctx;
      esg::v1::GetSessionRequest request;
      request.set_spacecraft_id("CHAN-1");
      esg::v1::SessionInfo info;
      ASSERT_TRUE(stub->GetSession(&ctx, request, &info).ok());
      EXPECT_NE(info.state(), esg::v1::SESSION_STATE_QUARANTINED) << info.quarantine_reason();
    }
    const std::vector<esg::v1::TelemetryFrame> stored = Export(*stub);
    ASSERT_EQ(stored.size(), 6u);
    EXPECT_EQ(stored[0].sequence(), 1);
    ASSERT_EQ(stored[0].channels_size(), 2);
    EXPECT_EQ(stored[0].channels().at("T_gyro2"), 301.5);
    EXPECT_EQ(stored[0].channels().at("heater_1"), 1.0);
    EXPECT_EQ(stored[1].sequence(), 6);
    ASSERT_EQ(stored[1].channels_size(), 1);
    EXPECT_EQ(stored[1].channels().at("heater_1"), 0.0);
    EXPECT_EQ(stored[2].channels_size(), 0);
    EXPECT_EQ(stored[3].sequence(), 8);
    ASSERT_EQ(stored[3].channels_size(), 1);
    EXPECT_EQ(stored[3].channels().at("T_gyro2"), 350.0);
  }
}

TEST(ChannelsIngest, BadChannelsAreRefusedNamingTheChannelAndAcceptedOnesAreKept) {
  LoopbackServer server;
  RefusesBadChannelsAndKeepsTheAcceptedOnes(server);
}

TEST(ChannelsIngestPostgres, BadChannelsAreRefusedNamingTheChannelAndAcceptedOnesAreKept) {
  std::string error;
  PostgresServer* pg = PostgresServer::Shared(&error);
  ASSERT_NE(pg, nullptr) << "the PostgreSQL test server cannot start: " << error;
  absl::StatusOr<std::string> uri = pg->CreateDatabase();
  ASSERT_THAT(uri, IsOk());
  LoopbackServer server({}, *uri);
  RefusesBadChannelsAndKeepsTheAcceptedOnes(server);
}

}  // namespace
}  // namespace esg::server
