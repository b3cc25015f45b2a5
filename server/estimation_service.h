// The esg.v1.EstimationService on gRPC's callback API (STYLE §3.7 example 6: route_guide's
// callback server). Reactors stay small: each checks the caller's role (server/auth.h), hands
// the work to EstimationCore and maps its absl::Status through ToGrpcStatus.
#ifndef ESG_SERVER_ESTIMATION_SERVICE_H_
#define ESG_SERVER_ESTIMATION_SERVICE_H_

#include "esg/v1/estimation_service.grpc.pb.h"
#include "server/auth.h"
#include "server/estimation_core.h"

namespace esg::server {

class EstimationServiceImpl final : public esg::v1::EstimationService::CallbackService {
 public:
  // `auth` may be null (no authentication). Neither is owned.
  EstimationServiceImpl(EstimationCore* core, const TokenAuthorizer* auth)
      : core_(core), auth_(auth) {}

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

 private:
  absl::Status Authorize(grpc::CallbackServerContext* context, Role role) const;

  EstimationCore* core_;
  const TokenAuthorizer* auth_;
};

}  // namespace esg::server

#endif  // ESG_SERVER_ESTIMATION_SERVICE_H_
