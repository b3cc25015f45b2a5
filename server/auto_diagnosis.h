// The service's own diagnosis of a model mismatch (docs/service.md "Automatic diagnosis",
// docs/decisions.md D99). When the filter raises a MODEL_INCONSISTENT alert, the service runs
// the model-discrepancy diagnosis (EstimationCore::Diagnose) over the archive of that spacecraft,
// stores it like a requested one (requested_by "service", answers_alert the alert's sequence),
// and raises a MODEL_DIAGNOSED alert that names the verdict, the diagnosis and the alert it
// answers.
//
// RULES
//   Trigger   a new MODEL_INCONSISTENT alert (not a repeat), as the filter worker publishes it
//             (EstimationCore::SetModelObserver); estimator/ knows nothing of it.
//   Debounce  per spacecraft: none while one is queued or running; none under a configuration
//             version for which an automatic diagnosis is stored whose last frame is less than
//             `span` before the alert (so one persistent mismatch, whatever its repeats and
//             re-raises, gives at most one run per `span` of telemetry); none under a version for
//             which an operator cancelled one (CancelAutoDiagnosis; the cancel is stored, so
//             it holds across restarts), until the configuration changes.
//   Span      the last `span` of measurement time up to the spacecraft's last durable frame.
//             Every configuration change re-applies the whole archive under the new
//             configuration, so the whole archive is the current configuration's; the span is
//             bounded by `span` alone.
//   Limits    one automatic diagnosis at a time over all spacecraft (one thread, a FIFO queue);
//             it takes a slot of the server's diagnosis limiter (--max-diagnoses) as the caller
//             kAutoDiagnosisCaller only when one is free, asking again every `slot_retry` while
//             none is: operators' calls are never refused because one waits, and at most one
//             slot is ever the service's.
//   Cancel    at Stop (the server's shutdown), at a reconfiguration of its spacecraft (its span is
//             stale: OnConfigured), and by an operator (Cancel); it stops at the diagnosis's next
//             check and stores nothing.
// Thread-safe.
#ifndef ESG_SERVER_AUTO_DIAGNOSIS_H_
#define ESG_SERVER_AUTO_DIAGNOSIS_H_

#include <atomic>
#include <cstdint>
#include <deque>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <thread>

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "esg/v1/estimation_service.pb.h"
#include "server/call_limiter.h"
#include "server/estimation_core.h"
#include "storage/records.h"

namespace esg::server {

struct AutoDiagnosisOptions {
  // The span diagnosed (measurement time up to the last durable frame), and the least telemetry
  // between two automatic diagnoses of a spacecraft under one configuration version
  // (esgd --auto-diagnosis-hours). Zero: no automatic diagnosis.
  absl::Duration span = absl::Hours(48);
  // Wall-clock wait before asking again for a diagnosis slot when none is free.
  absl::Duration slot_retry = absl::Seconds(5);
};

// The caller the automatic diagnosis holds its diagnosis slot as (no token or peer address has
// this form).
inline constexpr char kAutoDiagnosisCaller[] = "(esgd automatic diagnosis)";

// The MODEL_DIAGNOSED alert's message for `result` answering `alert` (exposed for tests): the
// verdict in words, the diagnosis, "answers alert #N (MODEL_INCONSISTENT <subsystem> at T)", and
// what to do.
std::string FollowUpMessage(const esg::v1::DiagnosisResult& result,
                            const storage::AlertRecord& alert);

class AutoDiagnosis {
 public:
  // Neither is owned; both must outlive this. Registers itself as `core`'s model observer and
  // starts its thread (none when options.span is zero).
  AutoDiagnosis(EstimationCore* core, CallLimiter* limiter, AutoDiagnosisOptions options);
  ~AutoDiagnosis();
  AutoDiagnosis(const AutoDiagnosis&) = delete;
  AutoDiagnosis& operator=(const AutoDiagnosis&) = delete;

  // The core's model observer (EstimationCore::SetModelObserver).
  void OnModelAlert(const storage::AlertRecord& alert);
  void OnConfigured(const std::string& spacecraft_id);

  // An operator's cancel: the queued or running automatic diagnosis of the spacecraft is
  // dropped or told to stop, and none starts again under its configuration version (stored:
  // DiagnosisStore::PutAutoCancel; a failure to store it is logged, and it then holds until
  // this server stops). Returns
  // the sequence of the alert it answered; nullopt when none was queued or running.
  std::optional<int64_t> Cancel(const std::string& spacecraft_id);

  // Unregisters from the core, cancels the queued and running diagnoses and joins the thread.
  // Idempotent.
  void Stop();

 private:
  struct Job {
    storage::AlertRecord alert;
    std::shared_ptr<std::atomic<bool>> cancelled = std::make_shared<std::atomic<bool>>(false);
    std::string why;  // why it was cancelled
  };

  void Loop();
  void Run(const Job& job);
  // Why the job must not run (debounce), or empty.
  std::string Debounced(const Job& job);
  // A slot of the diagnosis limiter, waiting for a free one; nullopt when cancelled meanwhile.
  std::optional<CallLimiter::Permit> WaitForSlot(const Job& job);
  void Finish(const Job& job, const absl::StatusOr<esg::v1::DiagnosisResult>& result,
              absl::Time started);
  std::string WhyCancelled(const Job& job);
  void CancelLocked(Job& job, const std::string& why) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  bool Busy(const std::string& spacecraft_id) const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);

  EstimationCore* const core_;
  CallLimiter* const limiter_;
  const AutoDiagnosisOptions options_;
  absl::Mutex mu_;
  std::deque<Job> queue_ ABSL_GUARDED_BY(mu_);
  std::optional<Job> running_ ABSL_GUARDED_BY(mu_);
  // Spacecraft whose automatic diagnosis an operator cancelled -> the configuration version then.
  std::map<std::string, int64_t> suppressed_ ABSL_GUARDED_BY(mu_);
  bool stop_ ABSL_GUARDED_BY(mu_) = false;
  std::thread thread_;
};

}  // namespace esg::server

#endif  // ESG_SERVER_AUTO_DIAGNOSIS_H_
