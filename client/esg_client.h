// The `esg` CLI's connection to esgd: a thin wrapper of the esg.v1.EstimationService stub
// (proto/esg/v1/estimation_service.proto, docs/service.md) whose unary calls return
// absl::StatusOr<T> and whose streams are small classes with the same error contract. It owns the
// channel options of the CLI: plaintext or TLS (CA bundle, optional client certificate for mTLS),
// a bearer token sent as `authorization: Bearer <token>` metadata on every call, a per-call
// deadline for unary calls, and a short reconnect backoff so that a client waiting for a restarted
// server sees it come back within a second or two.
//
// Routing: every call about one spacecraft carries the metadata `x-esg-spacecraft: <id>`
// (proto/routing_metadata.h), taken from the request's spacecraft id, so that a router (nginx,
// docs/deploy.md) sends it to the node that owns the spacecraft. Calls about every spacecraft
// (ListSessions, SubscribeAlerts without a spacecraft) carry none. A telemetry stream is opened
// for one spacecraft and carries its frames only (docs/service.md "Routing by spacecraft").
//
// Error contract: every failed call returns the gRPC status converted code for code to
// absl::Status (the numeric values are identical) with the server's message; a server
// that cannot be reached gives Unavailable.
#ifndef ESG_CLIENT_ESG_CLIENT_H_
#define ESG_CLIENT_ESG_CLIENT_H_

#include <cstdint>
#include <memory>
#include <string>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "esg/v1/estimation_service.grpc.pb.h"
#include "esg/v1/estimation_service.pb.h"
#include "grpcpp/channel.h"
#include "grpcpp/client_context.h"
#include "grpcpp/support/sync_stream.h"

namespace esg::client {

struct ClientOptions {
  std::string server = "127.0.0.1:50051";  // host:port
  // PEM files. Any of them switches the channel to TLS: tls_ca is the CA bundle that signs the
  // server certificate (empty: the system roots); tls_cert and tls_key, given together, are the
  // client certificate and key presented for mutual TLS.
  std::string tls_ca;
  std::string tls_cert;
  std::string tls_key;
  // Bearer token (empty: none).
  std::string token;
  // Deadline of each unary call.
  absl::Duration rpc_timeout = absl::Seconds(60);
};

// Per-call overrides of the unary calls.
struct CallOptions {
  // absl::ZeroDuration(): ClientOptions::rpc_timeout.
  absl::Duration timeout = absl::ZeroDuration();
  // Wait (up to the deadline) for the channel to connect instead of failing at once with
  // Unavailable when the server is not reachable; used when waiting for a restarted server.
  bool wait_for_ready = false;
};

// grpc::Status -> absl::Status, code for code.
absl::Status FromGrpcStatus(const grpc::Status& status);

// The bidirectional telemetry stream (StreamTelemetry). One thread may Write while another
// Reads (gRPC's synchronous stream contract); Cancel may be called from any thread.
class TelemetryStream {
 public:
  TelemetryStream(
      std::unique_ptr<grpc::ClientContext> context,
      std::unique_ptr<grpc::ClientReaderWriter<esg::v1::TelemetryFrame, esg::v1::TelemetryAck>>
          stream);
  // False when the stream is broken; Read then returns false and Finish tells why.
  bool Write(const esg::v1::TelemetryFrame& frame);
  // Half-closes the stream after the last frame.
  bool WritesDone();
  // Next acknowledgement, in frame order; false at the end of the stream.
  bool Read(esg::v1::TelemetryAck* ack);
  // After Read returned false: the final status of the call.
  absl::Status Finish();
  // Aborts the call: pending and later Write/Read return false.
  void Cancel();

 private:
  std::unique_ptr<grpc::ClientContext> context_;
  std::unique_ptr<grpc::ClientReaderWriter<esg::v1::TelemetryFrame, esg::v1::TelemetryAck>> stream_;
};

// The server-streaming alert subscription (SubscribeAlerts).
class AlertStream {
 public:
  AlertStream(std::unique_ptr<grpc::ClientContext> context,
              std::unique_ptr<grpc::ClientReader<esg::v1::Alert>> reader);
  // Next alert; false at the end of the stream (server finished, error, or Cancel).
  bool Read(esg::v1::Alert* alert);
  // After Read returned false: the final status (Cancelled after Cancel).
  absl::Status Finish();
  // Thread safe; unblocks a pending Read.
  void Cancel();

 private:
  std::unique_ptr<grpc::ClientContext> context_;
  std::unique_ptr<grpc::ClientReader<esg::v1::Alert>> reader_;
};

// A server-streaming call read message by message (Diagnose, ExportCoefficientHistory,
// ExportTelemetry, PredictAttitudeStream): the same contract as AlertStream.
template <typename Message>
class ReaderStream {
 public:
  ReaderStream(std::unique_ptr<grpc::ClientContext> context,
               std::unique_ptr<grpc::ClientReader<Message>> reader)
      : context_(std::move(context)), reader_(std::move(reader)) {}
  // Next message; false at the end of the stream (server finished, error, or Cancel).
  bool Read(Message* message) { return reader_->Read(message); }
  // After Read returned false: the final status of the call.
  absl::Status Finish() { return FromGrpcStatus(reader_->Finish()); }
  // Thread safe; unblocks a pending Read.
  void Cancel() { context_->TryCancel(); }

 private:
  std::unique_ptr<grpc::ClientContext> context_;
  std::unique_ptr<grpc::ClientReader<Message>> reader_;
};

class EsgClient {
 public:
  // Builds the channel (connection is lazy: an unreachable server shows up as Unavailable at the
  // first call). InvalidArgument "--tls-cert: ..." / "--tls-key: ..." when only one of the two is
  // given or --server is empty; NotFound "--tls-ca <path>: cannot read" for an unreadable PEM file.
  static absl::StatusOr<std::unique_ptr<EsgClient>> Create(const ClientOptions& options);

  const ClientOptions& options() const { return options_; }

  absl::StatusOr<esg::v1::ConfigureResponse> ConfigureSpacecraft(
      const esg::v1::ConfigureRequest& request, const CallOptions& call = {});
  // NotFound when the spacecraft is not configured.
  absl::StatusOr<esg::v1::SessionInfo> GetSession(const std::string& spacecraft_id,
                                                  const CallOptions& call = {});
  // Every session: follows next_page_token until the last page (each page its own call).
  absl::StatusOr<esg::v1::ListSessionsResponse> ListSessions(const CallOptions& call = {});
  // The whole prediction in one message (kept for compatibility; esg predict streams).
  absl::StatusOr<esg::v1::PredictResponse> PredictAttitude(const esg::v1::PredictRequest& request,
                                                           const CallOptions& call = {});
  // The prediction in chunks as the server computes them (PredictAttitudeStream).
  std::unique_ptr<ReaderStream<esg::v1::PredictChunk>> PredictAttitudeStream(
      const esg::v1::PredictRequest& request);
  absl::StatusOr<esg::v1::Alert> AcknowledgeAlert(const esg::v1::AcknowledgeRequest& request,
                                                  const CallOptions& call = {});
  // With request.page_token empty: the whole history, following next_page_token page by page
  // (each page its own call, each well under gRPC's default 4 MB message limit), merged in
  // order; the result's next_page_token is empty. With a page_token: that one page. Internal if
  // the server hands back the token it was given (a loop).
  absl::StatusOr<esg::v1::HistoryResponse> GetCoefficientHistory(
      const esg::v1::HistoryRequest& request, const CallOptions& call = {});

  // Per-step estimates (GetEstimateHistory), paged like GetCoefficientHistory: with
  // request.page_token empty the whole span, every page followed and merged in order.
  absl::StatusOr<esg::v1::EstimateHistoryResponse> GetEstimateHistory(
      const esg::v1::EstimateHistoryRequest& request, const CallOptions& call = {});

  // With request.page_token empty: every stored diagnosis of the spacecraft (summaries), following
  // next_page_token page by page; the result's next_page_token is empty. With a page_token: that
  // one page. Internal if the server hands back the token it was given (a loop).
  absl::StatusOr<esg::v1::ListDiagnosesResponse> ListDiagnoses(
      const esg::v1::ListDiagnosesRequest& request, const CallOptions& call = {});
  // One stored diagnosis with its full report; NotFound for an unknown id.
  absl::StatusOr<esg::v1::DiagnosisResult> GetDiagnosis(const std::string& spacecraft_id,
                                                        int64_t id, const CallOptions& call = {});

  // Operator actions (docs/service.md "Applying a diagnosis", "Readmitting a gyro").
  absl::StatusOr<esg::v1::ApplyDiagnosisResponse> ApplyDiagnosis(
      const esg::v1::ApplyDiagnosisRequest& request, const CallOptions& call = {});
  absl::StatusOr<esg::v1::ReadmitGyroResponse> ReadmitGyro(
      const esg::v1::ReadmitGyroRequest& request, const CallOptions& call = {});
  // Cancels the service's automatic diagnosis (docs/service.md "Automatic diagnosis").
  absl::StatusOr<esg::v1::CancelAutoDiagnosisResponse> CancelAutoDiagnosis(
      const esg::v1::CancelAutoDiagnosisRequest& request, const CallOptions& call = {});
  absl::StatusOr<esg::v1::OrbitDelivery> UploadOrbit(const esg::v1::UploadOrbitRequest& request,
                                                     const CallOptions& call = {});
  absl::StatusOr<esg::v1::ListOrbitsResponse> ListOrbits(const esg::v1::ListOrbitsRequest& request,
                                                         const CallOptions& call = {});

  // Opens a telemetry stream (no deadline) for the frames of `spacecraft_id`: routed by it, and
  // esgd refuses a frame of another spacecraft on it. Errors show up in TelemetryStream::Finish.
  std::unique_ptr<TelemetryStream> StreamTelemetry(const std::string& spacecraft_id);
  // Opens an alert subscription (no deadline). Errors show up in AlertStream::Finish.
  std::unique_ptr<AlertStream> SubscribeAlerts(const esg::v1::AlertSubscription& request);
  // Server streams without a deadline (a diagnosis runs for minutes, an export is as long as
  // the archive); errors show up in ReaderStream::Finish.
  std::unique_ptr<ReaderStream<esg::v1::DiagnoseUpdate>> Diagnose(
      const esg::v1::DiagnoseRequest& request);
  std::unique_ptr<ReaderStream<esg::v1::ExportCoefficientHistoryResponse>> ExportCoefficientHistory(
      const esg::v1::ExportCoefficientHistoryRequest& request);
  std::unique_ptr<ReaderStream<esg::v1::ExportTelemetryResponse>> ExportTelemetry(
      const esg::v1::ExportTelemetryRequest& request);

 private:
  EsgClient(ClientOptions options, std::shared_ptr<grpc::Channel> channel);
  // A context with the bearer token, the routing metadata of `spacecraft_id` (none when empty)
  // and, for unary calls, the deadline.
  std::unique_ptr<grpc::ClientContext> NewContext(bool unary, const CallOptions& call,
                                                  const std::string& spacecraft_id) const;

  ClientOptions options_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<esg::v1::EstimationService::Stub> stub_;
};

}  // namespace esg::client

#endif  // ESG_CLIENT_ESG_CLIENT_H_
