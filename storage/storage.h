// The service database as one object: opens the SQLite file (WAL, synchronous per options) or
// the PostgreSQL database (docs/service.md "Storage backends"), migrates it to the current
// schema, owns the stores, and commits the three write transactions the server makes
// (durability contracts in sqlite_db.h and postgres_db.h; docs/service.md "Durability and
// recovery"):
//   ArchiveFrames        the group commit of accepted telemetry: the unit of acknowledgement (a
//                        frame is acknowledged only after the call that archived it returned OK);
//   CommitFilterEffects  one filter job of a spacecraft: its coefficient estimates, per-step
//                        estimates, new alerts, repeats, clears and the checkpoint that
//                        carries the apply cursor, so
//                        a restart (checkpoint + archive after its cursor) applies no frame twice;
//                        with a re-run over late frames, also the revision of what it supersedes
//                        and the reorder window's bookkeeping (reorder_store.h);
//   CommitConfiguration  a configuration with the fresh checkpoint of its session (and the
//                        clearing of a quarantine alert it ends).
// Each is ONE transaction (IMMEDIATE with SQLite): on any error none of it is visible.
// Connections: SQLite, one for everything. PostgreSQL, three: the filter's commits
// (CommitFilterEffects, CommitFilterEffectsGroup) run on a connection of their own, and so does
// the lease renewal round (LeaseStore::RenewAll), so that neither a filter transaction nor a
// renewal of every lease of the server holds up the group commit of frames and the
// acknowledgements waiting for it; everything else (ArchiveFrames, CommitConfiguration, the
// stores' reads and writes) runs on the main one. All are opened with the same options
// (synchronous_commit=on), so the durability contract is the same on each, and a filter
// transaction checks its lease fence inside itself as before (a server taking the lease over
// waits for the fence's row lock until the filter's transaction ends).
#ifndef ESG_STORAGE_STORAGE_H_
#define ESG_STORAGE_STORAGE_H_

#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "storage/alert_store.h"
#include "storage/coefficient_store.h"
#include "storage/config_store.h"
#include "storage/diagnosis_store.h"
#include "storage/database.h"
#include "storage/estimate_store.h"
#include "storage/lease_store.h"
#include "storage/orbit_store.h"
#include "storage/records.h"
#include "storage/postgres_db.h"
#include "storage/reorder_store.h"
#include "storage/session_store.h"
#include "storage/sqlite_db.h"
#include "storage/telemetry_archive.h"

namespace esg::storage {

// A stored alert found over at a measurement epoch (AlertStore::Clear).
struct AlertClear {
  int64_t sequence = 0;
  absl::Time time;  // measurement epoch at which the condition ended
};

// What one filter job of one spacecraft writes (server/apply_worker.cc). Every record's
// spacecraft_id must equal `spacecraft_id`.
struct FilterEffects {
  std::string spacecraft_id;
  std::vector<CoefficientRecord> coefficients;
  // Per-step estimates (EstimateStore), each replacing a stored one at its measurement time.
  std::vector<EstimateRecord> estimates;
  std::vector<AlertRecord> new_alerts;  // sequences are assigned, in this order
  std::vector<AlertRepeat> repeats;     // repeats collapsed into stored alerts
  std::vector<AlertClear> clears;       // stored alerts to clear
  // A re-run from a window checkpoint (docs/service.md "Several ground stations"): before the
  // records above are written, the current coefficient estimates measured after `after` and
  // the alerts `alerts` are marked revised at `revised_time`, the alerts of `restores` set back
  // to their checkpointed state, the per-step estimates measured after `after` deleted (the
  // re-run writes them again; no audit copies), and the window checkpoints after `after`
  // dropped.
  struct Revision {
    absl::Time after = absl::InfinitePast();  // InfinitePast: from a fresh session
    absl::Time revised_time;
    std::vector<int64_t> alerts;
    std::vector<AlertRestore> restores;
  };
  std::optional<Revision> revision;
  // Late frames (measurement times) this job accounted for: forgotten by the transaction.
  std::vector<absl::Time> late_frames_done;
  // A window checkpoint to keep, and then the ones older than the latest before
  // `prune_before` to drop (InfinitePast: no pruning).
  std::optional<WindowCheckpoint> window_checkpoint;
  absl::Time prune_before = absl::InfinitePast();
  // Retention of the per-step estimates: after the records above are written, those measured
  // before this are deleted (InfinitePast: none).
  absl::Time estimates_before = absl::InfinitePast();
  // The checkpoint, built inside the transaction from the sequences assigned to new_alerts
  // (same order): it carries the live alert tracks with their sequences. Required.
  std::function<CheckpointRecord(const std::vector<int64_t>& alert_sequences)> checkpoint;
  // Several servers on one database: the writing server's lease, checked first inside the
  // transaction (LeaseStore::CheckHeld; Unavailable and nothing written when it was lost).
  std::optional<LeaseFence> fence;
};

// What a configuration writes (server/estimation_core.cc Configure).
struct ConfigurationChange {
  ConfigRecord config;
  // Whether the latest stored version is this one (ConfigStore::Put); nullptr: byte-identical.
  ConfigStore::SameConfig same_config;
  CheckpointRecord checkpoint;          // the new session's, same spacecraft
  std::vector<AlertRecord> new_alerts;  // e.g. a quarantine alert stored raised and cleared
  std::vector<AlertClear> clears;       // e.g. the quarantine alert the configuration ends
  // The new session replaces the old: its window checkpoints, late frames and per-step
  // estimates are dropped (the new session applies the whole archive in time order and writes
  // its own estimates); its coefficient snapshots and the alerts `revised_alerts` are marked
  // revised at the checkpoint's compute_time (kept for audit, superseded by the new session's).
  bool new_session = false;
  std::vector<int64_t> revised_alerts;
  // As FilterEffects::fence.
  std::optional<LeaseFence> fence;
};

// Thread-safe: any number of threads may call any method (serialized per connection: its
// Database). With DatabaseOptions::exclusive (the default) a Storage owns its file: no other
// Storage, process or sqlite3 shell can open it until this one is destroyed. With exclusive =
// false several Storage objects (processes) may open the same file; writers then wait on each
// other up to busy_timeout.
class Storage {
 public:
  // Opens or creates the database at `path` (the parent directory must exist) and migrates it
  // to kCurrentSchemaVersion. Errors of Database::Open and MigrateToCurrent; notably
  // FailedPrecondition "db: <path> cannot be written: <reason>" for a file that cannot be
  // written (read-only or immutable file, -wal or directory, read-only file system, full disk)
  // and for a database written by a newer program, Unavailable "db: <path> is locked by another
  // process" when another Storage owns the file, DataLoss for a corrupt file.
  // A `path` that is a PostgreSQL URI (IsPostgresUri) opens that database instead (OpenPostgres
  // with default options; `options` are SQLite's).
  static absl::StatusOr<std::unique_ptr<Storage>> Open(const std::string& path,
                                                       const DatabaseOptions& options = {});

  // Connects to the PostgreSQL database at `uri` and creates or migrates its schema (several
  // servers starting at once is safe). Errors of PostgresDatabase::Open and MigrateToCurrent.
  static absl::StatusOr<std::unique_ptr<Storage>> OpenPostgres(
      const std::string& uri, const PostgresOptions& options = {});

  // Migrates `db` and wraps it (for an engine opened by the caller).
  static absl::StatusOr<std::unique_ptr<Storage>> FromDatabase(std::unique_ptr<Database> db);

  // Archives `frames` (any spacecraft, any order) in one transaction: the server's group commit.
  // Every frame must be new: AlreadyExists "<id>: N frames are already archived (first sequence
  // S)" when one's identity or measurement time is stored or repeated in `frames`, and nothing
  // is stored (the caller decided them new; acknowledging them would be false). InvalidArgument
  // (naming "frames[i]") for a frame the archive rejects. Storage faults (sqlite_db.h table):
  // ResourceExhausted when the disk is full, Unavailable when a write or the fsync fails;
  // nothing is visible then, and the next call succeeds as soon as the cause is gone. OK: all
  // of it is durable (with Synchronous::kFull, across power loss). `late_frames` (spacecraft ->
  // measurement times of frames of this batch measured before one already accepted) are
  // recorded as late (ReorderStore) in the same transaction. `fences` (spacecraft -> the
  // writing server's lease; several servers on one database) are checked first inside the
  // transaction: Unavailable naming the spacecraft, and nothing stored, for a lease lost.
  absl::Status ArchiveFrames(
      const std::vector<ArchivedFrame>& frames,
      const std::map<std::string, std::vector<absl::Time>>& late_frames = {},
      const std::map<std::string, LeaseFence>& fences = {});

  // Writes a filter job's effects and its checkpoint in one transaction; returns the sequences
  // assigned to effects.new_alerts, in order. InvalidArgument naming the record
  // ("coefficients[1]", "estimates[0]", "new_alerts[0].severity", "repeats[0].spacecraft_id") for a record a
  // store rejects or of another spacecraft, or for a missing checkpoint function; NotFound for a
  // repeat or clear of a missing alert; storage faults as ArchiveFrames.
  absl::StatusOr<std::vector<int64_t>> CommitFilterEffects(const FilterEffects& effects);

  // Several filter jobs (of different spacecraft) in ONE transaction, each inside its own
  // savepoint: the server's group commit of the filter on PostgreSQL (docs/service.md "Durability
  // and recovery"). results[j] is what CommitFilterEffects(*jobs[j]) would return: a job refused
  // (its lease lost, a record a store rejects) is rolled back alone and the other jobs' effects
  // are committed; a failure of the transaction itself (Begin, a savepoint that cannot be rolled
  // back, the commit: a lost connection, a full disk) is every remaining job's error, and then
  // nothing of any job is visible. An OK result is durable as with CommitFilterEffects.
  std::vector<absl::StatusOr<std::vector<int64_t>>> CommitFilterEffectsGroup(
      const std::vector<const FilterEffects*>& jobs);

  // Stores a configuration, its session's checkpoint and the alert changes in one transaction;
  // returns the sequences assigned to change.new_alerts. Errors as CommitFilterEffects
  // ("config.", "checkpoint.", "new_alerts[i]", "clears[i]").
  absl::StatusOr<std::vector<int64_t>> CommitConfiguration(const ConfigurationChange& change);

  // Stores an operator's readmission of a gyro (SessionStore::PutReadmission) in one
  // transaction that first checks `fence` (several servers on one database: the writing
  // server's lease of the session; nullopt without leases): Aborted naming the spacecraft, and
  // nothing stored, for a lease lost (LeaseStore::CheckHeld). Errors otherwise as
  // PutReadmission, storage faults as ArchiveFrames.
  absl::Status CommitReadmission(const ReadmissionRecord& record,
                                 const std::optional<LeaseFence>& fence);

  // PostgreSQL: a new connection notified of every committed change of an alert
  // (kAlertsChannel) and of every estimate stored (kEstimatesChannel), by any server sharing the
  // database. FailedPrecondition with SQLite (one server).
  absl::StatusOr<std::unique_ptr<PostgresListener>> ListenForChanges();
  // PostgreSQL: the server process of this Storage's main connection, the sender_pid of the
  // notifications its own commits other than the filter's cause; 0 with SQLite.
  int ConnectionPid();
  // PostgreSQL: the server process of the filter's connection (CommitFilterEffects and
  // CommitFilterEffectsGroup), the sender_pid of the notifications the filter's commits cause
  // (its alerts and estimates). With SQLite the same as ConnectionPid().
  int FilterConnectionPid();
  // PostgreSQL: the server process of the lease renewal's connection (LeaseStore::RenewAll).
  // With SQLite the same as ConnectionPid().
  int RenewalConnectionPid();

  Database& database() { return *db_; }
  ConfigStore& configs() { return configs_; }
  TelemetryArchive& archive() { return archive_; }
  CoefficientStore& coefficients() { return coefficients_; }
  AlertStore& alerts() { return alerts_; }
  SessionStore& sessions() { return sessions_; }
  DiagnosisStore& diagnoses() { return diagnoses_; }
  OrbitStore& orbits() { return orbits_; }
  ReorderStore& reorder() { return reorder_; }
  EstimateStore& estimates() { return estimates_; }
  LeaseStore& leases() { return leases_; }

 private:
  explicit Storage(std::unique_ptr<Database> db);
  // The checks of CommitFilterEffects made before the transaction, and its writes inside one.
  static absl::Status CheckFilterEffects(const FilterEffects& effects);
  absl::StatusOr<std::vector<int64_t>> WriteFilterEffects(Transaction& txn,
                                                          const FilterEffects& effects);

  // The connection of the filter's commits: filter_db_ on PostgreSQL, else db_.
  Database& filter_database() { return filter_db_ != nullptr ? *filter_db_ : *db_; }

  std::unique_ptr<Database> db_;
  // PostgreSQL only (null with SQLite): the filter's own connection, and the lease renewal's.
  std::unique_ptr<Database> filter_db_;
  std::unique_ptr<Database> renewal_db_;
  ConfigStore configs_;
  TelemetryArchive archive_;
  CoefficientStore coefficients_;
  AlertStore alerts_;
  SessionStore sessions_;
  DiagnosisStore diagnoses_;
  OrbitStore orbits_;
  ReorderStore reorder_;
  EstimateStore estimates_;
  LeaseStore leases_;
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_STORAGE_H_
