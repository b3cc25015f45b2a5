// The esg.v1.EstimationService on gRPC's callback API (route_guide's
// callback server). Reactors stay small: each checks the caller's role (server/auth.h), hands
// the work to EstimationCore and maps its absl::Status through ToGrpcStatus.
//
// Long work never runs on gRPC's callback threads: PredictAttitude, and each chunk of
// PredictAttitudeStream, run on the service's own prediction pool (one thread per allowed
// concurrent prediction; the two rpcs share one bound), each Diagnose on a thread of its own.
// Both are bounded per caller and in total (CallLimits, docs/service.md "Limits");
// beyond a bound the call fails at once with RESOURCE_EXHAUSTED.
#ifndef ESG_SERVER_ESTIMATION_SERVICE_H_
#define ESG_SERVER_ESTIMATION_SERVICE_H_

#include <deque>
#include <string>
#include <thread>
#include <utility>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/functional/any_invocable.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"
#include "esg/v1/estimation_service.grpc.pb.h"
#include "server/auth.h"
#include "server/auto_diagnosis.h"
#include "server/call_counter.h"
#include "server/call_limiter.h"
#include "server/estimation_core.h"
#include "server/queue_budget.h"

namespace esg::server {

// Concurrent calls allowed, and bytes held for slow readers; a caller is a token's name, or
// without tokens a peer address (call_limiter.h). Each value must be >= 1 (EsgServer::Start
// checks).
struct CallLimits {
  int max_predictions_per_caller = 4;
  int max_predictions = 8;  // also the number of prediction threads
  int max_diagnoses_per_caller = 1;
  int max_diagnoses = 2;
  // SubscribeAlerts and SubscribeEstimates streams together. 64 per caller: the console gateway
  // holds up to 64 for one operator (console/gateway/operators.js).
  int max_subscriptions_per_caller = 64;
  int max_subscriptions = 1024;
  // ExportCoefficientHistory and ExportTelemetry streams together.
  int max_exports_per_caller = 4;
  int max_exports = 32;
  // Unread messages queued on subscription streams [bytes] (queue_budget.h): of one caller's
  // streams, of all streams.
  int64_t max_queued_bytes_per_caller = int64_t{64} << 20;
  int64_t max_queued_bytes = int64_t{256} << 20;
};

class EstimationServiceImpl final : public esg::v1::EstimationService::CallbackService {
 public:
  // `auth` may be null (no authentication). Neither is owned. Starts the prediction threads.
  // Starts the automatic diagnosis (auto_diagnosis.h) unless auto_diagnosis.span is zero.
  EstimationServiceImpl(EstimationCore* core, const TokenAuthorizer* auth,
                        const CallLimits& limits = {},
                        const AutoDiagnosisOptions& auto_diagnosis = {});
  // Joins the prediction threads: destroy the service only after the gRPC server has shut down
  // (every call finished), as EsgServer does.
  ~EstimationServiceImpl() override;

  grpc::ServerBidiReactor<esg::v1::TelemetryFrame, esg::v1::TelemetryAck>* StreamTelemetry(
      grpc::CallbackServerContext* context) override;
  grpc::ServerUnaryReactor* ConfigureSpacecraft(grpc::CallbackServerContext* context,
                                                const esg::v1::ConfigureRequest* request,
                                                esg::v1::ConfigureResponse* response) override;
  grpc::ServerUnaryReactor* GetSession(grpc::CallbackServerContext* context,
                                       const esg::v1::GetSessionRequest* request,
                                       esg::v1::SessionInfo* response) override;
  grpc::ServerUnaryReactor* ListSessions(grpc::CallbackServerContext* context,
                                         const esg::v1::ListSessionsRequest* request,
                                         esg::v1::ListSessionsResponse* response) override;
  grpc::ServerUnaryReactor* PredictAttitude(grpc::CallbackServerContext* context,
                                            const esg::v1::PredictRequest* request,
                                            esg::v1::PredictResponse* response) override;
  grpc::ServerWriteReactor<esg::v1::PredictChunk>* PredictAttitudeStream(
      grpc::CallbackServerContext* context, const esg::v1::PredictRequest* request) override;
  grpc::ServerWriteReactor<esg::v1::Alert>* SubscribeAlerts(
      grpc::CallbackServerContext* context, const esg::v1::AlertSubscription* request) override;
  grpc::ServerUnaryReactor* AcknowledgeAlert(grpc::CallbackServerContext* context,
                                             const esg::v1::AcknowledgeRequest* request,
                                             esg::v1::Alert* response) override;
  grpc::ServerUnaryReactor* GetCoefficientHistory(grpc::CallbackServerContext* context,
                                                  const esg::v1::HistoryRequest* request,
                                                  esg::v1::HistoryResponse* response) override;
  grpc::ServerWriteReactor<esg::v1::DiagnoseUpdate>* Diagnose(
      grpc::CallbackServerContext* context, const esg::v1::DiagnoseRequest* request) override;
  grpc::ServerUnaryReactor* ListDiagnoses(grpc::CallbackServerContext* context,
                                          const esg::v1::ListDiagnosesRequest* request,
                                          esg::v1::ListDiagnosesResponse* response) override;
  grpc::ServerUnaryReactor* GetDiagnosis(grpc::CallbackServerContext* context,
                                         const esg::v1::GetDiagnosisRequest* request,
                                         esg::v1::DiagnosisResult* response) override;
  grpc::ServerWriteReactor<esg::v1::ExportCoefficientHistoryResponse>* ExportCoefficientHistory(
      grpc::CallbackServerContext* context,
      const esg::v1::ExportCoefficientHistoryRequest* request) override;
  grpc::ServerWriteReactor<esg::v1::ExportTelemetryResponse>* ExportTelemetry(
      grpc::CallbackServerContext* context,
      const esg::v1::ExportTelemetryRequest* request) override;
  grpc::ServerUnaryReactor* GetEstimateHistory(grpc::CallbackServerContext* context,
                                               const esg::v1::EstimateHistoryRequest* request,
                                               esg::v1::EstimateHistoryResponse* response) override;
  grpc::ServerWriteReactor<esg::v1::EstimateRecord>* SubscribeEstimates(
      grpc::CallbackServerContext* context,
      const esg::v1::EstimateSubscription* request) override;
  grpc::ServerUnaryReactor* ApplyDiagnosis(grpc::CallbackServerContext* context,
                                           const esg::v1::ApplyDiagnosisRequest* request,
                                           esg::v1::ApplyDiagnosisResponse* response) override;
  grpc::ServerUnaryReactor* ReadmitGyro(grpc::CallbackServerContext* context,
                                        const esg::v1::ReadmitGyroRequest* request,
                                        esg::v1::ReadmitGyroResponse* response) override;
  grpc::ServerUnaryReactor* CancelAutoDiagnosis(
      grpc::CallbackServerContext* context, const esg::v1::CancelAutoDiagnosisRequest* request,
      esg::v1::CancelAutoDiagnosisResponse* response) override;
  grpc::ServerUnaryReactor* UploadOrbit(grpc::CallbackServerContext* context,
                                        const esg::v1::UploadOrbitRequest* request,
                                        esg::v1::OrbitDelivery* response) override;
  grpc::ServerUnaryReactor* ListOrbits(grpc::CallbackServerContext* context,
                                       const esg::v1::ListOrbitsRequest* request,
                                       esg::v1::ListOrbitsResponse* response) override;

  // The limiters: running calls, for tests and diagnostics (a test may hold permits itself).
  CallLimiter& prediction_limiter() { return predictions_; }
  CallLimiter& diagnosis_limiter() { return diagnoses_; }
  CallLimiter& subscription_limiter() { return subscriptions_; }
  CallLimiter& export_limiter() { return exports_; }
  QueueBudget& queue_budget() { return queued_; }
  // The service's own diagnosis of model mismatches; EsgServer stops it first at a shutdown.
  AutoDiagnosis& auto_diagnosis() { return *auto_diagnosis_; }
  // The calls of this service not finished yet.
  CallCounter& calls() { return calls_; }

 private:
  absl::Status Authorize(grpc::CallbackServerContext* context, Role role) const;
  // For a call whose request names `spacecraft_id`: the role, then the call's routing scope
  // (server/spacecraft_scope.h: its x-esg-spacecraft metadata, when given, must name it).
  absl::Status Authorize(grpc::CallbackServerContext* context, Role role,
                         absl::string_view spacecraft_id) const;
  // The caller of the call once its role is checked: the token's name with tokens, else the
  // peer's address without the port (CallerFromPeer). Errors as Authorize.
  absl::StatusOr<std::string> Caller(grpc::CallbackServerContext* context, Role role) const;
  // The operator name an operator action is stored under (role write): with tokens the caller's
  // token name, `requested` being empty or that name (else PERMISSION_DENIED naming
  // operator_name); without tokens `requested` as given.
  absl::StatusOr<std::string> OperatorName(grpc::CallbackServerContext* context,
                                           const std::string& requested) const;
  // For a stream about `spacecraft_id` (empty: all): the caller (role read), the routing scope,
  // then a slot of `limiter` for `call`. Errors as Authorize, or the limiter's
  // RESOURCE_EXHAUSTED.
  absl::StatusOr<std::pair<std::string, CallLimiter::Permit>> AdmitStream(
      grpc::CallbackServerContext* context, absl::string_view spacecraft_id,
      CallLimiter& limiter, absl::string_view call);
  absl::StatusOr<SubscriptionHold> HoldSubscription(grpc::CallbackServerContext* context,
                                                    absl::string_view spacecraft_id,
                                                    absl::string_view call);
  // Runs `task` on a prediction thread. Callers hold a prediction permit, so at most
  // limits.max_predictions tasks are queued or running and each starts at once.
  void RunPrediction(absl::AnyInvocable<void() &&> task);
  void PredictionLoop();

  EstimationCore* core_;
  const TokenAuthorizer* auth_;
  CallCounter calls_;
  CallLimiter predictions_;
  CallLimiter diagnoses_;
  CallLimiter subscriptions_;
  CallLimiter exports_;
  QueueBudget queued_;
  std::unique_ptr<AutoDiagnosis> auto_diagnosis_;  // after diagnoses_, whose slots it takes

  absl::Mutex pool_mu_;
  std::deque<absl::AnyInvocable<void() &&>> pool_tasks_ ABSL_GUARDED_BY(pool_mu_);
  bool pool_stop_ ABSL_GUARDED_BY(pool_mu_) = false;
  std::vector<std::thread> pool_;
};

}  // namespace esg::server

#endif  // ESG_SERVER_ESTIMATION_SERVICE_H_
