// The per-spacecraft records of EstimationCore, shared by the files that implement it
// (estimation_core.cc: lifecycle, load and configuration; ingest.cc: the ingest contract;
// committer.cc: group commit; apply_worker.cc: the filter workers; core_queries.cc and
// prediction.cc: the queries; shared_sessions.cc: several servers on one database). Not part
// of the server's interface.
#ifndef ESG_SERVER_CORE_INTERNAL_H_
#define ESG_SERVER_CORE_INTERNAL_H_

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "esg/v1/spacecraft_config.pb.h"
#include "estimator/calibration_model.h"
#include "estimator/session.h"
#include "estimator/spacecraft_config.h"
#include "server/alert_collapse.h"
#include "server/checkpoint_codec.h"
#include "server/estimation_core.h"

namespace esg::server {

// The frame an archived payload holds, checked as ingest checks a frame now (FrameFromProto):
// DataLoss when the payload does not parse, the check's error when a frame archived by an older
// version breaks a bound added since. The filter and a diagnosis both skip such a frame.
absl::StatusOr<estimator::TelemetryFrame> DecodeArchivedFrame(const std::string& payload);

inline constexpr const char* kDefaultModel = "10+11";
// The stored reason of the alert a quarantine raises (cleared when the quarantine ends).
inline constexpr const char* kQuarantineAlertReason = "SESSION_QUARANTINED";

// NotFound "spacecraft_id: 'X' is not configured" (X escaped and shortened).
absl::Status NotConfigured(const std::string& spacecraft_id);

// Applies to `session` each of `readmissions` (by after_time) stored after its last frame and
// before `frame_time`: after_time in [session.last_frame_time(), frame_time)
// (EstimationSession::ReadmitGyro); `log`: log each applied (not again in a re-run of frames
// whose effects are stored). One the session refuses (the gyro not excluded at this point of a
// re-run) changes nothing (operator_actions.cc).
void ApplyReadmissions(const std::string& spacecraft_id,
                       const std::vector<storage::ReadmissionRecord>& readmissions,
                       absl::Time frame_time, bool log, estimator::EstimationSession& session);

// What ApplyDiagnosis would set for the stored diagnosis `record` in `config`
// (DiagnosisResult.applies, .does_not_apply); nothing for a verdict none or unexplained, or a
// report that cannot be read (operator_actions.cc).
void DescribeApplication(const estimator::SpacecraftConfig& config,
                         const storage::DiagnosisRecord& record, esg::v1::DiagnosisResult* result);

// A window checkpoint's blob: the server checkpoint `apply` with `session`'s state (reorder.cc).
std::string EncodeWindowCheckpoint(const ServerCheckpoint& apply,
                                   const estimator::EstimationSession& session);

// One per configured spacecraft (shared by its ingest and state sides). Neither the wire form
// of the configuration nor its JSON is kept: GetSession converts `config` when asked
// (ConfigToProto) and a reconfiguration compares ConfigToJson of both, which saves two copies in
// every session (docs/performance.md "Sessions per node").
struct EstimationCore::Setup {
  estimator::SpacecraftConfig config;
  estimator::ModelSpec model;
  std::string model_name;
  std::array<bool, estimator::kMaxGyros> configured{};
};

// A frame accepted and queued for the archive, not yet durable.
struct PendingFrame {
  std::string station;
  int64_t sequence = 0;
  std::string payload;  // as it will be stored
};

// A durable frame waiting for the filter.
struct ReadyFrame {
  std::string station;
  int64_t sequence = 0;
  estimator::TelemetryFrame frame;
};

struct EstimationCore::Spacecraft {
  explicit Spacecraft(std::string spacecraft_id) : id(std::move(spacecraft_id)) {}
  const std::string id;

  // Several servers on one database (CoreOptions::node_id): the epoch of this server's lease of
  // the session (0: no leases), and whether it was found taken over (the record is then
  // replaced when the lease is taken again).
  std::atomic<int64_t> lease_epoch{0};
  std::atomic<bool> lease_lost{false};

  // Held for a whole worker job and by a reconfiguration.
  absl::Mutex job_mu;
  int apply_retries ABSL_GUARDED_BY(job_mu) = 0;  // failed commits of the filter in a row
  // Newest estimate (measurement time) when the retention of the per-step estimates last ran
  // (InfinitePast: not since the start); CoreOptions::estimate_retention_period.
  absl::Time estimates_retained_at ABSL_GUARDED_BY(job_mu) = absl::InfinitePast();

  // ---- Ingest side ----
  absl::Mutex ingest_mu ABSL_ACQUIRED_AFTER(job_mu);
  // Null when the stored configuration cannot be used (quarantined): frames are refused.
  std::shared_ptr<const Setup> ingest_setup ABSL_GUARDED_BY(ingest_mu);
  std::map<std::string, int64_t> highest_accepted ABSL_GUARDED_BY(ingest_mu);  // per station
  absl::Time last_accepted_time ABSL_GUARDED_BY(ingest_mu) = absl::InfinitePast();
  std::map<absl::Time, PendingFrame> pending ABSL_GUARDED_BY(ingest_mu);  // by measurement time
  std::map<std::pair<std::string, int64_t>, absl::Time> pending_ids ABSL_GUARDED_BY(ingest_mu);
  int64_t frames_rejected ABSL_GUARDED_BY(ingest_mu) = 0;
  int64_t frames_duplicate ABSL_GUARDED_BY(ingest_mu) = 0;
  int64_t frames_conflicting ABSL_GUARDED_BY(ingest_mu) = 0;

  // ---- Durable and applied state ----
  absl::Mutex state_mu ABSL_ACQUIRED_AFTER(ingest_mu);
  std::shared_ptr<const Setup> setup ABSL_GUARDED_BY(state_mu);  // null: see ingest_setup
  std::map<std::string, int64_t> highest_durable ABSL_GUARDED_BY(state_mu);  // per station
  absl::Time last_durable_time ABSL_GUARDED_BY(state_mu) = absl::InfinitePast();
  int64_t frames_accepted ABSL_GUARDED_BY(state_mu) = 0;
  std::map<absl::Time, ReadyFrame> ready ABSL_GUARDED_BY(state_mu);  // durable, not applied
  int64_t ready_bytes ABSL_GUARDED_BY(state_mu) = 0;
  std::optional<estimator::EstimationSession> session ABSL_GUARDED_BY(state_mu);
  // Counters, alert tracks, apply cursor and quarantine (its `session` is unused).
  ServerCheckpoint apply ABSL_GUARDED_BY(state_mu);
  int64_t generation ABSL_GUARDED_BY(state_mu) = 0;
  bool replay_from_archive ABSL_GUARDED_BY(state_mu) = true;
  absl::Time last_compute_time ABSL_GUARDED_BY(state_mu) = absl::InfinitePast();
  // Durable late frames (measurement times) not yet accounted for by a worker job: one at or
  // before the apply cursor makes the next job re-run the filter from a window checkpoint
  // (apply_worker.cc); mirrored by the late_frames table.
  std::set<absl::Time> late_frames ABSL_GUARDED_BY(state_mu);
  // Alerts raised outside the filter (ingest conflicts, quarantine at load), stored by the next
  // worker job.
  std::vector<AlertOccurrence> service_alerts ABSL_GUARDED_BY(state_mu);
  // The operators' stored readmissions of excluded gyros, by after_time (operator_actions.cc):
  // a job applies each before the first frame after its after_time, also in a re-run from the
  // archive; mirrored by the gyro_readmissions table.
  std::vector<storage::ReadmissionRecord> readmissions ABSL_GUARDED_BY(state_mu);

  // Orders alert publication (worker) with acknowledgements (rpc threads).
  absl::Mutex publish_mu;

  // Worker scheduling, guarded by EstimationCore::pool_mu_.
  bool scheduled = false;
  bool wake = false;
};

struct EstimationCore::CommitEntry {
  std::shared_ptr<Spacecraft> sc;
  bool barrier = false;  // no frame: completes with the next commit (duplicate of a pending frame)
  std::string station;
  int64_t sequence = 0;
  absl::Time time;
  bool late = false;  // measured before a frame accepted earlier: recorded as a late frame
  std::string payload;
  estimator::TelemetryFrame frame;
  std::function<void(absl::Status)> done;
};

}  // namespace esg::server

#endif  // ESG_SERVER_CORE_INTERNAL_H_
