// Orbit deliveries on the service (issue 36 item 2, docs/service.md "Orbits") over real gRPC
// and a real SQLite file: UploadOrbit reads a CCSDS OEM as `esg diagnose --orbit` does and
// stores it by the span it covers, ListOrbits lists them, a diagnosis takes the orbit of the
// deliveries that cover its span (the later upload where they overlap) and says which, or why
// none; bad deliveries are refused naming the field, and nothing is stored for them.
#include <chrono>
#include <string>
#include <vector>

#include "estimator/orbit.h"
#include "estimator/units.h"
#include "formats/oem.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "nlohmann/json.hpp"
#include "proto/convert.h"
#include "tests/server/server_test_util.h"

namespace esg::testing {
namespace {

using ::testing::HasSubstr;

// An OEM of `object` on a circular orbit (orbit.h CircularOrbitState) with states every 60 s
// over [from, to].
std::string CircularOem(const std::string& object, absl::Time from, absl::Time to) {
  std::vector<estimator::OrbitState> states;
  for (absl::Time t = from; t <= to; t += absl::Seconds(60)) {
    states.push_back(estimator::CircularOrbitState(estimator::DegToRad(51.6), 0.3, 5400.0, 0.0,
                                                   from, absl::ToDoubleSeconds(t - from)));
  }
  storage::OemHeader header;
  header.object_name = object;
  header.object_id = object;
  header.creation_date = from;
  absl::StatusOr<std::string> text = storage::WriteOem(header, states);
  EXPECT_TRUE(text.ok()) << text.status();
  return text.ok() ? *text : std::string();
}

grpc::Status Upload(esg::v1::EstimationService::Stub& stub, const std::string& id,
                    const std::string& oem, esg::v1::OrbitDelivery* out) {
  grpc::ClientContext context;
  esg::v1::UploadOrbitRequest request;
  request.set_spacecraft_id(id);
  request.set_oem(oem);
  return stub.UploadOrbit(&context, request, out);
}

esg::v1::ListOrbitsResponse List(esg::v1::EstimationService::Stub& stub, const std::string& id) {
  grpc::ClientContext context;
  esg::v1::ListOrbitsRequest request;
  request.set_spacecraft_id(id);
  esg::v1::ListOrbitsResponse out;
  const grpc::Status status = stub.ListOrbits(&context, request, &out);
  EXPECT_TRUE(status.ok()) << status.error_message();
  return out;
}

// The report's `orbit` line of a diagnosis of the whole archive.
std::string DiagnosisOrbitLine(esg::v1::EstimationService::Stub& stub, const std::string& id) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(300));
  esg::v1::DiagnoseRequest request;
  request.set_spacecraft_id(id);
  auto reader = stub.Diagnose(&context, request);
  esg::v1::DiagnoseUpdate update;
  std::string report_json;
  while (reader->Read(&update)) {
    if (update.has_result()) report_json = update.result().report_json();
  }
  const grpc::Status status = reader->Finish();
  EXPECT_TRUE(status.ok()) << status.error_message();
  if (report_json.empty()) return "(no report)";
  const nlohmann::json report = nlohmann::json::parse(report_json);
  return report.value("orbit", std::string("(no orbit line)"));
}

struct Flight {
  SimulatedRun run;
  absl::Time first, last;
};

Flight ConfiguredFlight(esg::v1::EstimationService::Stub& stub, const std::string& id) {
  Flight f{SimulateRun(id, 2.0, 5), absl::Time(), absl::Time()};
  grpc::ClientContext context;
  esg::v1::ConfigureResponse response;
  EXPECT_TRUE(stub.ConfigureSpacecraft(&context, ConfigureRequestFor(f.run.config), &response).ok());
  EXPECT_TRUE(StreamFrames(stub, f.run.frames).status.ok());
  f.first = *proto_convert::TimeFromProto(f.run.frames.front().time());
  f.last = *proto_convert::TimeFromProto(f.run.frames.back().time());
  return f;
}

TEST(OrbitRpc, ADeliveryIsStoredListedAndUsedByTheDiagnosisOfTheSpanItCovers) {
  LoopbackServer server;
  auto stub = server.Stub();
  const Flight f = ConfiguredFlight(*stub, "ORB-1");

  // Before any delivery the diagnosis runs without an orbit and says so.
  EXPECT_THAT(DiagnosisOrbitLine(*stub, "ORB-1"), HasSubstr("no orbit delivery"));

  // A delivery covering half the flight is stored and listed, but not used: it does not cover
  // the span diagnosed.
  const absl::Time middle = f.first + (f.last - f.first) / 2;
  esg::v1::OrbitDelivery first;
  ASSERT_TRUE(Upload(*stub, "ORB-1", CircularOem("ORB-1", f.first - absl::Hours(1), middle),
                     &first).ok());
  EXPECT_GT(first.id(), 0);
  EXPECT_EQ(first.spacecraft_id(), "ORB-1");
  EXPECT_EQ(*proto_convert::TimeFromProto(first.from()), f.first - absl::Hours(1));
  EXPECT_EQ(first.states(), 1 + (middle - (f.first - absl::Hours(1))) / absl::Seconds(60));
  EXPECT_THAT(DiagnosisOrbitLine(*stub, "ORB-1"),
              AllOf(HasSubstr(absl::StrCat("orbit delivery ", first.id(), " not used")),
                    HasSubstr("do not cover the span diagnosed")));

  // A second delivery covering the rest: together they cover the flight and both are used.
  esg::v1::OrbitDelivery second;
  ASSERT_TRUE(Upload(*stub, "ORB-1",
                     CircularOem("ORB-1", middle - absl::Minutes(30), f.last + absl::Hours(1)),
                     &second).ok());
  EXPECT_GT(second.id(), first.id());
  const esg::v1::ListOrbitsResponse listed = List(*stub, "ORB-1");
  ASSERT_EQ(listed.deliveries_size(), 2);
  EXPECT_EQ(listed.deliveries(0).id(), first.id());
  EXPECT_EQ(listed.deliveries(1).id(), second.id());
  EXPECT_EQ(listed.deliveries(1).states(), second.states());
  EXPECT_EQ(DiagnosisOrbitLine(*stub, "ORB-1"),
            absl::StrCat("orbit deliveries ", first.id(), ", ", second.id(),
                         ": used (the Earth's shadow in the sun's regressors)"));
  // Another spacecraft sees none of them.
  ConfiguredFlight(*stub, "ORB-2");
  EXPECT_EQ(List(*stub, "ORB-2").deliveries_size(), 0);
}

TEST(OrbitRpc, BadDeliveriesAreRefusedNamingTheFieldAndNothingIsStored) {
  LoopbackServer server;
  auto stub = server.Stub();
  const Flight f = ConfiguredFlight(*stub, "ORB-3");
  const std::string good = CircularOem("ORB-3", f.first, f.last);
  esg::v1::OrbitDelivery out;

  grpc::Status status = Upload(*stub, "ORB-3", "", &out);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), HasSubstr("oem: empty"));

  status = Upload(*stub, "ORB-3", CircularOem("SOMEONE-ELSE", f.first, f.last), &out);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), AllOf(HasSubstr("oem: line"), HasSubstr("OBJECT_NAME"),
                                            HasSubstr("SOMEONE-ELSE")));

  std::string tt = good;
  const size_t at = tt.find("TIME_SYSTEM");
  ASSERT_NE(at, std::string::npos);
  tt.replace(tt.find("UTC", at), 3, "TT");
  status = Upload(*stub, "ORB-3", tt, &out);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), AllOf(HasSubstr("oem: line"), HasSubstr("TIME_SYSTEM")));

  status = Upload(*stub, "ORB-3", "CCSDS_OEM_VERS = 2.0\nnonsense\n", &out);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), HasSubstr("oem: line"));

  status = Upload(*stub, "NOT-CONFIGURED", CircularOem("NOT-CONFIGURED", f.first, f.last), &out);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_THAT(status.error_message(), HasSubstr("NOT-CONFIGURED"));

  status = Upload(*stub, "", good, &out);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), HasSubstr("spacecraft_id"));

  EXPECT_EQ(List(*stub, "ORB-3").deliveries_size(), 0);
  ASSERT_TRUE(Upload(*stub, "ORB-3", good, &out).ok());
  EXPECT_EQ(List(*stub, "ORB-3").deliveries_size(), 1);
}

TEST(OrbitRpc, BeyondTheBoundTheOldestDeliveriesGo) {
  server::ServerOptions options;
  options.max_stored_orbits = 2;
  LoopbackServer server(options);
  auto stub = server.Stub();
  const Flight f = ConfiguredFlight(*stub, "ORB-4");
  std::vector<int64_t> ids;
  for (int day = 0; day < 3; ++day) {
    esg::v1::OrbitDelivery out;
    ASSERT_TRUE(Upload(*stub, "ORB-4",
                       CircularOem("ORB-4", f.first + absl::Hours(24 * day),
                                   f.first + absl::Hours(24 * day + 2)),
                       &out).ok());
    ids.push_back(out.id());
  }
  const esg::v1::ListOrbitsResponse listed = List(*stub, "ORB-4");
  ASSERT_EQ(listed.deliveries_size(), 2);
  EXPECT_EQ(listed.deliveries(0).id(), ids[1]);
  EXPECT_EQ(listed.deliveries(1).id(), ids[2]);
}

}  // namespace
}  // namespace esg::testing
