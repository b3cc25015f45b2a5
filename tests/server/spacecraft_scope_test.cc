// server/spacecraft_scope.h: the routing metadata x-esg-spacecraft scopes a call to one
// spacecraft (docs/service.md "Routing by spacecraft"). First the helper on its own, then the
// service on loopback: a scoped stream refuses another spacecraft's frame in its ack and goes on,
// a scoped request naming another spacecraft is INVALID_ARGUMENT, and calls without the metadata
// behave as before.
#include "server/spacecraft_scope.h"

#include <map>
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "proto/routing_metadata.h"
#include "tests/server/server_test_util.h"
#include "tests/testing/status_matchers.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::LoopbackServer;
using ::esg::testing::Session;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StatusIs;
using ::esg::testing::StreamFrames;
using ::testing::AllOf;
using ::testing::HasSubstr;
using ::testing::StartsWith;

using Metadata = std::multimap<grpc::string_ref, grpc::string_ref>;

TEST(SpacecraftScope, TheMetadataKeyIsTheOneNginxHashesOn) {
  // deploy/nginx/esg.conf hashes on $http_x_esg_spacecraft: the header x-esg-spacecraft.
  EXPECT_STREQ(proto_convert::kSpacecraftMetadataKey, "x-esg-spacecraft");
}

TEST(SpacecraftScope, NoMetadataIsNoScope) {
  const Metadata metadata{{"authorization", "Bearer x"}, {"x-esg-other", "RDK-1"}};
  absl::StatusOr<std::string> scope = SpacecraftScope(metadata);
  ASSERT_TRUE(scope.ok()) << scope.status();
  EXPECT_EQ(*scope, "");
}

TEST(SpacecraftScope, TheMetadataNamesTheSpacecraft) {
  const Metadata metadata{{"x-esg-spacecraft", "RDK-1"}};
  absl::StatusOr<std::string> scope = SpacecraftScope(metadata);
  ASSERT_TRUE(scope.ok()) << scope.status();
  EXPECT_EQ(*scope, "RDK-1");
}

TEST(SpacecraftScope, AValueThatIsNoIdentifierIsRefusedNamingTheMetadata) {
  for (const char* bad : {"", "-RDK", "RDK 1", "RDK\n1"}) {
    const Metadata metadata{{"x-esg-spacecraft", bad}};
    EXPECT_THAT(SpacecraftScope(metadata),
                StatusIs(absl::StatusCode::kInvalidArgument, StartsWith("x-esg-spacecraft: ")))
        << bad;
  }
}

TEST(SpacecraftScope, RepeatedMetadataMustAgree) {
  const Metadata same{{"x-esg-spacecraft", "RDK-1"}, {"x-esg-spacecraft", "RDK-1"}};
  absl::StatusOr<std::string> scope = SpacecraftScope(same);
  ASSERT_TRUE(scope.ok()) << scope.status();
  EXPECT_EQ(*scope, "RDK-1");
  const Metadata different{{"x-esg-spacecraft", "RDK-1"}, {"x-esg-spacecraft", "RDK-2"}};
  EXPECT_THAT(SpacecraftScope(different),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       AllOf(StartsWith("x-esg-spacecraft: given twice"), HasSubstr("'RDK-1'"),
                             HasSubstr("'RDK-2'"))));
}

TEST(SpacecraftScope, AnUnscopedCallMayNameAnySpacecraft) {
  EXPECT_TRUE(CheckInScope("", "RDK-1").ok());
  EXPECT_TRUE(CheckInScope("", "").ok());
}

TEST(SpacecraftScope, AScopedCallMayNameOnlyItsSpacecraft) {
  EXPECT_TRUE(CheckInScope("RDK-1", "RDK-1").ok());
  EXPECT_THAT(CheckInScope("RDK-1", "RDK-2"),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       AllOf(StartsWith("spacecraft_id: 'RDK-2' is not 'RDK-1'"),
                             HasSubstr("x-esg-spacecraft"))));
  // A request about every spacecraft is outside every scope.
  EXPECT_THAT(CheckInScope("RDK-1", ""),
              StatusIs(absl::StatusCode::kInvalidArgument,
                       AllOf(StartsWith("spacecraft_id: empty (every spacecraft)"),
                             HasSubstr("'RDK-1'"))));
}

TEST(SpacecraftScope, AnIdThatIsNoIdentifierIsQuotedEscapedAndShort) {
  const absl::Status status = CheckInScope("RDK-1", std::string("evil\n") + std::string(200, 'x'));
  ASSERT_EQ(status.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(std::string(status.message()).find('\n'), std::string::npos) << status.message();
  EXPECT_THAT(std::string(status.message()), HasSubstr("'evil\\nxxx"));
  EXPECT_LT(status.message().size(), 400u) << status.message();
}

// ---- The service on loopback ----------------------------------------------------------------

const SimulatedRun& RunA() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("SCOPE-A", 0.5, 31));
  return *run;
}
const SimulatedRun& RunB() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("SCOPE-B", 0.5, 32));
  return *run;
}

void Configure(esg::v1::EstimationService::Stub& stub, const estimator::SpacecraftConfig& config) {
  grpc::ClientContext ctx;
  esg::v1::ConfigureResponse r;
  ASSERT_TRUE(stub.ConfigureSpacecraft(&ctx, ConfigureRequestFor(config), &r).ok());
}

grpc::Status GetSession(esg::v1::EstimationService::Stub& stub, const std::string& id,
                        const std::string& routed_by) {
  grpc::ClientContext ctx;
  if (!routed_by.empty()) ctx.AddMetadata("x-esg-spacecraft", routed_by);
  esg::v1::GetSessionRequest request;
  request.set_spacecraft_id(id);
  esg::v1::SessionInfo info;
  return stub.GetSession(&ctx, request, &info);
}

TEST(SpacecraftScopeService, AScopedStreamRefusesAnotherSpacecraftsFrameAndKeepsItsOwn) {
  LoopbackServer server;
  auto stub = server.Stub();
  Configure(*stub, RunA().config);
  Configure(*stub, RunB().config);
  // Five frames of A with one frame of B (configured on this node too) in the middle.
  std::vector<esg::v1::TelemetryFrame> frames(RunA().frames.begin(), RunA().frames.begin() + 5);
  frames.insert(frames.begin() + 2, RunB().frames[0]);
  auto result = StreamFrames(*stub, frames, /*token=*/"", /*routed_by=*/"SCOPE-A");
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), 6u);
  for (int i = 0; i < 6; ++i) {
    if (i == 2) continue;
    EXPECT_TRUE(result.acks[i].accepted()) << i;
    EXPECT_EQ(result.acks[i].spacecraft_id(), "SCOPE-A") << i;
  }
  const esg::v1::TelemetryAck& refused = result.acks[2];
  EXPECT_FALSE(refused.accepted());
  EXPECT_EQ(refused.spacecraft_id(), "SCOPE-B");
  EXPECT_EQ(refused.rejection().code(), static_cast<int>(absl::StatusCode::kInvalidArgument));
  EXPECT_EQ(refused.rejection().field(), "spacecraft_id");
  EXPECT_THAT(refused.rejection().reason(),
              AllOf(HasSubstr("'SCOPE-B'"), HasSubstr("'SCOPE-A'"), HasSubstr("x-esg-spacecraft")));
  EXPECT_EQ(Session(*stub, "SCOPE-A").frames_accepted(), 5);
  EXPECT_EQ(Session(*stub, "SCOPE-B").frames_accepted(), 0);
  // Not held against B's session: the frame never reached it.
  EXPECT_EQ(Session(*stub, "SCOPE-B").frames_rejected(), 0);
}

TEST(SpacecraftScopeService, AnUnscopedStreamCarriesSeveralSpacecraftAsBefore) {
  LoopbackServer server;
  auto stub = server.Stub();
  Configure(*stub, RunA().config);
  Configure(*stub, RunB().config);
  const std::vector<esg::v1::TelemetryFrame> frames = {RunA().frames[0], RunB().frames[0],
                                                       RunA().frames[1], RunB().frames[1]};
  auto result = StreamFrames(*stub, frames);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), 4u);
  for (const esg::v1::TelemetryAck& ack : result.acks) EXPECT_TRUE(ack.accepted());
}

TEST(SpacecraftScopeService, AStreamWithAMalformedScopeFailsBeforeAnyFrame) {
  LoopbackServer server;
  auto stub = server.Stub();
  Configure(*stub, RunA().config);
  auto result = StreamFrames(*stub, {RunA().frames[0]}, "", "bad scope");
  EXPECT_EQ(result.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(result.status.error_message(), StartsWith("x-esg-spacecraft: "));
  EXPECT_TRUE(result.acks.empty());
  EXPECT_EQ(Session(*stub, "SCOPE-A").frames_accepted(), 0);
}

TEST(SpacecraftScopeService, AScopedRequestMustNameItsSpacecraft) {
  LoopbackServer server;
  auto stub = server.Stub();
  Configure(*stub, RunA().config);
  Configure(*stub, RunB().config);
  EXPECT_TRUE(GetSession(*stub, "SCOPE-A", "").ok());
  EXPECT_TRUE(GetSession(*stub, "SCOPE-A", "SCOPE-A").ok());
  const grpc::Status other = GetSession(*stub, "SCOPE-A", "SCOPE-B");
  EXPECT_EQ(other.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(other.error_message(),
              AllOf(StartsWith("spacecraft_id: 'SCOPE-A' is not 'SCOPE-B'")));

  {  // A unary call of another shape: the coefficient history.
    grpc::ClientContext ctx;
    ctx.AddMetadata("x-esg-spacecraft", "SCOPE-B");
    esg::v1::HistoryRequest request;
    request.set_spacecraft_id("SCOPE-A");
    esg::v1::HistoryResponse response;
    const grpc::Status status = stub->GetCoefficientHistory(&ctx, request, &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_THAT(status.error_message(), StartsWith("spacecraft_id: "));
  }
  {  // A server stream: the telemetry export.
    grpc::ClientContext ctx;
    ctx.AddMetadata("x-esg-spacecraft", "SCOPE-B");
    esg::v1::ExportTelemetryRequest request;
    request.set_spacecraft_id("SCOPE-A");
    auto reader = stub->ExportTelemetry(&ctx, request);
    esg::v1::ExportTelemetryResponse chunk;
    while (reader->Read(&chunk)) {
    }
    const grpc::Status status = reader->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_THAT(status.error_message(), StartsWith("spacecraft_id: "));
  }
  {  // A subscription to every spacecraft is no call about one.
    grpc::ClientContext ctx;
    ctx.AddMetadata("x-esg-spacecraft", "SCOPE-A");
    esg::v1::AlertSubscription request;
    auto reader = stub->SubscribeAlerts(&ctx, request);
    esg::v1::Alert alert;
    while (reader->Read(&alert)) {
    }
    const grpc::Status status = reader->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_THAT(status.error_message(), StartsWith("spacecraft_id: empty (every spacecraft)"));
  }
  {  // A prediction is refused before it takes a prediction slot.
    grpc::ClientContext ctx;
    ctx.AddMetadata("x-esg-spacecraft", "SCOPE-B");
    esg::v1::PredictRequest request;
    request.set_spacecraft_id("SCOPE-A");
    esg::v1::PredictResponse response;
    const grpc::Status status = stub->PredictAttitude(&ctx, request, &response);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_THAT(status.error_message(), StartsWith("spacecraft_id: "));
  }
}

TEST(SpacecraftScopeService, ListSessionsNamesNoSpacecraftAndIgnoresTheScope) {
  LoopbackServer server;
  auto stub = server.Stub();
  Configure(*stub, RunA().config);
  Configure(*stub, RunB().config);
  grpc::ClientContext ctx;
  ctx.AddMetadata("x-esg-spacecraft", "SCOPE-A");
  esg::v1::ListSessionsResponse response;
  ASSERT_TRUE(stub->ListSessions(&ctx, {}, &response).ok());
  EXPECT_EQ(response.sessions_size(), 2);
}

}  // namespace
}  // namespace esg::server
