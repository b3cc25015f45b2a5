// The Diagnose RPC (issue 5, docs/discovery.md) over real gRPC: progress while it runs, the report
// as the final update, stored in SQLite and listed by ListDiagnoses; bad requests get their code
// and name the field.
#include <chrono>

#include <cmath>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "tests/server/server_test_util.h"

namespace esg::testing {
namespace {

using ::testing::HasSubstr;

struct DiagnoseCall {
  std::vector<esg::v1::DiagnoseUpdate> updates;
  grpc::Status status;
};

DiagnoseCall CallDiagnose(esg::v1::EstimationService::Stub& stub,
                          const esg::v1::DiagnoseRequest& request) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(300));
  auto reader = stub.Diagnose(&context, request);
  DiagnoseCall call;
  esg::v1::DiagnoseUpdate update;
  while (reader->Read(&update)) call.updates.push_back(update);
  call.status = reader->Finish();
  return call;
}

TEST(DiagnoseRpc, StreamsProgressThenTheStoredReport) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = SimulateRun("DIAG-1", 12.0, 3);
  {
    grpc::ClientContext context;
    esg::v1::ConfigureResponse response;
    ASSERT_TRUE(
        stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config, "10+11"), &response)
            .ok());
  }
  const StreamResult streamed = StreamFrames(*stub, run.frames);
  ASSERT_TRUE(streamed.status.ok()) << streamed.status.error_message();

  esg::v1::DiagnoseRequest request;
  request.set_spacecraft_id("DIAG-1");
  const DiagnoseCall call = CallDiagnose(*stub, request);
  ASSERT_TRUE(call.status.ok()) << call.status.error_message();
  ASSERT_GE(call.updates.size(), 2u);  // progress, then the result
  for (size_t i = 0; i + 1 < call.updates.size(); ++i) {
    EXPECT_FALSE(call.updates[i].has_result());
    EXPECT_GE(call.updates[i].progress(), 0.0);
    EXPECT_LE(call.updates[i].progress(), 1.0);
    // Never backwards: a round's time-behaviour fits continue its count (with nothing
    // significant among the constant effects, as here, they run).
    if (i > 0) {
      EXPECT_GE(call.updates[i].progress(), call.updates[i - 1].progress())
          << call.updates[i].stage() << " after " << call.updates[i - 1].stage();
    }
  }
  const esg::v1::DiagnoseUpdate& last = call.updates.back();
  ASSERT_TRUE(last.has_result());
  const esg::v1::DiagnosisResult& result = last.result();
  EXPECT_EQ(result.frames(), static_cast<int64_t>(run.frames.size()));
  EXPECT_GT(result.id(), 0);
  // The simulated truth is the configured model: nothing is missing.
  EXPECT_EQ(result.verdict(), "none");
  const nlohmann::json report = nlohmann::json::parse(result.report_json());
  EXPECT_EQ(report.at("verdict"), result.verdict());
  EXPECT_TRUE(report.at("fit").contains("before"));
  EXPECT_TRUE(report.at("fit").at("before").contains("residualRmsArcsec"));

  grpc::ClientContext context;
  esg::v1::ListDiagnosesRequest list_request;
  list_request.set_spacecraft_id("DIAG-1");
  esg::v1::ListDiagnosesResponse listed;
  ASSERT_TRUE(stub->ListDiagnoses(&context, list_request, &listed).ok());
  ASSERT_EQ(listed.diagnoses_size(), 1);
  EXPECT_EQ(listed.diagnoses(0).id(), result.id());
  EXPECT_EQ(listed.diagnoses(0).verdict(), result.verdict());
  // The frame count is stored with the diagnosis, not only returned by the call that made it.
  EXPECT_EQ(listed.diagnoses(0).frames(), static_cast<int64_t>(run.frames.size()));
  // The list carries summaries; GetDiagnosis returns the stored report in full.
  grpc::ClientContext get_context;
  esg::v1::GetDiagnosisRequest get;
  get.set_spacecraft_id("DIAG-1");
  get.set_id(result.id());
  esg::v1::DiagnosisResult stored;
  ASSERT_TRUE(stub->GetDiagnosis(&get_context, get, &stored).ok());
  EXPECT_EQ(stored.report_json(), result.report_json());
  EXPECT_EQ(stored.frames(), static_cast<int64_t>(run.frames.size()));
}

TEST(DiagnoseRpc, BadRequestsGetTheirCodeAndNameTheField) {
  LoopbackServer server;
  auto stub = server.Stub();
  const SimulatedRun run = SimulateRun("DIAG-2", 1.0, 4);
  {
    grpc::ClientContext context;
    esg::v1::ConfigureResponse response;
    ASSERT_TRUE(
        stub->ConfigureSpacecraft(&context, ConfigureRequestFor(run.config), &response).ok());
  }
  ASSERT_TRUE(StreamFrames(*stub, run.frames).status.ok());

  esg::v1::DiagnoseRequest unknown;
  unknown.set_spacecraft_id("NOPE");
  DiagnoseCall call = CallDiagnose(*stub, unknown);
  EXPECT_EQ(call.status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_THAT(call.status.error_message(), HasSubstr("NOPE"));

  esg::v1::DiagnoseRequest reversed;
  reversed.set_spacecraft_id("DIAG-2");
  reversed.mutable_from()->set_seconds(1551400000);
  reversed.mutable_to()->set_seconds(1551390000);
  call = CallDiagnose(*stub, reversed);
  EXPECT_EQ(call.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(call.status.error_message(), HasSubstr("to:"));

  esg::v1::DiagnoseRequest empty_span;
  empty_span.set_spacecraft_id("DIAG-2");
  empty_span.mutable_from()->set_seconds(1);
  empty_span.mutable_to()->set_seconds(2);
  call = CallDiagnose(*stub, empty_span);
  EXPECT_EQ(call.status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_THAT(call.status.error_message(), HasSubstr("no archived telemetry"));

  esg::v1::DiagnoseRequest bad_model;
  bad_model.set_spacecraft_id("DIAG-2");
  bad_model.set_model("12");
  call = CallDiagnose(*stub, bad_model);
  EXPECT_EQ(call.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(call.status.error_message(), HasSubstr("model"));

  for (double period : {-5400.0, std::nan("")}) {
    esg::v1::DiagnoseRequest bad_period;
    bad_period.set_spacecraft_id("DIAG-2");
    bad_period.set_orbital_period_s(period);
    call = CallDiagnose(*stub, bad_period);
    EXPECT_EQ(call.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << period;
    EXPECT_THAT(call.status.error_message(), HasSubstr("orbital_period_s")) << period;
  }
}

}  // namespace
}  // namespace esg::testing
