// Hostile and careless input against a real esgd on loopback (docs/service.md "Security",
// "Ingest contract", "Limits"): each case was accepted before the check it tests, and each
// refusal names its field.
//   - a frame's sequence beyond 2^53 - 1 and a suspension offset voltage beyond 10 kV;
//   - an archived frame the current checks refuse (stored by an older esgd) is skipped with an
//     alert when the filter runs over the archive again, never a quarantine loop, and a
//     diagnosis of the window skips it too;
//   - operator names: another operator's name under a token is refused, names are bounded and
//     hold no control or bidirectional formatting character;
//   - a status message echoing a 1 MB value stays bounded (INVALID_ARGUMENT, not
//     RESOURCE_EXHAUSTED);
//   - refused tokens are throttled per address, and a valid token still passes meanwhile;
//   - a drift coefficient out of range or of an unknown term is named where the request gave it:
//     its keyed entry, or the deprecated field that still reads.
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "absl/time/civil_time.h"
#include "estimator/basis_term.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/auth_throttle.h"
#include "server/grpc_status.h"
#include "server/log.h"
#include "storage/storage.h"
#include "tests/server/server_test_util.h"

namespace esg::server {
namespace {

using ::esg::testing::ConfigureRequestFor;
using ::esg::testing::LoopbackServer;
using ::esg::testing::SimulatedRun;
using ::esg::testing::SimulateRun;
using ::esg::testing::StreamFrames;
using ::esg::testing::TempDir;
using ::esg::testing::WriteTokens;
using ::testing::HasSubstr;

const SimulatedRun& RunH() {
  static const SimulatedRun* run = new SimulatedRun(SimulateRun("HOST-1", 1.5, 41));
  return *run;
}

// RunH's configuration with a calibrated drift proportional to gyro 1's suspension offset
// voltage: the term through which an absurd offset voltage reaches the covariance.
estimator::SpacecraftConfig WithVoltageTerm(estimator::SpacecraftConfig config) {
  estimator::BasisTerm term;
  term.kind = estimator::BasisKind::kSuspensionVoltage;
  term.axis = 1;
  term.index = {1, 1};
  // The largest prior the limits allow: 10 deg/h at 1 mV, 1e4 deg/h per V (docs/formats.md).
  term.sigma = 1e4 / estimator::BasisValueToJson(term.kind);
  config.gyros[0].basis_terms.push_back(term);
  return config;
}

void Configure(esg::v1::EstimationService::Stub& stub, const estimator::SpacecraftConfig& config,
               bool replace = false) {
  grpc::ClientContext ctx;
  esg::v1::ConfigureRequest request = ConfigureRequestFor(config);
  request.set_replace(replace);
  esg::v1::ConfigureResponse r;
  const grpc::Status status = stub.ConfigureSpacecraft(&ctx, request, &r);
  ASSERT_TRUE(status.ok()) << status.error_message();
}

esg::v1::SessionInfo GetSession(esg::v1::EstimationService::Stub& stub, const std::string& id) {
  grpc::ClientContext ctx;
  esg::v1::GetSessionRequest request;
  request.set_spacecraft_id(id);
  esg::v1::SessionInfo info;
  EXPECT_TRUE(stub.GetSession(&ctx, request, &info).ok());
  return info;
}

TEST(HostileInput, SequenceBeyondTwoToThe53AndOffsetVoltageBeyondTenKilovoltsAreRefused) {
  LoopbackServer server;
  auto stub = server.Stub();
  Configure(*stub, WithVoltageTerm(RunH().config));
  std::vector<esg::v1::TelemetryFrame> frames(RunH().frames.begin(), RunH().frames.begin() + 3);
  frames[1].set_sequence(INT64_MAX);
  frames[2].set_sequence((int64_t{1} << 53));
  esg::v1::TelemetryFrame hot = RunH().frames[3];
  hot.set_sequence(4);
  hot.mutable_gyros(0)->clear_u_k_mv();
  for (double u : {1e308, 0.0, 0.0}) hot.mutable_gyros(0)->add_u_k_mv(u);
  frames.push_back(hot);
  // The largest sequence that is still exact in JSON is accepted.
  esg::v1::TelemetryFrame last = RunH().frames[4];
  last.set_sequence((int64_t{1} << 53) - 1);
  frames.push_back(last);
  const auto result = StreamFrames(*stub, frames);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_EQ(result.acks.size(), 5u);
  EXPECT_TRUE(result.acks[0].accepted());
  for (int i : {1, 2}) {
    EXPECT_FALSE(result.acks[i].accepted()) << i;
    EXPECT_EQ(result.acks[i].rejection().field(), "sequence") << i;
    EXPECT_THAT(result.acks[i].rejection().reason(), HasSubstr("9007199254740991")) << i;
  }
  EXPECT_FALSE(result.acks[3].accepted());
  EXPECT_EQ(result.acks[3].rejection().field(), "gyros[0].u_k_mv[0]");
  EXPECT_THAT(result.acks[3].rejection().reason(), HasSubstr("beyond +-1e+07 mV"));
  EXPECT_TRUE(result.acks[4].accepted()) << result.acks[4].rejection().reason();
  ASSERT_TRUE(server.core().WaitApplied("HOST-1", absl::Seconds(60)).ok());
  const esg::v1::SessionInfo info = GetSession(*stub, "HOST-1");
  EXPECT_NE(info.state(), esg::v1::SESSION_STATE_QUARANTINED) << info.quarantine_reason();
}

// The largest offset voltage accepted, on a term calibrated from it: the filter stays finite.
TEST(HostileInput, LargestAcceptedOffsetVoltageDoesNotQuarantine) {
  LoopbackServer server;
  auto stub = server.Stub();
  Configure(*stub, WithVoltageTerm(RunH().config));
  std::vector<esg::v1::TelemetryFrame> frames(RunH().frames.begin(), RunH().frames.begin() + 30);
  for (size_t k = 5; k < frames.size(); ++k) {
    frames[k].mutable_gyros(0)->clear_u_k_mv();
    for (double u : {1e7, -1e7, 1e7}) frames[k].mutable_gyros(0)->add_u_k_mv(u);
  }
  const auto result = StreamFrames(*stub, frames);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  for (const auto& ack : result.acks) EXPECT_TRUE(ack.accepted()) << ack.rejection().reason();
  ASSERT_TRUE(server.core().WaitApplied("HOST-1", absl::Seconds(60)).ok());
  const esg::v1::SessionInfo info = GetSession(*stub, "HOST-1");
  EXPECT_NE(info.state(), esg::v1::SESSION_STATE_QUARANTINED) << info.quarantine_reason();
}

// The earliest ramp epoch accepted (1970-01-01, 49 years before the frames) with the largest
// prior: the filter stays finite. An epoch of 0001-01-01 quarantined the session at its third
// frame; it is refused now (BasisTermEpochAndPeriodAreBounded).
TEST(HostileInput, EarliestRampEpochDoesNotQuarantine) {
  LoopbackServer server;
  auto stub = server.Stub();
  estimator::SpacecraftConfig config = RunH().config;
  estimator::BasisTerm ramp;
  ramp.kind = estimator::BasisKind::kRamp;
  ramp.axis = 2;
  ramp.epoch = absl::UnixEpoch();
  ramp.sigma = 10.0 / estimator::BasisValueToJson(ramp.kind);  // 10 deg/h per hour
  config.gyros[1].basis_terms.push_back(ramp);
  Configure(*stub, config);
  std::vector<esg::v1::TelemetryFrame> frames(RunH().frames.begin(), RunH().frames.begin() + 30);
  const auto result = StreamFrames(*stub, frames);
  ASSERT_TRUE(result.status.ok()) << result.status.error_message();
  ASSERT_TRUE(server.core().WaitApplied("HOST-1", absl::Seconds(60)).ok());
  const esg::v1::SessionInfo info = GetSession(*stub, "HOST-1");
  EXPECT_NE(info.state(), esg::v1::SESSION_STATE_QUARANTINED) << info.quarantine_reason();
}

TEST(HostileInput, BasisTermEpochAndPeriodAndExponentsAreBounded) {
  LoopbackServer server;
  auto stub = server.Stub();
  auto configure = [&](const estimator::BasisTerm& term) {
    estimator::SpacecraftConfig config = RunH().config;
    config.gyros[0].basis_terms.push_back(term);
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    return stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(config), &r);
  };
  estimator::BasisTerm ramp;
  ramp.kind = estimator::BasisKind::kRamp;
  ramp.axis = 1;
  ramp.epoch = absl::FromCivil(absl::CivilSecond(1, 1, 1, 0, 0, 0), absl::UTCTimeZone());
  grpc::Status status = configure(ramp);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), HasSubstr("gyros[0].basisTerms[0].epoch: 0001-01-01"));
  estimator::BasisTerm orbital;
  orbital.kind = estimator::BasisKind::kOrbitalHarmonic;
  orbital.axis = 1;
  for (double period : {1e-300, 59.0, 400.0 * 86400.0}) {
    orbital.period = period;
    status = configure(orbital);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << period;
    EXPECT_THAT(status.error_message(), HasSubstr("gyros[0].basisTerms[0].periodS: ")) << period;
  }
  estimator::BasisTerm harmonic;
  harmonic.kind = estimator::BasisKind::kSpinAxisHarmonic;
  harmonic.axis = 1;
  harmonic.exponents = {2147483647, 2147483647, 2};  // the sum overflowed to 0
  status = configure(harmonic);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(),
              HasSubstr("gyros[0].basisTerms[0].exponents: each must be 0..4, got 2147483647"));
}

// A sigma typed so small that it underflows to 0 in SI is refused like one too small to be a
// variance, never read as 0 (a held state).
TEST(HostileInput, PriorSigmaThatUnderflowsIsRefused) {
  LoopbackServer server;
  auto stub = server.Stub();
  for (double sigma : {5e-324, 1e-200}) {
    esg::v1::ConfigureRequest request = ConfigureRequestFor(RunH().config);
    esg::v1::BasisTerm* term = request.mutable_config()->mutable_gyros(0)->add_basis_terms();
    term->set_kind("spin_axis_harmonic");
    term->set_axis(1);
    term->set_sigma_deg_h(sigma);
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    const grpc::Status status = stub->ConfigureSpacecraft(&ctx, request, &r);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << sigma;
    EXPECT_THAT(status.error_message(), HasSubstr("gyros[0].basisTerms[0].sigmaDegH: ")) << sigma;
  }
}

// ConfigureSpacecraft names a drift coefficient the way the request wrote it: a keyed one
// (GyroDriftModel.coefficients, as every writer now sends) by its entry, one given by a
// deprecated field (read for one release) by that field.
TEST(HostileInput, ADriftCoefficientIsNamedWhereTheRequestGaveIt) {
  LoopbackServer server;
  auto stub = server.Stub();
  const auto configure = [&](const esg::v1::ConfigureRequest& request) {
    grpc::ClientContext ctx;
    esg::v1::ConfigureResponse r;
    return stub->ConfigureSpacecraft(&ctx, request, &r);
  };
  const esg::v1::ConfigureRequest keyed = ConfigureRequestFor(RunH().config);
  ASSERT_EQ(keyed.config().gyros(1).model().coefficients(2).term(), "c1y");
  esg::v1::ConfigureRequest request = keyed;
  request.mutable_config()
      ->mutable_gyros(1)
      ->mutable_model()
      ->mutable_coefficients(2)
      ->set_value_deg_h(11.0);
  grpc::Status status = configure(request);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(),
              HasSubstr("gyros[1].model.coefficients[2].valueDegH: 11 is outside [-10, 10] deg/h"));
  request = keyed;
  request.mutable_config()
      ->mutable_gyros(1)
      ->mutable_model_sigma()
      ->mutable_coefficients(4)
      ->set_value_deg_h(-0.1);
  status = configure(request);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(
      status.error_message(),
      HasSubstr("gyros[1].modelSigma.coefficients[4].valueDegH: -0.1 is outside [0, 10] deg/h"));
  request = keyed;
  request.mutable_config()->mutable_gyros(1)->mutable_model()->mutable_coefficients(0)->set_term(
      "k9");
  status = configure(request);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(),
              HasSubstr("gyros[1].model.coefficients[0].term: unknown term \"k9\""));
  // The deprecated field c1_deg_h ("c1DegH" in JSON), set by reflection as an older client would.
  request = keyed;
  esg::v1::GyroDriftModel* model = request.mutable_config()->mutable_gyros(1)->mutable_model();
  model->clear_coefficients();
  const google::protobuf::FieldDescriptor* c1 = model->GetDescriptor()->FindFieldByName("c1_deg_h");
  ASSERT_NE(c1, nullptr);
  for (double v : {0.0, 11.0, 0.0}) model->GetReflection()->AddDouble(model, c1, v);
  status = configure(request);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(),
              HasSubstr("gyros[1].model.c1DegH[1]: 11 is outside [-10, 10] deg/h"));
  // The request unaltered is accepted: each refusal above was of the value changed.
  status = configure(keyed);
  EXPECT_TRUE(status.ok()) << status.error_message();
}

// A frame an older esgd archived with u_k_mv = 1e308: re-applying the archive (a replaced
// configuration) skips it with an alert; the session is not quarantined and goes on with the
// frames after it; a diagnosis over the window skips it as well.
TEST(HostileInput, ArchivedFrameTheChecksNowRefuseIsSkippedWithAnAlertOnReRun) {
  LoopbackServer server;
  auto stub = server.Stub();
  const std::string id = "HOST-1";
  Configure(*stub, WithVoltageTerm(RunH().config));
  const std::vector<esg::v1::TelemetryFrame>& all = RunH().frames;
  std::vector<esg::v1::TelemetryFrame> first(all.begin(), all.begin() + 40);
  ASSERT_TRUE(StreamFrames(*stub, first).status.ok());
  ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(60)).ok());
  esg::v1::TelemetryFrame old = all[40];
  old.mutable_gyros(0)->clear_u_k_mv();
  for (double u : {1e308, 0.0, 0.0}) old.mutable_gyros(0)->add_u_k_mv(u);
  storage::ArchivedFrame archived;
  archived.spacecraft_id = id;
  archived.sequence = old.sequence();
  archived.measurement_time = *proto_convert::TimeFromProto(old.time());
  archived.payload = old.SerializeAsString();
  ASSERT_TRUE(server.core().storage().archive().AppendBatch(id, {archived}).ok());
  std::vector<esg::v1::TelemetryFrame> rest(all.begin() + 41, all.end());
  ASSERT_TRUE(StreamFrames(*stub, rest).status.ok());
  ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(60)).ok());

  // A changed configuration (the term's prior halved) runs the filter over the archive again.
  estimator::SpacecraftConfig replaced = WithVoltageTerm(RunH().config);
  replaced.gyros[0].basis_terms.back().sigma /= 2.0;
  Configure(*stub, replaced, /*replace=*/true);
  ASSERT_TRUE(server.core().WaitApplied(id, absl::Seconds(120)).ok());
  const esg::v1::SessionInfo info = GetSession(*stub, id);
  EXPECT_NE(info.state(), esg::v1::SESSION_STATE_QUARANTINED) << info.quarantine_reason();
  EXPECT_EQ(info.highest_applied_sequence(), all.back().sequence());
  auto alerts = server.core().storage().alerts().Since(id, absl::InfinitePast(), 1000);
  ASSERT_TRUE(alerts.ok());
  int unreadable = 0;
  for (const storage::AlertRecord& a : *alerts) {
    EXPECT_NE(a.reason, "SESSION_QUARANTINED") << a.message;
    if (a.reason == "ARCHIVED_FRAME_UNREADABLE") {
      ++unreadable;
      EXPECT_THAT(a.message, HasSubstr("gyros[0].u_k_mv[0]"));
    }
  }
  EXPECT_GE(unreadable, 1);

  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(300));
  esg::v1::DiagnoseRequest request;
  request.set_spacecraft_id(id);
  auto reader = stub->Diagnose(&ctx, request);
  esg::v1::DiagnoseUpdate progress;
  bool result = false;
  while (reader->Read(&progress)) result = result || progress.has_result();
  const grpc::Status status = reader->Finish();
  EXPECT_TRUE(status.ok()) << status.error_code() << " " << status.error_message();
  EXPECT_TRUE(result);
}

esg::v1::AcknowledgeRequest AckRequest(const std::string& id, int64_t sequence,
                                       const std::string& name) {
  esg::v1::AcknowledgeRequest request;
  request.set_spacecraft_id(id);
  request.set_sequence(sequence);
  request.set_operator_name(name);
  return request;
}

int64_t StoredAlert(LoopbackServer& server, const std::string& id) {
  storage::AlertRecord record;
  record.spacecraft_id = id;
  record.severity = "WARNING";
  record.reason = "INNOVATION_TEST";
  record.subsystem = "star_tracker";
  record.message = "a stored alert to acknowledge";
  absl::StatusOr<int64_t> sequence = server.core().storage().alerts().Append(record);
  EXPECT_TRUE(sequence.ok()) << sequence.status();
  return sequence.value_or(0);
}

TEST(HostileInput, OperatorNamesAreBoundedAndPrintableAndMessagesStaySmall) {
  LoopbackServer server;  // no tokens: the caller names itself
  auto stub = server.Stub();
  Configure(*stub, RunH().config);
  const int64_t sequence = StoredAlert(server, "HOST-1");
  auto acknowledge = [&](const std::string& name, esg::v1::Alert* out) {
    grpc::ClientContext ctx;
    return stub->AcknowledgeAlert(&ctx, AckRequest("HOST-1", sequence, name), out);
  };
  esg::v1::Alert alert;
  const std::string huge(4 << 20, 'x');  // 4 MiB: was stored and logged whole
  for (const std::string& name :
       {huge, std::string("mallory\xE2\x80\xAEtxt.exe"), std::string("a\nb"),
        std::string(65, 'n')}) {
    const grpc::Status status = acknowledge(name, &alert);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
    EXPECT_THAT(status.error_message(), ::testing::StartsWith("operator_name: "));
    EXPECT_LE(status.error_message().size(), 1024u);
  }
  // 64 characters of Cyrillic (128 bytes) are a name.
  std::string cyrillic;
  for (int i = 0; i < 64; ++i) cyrillic += "\xD0\x90";
  ASSERT_TRUE(acknowledge(cyrillic, &alert).ok());
  EXPECT_EQ(alert.acknowledged_by(), cyrillic);

  // A 1 MB value echoed by a refusal stays INVALID_ARGUMENT with a bounded message.
  grpc::ClientContext ctx;
  esg::v1::DiagnoseRequest diagnose;
  diagnose.set_spacecraft_id("HOST-1");
  diagnose.set_model(std::string(1 << 20, '7'));
  auto reader = stub->Diagnose(&ctx, diagnose);
  esg::v1::DiagnoseUpdate progress;
  while (reader->Read(&progress)) {
  }
  const grpc::Status status = reader->Finish();
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("model: unknown term"));
  EXPECT_LE(status.error_message().size(), 1024u);
}

// Diagnose's refusals start with the request's field ("nanos -1 ..." and "model: model: ..."
// did not).
TEST(HostileInput, DiagnoseRefusalsNameTheirFieldFirst) {
  LoopbackServer server;
  auto stub = server.Stub();
  Configure(*stub, RunH().config);
  auto diagnose = [&](const esg::v1::DiagnoseRequest& request) {
    grpc::ClientContext ctx;
    auto reader = stub->Diagnose(&ctx, request);
    esg::v1::DiagnoseUpdate update;
    while (reader->Read(&update)) {
    }
    return reader->Finish();
  };
  esg::v1::DiagnoseRequest request;
  request.set_spacecraft_id("HOST-1");
  request.mutable_from()->set_nanos(-1);
  grpc::Status status = diagnose(request);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("from: "));
  request.clear_from();
  request.mutable_to()->set_seconds(-62135596801);  // before 0001-01-01
  status = diagnose(request);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("to: "));
  request.clear_to();
  request.set_model("12");
  status = diagnose(request);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("model: unknown term '12'"));
  request.set_model("");
  request.set_orbital_period_s(1e-300);
  status = diagnose(request);
  EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("orbital_period_s: 1e-300 s"));
  request.set_orbital_period_s(0.0);
  status = diagnose(request);  // nothing archived yet
  EXPECT_EQ(status.error_code(), grpc::StatusCode::FAILED_PRECONDITION);
  EXPECT_THAT(status.error_message(), ::testing::StartsWith("spacecraft_id: no archived"));
}

// The catch-all under every status and log line: a message is cut at a character boundary.
TEST(HostileInput, LongMessagesAreCutAtACharacterBoundary) {
  std::string cyrillic;
  for (int i = 0; i < 2000; ++i) cyrillic += "\xD0\x90";  // 4000 bytes
  const std::string cut = BoundedMessage("field: " + cyrillic);
  EXPECT_LE(cut.size(), kMaxStatusMessageBytes);
  EXPECT_THAT(cut, ::testing::StartsWith("field: \xD0\x90"));
  EXPECT_THAT(cut, ::testing::EndsWith("bytes cut)"));
  const size_t marker = cut.find(" ... (");
  ASSERT_NE(marker, std::string::npos);
  EXPECT_EQ((marker - 7) % 2, 0u);  // whole two-byte characters before the marker
  EXPECT_EQ(BoundedMessage("short"), "short");
  EXPECT_LE(BoundedText(std::string(1 << 20, 'x'), kMaxLogMessageBytes).size(),
            kMaxLogMessageBytes);
}

TEST(HostileInput, ATokenAcknowledgesOnlyUnderItsOwnName) {
  TempDir dir;
  WriteTokens(dir.File("tokens"),
              "alice-7f3a9c21d4e8b6 read,write alice\nbob-2c8e4a6f1b9d37 read,write bob\n");
  ServerOptions options;
  options.tokens_file = dir.File("tokens");
  LoopbackServer server(options);
  auto stub = server.Stub();
  {
    grpc::ClientContext ctx;
    ctx.AddMetadata("authorization", "Bearer alice-7f3a9c21d4e8b6");
    esg::v1::ConfigureResponse r;
    ASSERT_TRUE(stub->ConfigureSpacecraft(&ctx, ConfigureRequestFor(RunH().config), &r).ok());
  }
  const int64_t sequence = StoredAlert(server, "HOST-1");
  auto acknowledge = [&](const std::string& token, const std::string& name) {
    grpc::ClientContext ctx;
    ctx.AddMetadata("authorization", "Bearer " + token);
    esg::v1::Alert out;
    return std::make_pair(stub->AcknowledgeAlert(&ctx, AckRequest("HOST-1", sequence, name), &out),
                          out);
  };
  // Alice's token naming bob (and carol): refused, nothing recorded.
  for (const std::string name : {"bob", "carol"}) {
    const auto [status, alert] = acknowledge("alice-7f3a9c21d4e8b6", name);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::PERMISSION_DENIED) << name;
    EXPECT_THAT(status.error_message(),
                HasSubstr("operator_name: '" + name + "' is not the caller's name 'alice'"));
  }
  auto stored = server.core().storage().alerts().Get("HOST-1", sequence);
  ASSERT_TRUE(stored.ok());
  EXPECT_FALSE(stored->acknowledged);
  // Her own name, or none: recorded as alice.
  const auto [status, alert] = acknowledge("alice-7f3a9c21d4e8b6", "alice");
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(alert.acknowledged_by(), "alice");
}

TEST(HostileInput, RefusedTokensAreThrottledPerAddressAndAValidTokenStillPasses) {
  TempDir dir;
  WriteTokens(dir.File("tokens"), "ops-5b1e9d7c3a2f48 read,write ops\n");
  ServerOptions options;
  options.tokens_file = dir.File("tokens");
  LoopbackServer server(options);
  auto stub = server.Stub();
  auto get = [&](const std::string& token) {
    grpc::ClientContext ctx;
    ctx.AddMetadata("authorization", "Bearer " + token);
    esg::v1::ListSessionsRequest request;
    esg::v1::ListSessionsResponse response;
    return stub->ListSessions(&ctx, request, &response).error_code();
  };
  int unauthenticated = 0;
  int throttled = 0;
  for (int i = 0; i < 200; ++i) {
    const grpc::StatusCode code = get(absl::StrCat("guess-", i, "-0123456789abcdef"));
    unauthenticated += code == grpc::StatusCode::UNAUTHENTICATED;
    throttled += code == grpc::StatusCode::RESOURCE_EXHAUSTED;
    if (i == 100) {
      EXPECT_EQ(get("ops-5b1e9d7c3a2f48"), grpc::StatusCode::OK);  // not locked out
    }
  }
  EXPECT_EQ(unauthenticated + throttled, 200);
  // The budget (20 at once, 2 per second) lets a few refill while the loop runs, never most.
  EXPECT_GE(unauthenticated, FailedAuthThrottle::kBurst);
  EXPECT_LT(unauthenticated, 100);
  EXPECT_GT(throttled, 100);
}

TEST(FailedAuthThrottle, BudgetRefillsPerAddressAndLinesAreCountedNotWritten) {
  FailedAuthThrottle throttle;
  const absl::Time t0 = absl::FromUnixSeconds(1700000000);
  int within = 0;
  // 1000 refusals in 1 s from one client over many connections (ports), each logged through the
  // throttle as auth.cc does.
  ::testing::internal::CaptureStderr();
  for (int i = 0; i < 1000; ++i) {
    const std::string peer = absl::StrCat("ipv4:10.0.0.5:", 40000 + i);
    const absl::Time now = t0 + absl::Milliseconds(i);
    const FailedAuthThrottle::Verdict verdict = throttle.Refused(peer, now);
    within += verdict == FailedAuthThrottle::Verdict::kWithinBudget;
    throttle.Log(peer, verdict, "authorization refused", {{"peer", peer}}, now);
  }
  EXPECT_GE(within, 20);
  EXPECT_LE(within, 22);  // 20, plus at most 2 regained in the second
  // Another address has its own budget.
  EXPECT_EQ(throttle.Refused("ipv6:[::1]:5000", t0 + absl::Seconds(1)),
            FailedAuthThrottle::Verdict::kWithinBudget);
  // Ten seconds later: refilled; the next refusal's line follows the count of the held-back ones.
  const absl::Time later = t0 + absl::Seconds(11);
  EXPECT_EQ(throttle.Refused("ipv4:10.0.0.5:1", later), FailedAuthThrottle::Verdict::kWithinBudget);
  throttle.Log("ipv4:10.0.0.5:1", FailedAuthThrottle::Verdict::kWithinBudget,
               "authorization refused", {}, later);
  const std::string log = ::testing::internal::GetCapturedStderr();
  const std::vector<std::string> lines = absl::StrSplit(log, '\n', absl::SkipEmpty());
  // 10 lines (LogThrottle's default per interval), the summary of the other 990, the next line.
  ASSERT_EQ(lines.size(), 12u) << log;
  EXPECT_THAT(lines[10],
              HasSubstr("990 more authorization_refused lines for peer ipv4:10.0.0.5 in the last "
                        "10 s"));
  EXPECT_THAT(lines[11], HasSubstr("authorization refused"));
  EXPECT_EQ(FailedAuthThrottle::Address("ipv6:%5B::1%5D:50051"), "ipv6:%5B::1%5D");
  EXPECT_EQ(FailedAuthThrottle::Address("unix:/run/esg.sock"), "unix:/run/esg.sock");
}

}  // namespace
}  // namespace esg::server
