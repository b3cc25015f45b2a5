// The Diagnose reactor; what it guarantees is stated in diagnose_reactor.h.
#include "server/diagnose_reactor.h"

#include <atomic>
#include <string>
#include <thread>
#include <utility>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "server/grpc_status.h"

namespace esg::server {
namespace {

class DiagnoseReactor : public grpc::ServerWriteReactor<esg::v1::DiagnoseUpdate> {
 public:
  // `permit` holds the caller's slot, or why the call is refused (role, limit).
  DiagnoseReactor(CallCounter* calls, grpc::CallbackServerContext* context, EstimationCore* core,
                  esg::v1::DiagnoseRequest request, absl::StatusOr<CallLimiter::Permit> permit)
      : token_(calls), context_(context) {
    if (!permit.ok()) {
      finished_ = true;
      Finish(ToGrpcStatus(permit.status()));
      return;
    }
    worker_ = std::thread(
        [this, core, request = std::move(request), permit = std::move(*permit)]() mutable {
          absl::StatusOr<esg::v1::DiagnosisResult> result = core->Diagnose(
              request, [this](double fraction, const std::string& stage) { Post(fraction, stage); },
              [this] { return cancelled_.load(std::memory_order_relaxed); });
          permit.Release();
          absl::MutexLock lock(&mu_);
          worker_done_ = true;
          if (result.ok()) {
            final_.set_progress(1.0);
            final_.set_stage("done");
            *final_.mutable_result() = std::move(*result);
            have_final_ = true;
          } else {
            status_ = result.status();
          }
          MaybeWriteLocked();
        });
  }

  void OnWriteDone(bool ok) override {
    absl::MutexLock lock(&mu_);
    writing_ = false;
    if (!ok) {  // the client went away: stop the diagnosis; finish once the worker is done
      broken_ = true;
      cancelled_ = true;
    }
    MaybeWriteLocked();
  }

  void OnCancel() override {
    absl::MutexLock lock(&mu_);
    broken_ = true;
    cancelled_ = true;
    MaybeWriteLocked();
  }

  void OnDone() override {
    if (worker_.joinable()) worker_.join();
    delete this;
  }

 private:
  CallCounter::Token token_;
  grpc::CallbackServerContext* context_;  // gRPC's, valid until OnDone
  void Post(double fraction, const std::string& stage) {
    absl::MutexLock lock(&mu_);
    pending_.set_progress(fraction);
    pending_.set_stage(stage);
    have_pending_ = true;
    MaybeWriteLocked();
  }

  void MaybeWriteLocked() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
    if (writing_ || finished_) return;
    if (!broken_ && have_pending_) {
      current_ = pending_;
      have_pending_ = false;
      writing_ = true;
      StartWrite(&current_);
      return;
    }
    if (!worker_done_) return;
    if (!broken_ && have_final_) {
      current_ = final_;
      have_final_ = false;
      writing_ = true;
      StartWrite(&current_);
      return;
    }
    finished_ = true;
    Finish(
        ToGrpcStatus(broken_ ? absl::CancelledError("the client went away") : status_, *context_));
  }

  absl::Mutex mu_;
  esg::v1::DiagnoseUpdate pending_ ABSL_GUARDED_BY(mu_);
  esg::v1::DiagnoseUpdate final_ ABSL_GUARDED_BY(mu_);
  esg::v1::DiagnoseUpdate current_;  // the update being written
  bool have_pending_ ABSL_GUARDED_BY(mu_) = false;
  bool have_final_ ABSL_GUARDED_BY(mu_) = false;
  bool writing_ ABSL_GUARDED_BY(mu_) = false;
  bool worker_done_ ABSL_GUARDED_BY(mu_) = false;
  bool broken_ ABSL_GUARDED_BY(mu_) = false;
  bool finished_ ABSL_GUARDED_BY(mu_) = false;
  absl::Status status_ ABSL_GUARDED_BY(mu_);
  // Read by the diagnosis (its cancellation predicate) without the lock.
  std::atomic<bool> cancelled_{false};
  std::thread worker_;
};

}  // namespace

grpc::ServerWriteReactor<esg::v1::DiagnoseUpdate>* NewDiagnoseReactor(
    CallCounter* calls, grpc::CallbackServerContext* context, EstimationCore* core,
    esg::v1::DiagnoseRequest request, absl::StatusOr<CallLimiter::Permit> permit) {
  return new DiagnoseReactor(calls, context, core, std::move(request), std::move(permit));
}

}  // namespace esg::server
