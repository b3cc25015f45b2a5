// The esg.v1.EstimationService methods (see estimation_service.h, docs/service.md): each
// authorizes the call, then hands it to EstimationCore or to its reactor (unary_call.h,
// export_reactor.h, telemetry_reactor.h, alert_reactor.h, estimate_reactor.h,
// diagnose_reactor.h). The prediction pool runs PredictAttitude off the callback threads.
#include "server/estimation_service.h"

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <thread>
#include <utility>

#include "absl/functional/any_invocable.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "estimator/status_macros.h"
#include "proto/convert.h"
#include "server/alert_reactor.h"
#include "server/diagnose_reactor.h"
#include "server/estimate_reactor.h"
#include "server/export_reactor.h"
#include "server/grpc_status.h"
#include "server/log.h"
#include "server/memory_release.h"
#include "server/prediction_stream.h"
#include "server/proto_mapping.h"
#include "server/spacecraft_scope.h"
#include "server/telemetry_reactor.h"
#include "server/unary_call.h"

namespace esg::server {

EstimationServiceImpl::EstimationServiceImpl(EstimationCore* core, const TokenAuthorizer* auth,
                                             const CallLimits& limits,
                                             const AutoDiagnosisOptions& auto_diagnosis)
    : core_(core),
      auth_(auth),
      predictions_("PredictAttitude", "prediction", "predictions",
                   limits.max_predictions_per_caller, limits.max_predictions),
      diagnoses_("Diagnose", "diagnosis", "diagnoses", limits.max_diagnoses_per_caller,
                 limits.max_diagnoses),
      subscriptions_("SubscribeAlerts/SubscribeEstimates", "subscription", "subscriptions",
                     limits.max_subscriptions_per_caller, limits.max_subscriptions, "holds"),
      exports_("ExportCoefficientHistory/ExportTelemetry", "export stream", "export streams",
               limits.max_exports_per_caller, limits.max_exports, "runs"),
      queued_(limits.max_queued_bytes_per_caller, limits.max_queued_bytes),
      auto_diagnosis_(std::make_unique<AutoDiagnosis>(core, &diagnoses_, auto_diagnosis)) {
  for (int i = 0; i < predictions_.total(); ++i) pool_.emplace_back([this] { PredictionLoop(); });
}

EstimationServiceImpl::~EstimationServiceImpl() {
  auto_diagnosis_->Stop();
  {
    absl::MutexLock lock(&pool_mu_);
    pool_stop_ = true;
  }
  for (std::thread& t : pool_) t.join();
}

void EstimationServiceImpl::RunPrediction(absl::AnyInvocable<void() &&> task) {
  absl::MutexLock lock(&pool_mu_);
  pool_tasks_.push_back(std::move(task));
}

void EstimationServiceImpl::PredictionLoop() {
  while (true) {
    absl::AnyInvocable<void() &&> task;
    {
      absl::MutexLock lock(&pool_mu_);
      auto ready = [this]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(pool_mu_) {
        return pool_stop_ || !pool_tasks_.empty();
      };
      pool_mu_.Await(absl::Condition(&ready));
      if (pool_tasks_.empty()) return;  // stopping, nothing left
      task = std::move(pool_tasks_.front());
      pool_tasks_.pop_front();
    }
    std::move(task)();
  }
}

absl::Status EstimationServiceImpl::Authorize(grpc::CallbackServerContext* context,
                                              Role role) const {
  if (auth_ == nullptr) return absl::OkStatus();
  return auth_->Check(*context, role);
}

absl::Status EstimationServiceImpl::Authorize(grpc::CallbackServerContext* context, Role role,
                                              absl::string_view spacecraft_id) const {
  // The role first: a caller without one learns nothing about the routing.
  if (absl::Status allowed = Authorize(context, role); !allowed.ok()) return allowed;
  return CheckCallScope(*context, spacecraft_id);
}

absl::StatusOr<std::string> EstimationServiceImpl::Caller(grpc::CallbackServerContext* context,
                                                          Role role) const {
  if (auth_ != nullptr) return auth_->Authenticate(*context, role);
  return CallerFromPeer(context->peer());
}

absl::StatusOr<std::pair<std::string, CallLimiter::Permit>> EstimationServiceImpl::AdmitStream(
    grpc::CallbackServerContext* context, absl::string_view spacecraft_id, CallLimiter& limiter,
    absl::string_view call) {
  absl::StatusOr<std::string> caller = Caller(context, Role::kRead);
  if (!caller.ok()) return caller.status();
  // Before a slot is taken: a misrouted call must not hold one.
  if (absl::Status in_scope = CheckCallScope(*context, spacecraft_id); !in_scope.ok()) {
    return in_scope;
  }
  absl::StatusOr<CallLimiter::Permit> permit = limiter.Acquire(*caller, call);
  if (!permit.ok()) return permit.status();
  return std::make_pair(*std::move(caller), *std::move(permit));
}

absl::StatusOr<SubscriptionHold> EstimationServiceImpl::HoldSubscription(
    grpc::CallbackServerContext* context, absl::string_view spacecraft_id,
    absl::string_view call) {
  absl::StatusOr<std::pair<std::string, CallLimiter::Permit>> admitted =
      AdmitStream(context, spacecraft_id, subscriptions_, call);
  if (!admitted.ok()) return admitted.status();
  return SubscriptionHold{std::move(admitted->second), queued_.Open(admitted->first)};
}

grpc::ServerBidiReactor<esg::v1::TelemetryFrame, esg::v1::TelemetryAck>*
EstimationServiceImpl::StreamTelemetry(grpc::CallbackServerContext* context) {
  // The stream's scope is checked once, at its start; each frame is checked against it by the
  // ingest contract, so a frame of another spacecraft is refused and the stream goes on.
  absl::Status admitted = Authorize(context, Role::kWrite);
  absl::StatusOr<std::string> scope = SpacecraftScope(context->client_metadata());
  if (admitted.ok() && !scope.ok()) admitted = scope.status();
  return NewTelemetryReactor(context, &calls_, core_, admitted, context->peer(),
                             scope.ok() ? *std::move(scope) : std::string());
}

grpc::ServerUnaryReactor* EstimationServiceImpl::ConfigureSpacecraft(
    grpc::CallbackServerContext* context, const esg::v1::ConfigureRequest* request,
    esg::v1::ConfigureResponse* response) {
  return Unary(&calls_, context,
               Authorize(context, Role::kWrite, request->config().spacecraft_id()), response,
               [&] { return core_->Configure(*request); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::GetSession(
    grpc::CallbackServerContext* context, const esg::v1::GetSessionRequest* request,
    esg::v1::SessionInfo* response) {
  return Unary(&calls_, context, Authorize(context, Role::kRead, request->spacecraft_id()),
               response, [&] { return core_->GetSession(request->spacecraft_id()); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::ListSessions(
    grpc::CallbackServerContext* context, const esg::v1::ListSessionsRequest* request,
    esg::v1::ListSessionsResponse* response) {
  // Names no spacecraft, so it has no routing scope: with x-esg-spacecraft it lists this node's
  // sessions like without (docs/service.md "Routing by spacecraft").
  return Unary(&calls_, context, Authorize(context, Role::kRead), response,
               [&] { return core_->ListSessions(*request); });
}

// The prediction runs on a prediction thread, never on the callback thread: a 48 h prediction
// at the sample limit takes long and would hold a gRPC thread. The estimator's Predict cannot be
// interrupted; its run is bounded by CoreOptions::max_prediction_samples and the horizon, and a
// call cancelled before its turn does not start. The permit is given back before Finish, so a
// client that sends its next prediction on the response is not refused.
grpc::ServerUnaryReactor* EstimationServiceImpl::PredictAttitude(
    grpc::CallbackServerContext* context, const esg::v1::PredictRequest* request,
    esg::v1::PredictResponse* response) {
  UnaryReactor* reactor = new UnaryReactor(&calls_);
  absl::StatusOr<std::string> caller = Caller(context, Role::kRead);
  if (caller.ok()) {
    // Before a permit is taken: a misrouted call must not hold a prediction slot.
    if (absl::Status in_scope = CheckCallScope(*context, request->spacecraft_id());
        !in_scope.ok()) {
      caller = in_scope;
    }
  }
  if (!caller.ok()) {
    reactor->Finish(ToGrpcStatus(caller.status()));
    return reactor;
  }
  absl::StatusOr<CallLimiter::Permit> permit = predictions_.Acquire(*caller);
  if (!permit.ok()) {
    reactor->Finish(ToGrpcStatus(permit.status()));
    return reactor;
  }
  RunPrediction([this, context, request, response, reactor, permit = std::move(*permit)]() mutable {
    absl::Status status;
    if (context->IsCancelled()) {
      status = absl::CancelledError("PredictAttitude: cancelled before it started");
    } else {
      absl::StatusOr<esg::v1::PredictResponse> result = core_->Predict(*request);
      if (result.ok()) *response = std::move(*result);
      status = result.status();
    }
    // The response (33 MB for 100 000 samples with AEM) is freed once written; its memory goes
    // back to the system then (memory_release.h), not only to malloc's arenas.
    reactor->FreesOnDone(static_cast<int64_t>(response->ByteSizeLong()));
    permit.Release();
    reactor->Finish(ToGrpcStatus(status, *context));
  });
  return reactor;
}

namespace {

// PredictAttitudeStream's reactor: each chunk is computed on a prediction thread (never on a
// callback thread), and only once the client has taken the previous one (one write in flight:
// gRPC flow control), so a call holds one chunk at a time however large the prediction. The
// caller's prediction slot is held from the first chunk to the last and given back before
// Finish. A client that goes away ends the call with CANCELLED at the next chunk.
class PredictStreamReactor : public grpc::ServerWriteReactor<esg::v1::PredictChunk> {
 public:
  using Run = std::function<void(absl::AnyInvocable<void() &&>)>;
  PredictStreamReactor(CallCounter* calls, EstimationCore* core, Run run,
                       grpc::CallbackServerContext* context, const esg::v1::PredictRequest* request,
                       CallLimiter::Permit permit)
      : token_(calls),
        core_(core),
        run_(std::move(run)),
        context_(context),
        request_(request),
        permit_(std::move(permit)) {
    ComputeNext();
  }

  void OnWriteDone(bool ok) override {
    if (!ok) {
      FinishWith(absl::CancelledError("PredictAttitudeStream: the client went away"));
      return;
    }
    ComputeNext();
  }

  void OnDone() override {
    NoteFreedMemory(written_bytes_);
    delete this;
  }

 private:
  void ComputeNext() {
    run_([this] {
      if (context_->IsCancelled()) {
        FinishWith(absl::CancelledError("PredictAttitudeStream: cancelled"));
        return;
      }
      if (prediction_ == nullptr) {
        absl::StatusOr<std::unique_ptr<PredictionStream>> started =
            core_->StartPrediction(*request_);
        if (!started.ok()) {
          FinishWith(started.status());
          return;
        }
        prediction_ = std::move(*started);
      }
      absl::StatusOr<std::optional<esg::v1::PredictChunk>> chunk =
          prediction_->Next(kPredictChunkSamples);
      if (!chunk.ok() || !chunk->has_value()) {
        prediction_.reset();
        FinishWith(chunk.ok() ? absl::OkStatus() : chunk.status());
        return;
      }
      current_ = std::move(**chunk);
      written_bytes_ += static_cast<int64_t>(current_.ByteSizeLong());
      StartWrite(&current_);
    });
  }

  // The slot first: a client that starts its next prediction on the status is not refused.
  void FinishWith(const absl::Status& status) {
    prediction_.reset();
    permit_.Release();
    Finish(ToGrpcStatus(status, *context_));
  }

  CallCounter::Token token_;
  EstimationCore* const core_;
  const Run run_;
  grpc::CallbackServerContext* const context_;
  const esg::v1::PredictRequest* const request_;
  CallLimiter::Permit permit_;
  std::unique_ptr<PredictionStream> prediction_;
  esg::v1::PredictChunk current_;  // the chunk being written
  int64_t written_bytes_ = 0;
};

// A call refused before it starts.
class RefusedPredictStream : public grpc::ServerWriteReactor<esg::v1::PredictChunk> {
 public:
  RefusedPredictStream(CallCounter* calls, const absl::Status& status) : token_(calls) {
    Finish(ToGrpcStatus(status));
  }
  void OnDone() override { delete this; }

 private:
  CallCounter::Token token_;
};

}  // namespace

grpc::ServerWriteReactor<esg::v1::PredictChunk>* EstimationServiceImpl::PredictAttitudeStream(
    grpc::CallbackServerContext* context, const esg::v1::PredictRequest* request) {
  absl::StatusOr<std::string> caller = Caller(context, Role::kRead);
  if (caller.ok()) {
    // Before a permit is taken: a misrouted call must not hold a prediction slot.
    if (absl::Status in_scope = CheckCallScope(*context, request->spacecraft_id());
        !in_scope.ok()) {
      caller = in_scope;
    }
  }
  if (!caller.ok()) return new RefusedPredictStream(&calls_, caller.status());
  // The same bounds as PredictAttitude: one limiter counts both rpcs.
  absl::StatusOr<CallLimiter::Permit> permit =
      predictions_.Acquire(*caller, "PredictAttitudeStream");
  if (!permit.ok()) return new RefusedPredictStream(&calls_, permit.status());
  return new PredictStreamReactor(
      &calls_, core_,
      [this](absl::AnyInvocable<void() &&> task) { RunPrediction(std::move(task)); }, context,
      request, std::move(*permit));
}

grpc::ServerWriteReactor<esg::v1::Alert>* EstimationServiceImpl::SubscribeAlerts(
    grpc::CallbackServerContext* context, const esg::v1::AlertSubscription* request) {
  return NewAlertReactor(&calls_, core_, *request,
                         HoldSubscription(context, request->spacecraft_id(), "SubscribeAlerts"));
}

grpc::ServerUnaryReactor* EstimationServiceImpl::AcknowledgeAlert(
    grpc::CallbackServerContext* context, const esg::v1::AcknowledgeRequest* request,
    esg::v1::Alert* response) {
  // With a tokens file the acknowledgement is recorded under the caller's token name
  // (docs/service.md "Security"): an empty operator_name means it, any other name is refused,
  // so that no token acknowledges in another operator's name.
  absl::StatusOr<std::string> token_name =
      auth_ != nullptr ? auth_->Authenticate(*context, Role::kWrite) : std::string();
  esg::v1::AcknowledgeRequest named = *request;
  absl::Status admitted = token_name.status();
  if (auth_ != nullptr && token_name.ok()) {
    if (named.operator_name().empty()) {
      named.set_operator_name(*token_name);
    } else if (named.operator_name() != *token_name) {
      admitted = absl::PermissionDeniedError(absl::StrCat(
          "operator_name: ",
          named.operator_name().size() <= 64
              ? absl::StrCat("'", absl::CHexEscape(named.operator_name()), "'")
              : absl::StrCat(named.operator_name().size(), " bytes"),
          " is not the caller's name '", *token_name,
          "'; with tokens an acknowledgement carries the token's own name (send it empty)"));
    }
  }
  if (admitted.ok()) admitted = CheckCallScope(*context, request->spacecraft_id());
  return Unary(&calls_, context, admitted, response,
               [this, named = std::move(named)]() -> absl::StatusOr<esg::v1::Alert> {
                 absl::StatusOr<esg::v1::Alert> alert = core_->Acknowledge(named);
                 if (!alert.ok()) return alert.status();
                 // The store keeps the first acknowledgement; another operator's is refused so
                 // that it is never silently dropped (the same operator again is idempotent).
                 if (alert->acknowledged_by() != named.operator_name()) {
                   absl::Status refused = absl::FailedPreconditionError(absl::StrCat(
                       "operator_name: alert ", alert->sequence(), " of spacecraft '",
                       alert->spacecraft_id(), "' was already acknowledged by '",
                       alert->acknowledged_by(), "' at ",
                       FormatUtc(proto_convert::TimeFromProto(alert->acknowledged_time())
                                     .value_or(absl::InfinitePast())),
                       "; the first acknowledgement stands"));
                   LogEvent("WARN", "alert_acknowledgement_refused",
                            absl::StrCat("acknowledgement by '", named.operator_name(),
                                         "' refused: ", refused.message()),
                            {{"spacecraftId", named.spacecraft_id()},
                             {"alertSequence", named.sequence()},
                             {"operator", named.operator_name()}});
                   return refused;
                 }
                 return alert;
               });
}

absl::StatusOr<std::string> EstimationServiceImpl::OperatorName(
    grpc::CallbackServerContext* context, const std::string& requested) const {
  if (auth_ == nullptr) return requested;
  ASSIGN_OR_RETURN(std::string token_name, auth_->Authenticate(*context, Role::kWrite));
  if (requested.empty()) return token_name;
  if (requested != token_name) {
    return absl::PermissionDeniedError(absl::StrCat(
        "operator_name: ",
        requested.size() <= 64 ? absl::StrCat("'", absl::CHexEscape(requested), "'")
                               : absl::StrCat(requested.size(), " bytes"),
        " is not the caller's name '", token_name,
        "'; with tokens an operator action carries the token's own name (send it empty)"));
  }
  return requested;
}

grpc::ServerUnaryReactor* EstimationServiceImpl::ApplyDiagnosis(
    grpc::CallbackServerContext* context, const esg::v1::ApplyDiagnosisRequest* request,
    esg::v1::ApplyDiagnosisResponse* response) {
  return Unary(&calls_, context, Authorize(context, Role::kWrite, request->spacecraft_id()),
               response, [&] { return core_->ApplyDiagnosis(*request); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::ReadmitGyro(
    grpc::CallbackServerContext* context, const esg::v1::ReadmitGyroRequest* request,
    esg::v1::ReadmitGyroResponse* response) {
  // With a tokens file the readmission is stored under the caller's token name, as an
  // acknowledgement is (docs/service.md "Security").
  absl::StatusOr<std::string> name = OperatorName(context, request->operator_name());
  absl::Status admitted = name.status();
  if (admitted.ok()) admitted = CheckCallScope(*context, request->spacecraft_id());
  esg::v1::ReadmitGyroRequest named = *request;
  if (name.ok()) named.set_operator_name(*name);
  return Unary(&calls_, context, admitted, response,
               [this, named = std::move(named)] { return core_->ReadmitGyro(named); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::CancelAutoDiagnosis(
    grpc::CallbackServerContext* context, const esg::v1::CancelAutoDiagnosisRequest* request,
    esg::v1::CancelAutoDiagnosisResponse* response) {
  return Unary(&calls_, context, Authorize(context, Role::kWrite, request->spacecraft_id()),
               response, [&]() -> absl::StatusOr<esg::v1::CancelAutoDiagnosisResponse> {
                 if (request->spacecraft_id().empty()) {
                   return absl::InvalidArgumentError("spacecraft_id: required");
                 }
                 RETURN_IF_ERROR(core_->CheckSpacecraft(request->spacecraft_id()));
                 esg::v1::CancelAutoDiagnosisResponse out;
                 const std::optional<int64_t> answered =
                     auto_diagnosis_->Cancel(request->spacecraft_id());
                 out.set_cancelled(answered.has_value());
                 out.set_answers_alert(answered.value_or(0));
                 return out;
               });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::GetCoefficientHistory(
    grpc::CallbackServerContext* context, const esg::v1::HistoryRequest* request,
    esg::v1::HistoryResponse* response) {
  return Unary(&calls_, context, Authorize(context, Role::kRead, request->spacecraft_id()),
               response, [&] { return core_->History(*request); });
}

grpc::ServerWriteReactor<esg::v1::ExportCoefficientHistoryResponse>*
EstimationServiceImpl::ExportCoefficientHistory(
    grpc::CallbackServerContext* context, const esg::v1::ExportCoefficientHistoryRequest* request) {
  // The pages of GetCoefficientHistory at the export chunk size, followed by their tokens.
  esg::v1::HistoryRequest pages;
  pages.set_spacecraft_id(request->spacecraft_id());
  pages.set_gyro_id(request->gyro_id());
  if (request->has_from()) *pages.mutable_from() = request->from();
  if (request->has_to()) *pages.mutable_to() = request->to();
  pages.set_include_revised(request->include_revised());
  pages.set_page_size(static_cast<int32_t>(EstimationCore::kExportChunkSize));
  EstimationCore* core = core_;
  bool last_page = false;
  return new ExportReactor<esg::v1::ExportCoefficientHistoryResponse>(
      &calls_,
      AdmitStream(context, request->spacecraft_id(), exports_, "ExportCoefficientHistory"),
      [core, pages, last_page]() mutable
      -> absl::StatusOr<std::optional<esg::v1::ExportCoefficientHistoryResponse>> {
        if (last_page) return std::nullopt;
        absl::StatusOr<esg::v1::HistoryResponse> page = core->History(pages);
        if (!page.ok()) return page.status();
        last_page = page->next_page_token().empty();
        pages.set_page_token(page->next_page_token());
        if (page->snapshots_size() == 0) return std::nullopt;
        esg::v1::ExportCoefficientHistoryResponse chunk;
        chunk.mutable_snapshots()->Swap(page->mutable_snapshots());
        return chunk;
      });
}

grpc::ServerWriteReactor<esg::v1::ExportTelemetryResponse>* EstimationServiceImpl::ExportTelemetry(
    grpc::CallbackServerContext* context, const esg::v1::ExportTelemetryRequest* request) {
  EstimationCore* core = core_;
  absl::Time after = absl::InfinitePast();
  bool done = false;
  return new ExportReactor<esg::v1::ExportTelemetryResponse>(
      &calls_, AdmitStream(context, request->spacecraft_id(), exports_, "ExportTelemetry"),
      [core, request = *request, after,
       done]() mutable -> absl::StatusOr<std::optional<esg::v1::ExportTelemetryResponse>> {
        if (done) return std::nullopt;
        absl::StatusOr<esg::v1::ExportTelemetryResponse> chunk =
            core->ExportTelemetryChunk(request, &after, &done);
        if (!chunk.ok()) return chunk.status();
        if (chunk->frames_size() == 0) return std::nullopt;
        return *std::move(chunk);
      });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::GetEstimateHistory(
    grpc::CallbackServerContext* context, const esg::v1::EstimateHistoryRequest* request,
    esg::v1::EstimateHistoryResponse* response) {
  return Unary(&calls_, context, Authorize(context, Role::kRead, request->spacecraft_id()),
               response, [&] { return core_->EstimateHistory(*request); });
}

grpc::ServerWriteReactor<esg::v1::EstimateRecord>* EstimationServiceImpl::SubscribeEstimates(
    grpc::CallbackServerContext* context, const esg::v1::EstimateSubscription* request) {
  return NewEstimateReactor(
      &calls_, core_, *request,
      HoldSubscription(context, request->spacecraft_id(), "SubscribeEstimates"));
}

grpc::ServerWriteReactor<esg::v1::DiagnoseUpdate>* EstimationServiceImpl::Diagnose(
    grpc::CallbackServerContext* context, const esg::v1::DiagnoseRequest* request) {
  absl::StatusOr<std::string> caller = Caller(context, Role::kRead);
  if (caller.ok()) {
    // Before a permit is taken: a misrouted call must not hold the caller's diagnosis slot.
    if (absl::Status in_scope = CheckCallScope(*context, request->spacecraft_id());
        !in_scope.ok()) {
      caller = in_scope;
    }
  }
  return NewDiagnoseReactor(&calls_, context, core_, *request,
                            caller.ok() ? diagnoses_.Acquire(*caller)
                                        : absl::StatusOr<CallLimiter::Permit>(caller.status()));
}

grpc::ServerUnaryReactor* EstimationServiceImpl::ListDiagnoses(
    grpc::CallbackServerContext* context, const esg::v1::ListDiagnosesRequest* request,
    esg::v1::ListDiagnosesResponse* response) {
  return Unary(&calls_, context, Authorize(context, Role::kRead, request->spacecraft_id()),
               response, [&] { return core_->ListDiagnoses(*request); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::UploadOrbit(
    grpc::CallbackServerContext* context, const esg::v1::UploadOrbitRequest* request,
    esg::v1::OrbitDelivery* response) {
  // Stored under the caller's name (the token's; the peer without tokens), as an operator
  // action is (docs/service.md "Orbits").
  absl::StatusOr<std::string> caller = Caller(context, Role::kWrite);
  absl::Status admitted = caller.status();
  if (admitted.ok()) admitted = CheckCallScope(*context, request->spacecraft_id());
  const std::string uploaded_by = caller.ok() ? *caller : std::string();
  return Unary(&calls_, context, admitted, response,
               [&] { return core_->UploadOrbit(*request, uploaded_by); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::ListOrbits(
    grpc::CallbackServerContext* context, const esg::v1::ListOrbitsRequest* request,
    esg::v1::ListOrbitsResponse* response) {
  return Unary(&calls_, context, Authorize(context, Role::kRead, request->spacecraft_id()),
               response, [&] { return core_->ListOrbits(*request); });
}

grpc::ServerUnaryReactor* EstimationServiceImpl::GetDiagnosis(
    grpc::CallbackServerContext* context, const esg::v1::GetDiagnosisRequest* request,
    esg::v1::DiagnosisResult* response) {
  return Unary(&calls_, context, Authorize(context, Role::kRead, request->spacecraft_id()),
               response, [&] { return core_->GetDiagnosis(*request); });
}

}  // namespace esg::server
