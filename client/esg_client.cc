// The esgd stub wrapper of the CLI (see esg_client.h).
#include "client/esg_client.h"

#include <fstream>
#include <sstream>
#include <utility>

#include "absl/strings/str_cat.h"
#include "grpc/grpc.h"
#include "grpcpp/create_channel.h"
#include "grpcpp/security/credentials.h"
#include "grpcpp/support/channel_arguments.h"
#include "proto/routing_metadata.h"

namespace esg::client {
namespace {

absl::StatusOr<std::string> ReadPem(const std::string& option, const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat(option, " ", path, ": cannot read"));
  std::ostringstream text;
  text << in.rdbuf();
  if (text.str().empty()) {
    return absl::InvalidArgumentError(absl::StrCat(option, " ", path, ": empty file"));
  }
  return text.str();
}

template <typename Response, typename Call>
absl::StatusOr<Response> Unary(std::unique_ptr<grpc::ClientContext> context, Call call) {
  Response response;
  const grpc::Status status = call(context.get(), &response);
  if (!status.ok()) return FromGrpcStatus(status);
  return response;
}

// The whole of a paged call (ListSessions, GetCoefficientHistory, GetEstimateHistory,
// ListDiagnoses): with request.page_token empty, every page from the first, each its own call
// (`one_page`), with the records of `records` (e.g. &HistoryResponse::mutable_snapshots) moved
// into one response in order, whose next_page_token is empty; Internal "CALL: the server returned
// the same page token" if the server hands back the token it was given (a loop). With a
// page_token: that one page.
template <typename Response, typename Request, typename OnePage, typename Record>
absl::StatusOr<Response> AllPages(
    const char* call, const Request& request, OnePage one_page,
    google::protobuf::RepeatedPtrField<Record>* (Response::*records)()) {
  if (!request.page_token().empty()) return one_page(request);
  Request page_request = request;
  Response all;
  do {
    absl::StatusOr<Response> page = one_page(page_request);
    if (!page.ok()) return page.status();
    if (!page->next_page_token().empty() && page->next_page_token() == page_request.page_token()) {
      return absl::InternalError(absl::StrCat(call, ": the server returned the same page token"));
    }
    google::protobuf::RepeatedPtrField<Record>* from = ((*page).*records)();
    google::protobuf::RepeatedPtrField<Record>* to = (all.*records)();
    to->Reserve(to->size() + from->size());
    for (Record& r : *from) *to->Add() = std::move(r);
    page_request.set_page_token(page->next_page_token());
  } while (!page_request.page_token().empty());
  return all;
}

}  // namespace

absl::Status FromGrpcStatus(const grpc::Status& status) {
  if (status.ok()) return absl::OkStatus();
  // grpc::StatusCode and absl::StatusCode share their numeric values (0..16).
  return absl::Status(static_cast<absl::StatusCode>(status.error_code()), status.error_message());
}

// ---- TelemetryStream --------------------------------------------------------------------------

TelemetryStream::TelemetryStream(
    std::unique_ptr<grpc::ClientContext> context,
    std::unique_ptr<grpc::ClientReaderWriter<esg::v1::TelemetryFrame, esg::v1::TelemetryAck>>
        stream)
    : context_(std::move(context)), stream_(std::move(stream)) {}

bool TelemetryStream::Write(const esg::v1::TelemetryFrame& frame) { return stream_->Write(frame); }
bool TelemetryStream::WritesDone() { return stream_->WritesDone(); }
bool TelemetryStream::Read(esg::v1::TelemetryAck* ack) { return stream_->Read(ack); }
absl::Status TelemetryStream::Finish() { return FromGrpcStatus(stream_->Finish()); }
void TelemetryStream::Cancel() { context_->TryCancel(); }

// ---- AlertStream ------------------------------------------------------------------------------

AlertStream::AlertStream(std::unique_ptr<grpc::ClientContext> context,
                         std::unique_ptr<grpc::ClientReader<esg::v1::Alert>> reader)
    : context_(std::move(context)), reader_(std::move(reader)) {}

bool AlertStream::Read(esg::v1::Alert* alert) { return reader_->Read(alert); }
absl::Status AlertStream::Finish() { return FromGrpcStatus(reader_->Finish()); }
void AlertStream::Cancel() { context_->TryCancel(); }

// ---- EsgClient --------------------------------------------------------------------------------

absl::StatusOr<std::unique_ptr<EsgClient>> EsgClient::Create(const ClientOptions& options) {
  if (options.server.empty()) return absl::InvalidArgumentError("--server: must not be empty");
  if (options.tls_cert.empty() != options.tls_key.empty()) {
    return absl::InvalidArgumentError(options.tls_cert.empty()
                                          ? "--tls-key: given without --tls-cert"
                                          : "--tls-cert: given without --tls-key");
  }
  std::shared_ptr<grpc::ChannelCredentials> credentials;
  if (options.tls_ca.empty() && options.tls_cert.empty()) {
    credentials = grpc::InsecureChannelCredentials();
  } else {
    grpc::SslCredentialsOptions ssl;
    if (!options.tls_ca.empty()) {
      absl::StatusOr<std::string> ca = ReadPem("--tls-ca", options.tls_ca);
      if (!ca.ok()) return ca.status();
      ssl.pem_root_certs = *std::move(ca);
    }
    if (!options.tls_cert.empty()) {
      absl::StatusOr<std::string> cert = ReadPem("--tls-cert", options.tls_cert);
      if (!cert.ok()) return cert.status();
      absl::StatusOr<std::string> key = ReadPem("--tls-key", options.tls_key);
      if (!key.ok()) return key.status();
      ssl.pem_cert_chain = *std::move(cert);
      ssl.pem_private_key = *std::move(key);
    }
    credentials = grpc::SslCredentials(ssl);
  }
  grpc::ChannelArguments args;
  // A restarted server is found again quickly (gRPC's default backoff grows to 120 s). The
  // minimum reconnect backoff is left at its default: gRPC core also takes it as the time a
  // connection attempt may take (20 s). At 200 ms, clients connecting to a busy server gave up
  // with "connection attempt timed out before receiving SETTINGS frame" (12 replays at once into
  // one node on two cores: 6-12 of 30 failed; scripts/multi_node_throughput.sh).
  args.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 200);
  args.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 2000);
  // Telemetry and predictions can be large; the server sets its own limit.
  args.SetMaxReceiveMessageSize(64 * 1024 * 1024);
  std::shared_ptr<grpc::Channel> channel =
      grpc::CreateCustomChannel(options.server, credentials, args);
  return std::unique_ptr<EsgClient>(new EsgClient(options, std::move(channel)));
}

EsgClient::EsgClient(ClientOptions options, std::shared_ptr<grpc::Channel> channel)
    : options_(std::move(options)),
      channel_(std::move(channel)),
      stub_(esg::v1::EstimationService::NewStub(channel_)) {}

std::unique_ptr<grpc::ClientContext> EsgClient::NewContext(
    bool unary, const CallOptions& call, const std::string& spacecraft_id) const {
  auto context = std::make_unique<grpc::ClientContext>();
  if (!options_.token.empty()) {
    context->AddMetadata("authorization", absl::StrCat("Bearer ", options_.token));
  }
  if (!spacecraft_id.empty()) {
    context->AddMetadata(proto_convert::kSpacecraftMetadataKey, spacecraft_id);
  }
  if (unary) {
    const absl::Duration timeout =
        call.timeout > absl::ZeroDuration() ? call.timeout : options_.rpc_timeout;
    context->set_deadline(absl::ToChronoTime(absl::Now() + timeout));
  }
  context->set_wait_for_ready(call.wait_for_ready);
  return context;
}

absl::StatusOr<esg::v1::ConfigureResponse> EsgClient::ConfigureSpacecraft(
    const esg::v1::ConfigureRequest& request, const CallOptions& call) {
  return Unary<esg::v1::ConfigureResponse>(
      NewContext(true, call, request.config().spacecraft_id()),
      [&](grpc::ClientContext* c, esg::v1::ConfigureResponse* r) {
        return stub_->ConfigureSpacecraft(c, request, r);
      });
}

absl::StatusOr<esg::v1::SessionInfo> EsgClient::GetSession(const std::string& spacecraft_id,
                                                           const CallOptions& call) {
  esg::v1::GetSessionRequest request;
  request.set_spacecraft_id(spacecraft_id);
  return Unary<esg::v1::SessionInfo>(NewContext(true, call, spacecraft_id),
                                     [&](grpc::ClientContext* c, esg::v1::SessionInfo* r) {
                                       return stub_->GetSession(c, request, r);
                                     });
}

absl::StatusOr<esg::v1::ListSessionsResponse> EsgClient::ListSessions(const CallOptions& call) {
  auto one_page = [&](const esg::v1::ListSessionsRequest& page_request) {
    return Unary<esg::v1::ListSessionsResponse>(
        NewContext(true, call, /*spacecraft_id=*/""),
        [&](grpc::ClientContext* c, esg::v1::ListSessionsResponse* r) {
          return stub_->ListSessions(c, page_request, r);
        });
  };
  return AllPages<esg::v1::ListSessionsResponse>("ListSessions", esg::v1::ListSessionsRequest(),
                                                 one_page,
                                                 &esg::v1::ListSessionsResponse::mutable_sessions);
}

absl::StatusOr<esg::v1::PredictResponse> EsgClient::PredictAttitude(
    const esg::v1::PredictRequest& request, const CallOptions& call) {
  return Unary<esg::v1::PredictResponse>(NewContext(true, call, request.spacecraft_id()),
                                         [&](grpc::ClientContext* c, esg::v1::PredictResponse* r) {
                                           return stub_->PredictAttitude(c, request, r);
                                         });
}

absl::StatusOr<esg::v1::Alert> EsgClient::AcknowledgeAlert(
    const esg::v1::AcknowledgeRequest& request, const CallOptions& call) {
  return Unary<esg::v1::Alert>(NewContext(true, call, request.spacecraft_id()),
                               [&](grpc::ClientContext* c, esg::v1::Alert* r) {
                                 return stub_->AcknowledgeAlert(c, request, r);
                               });
}

absl::StatusOr<esg::v1::HistoryResponse> EsgClient::GetCoefficientHistory(
    const esg::v1::HistoryRequest& request, const CallOptions& call) {
  auto one_page = [&](const esg::v1::HistoryRequest& page_request) {
    return Unary<esg::v1::HistoryResponse>(
        NewContext(true, call, page_request.spacecraft_id()),
        [&](grpc::ClientContext* c, esg::v1::HistoryResponse* r) {
          return stub_->GetCoefficientHistory(c, page_request, r);
        });
  };
  return AllPages<esg::v1::HistoryResponse>("GetCoefficientHistory", request, one_page,
                                            &esg::v1::HistoryResponse::mutable_snapshots);
}

absl::StatusOr<esg::v1::EstimateHistoryResponse> EsgClient::GetEstimateHistory(
    const esg::v1::EstimateHistoryRequest& request, const CallOptions& call) {
  auto one_page = [&](const esg::v1::EstimateHistoryRequest& page_request) {
    return Unary<esg::v1::EstimateHistoryResponse>(
        NewContext(true, call, page_request.spacecraft_id()),
        [&](grpc::ClientContext* c, esg::v1::EstimateHistoryResponse* r) {
          return stub_->GetEstimateHistory(c, page_request, r);
        });
  };
  return AllPages<esg::v1::EstimateHistoryResponse>(
      "GetEstimateHistory", request, one_page,
      &esg::v1::EstimateHistoryResponse::mutable_estimates);
}

absl::StatusOr<esg::v1::ListDiagnosesResponse> EsgClient::ListDiagnoses(
    const esg::v1::ListDiagnosesRequest& request, const CallOptions& call) {
  auto one_page = [&](const esg::v1::ListDiagnosesRequest& page_request) {
    return Unary<esg::v1::ListDiagnosesResponse>(
        NewContext(true, call, page_request.spacecraft_id()),
        [&](grpc::ClientContext* c, esg::v1::ListDiagnosesResponse* r) {
          return stub_->ListDiagnoses(c, page_request, r);
        });
  };
  return AllPages<esg::v1::ListDiagnosesResponse>(
      "ListDiagnoses", request, one_page, &esg::v1::ListDiagnosesResponse::mutable_diagnoses);
}

absl::StatusOr<esg::v1::DiagnosisResult> EsgClient::GetDiagnosis(const std::string& spacecraft_id,
                                                                 int64_t id,
                                                                 const CallOptions& call) {
  esg::v1::GetDiagnosisRequest request;
  request.set_spacecraft_id(spacecraft_id);
  request.set_id(id);
  return Unary<esg::v1::DiagnosisResult>(NewContext(true, call, spacecraft_id),
                                         [&](grpc::ClientContext* c, esg::v1::DiagnosisResult* r) {
                                           return stub_->GetDiagnosis(c, request, r);
                                         });
}

absl::StatusOr<esg::v1::ApplyDiagnosisResponse> EsgClient::ApplyDiagnosis(
    const esg::v1::ApplyDiagnosisRequest& request, const CallOptions& call) {
  return Unary<esg::v1::ApplyDiagnosisResponse>(
      NewContext(true, call, request.spacecraft_id()),
      [&](grpc::ClientContext* c, esg::v1::ApplyDiagnosisResponse* r) {
        return stub_->ApplyDiagnosis(c, request, r);
      });
}

absl::StatusOr<esg::v1::CancelAutoDiagnosisResponse> EsgClient::CancelAutoDiagnosis(
    const esg::v1::CancelAutoDiagnosisRequest& request, const CallOptions& call) {
  return Unary<esg::v1::CancelAutoDiagnosisResponse>(
      NewContext(true, call, request.spacecraft_id()),
      [&](grpc::ClientContext* c, esg::v1::CancelAutoDiagnosisResponse* r) {
        return stub_->CancelAutoDiagnosis(c, request, r);
      });
}

absl::StatusOr<esg::v1::OrbitDelivery> EsgClient::UploadOrbit(
    const esg::v1::UploadOrbitRequest& request, const CallOptions& call) {
  return Unary<esg::v1::OrbitDelivery>(
      NewContext(true, call, request.spacecraft_id()),
      [&](grpc::ClientContext* c, esg::v1::OrbitDelivery* r) {
        return stub_->UploadOrbit(c, request, r);
      });
}

absl::StatusOr<esg::v1::ListOrbitsResponse> EsgClient::ListOrbits(
    const esg::v1::ListOrbitsRequest& request, const CallOptions& call) {
  return Unary<esg::v1::ListOrbitsResponse>(
      NewContext(true, call, request.spacecraft_id()),
      [&](grpc::ClientContext* c, esg::v1::ListOrbitsResponse* r) {
        return stub_->ListOrbits(c, request, r);
      });
}

absl::StatusOr<esg::v1::ReadmitGyroResponse> EsgClient::ReadmitGyro(
    const esg::v1::ReadmitGyroRequest& request, const CallOptions& call) {
  return Unary<esg::v1::ReadmitGyroResponse>(
      NewContext(true, call, request.spacecraft_id()),
      [&](grpc::ClientContext* c, esg::v1::ReadmitGyroResponse* r) {
        return stub_->ReadmitGyro(c, request, r);
      });
}

std::unique_ptr<TelemetryStream> EsgClient::StreamTelemetry(const std::string& spacecraft_id) {
  std::unique_ptr<grpc::ClientContext> context = NewContext(false, {}, spacecraft_id);
  auto stream = stub_->StreamTelemetry(context.get());
  return std::make_unique<TelemetryStream>(std::move(context), std::move(stream));
}

std::unique_ptr<AlertStream> EsgClient::SubscribeAlerts(const esg::v1::AlertSubscription& request) {
  // Every spacecraft (an empty id): no routing metadata, the router picks a node.
  std::unique_ptr<grpc::ClientContext> context = NewContext(false, {}, request.spacecraft_id());
  auto reader = stub_->SubscribeAlerts(context.get(), request);
  return std::make_unique<AlertStream>(std::move(context), std::move(reader));
}

std::unique_ptr<ReaderStream<esg::v1::DiagnoseUpdate>> EsgClient::Diagnose(
    const esg::v1::DiagnoseRequest& request) {
  std::unique_ptr<grpc::ClientContext> context = NewContext(false, {}, request.spacecraft_id());
  auto reader = stub_->Diagnose(context.get(), request);
  return std::make_unique<ReaderStream<esg::v1::DiagnoseUpdate>>(std::move(context),
                                                                 std::move(reader));
}

std::unique_ptr<ReaderStream<esg::v1::ExportCoefficientHistoryResponse>>
EsgClient::ExportCoefficientHistory(const esg::v1::ExportCoefficientHistoryRequest& request) {
  std::unique_ptr<grpc::ClientContext> context = NewContext(false, {}, request.spacecraft_id());
  auto reader = stub_->ExportCoefficientHistory(context.get(), request);
  return std::make_unique<ReaderStream<esg::v1::ExportCoefficientHistoryResponse>>(
      std::move(context), std::move(reader));
}

std::unique_ptr<ReaderStream<esg::v1::ExportTelemetryResponse>> EsgClient::ExportTelemetry(
    const esg::v1::ExportTelemetryRequest& request) {
  std::unique_ptr<grpc::ClientContext> context = NewContext(false, {}, request.spacecraft_id());
  auto reader = stub_->ExportTelemetry(context.get(), request);
  return std::make_unique<ReaderStream<esg::v1::ExportTelemetryResponse>>(std::move(context),
                                                                          std::move(reader));
}

std::unique_ptr<ReaderStream<esg::v1::PredictChunk>> EsgClient::PredictAttitudeStream(
    const esg::v1::PredictRequest& request) {
  std::unique_ptr<grpc::ClientContext> context = NewContext(false, {}, request.spacecraft_id());
  auto reader = stub_->PredictAttitudeStream(context.get(), request);
  return std::make_unique<ReaderStream<esg::v1::PredictChunk>>(std::move(context),
                                                               std::move(reader));
}

}  // namespace esg::client
