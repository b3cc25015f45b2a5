// The service's engine behind the gRPC layer (docs/service.md): the per-spacecraft registry,
// telemetry ingest under the ingest contract (docs/service.md "Ingest contract") with group
// commit, the workers that apply archived frames to each spacecraft's EstimationSession, alert
// collapsing and fan-out, quarantine, and the queries. No gRPC types except the esg.v1
// messages; errors are absl::Status. The implementation is spread over files by job:
// estimation_core.cc (start, load, quarantine, configure, stop), spacecraft_registry.h (the
// registry), ingest.cc, committer.cc (group commit), apply_worker.cc (the filter workers),
// alert_collapse.h (alert collapsing, a pure function of the occurrences), core_queries.cc,
// prediction.cc, proto_mapping.cc (storage records <-> esg.v1 messages), service_metrics.h
// (the metrics); core_internal.h holds the records. Storage is written only through the three
// transactions of storage/storage.h (ArchiveFrames, CommitFilterEffects, CommitConfiguration).
//
// DATA FLOW AND DURABILITY
//   Ingest (any thread)  validate -> decide (new, duplicate, conflict, late) -> accept (the
//                        station's sequence and the spacecraft's time high-water marks advance)
//                        -> committer queue.
//   Committer (1 thread) takes everything queued, appends it to the telemetry archive in ONE
//                        SQLite transaction (group commit; synchronous=FULL by default), then
//                        raises each station's highest durable sequence and calls the ack
//                        callbacks. An ack therefore always follows the durable commit. A failed
//                        commit fails the streams of its frames with UNAVAILABLE (never an ack),
//                        rolls the high-water marks back to the durable ones, and refuses ingest
//                        until a probe write succeeds (health NOT_SERVING meanwhile).
//   Workers (pool)       per spacecraft, one job at a time: apply durable frames in measurement-
//                        time order to a copy of the session; commit the coefficient snapshots
//                        and the per-step estimate (every measurement step; estimate_hub.h
//                        publishes the estimates once committed), new alerts, repeats and
//                        clears, the retention of the estimates, and the
//                        checkpoint (session values + apply cursor) in ONE transaction; then
//                        install the copy. On PostgreSQL these commits run on a connection of
//                        their own (storage.h "Connections"), so ingest's commits and acks never
//                        wait for them; the jobs that finish together share
//                        that transaction, each in its own savepoint (CommitFilterJob): one
//                        job's failure (a lost lease) undoes its own effects only. The checkpoint thus always matches the effects
//                        stored, so a restart (load checkpoint, replay archive after its
//                        cursor) applies no frame twice and loses none.
//   Late frames          a frame accepted within the reorder window but measured before an
//                        accepted one is archived together with a late-frame record (same
//                        transaction). A job that finds a late frame at or before its cursor
//                        re-runs: it restores the latest window checkpoint before the frame,
//                        marks the coefficient estimates and alerts after it revised, deletes
//                        the per-step estimates after it (written again), and replays the
//                        archive from there in time order, committing all of it, the removal
//                        of the late-frame records and the new checkpoint in ONE transaction.
//                        A restart reads the records back, so a late frame is never lost.
// LOCK ORDER: Spacecraft::job_mu -> ingest_mu -> state_mu -> (storage's database lock);
// the stream's own lock may be held while taking state_mu.
#ifndef ESG_SERVER_ESTIMATION_CORE_H_
#define ESG_SERVER_ESTIMATION_CORE_H_

#include <atomic>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "esg/v1/estimation_service.pb.h"
#include "estimator/calibration_model.h"
#include "estimator/frame_gap.h"
#include "estimator/orbit.h"
#include "estimator/session.h"
#include "estimator/spacecraft_config.h"
#include "server/alert_collapse.h"
#include "server/alert_hub.h"
#include "server/checkpoint_codec.h"
#include "server/estimate_hub.h"
#include "server/proto_mapping.h"
#include "server/service_metrics.h"
#include "server/session_summary.h"
#include "server/spacecraft_registry.h"
#include "storage/storage.h"

namespace esg::server {

class PredictionStream;

// Who asked for a diagnosis (storage::DiagnosisRecord requested_by, answers_alert): empty and 0
// for an operator's Diagnose call.
struct DiagnosisOrigin {
  std::string requested_by;
  int64_t answers_alert = 0;
};

// The orbit a diagnosis takes from the spacecraft's stored deliveries (core_orbits.cc): null
// when none covers the whole span, and a note that says which deliveries were used, or why none.
struct StoredOrbit {
  std::shared_ptr<const estimator::Orbit> orbit;
  std::string note;
};

struct CoreOptions {
  int worker_threads = 2;
  // Nice value of the worker threads (Linux, per thread): > 0 gives ingest and queries the CPU
  // first; the filter catches up when the load drops. 0 leaves the priority unchanged.
  int worker_nice = 10;
  // Frames applied per worker job (and per apply transaction) at most.
  int max_frames_per_job = 32;
  // PostgreSQL: how many filter jobs may wait for their commit at once. The jobs waiting
  // together are committed in ONE transaction (storage::Storage::CommitFilterEffectsGroup, each
  // job in its own savepoint), so a node makes one commit for many spacecraft instead of one per
  // job. The worker pool then has this many threads, of which at most worker_threads apply
  // frames at a time. 0 (the default), or not above worker_threads: each job commits alone.
  // The filter commits on a connection of its own (storage.h "Connections"), so ingest's commits
  // never wait for a group (docs/deploy.md "Capacity", BM_FleetAtOneHertz). SQLite: unused.
  int filter_commit_group = 0;
  // With the group commit: how long the first job of a group waits for others to finish and join
  // its transaction (or until filter_commit_group jobs wait). Delays the publication of the
  // estimates by at most this much, never an acknowledgement, which follows ingest's own commit
  // (docs/decisions.md D109). Zero: a group is what waits when the previous commit ends.
  absl::Duration filter_commit_window = absl::Milliseconds(25);
  // Occurrences of the same (reason, subsystem) within this measurement-time window collapse into
  // one alert (repeat_count); an alert without a new occurrence for this long is cleared.
  absl::Duration alert_collapse_window = absl::Minutes(30);
  // Late frames (measured before the spacecraft's last accepted frame) at most this much before
  // it are accepted and applied in time order by a re-run from a window checkpoint; older ones
  // are refused (docs/service.md "Several ground stations", docs/decisions.md D60).
  absl::Duration reorder_window = absl::Hours(2);
  // Per-step estimates older than this before the newest estimate of their spacecraft
  // (measurement time) are deleted (docs/service.md "Per-step estimates"); zero keeps them all.
  absl::Duration estimate_retention = absl::Hours(24 * 30);
  // The retention runs in a filter job once the newest estimate of the spacecraft has advanced
  // by this much (measurement time) since it last ran, and at the first job after the start.
  absl::Duration estimate_retention_period = absl::Hours(1);
  // Measurement-time period of the window checkpoints re-runs start from (D61).
  absl::Duration window_checkpoint_period = absl::Hours(1);
  // Largest accepted time step between consecutive frames of a spacecraft (rejected beyond:
  // the filter integrates across a gap at the configured rate). The offline verbs of esg apply
  // the same limit to a recording's rows.
  absl::Duration max_frame_gap = estimator::kMaxFrameGap;
  // Longest prediction horizon after the last applied frame (OutOfRange beyond).
  absl::Duration max_prediction_horizon = absl::Hours(48);
  // Most samples in one prediction.
  int max_prediction_samples = 100000;
  // Largest lead of a frame's measurement time over this server's clock; a frame further ahead
  // is refused (docs/service.md "Ingest contract"): nothing is measured in the future, and a
  // frame accepted ahead of the present would move the reorder window past the correct frames
  // that follow it. Kept below reorder_window, a frame accepted ahead of the clock never makes
  // a correct later frame too late.
  absl::Duration max_clock_lead = absl::Minutes(5);
  // Largest serialized telemetry frame accepted (a frame of four gyros is about 300 bytes).
  int64_t max_frame_bytes = 8192;
  // Frames queued for the archive, in bytes, over all streams; beyond, a stream fails with
  // RESOURCE_EXHAUSTED and the client resumes from its highest durable sequence.
  int64_t max_commit_backlog_bytes = 64 << 20;
  // Durable frames kept in memory per spacecraft for the filter; beyond, it reads the archive.
  int64_t max_ready_bytes = 16 << 20;
  // Accepted measurement times: [earliest_frame_time, latest_frame_time).
  absl::Time earliest_frame_time = absl::UnixEpoch();
  absl::Time latest_frame_time =
      absl::FromCivil(absl::CivilSecond(2200, 1, 1, 0, 0, 0), absl::UTCTimeZone());
  // Several servers sharing one PostgreSQL database (docs/service.md "Several servers"): this
  // server's node id, non-empty to turn on session leases. A spacecraft's session is then loaded
  // when a call for it first arrives, after taking its lease (storage/lease_store.h); every write
  // checks the lease; the leases are renewed every lease_duration / 3 and released at Stop().
  // Empty: one server owns the database and loads every session at the start.
  std::string node_id;
  absl::Duration lease_duration = absl::Seconds(15);
  // Consecutive filter failures (Internal or DataLoss from the estimator) that quarantine a
  // spacecraft.
  int quarantine_after_failures = 1;
  // Longest wait between two probe writes while storage cannot commit; the probes back off
  // exponentially up to it (server/backoff.h).
  absl::Duration storage_probe_period = absl::Seconds(1);
  // Tests only: called on a filter worker at the start of each job of a spacecraft, before it
  // takes frames; it may block, holding that spacecraft's filter behind ingest (frames stay
  // durable but not applied). It must return before the server stops. Empty: nothing.
  std::function<void(const std::string& spacecraft_id)> before_apply_job;
  // Tests only: called by a SubscribeEstimates call before it reads each page of its replay
  // (on a gRPC thread, no lock held); it may block, holding the replay while live estimates
  // arrive. It must return before the server stops. Empty: nothing.
  std::function<void(const std::string& spacecraft_id)> before_estimate_replay_page;
};

class EstimationCore {
 public:
  // Loads every configured spacecraft from `storage` (configuration, checkpoint, archive high-water
  // marks), starts the committer and the workers, and schedules the replay of archived frames
  // after each checkpoint. Errors of the storage reads; DataLoss for a corrupt checkpoint.
  static absl::StatusOr<std::unique_ptr<EstimationCore>> Start(storage::Storage* storage,
                                                               const CoreOptions& options);
  ~EstimationCore();

  // The first step of a shutdown (docs/service.md "Running it", Shutdown): from now on every
  // frame is refused with Unavailable and a retry delay (the stream fails, no ack), and each open
  // stream is told through the callback it registered (AddIngestStream), so that it stops
  // reading, sends the acks of the frames already queued once they are committed, and finishes.
  // Idempotent.
  void CloseIngest();
  // Registers an open telemetry stream: `on_close` is called once by CloseIngest (at once when
  // ingest is closed already), from the thread that closes it. Returns the id to remove it with
  // when the stream ends.
  int64_t AddIngestStream(std::function<void()> on_close);
  void RemoveIngestStream(int64_t id);
  // Unavailable "the server is shutting down ...; resume from highest_durable_sequence + 1 ..."
  // with a retry delay of 1 s (grpc_status.h WithRetryDelay): how a stream ends once ingest is
  // closed.
  static absl::Status ShuttingDown();

  // Stops accepting frames, commits what is queued (acks go out), lets the workers apply the
  // durable backlog until `drain_deadline`, then stops all threads. Idempotent.
  void Stop(absl::Duration drain_deadline);

  // ---- Ingest (ingest.cc; docs/service.md "Ingest contract") ----
  // Decides one frame. Fills `*ack` (spacecraft_id, station_id, sequence, accepted, duplicate,
  // rejection with its code; highest_durable_sequence is filled by FillDurable when the ack is
  // sent). Returns true when the ack must wait for durability: `on_durable` is then called
  // exactly once, from the committer thread, with OK after the commit that makes the frame
  // durable, or with the error that kept it from storage (the stream must then fail with it:
  // no ack). Returns false when the ack can be sent at once (a refusal, or a duplicate of a
  // durable frame); `on_durable` is not called. A non-OK result fails the stream without an ack
  // for this frame: Unavailable while storage cannot commit or the server stops,
  // ResourceExhausted when the commit backlog is full.
  // `scope`: the spacecraft the stream is routed by (its x-esg-spacecraft metadata,
  // server/spacecraft_scope.h), empty when it carries none; a frame of another spacecraft is
  // refused like any invalid frame (INVALID_ARGUMENT, field spacecraft_id) and the stream goes on.
  absl::StatusOr<bool> Ingest(const esg::v1::TelemetryFrame& frame, esg::v1::TelemetryAck* ack,
                              std::function<void(absl::Status)> on_durable,
                              absl::string_view scope = {});
  void FillDurable(esg::v1::TelemetryAck* ack);

  // Storage health: called with false and the reason when a commit fails, with true when a
  // later commit or probe succeeds (the server maps it to the health service). Set before
  // traffic starts; called from the committer thread.
  void SetStorageHealthListener(std::function<void(bool ok, const std::string& reason)> listener);
  // Empty while storage commits (ingest and filter); else why it cannot.
  std::string StorageFault();

  // ---- Configuration and queries ----
  // `precondition`, when given, runs under the lock that serialises configurations, before
  // anything changes; its error refuses the call (ApplyDiagnosis: the configuration the diagnosis
  // ran on is still the spacecraft's, so no configuration stored meanwhile is overwritten).
  absl::StatusOr<esg::v1::ConfigureResponse> Configure(
      const esg::v1::ConfigureRequest& request,
      const std::function<absl::Status()>& precondition = nullptr);
  absl::StatusOr<esg::v1::SessionInfo> GetSession(const std::string& spacecraft_id);
  // Paged lists (docs/service.md "Paging"): page_size 0 is the default, above the maximum the
  // maximum, negative InvalidArgument; a page_token that is not the next_page_token of the same
  // request is InvalidArgument naming page_token.
  static constexpr int64_t kDefaultSessionsPageSize = 100;
  static constexpr int64_t kMaxSessionsPageSize = 500;
  static constexpr int64_t kDefaultHistoryPageSize = 5000;
  static constexpr int64_t kMaxHistoryPageSize = 5000;
  static constexpr int64_t kDefaultEstimatesPageSize = 2000;
  static constexpr int64_t kMaxEstimatesPageSize = 5000;
  static constexpr int64_t kDefaultDiagnosesPageSize = 50;
  static constexpr int64_t kMaxDiagnosesPageSize = 100;
  // Records per message of the export streams.
  static constexpr int64_t kExportChunkSize = 1000;
  absl::StatusOr<esg::v1::ListSessionsResponse> ListSessions(
      const esg::v1::ListSessionsRequest& request);
  // Samples at or before the last applied frame from the archived readings, later ones planned
  // or held (prediction.cc; docs/service.md "PredictAttitude"). FailedPrecondition naming the
  // state when the session's output is not available.
  absl::StatusOr<esg::v1::PredictResponse> Predict(const esg::v1::PredictRequest& request);
  // The same prediction one chunk at a time (prediction_stream.h; PredictAttitudeStream): the
  // request is checked and the session copied now, every error above that does not depend on
  // the samples returned here; the samples are computed by PredictionStream::Next.
  absl::StatusOr<std::unique_ptr<PredictionStream>> StartPrediction(
      const esg::v1::PredictRequest& request);
  absl::StatusOr<esg::v1::HistoryResponse> History(const esg::v1::HistoryRequest& request);
  // One page of a spacecraft's per-step estimates in measurement-time order (docs/service.md
  // "Per-step estimates", "Paging"). InvalidArgument for an empty spacecraft_id, `to` before
  // `from`, a negative page_size or a bad page_token; NotFound for an unknown spacecraft.
  absl::StatusOr<esg::v1::EstimateHistoryResponse> EstimateHistory(
      const esg::v1::EstimateHistoryRequest& request);
  // Ids of the configured spacecraft, in order; with leases, every spacecraft configured in the
  // database (also those other servers hold).
  std::vector<std::string> SpacecraftIds();
  // The next chunk (at most kExportChunkSize frames) of an export: frames in the request's span
  // measured after `*after` (InfinitePast to start), which advances to the last frame returned;
  // `*done` is set when no frame follows.
  absl::StatusOr<esg::v1::ExportTelemetryResponse> ExportTelemetryChunk(
      const esg::v1::ExportTelemetryRequest& request, absl::Time* after, bool* done);

  // Model-discrepancy diagnosis (estimator/discovery/diagnose.h, docs/discovery.md) over the
  // archived telemetry of a spacecraft in [from, to); the result is stored (DiagnosisStore) and
  // returned. Long-running (seconds): call it off the gRPC threads. `cancelled` (may be empty)
  // is polled between the stages and candidate model runs; once it returns true the diagnosis
  // stops, nothing is stored, and the result is Cancelled "diagnosis cancelled". NotFound for an
  // unknown spacecraft, InvalidArgument for a bad span or model, FailedPrecondition when the
  // span holds no frames.
  // `origin`: who asked (empty for a Diagnose call; the automatic diagnosis's, auto_diagnosis.h),
  // stored with the result.
  absl::StatusOr<esg::v1::DiagnosisResult> Diagnose(
      const esg::v1::DiagnoseRequest& request,
      const std::function<void(double fraction, const std::string& stage)>& progress,
      const std::function<bool()>& cancelled = {}, const DiagnosisOrigin& origin = {});
  absl::StatusOr<esg::v1::ListDiagnosesResponse> ListDiagnoses(
      const esg::v1::ListDiagnosesRequest& request);
  // NotFound for an id that is not a diagnosis of the spacecraft.
  absl::StatusOr<esg::v1::DiagnosisResult> GetDiagnosis(
      const esg::v1::GetDiagnosisRequest& request);
  absl::StatusOr<esg::v1::Alert> Acknowledge(const esg::v1::AcknowledgeRequest& request);

  // ---- Orbits (core_orbits.cc; docs/service.md "Orbits") ----
  // Stores a delivery after reading it as `esg diagnose --orbit` reads a file; `uploaded_by`
  // the caller. InvalidArgument naming the field (spacecraft_id, "oem: line N: KEYWORD: ...").
  absl::StatusOr<esg::v1::OrbitDelivery> UploadOrbit(const esg::v1::UploadOrbitRequest& request,
                                                     const std::string& uploaded_by);
  absl::StatusOr<esg::v1::ListOrbitsResponse> ListOrbits(const esg::v1::ListOrbitsRequest& request);
  // The orbit of the deliveries meeting [from, to], later uploads used where they overlap, when
  // they cover it whole; else none and the note says why.
  absl::StatusOr<StoredOrbit> OrbitFor(const std::string& spacecraft_id, absl::Time from,
                                       absl::Time to);

  // ---- Operator actions (operator_actions.cc; docs/service.md "Applying a diagnosis",
  // "Readmitting a gyro") ----
  // The stored diagnosis's findings that map to configuration applied to the configuration it
  // ran on, through Configure with replace = true. Refusals as the RPC's (estimation_service.proto).
  absl::StatusOr<esg::v1::ApplyDiagnosisResponse> ApplyDiagnosis(
      const esg::v1::ApplyDiagnosisRequest& request);
  // Stores the readmission of an excluded gyro (request.operator_name set by the caller); the next
  // filter job applies it before its first frame (EstimationSession::ReadmitGyro). Refusals as the
  // RPC's (estimation_service.proto).
  absl::StatusOr<esg::v1::ReadmitGyroResponse> ReadmitGyro(
      const esg::v1::ReadmitGyroRequest& request);
  // NotFound unless empty or configured.
  absl::Status CheckSpacecraft(const std::string& spacecraft_id);

  // ---- The automatic diagnosis (server/auto_diagnosis.h; docs/service.md "Automatic
  // diagnosis") ----
  // Called with each new MODEL_INCONSISTENT alert once it is stored and published (a filter
  // worker's thread, no lock of the core held), and with the id of each spacecraft whose
  // configuration changed (after the change is stored). Either may be empty; both must return
  // quickly. Replaces the previous observer; SetModelObserver({}, {}) before the observer goes.
  void SetModelObserver(std::function<void(const storage::AlertRecord&)> on_model_alert,
                        std::function<void(const std::string&)> on_configured);
  // Raises an alert of the service itself (reason a catalog name, e.g. "MODEL_DIAGNOSED") at the
  // measurement time of the spacecraft's last applied frame, or `occurrence.time` when later; the
  // next filter job stores and publishes it (scheduled now). NotFound for an unknown spacecraft.
  absl::Status RaiseServiceAlert(const std::string& spacecraft_id, AlertOccurrence occurrence);
  // The measurement time of the spacecraft's last durable frame (InfinitePast: none); NotFound
  // for a spacecraft not held by this server.
  absl::StatusOr<absl::Time> LastDurableTime(const std::string& spacecraft_id);

  // Blocks until every durable frame of the spacecraft is applied (or `timeout`); for tests and
  // the benchmark. DeadlineExceeded on timeout.
  absl::Status WaitApplied(const std::string& spacecraft_id, absl::Duration timeout);

  AlertHub& alert_hub() { return hub_; }
  EstimateHub& estimate_hub() { return estimate_hub_; }
  // The service's metrics (docs/service.md "Metrics"); the gRPC layer counts ingest in it.
  ServiceMetrics& metrics() { return metrics_; }
  const CoreOptions& options() const { return options_; }
  storage::Storage& storage() { return *storage_; }
  // The filter's commits so far: transactions begun for filter jobs (a group counts once, each
  // job alone once) and the jobs they carried; for tests and the benchmark (D109).
  struct FilterCommitCounts {
    int64_t transactions = 0;
    int64_t jobs = 0;
  };
  FilterCommitCounts filter_commit_counts() const {
    return {filter_transactions_.load(std::memory_order_relaxed),
            filter_jobs_committed_.load(std::memory_order_relaxed)};
  }

 private:
  struct Setup;
  struct Spacecraft;
  struct CommitEntry;

  explicit EstimationCore(storage::Storage* storage, const CoreOptions& options);
  absl::Status Load();
  // Loads one configured spacecraft; a checkpoint that cannot be used quarantines it (rebuilt
  // from the archive where possible) instead of failing the start. Errors: storage reads only.
  // `lease_epoch`: the session lease taken for it (0: no leases).
  absl::Status LoadSpacecraft(const storage::ConfigRecord& record, int64_t lease_epoch = 0);
  // The record LoadSpacecraft registers, built from the database (configuration, checkpoint,
  // archive marks); `snapshot`: for a summary only (nothing logged, not registered).
  absl::StatusOr<std::shared_ptr<Spacecraft>> RestoreSpacecraft(const storage::ConfigRecord& record,
                                                                bool snapshot);
  // RestoreSpacecraft's steps (estimation_core.cc), in order, each with what it decides.
  struct Restoration;
  // The archive's marks of the spacecraft (highest sequences, latest frame time, frame count,
  // late frames, readmissions) into r. Errors: storage reads.
  absl::Status ReadArchiveMarks(const std::string& spacecraft_id, Restoration& r);
  // The stored configuration's setup into r.setup, or why it cannot be used (r.config_problem).
  static void SetupFromStoredConfig(const storage::ConfigRecord& record, Restoration& r);
  // The stored checkpoint, decoded and checked against the archive, into r.checkpoint, or why it
  // cannot be used (r.checkpoint_problem: missing, undecodable, ahead of the archive). Errors:
  // storage reads.
  absl::Status ReadStoredCheckpoint(const std::string& spacecraft_id, Restoration& r);
  // The checkpoint's model and session restored (else a fresh session; else the configuration
  // cannot be used: r.setup null), with why into r's problems; the checkpoint's session dropped.
  static void RestoreSession(Restoration& r);
  // The quarantine reason ("" for none): a configuration that cannot be used refuses frames, a
  // checkpoint that cannot be used is rebuilt from the archive (r.checkpoint reset to a
  // rebuilding one). Errors: storage reads.
  absl::StatusOr<std::string> QuarantineReason(const std::string& spacecraft_id, Restoration& r);
  // Installs r in sc under ingest_mu, then state_mu (with the quarantine alert when `reason` is
  // not empty).
  static void InstallRestoration(Spacecraft& sc, Restoration& r, const std::string& reason);
  // Configure's steps (estimation_core.cc), in order, each with what it decides.
  struct Configuration;
  // The request checked (InvalidArgument "config: required", the configuration's and the model's
  // own errors) and turned into the new setup, a fresh session and the records to store.
  static absl::StatusOr<Configuration> PrepareConfiguration(
      const esg::v1::ConfigureRequest& request);
  // Commits the configuration change `c` describes (timed as the "configure" commit); the
  // sequences it stored or cleared go to c.ended_sequences.
  absl::Status StoreConfiguration(Configuration& c) ABSL_EXCLUSIVE_LOCKS_REQUIRED(configure_mu_);
  // The configured spacecraft's record (its fence in c.fence), or null for a new one (with
  // leases, its lease taken: *new_lease_epoch and c.fence); Lookup's and the lease's errors.
  absl::StatusOr<std::shared_ptr<Spacecraft>> FindForConfigure(const std::string& spacecraft_id,
                                                               Configuration& c,
                                                               int64_t* new_lease_epoch)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(configure_mu_);
  // Stores and registers a new spacecraft with the fresh session; the "created" response.
  absl::StatusOr<esg::v1::ConfigureResponse> ConfigureNewSpacecraft(Configuration& c,
                                                                    int64_t lease_epoch)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(configure_mu_);
  // Replaces sc's session when the configuration or model changed, or when a quarantined one is
  // replaced: FailedPrecondition if it has telemetry and `replace` is false; else stores the
  // change and installs the fresh session (the archive to be reapplied). Takes ingest_mu and
  // state_mu. OK without change when the same configuration and model are given again.
  absl::Status ReplaceSessionIfChanged(Spacecraft& sc, Configuration& c, bool replace)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(configure_mu_, sc.job_mu);
  // The quarantine alert cleared at the reconfiguration, into c.quarantine_end.
  void EndQuarantineAtReconfiguration(Spacecraft& sc, Configuration& c)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.ingest_mu, sc.state_mu);
  // Publishes the revised alerts, then those the reconfiguration stored or cleared (counted),
  // under publish_mu so no job of the new session publishes first.
  void PublishReconfiguration(Spacecraft& sc, const Configuration& c)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  // With leases: the summary of a session this server does not hold, read from the database,
  // with served_by the holder of an unexpired lease.
  absl::StatusOr<esg::v1::SessionInfo> SummarizeFromDatabase(const storage::ConfigRecord& record);
  // The spacecraft's record for a call that needs its session: Find(), and with leases (node_id)
  // a record whose lease this server holds, taking the lease and loading the session (checkpoint
  // plus archive after it) if needed. NotFound "not configured"; Unavailable "spacecraft_id:
  // 'X' is served by node N until T; retry after that" while another server holds the lease
  // (LeaseRefused).
  absl::StatusOr<std::shared_ptr<Spacecraft>> Lookup(const std::string& spacecraft_id);
  // A failed LeaseStore::Acquire's status: a refusal because another server holds the lease is
  // counted (lease event "refused") and becomes Unavailable "spacecraft_id: 'X' is served by node
  // N until T; retry after that ..." (the store's message, the field first as every refusal of a
  // frame: RejectionFromStatus) with the time until the holder's expiry as its retry delay
  // (grpc_status.h WithRetryDelay: trailing metadata grpc-retry-pushback-ms of a call,
  // Rejection.retry_after_ms of a frame), at most lease_duration; any other status as is.
  absl::Status LeaseRefused(const absl::Status& status);
  // OK if the spacecraft is configured (in the registry, or with leases in the database): for
  // calls that only read the database. NotFound "not configured" otherwise.
  absl::Status CheckConfigured(const std::string& spacecraft_id);
  bool shared() const { return !options_.node_id.empty(); }
  // The lease fence of `sc` for a write (nullopt without leases).
  std::optional<storage::LeaseFence> FenceOf(const Spacecraft& sc) const;
  // Marks `sc`'s lease taken over by another server (found by a renewal or a fenced commit):
  // counted and logged (session_lost, `why`) the first time only.
  void MarkLeaseLost(Spacecraft& sc, absl::string_view why);
  // Renews the held leases every lease_duration / 3, all in one transaction
  // (LeaseStore::RenewAll); a lease found taken over marks its record lost (calls for it take
  // the lease again, or are refused while another server holds it).
  void LeaseLoop();
  // Publishes to this server's subscribers every alert change and every estimate another server
  // committed (PostgreSQL LISTEN/NOTIFY, storage::kAlertsChannel and kEstimatesChannel),
  // reading them from the database; estimates only while someone subscribes to them.
  void RelayLoop();
  // Reads the estimates of `spacecraft_id` measured at `times` (not empty) and publishes those
  // still stored, in measurement-time order.
  void RelayEstimates(const std::string& spacecraft_id, const std::set<absl::Time>& times);
  // Ingest helpers (ingest.cc). CheckFrame: the frame's own checks against its spacecraft (not
  // quarantined, sequence, fields, configured gyros, accepted window, the clock); a refusal
  // "field: reason", or OK.
  absl::Status CheckFrame(Spacecraft& sc, const esg::v1::TelemetryFrame& proto,
                          const absl::StatusOr<estimator::TelemetryFrame>& frame)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.ingest_mu);
  // A frame whose station and sequence, or whose time, the spacecraft accepted before, judged
  // against the stored frame: empty for a late frame the reorder window still takes (to be
  // queued); otherwise Ingest's result (a conflict or a frame too late refused in *ack, an exact
  // duplicate acknowledged as one, taking `on_durable` when the original is not durable yet, or
  // a storage error).
  std::optional<absl::StatusOr<bool>> JudgeKnownFrame(
      const std::shared_ptr<Spacecraft>& sc, const std::string& station, int64_t sequence,
      absl::Time time, const std::string& payload, bool known_identity,
      esg::v1::TelemetryAck* ack, std::function<void(absl::Status)>& on_durable)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc->ingest_mu);
  absl::StatusOr<std::optional<storage::ArchivedFrame>> FindStoredFrame(
      Spacecraft& sc, const std::string& station, int64_t sequence, absl::Time time,
      bool by_identity) ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.ingest_mu);
  // Committer helpers (committer.cc).
  absl::Status CommitFrames(const std::vector<CommitEntry>& batch);
  void FailBatch(std::vector<CommitEntry>& batch, const absl::Status& error);
  // Ingest's commits (they hold ingest while failing) and the filter's commits fail or recover;
  // health follows both. Logged once per change. StorageCommitFailed: a commit of frames failed
  // (a new fault, or the same one again: counted, logged only when the reason changes);
  // StorageCommitSucceeded: ends a fault ("ingest resumed", with its counts).
  void StorageCommitFailed(const std::string& reason);
  void StorageCommitSucceeded();
  void SetApplyFault(const std::string& spacecraft_id, const std::string& reason);
  void NotifyStorageHealth();
  // A probe write while storage cannot commit; when it succeeds, ingest takes frames again on
  // trial (storage_trial_). True when it succeeded.
  bool ProbeStorage();
  std::shared_ptr<Spacecraft> Find(const std::string& spacecraft_id);
  void Schedule(const std::shared_ptr<Spacecraft>& sc);
  void CommitterLoop();
  void WorkerLoop();
  // Diagnose without the log lines and metrics around it.
  absl::StatusOr<esg::v1::DiagnosisResult> RunDiagnosis(
      const esg::v1::DiagnoseRequest& request,
      const std::function<void(double fraction, const std::string& stage)>& progress,
      const std::function<bool()>& cancelled, const DiagnosisOrigin& origin);
  // Tells the model observer of the new MODEL_INCONSISTENT alerts among `published` (a filter
  // job's, committed), and of a reconfiguration of `spacecraft_id`.
  void NotifyModelAlerts(const std::vector<storage::AlertRecord>& published);
  void NotifyConfigured(const std::string& spacecraft_id);
  // Reads the gauges of the metrics from the registry and the committer (each scrape).
  void CollectGauges();
  // Applies the next frames of one spacecraft; true when more remain (apply_worker.cc). A job
  // is a sequence of steps, each a function of its own, passing an ApplyJob on: take the frames
  // and the session under the spacecraft's lock, read what the store holds for them (a re-run's
  // start, archived frames), apply them to a copy of the session, commit the effects with the
  // checkpoint, install the session and publish. A step returning a value ends the job there
  // with that value.
  struct ApplyJob;
  bool RunJob(const std::shared_ptr<Spacecraft>& sc);
  void TakeJob(Spacecraft& sc, ApplyJob& job) ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  std::optional<bool> ReadJobFrames(Spacecraft& sc, ApplyJob& job)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  void ApplyJobFrames(Spacecraft& sc, ApplyJob& job) ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  std::optional<bool> CommitJob(Spacecraft& sc, ApplyJob& job)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  // Empty when a reconfiguration replaced the session meanwhile (nothing is installed).
  std::optional<bool> InstallJob(Spacecraft& sc, ApplyJob& job)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  void PublishJob(Spacecraft& sc, const ApplyJob& job) ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  // A read of the store failed before anything was applied: a filter fault of the spacecraft
  // (logged once, until its commits succeed again), the service alerts the job took handed
  // back, and the job retried after a pause that backs off (server/backoff.h). True.
  bool RetryJobAfterReadError(Spacecraft& sc, ApplyJob& job, const std::string& message)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  // Ends the filter fault that failed reads or commits raised, if any.
  void EndApplyFault(Spacecraft& sc) ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  void QuarantineJob(Spacecraft& sc, ApplyJob& job, absl::Time time, const std::string& station,
                     int64_t sequence, const absl::Status& failure)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(sc.job_mu);
  // Commits one job's effects: alone (SQLite), or with the other jobs waiting at the same time
  // in one transaction (PostgreSQL: group_filter_commits_); the result is the job's own
  // (committer.cc).
  absl::StatusOr<std::vector<int64_t>> CommitFilterJob(const storage::FilterEffects& effects);
  // With group_filter_commits_: a job applies frames only while it holds one of worker_threads
  // slots, so the extra threads that wait for commits do not add to the filter's CPU share.
  void AcquireApplySlot();
  void ReleaseApplySlot();
  // A re-run over late frames (reorder.cc): where it starts and what it revises.
  struct Rerun {
    absl::Time after = absl::InfinitePast();  // the restored cursor (InfinitePast: fresh)
    std::vector<storage::AlertRestore> restores;
    std::vector<int64_t> revised_alerts;
  };
  // Replaces *session and *apply by the latest window checkpoint before `late_time` (or a fresh
  // session of `setup` when there is none or it cannot be restored). Errors: storage reads.
  absl::StatusOr<Rerun> StartRerun(const std::string& spacecraft_id, const Setup& setup,
                                   absl::Time late_time,
                                   std::optional<estimator::EstimationSession>* session,
                                   ServerCheckpoint* apply);
  // Current alerts the filter raised (not the ingest or the service) first raised after
  // `after`: what a re-run from `after`, or a new session, supersedes (reorder.cc).
  absl::StatusOr<std::vector<int64_t>> FilterAlertsAfter(const std::string& spacecraft_id,
                                                         absl::Time after);
  // The spacecraft's summary, read under its locks (proto_mapping.h SessionInfoToProto).
  SessionSummary Summarize(Spacecraft& sc);

  storage::Storage* const storage_;
  const CoreOptions options_;
  ServiceMetrics metrics_;
  AlertHub hub_;
  EstimateHub estimate_hub_;

  SpacecraftRegistry<Spacecraft> registry_;
  absl::Mutex configure_mu_;  // serialises Configure calls

  // Committer.
  absl::Mutex commit_mu_;
  std::vector<CommitEntry> commit_queue_ ABSL_GUARDED_BY(commit_mu_);
  int64_t commit_queue_bytes_ ABSL_GUARDED_BY(commit_mu_) = 0;
  // Why storage cannot commit (empty: it can). Ingest is refused while set, unless a probe
  // write succeeded since (storage_trial_).
  std::string storage_fault_ ABSL_GUARDED_BY(commit_mu_);
  // A probe write succeeded while storage_fault_ is set: ingest takes frames again and health
  // is SERVING, but storage counts as recovered ("ingest resumed") only once a commit of frames
  // succeeds; a commit that fails ends the trial (docs/decisions.md D95: a probe fit on a full
  // disk, the next commit did not).
  bool storage_trial_ ABSL_GUARDED_BY(commit_mu_) = false;
  // Since when storage_fault_ is set, and the commits and probes that failed since then.
  absl::Time storage_fault_since_ ABSL_GUARDED_BY(commit_mu_);
  int64_t storage_failed_commits_ ABSL_GUARDED_BY(commit_mu_) = 0;
  int64_t storage_failed_probes_ ABSL_GUARDED_BY(commit_mu_) = 0;
  // Why the filter's commits of a spacecraft fail (absent: they commit); health only, ingest
  // goes on.
  std::map<std::string, std::string> apply_faults_ ABSL_GUARDED_BY(commit_mu_);
  absl::Mutex listener_mu_;
  std::function<void(bool, const std::string&)> storage_listener_ ABSL_GUARDED_BY(listener_mu_);
  bool commit_stop_ ABSL_GUARDED_BY(commit_mu_) = false;
  bool ingest_closed_ ABSL_GUARDED_BY(commit_mu_) = false;
  // Open telemetry streams and what closes each (CloseIngest).
  absl::Mutex streams_mu_ ABSL_ACQUIRED_AFTER(commit_mu_);
  std::map<int64_t, std::function<void()>> ingest_streams_ ABSL_GUARDED_BY(streams_mu_);
  int64_t next_stream_id_ ABSL_GUARDED_BY(streams_mu_) = 0;
  bool streams_closed_ ABSL_GUARDED_BY(streams_mu_) = false;
  std::thread committer_;
  std::thread lease_renewer_;  // with leases only
  std::thread relay_;          // with leases only
  absl::Mutex takeover_mu_;    // one lease take and session load at a time

  // Filter group commit (PostgreSQL): the jobs waiting for their commit, and whether one of
  // their threads is committing a group now (the next group is taken when it is done).
  struct FilterCommit;
  const bool group_filter_commits_;
  absl::Mutex filter_commit_mu_;
  std::vector<FilterCommit*> filter_commit_queue_ ABSL_GUARDED_BY(filter_commit_mu_);
  bool filter_committing_ ABSL_GUARDED_BY(filter_commit_mu_) = false;
  std::atomic<int64_t> filter_transactions_{0};
  std::atomic<int64_t> filter_jobs_committed_{0};
  absl::Mutex apply_slots_mu_;
  int apply_slots_free_ ABSL_GUARDED_BY(apply_slots_mu_) = 0;

  // Worker pool.
  absl::Mutex pool_mu_;
  std::deque<std::shared_ptr<Spacecraft>> ready_ ABSL_GUARDED_BY(pool_mu_);
  bool pool_stop_ ABSL_GUARDED_BY(pool_mu_) = false;
  std::vector<std::thread> workers_;

  absl::Mutex stop_mu_;
  bool stopped_ ABSL_GUARDED_BY(stop_mu_) = false;

  // SetModelObserver's; held while one is called, so none runs after it is replaced.
  absl::Mutex observer_mu_;
  std::function<void(const storage::AlertRecord&)> on_model_alert_ ABSL_GUARDED_BY(observer_mu_);
  std::function<void(const std::string&)> on_configured_ ABSL_GUARDED_BY(observer_mu_);
};

}  // namespace esg::server

#endif  // ESG_SERVER_ESTIMATION_CORE_H_
