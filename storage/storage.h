// The service database as one object: opens the SQLite file (WAL, synchronous per options),
// migrates it to the current schema, owns the stores, and commits the effects of a batch of
// telemetry atomically (durability contract in sqlite_db.h).
//
// CommitBatch is the server's unit of acknowledgement: "these frames + the coefficient
// estimates, alerts, alert repeats and checkpoint they produced" go into ONE transaction, so a
// crash never leaves frames without their effects or effects without their frames. Ack a frame
// only after CommitBatch returned OK for it.
#ifndef ESG_STORAGE_STORAGE_H_
#define ESG_STORAGE_STORAGE_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "storage/alert_store.h"
#include "storage/coefficient_store.h"
#include "storage/config_store.h"
#include "storage/diagnosis_store.h"
#include "storage/records.h"
#include "storage/session_store.h"
#include "storage/sqlite_db.h"
#include "storage/telemetry_archive.h"

namespace esg::storage {

// Everything one ingest step of one spacecraft writes. Every record's spacecraft_id must equal
// Batch::spacecraft_id.
struct Batch {
  std::string spacecraft_id;
  std::vector<ArchivedFrame> frames;
  std::vector<CoefficientRecord> coefficients;
  std::vector<AlertRecord> alerts;           // new alerts; sequences are assigned
  std::vector<AlertRepeat> alert_repeats;    // repeats collapsed into existing alerts
  std::optional<CheckpointRecord> checkpoint;  // replaces the stored one if present
};

struct BatchResult {
  std::vector<int64_t> new_frame_sequences;        // frames stored by this batch, input order
  std::vector<int64_t> duplicate_frame_sequences;  // frames already stored (ignored)
  std::vector<int64_t> alert_sequences;            // sequence of alerts[i], same order
};

// Thread-safe: any number of threads may call any method (serialized per Storage through its
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
  static absl::StatusOr<std::unique_ptr<Storage>> Open(const std::string& path,
                                                       const DatabaseOptions& options = {});

  // Writes the whole batch in one IMMEDIATE transaction and returns what was new. When it
  // returns OK, all of it is durable (sqlite_db.h); on any error none of it is visible.
  // Frames whose (spacecraft_id, sequence) is already stored are ignored and reported; their
  // coefficients/alerts/checkpoint are still written (they are the caller's to decide).
  // InvalidArgument (naming the record, e.g. "alerts[2].severity") for a record another store
  // would reject or whose spacecraft_id differs from the batch's; NotFound if an alert repeat
  // names a missing alert; Unavailable if the database stays locked beyond busy_timeout.
  // Storage faults (sqlite_db.h table): ResourceExhausted when the disk is full, Unavailable
  // when a write or the fsync fails; nothing of the batch is visible then, and the same Storage
  // takes the next CommitBatch as soon as the cause is gone.
  absl::StatusOr<BatchResult> CommitBatch(const Batch& batch);

  Database& database() { return *db_; }
  ConfigStore& configs() { return configs_; }
  TelemetryArchive& archive() { return archive_; }
  CoefficientStore& coefficients() { return coefficients_; }
  AlertStore& alerts() { return alerts_; }
  SessionStore& sessions() { return sessions_; }
  DiagnosisStore& diagnoses() { return diagnoses_; }

 private:
  explicit Storage(std::unique_ptr<Database> db);

  std::unique_ptr<Database> db_;
  ConfigStore configs_;
  TelemetryArchive archive_;
  CoefficientStore coefficients_;
  AlertStore alerts_;
  SessionStore sessions_;
  DiagnosisStore diagnoses_;
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_STORAGE_H_
