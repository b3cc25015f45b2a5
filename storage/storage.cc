// The Storage facade; contract in storage.h.
#include "storage/storage.h"

#include <algorithm>
#include <map>
#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/postgres_schema.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

// Prefixes the field path of a store's error with the record's place in the transaction.
absl::Status InBatch(absl::Status status, absl::string_view where) {
  if (status.ok()) return status;
  return absl::Status(status.code(), absl::StrCat(where, ": ", status.message()));
}

absl::Status CheckSpacecraft(const std::string& record_id, const std::string& batch_id,
                             absl::string_view where) {
  if (record_id == batch_id) return absl::OkStatus();
  return absl::InvalidArgumentError(absl::StrCat(where, ".spacecraft_id = '", record_id,
                                                 "': differs from the transaction's '", batch_id,
                                                 "'"));
}

// A write transaction on `db`, the filter's connection: own_connection (PostgreSQL) when it is
// not the main one. That connection may have sat idle through a restart of the database server:
// its first BEGIN then finds the connection lost (having done nothing) and the next one
// reconnects.
absl::StatusOr<Transaction> BeginFilterTransaction(Database& db, bool own_connection) {
  {
    absl::StatusOr<Transaction> txn = db.Begin(TransactionMode::kImmediate);
    if (!own_connection || !absl::IsUnavailable(txn.status())) return txn;
  }
  return db.Begin(TransactionMode::kImmediate);
}

}  // namespace

Storage::Storage(std::unique_ptr<Database> db)
    : db_(std::move(db)),
      configs_(db_.get()),
      archive_(db_.get()),
      coefficients_(db_.get()),
      alerts_(db_.get()),
      sessions_(db_.get()),
      diagnoses_(db_.get()),
      orbits_(db_.get()),
      reorder_(db_.get()),
      estimates_(db_.get()),
      leases_(db_.get()) {}

absl::StatusOr<std::unique_ptr<Storage>> Storage::Open(const std::string& path,
                                                       const DatabaseOptions& options) {
  if (IsPostgresUri(path)) return OpenPostgres(path);
  ASSIGN_OR_RETURN(std::unique_ptr<SqliteDatabase> db, SqliteDatabase::Open(path, options));
  return FromDatabase(std::move(db));
}

absl::StatusOr<std::unique_ptr<Storage>> Storage::OpenPostgres(const std::string& uri,
                                                               const PostgresOptions& options) {
  ASSIGN_OR_RETURN(std::unique_ptr<PostgresDatabase> db, PostgresDatabase::Open(uri, options));
  ASSIGN_OR_RETURN(std::unique_ptr<Storage> storage, FromDatabase(std::move(db)));
  // The filter's connection, opened after the migration so that it sees the current schema.
  ASSIGN_OR_RETURN(storage->filter_db_, PostgresDatabase::Open(uri, options));
  ASSIGN_OR_RETURN(storage->renewal_db_, PostgresDatabase::Open(uri, options));
  storage->leases_.SetRenewalDatabase(storage->renewal_db_.get());
  return storage;
}

absl::StatusOr<std::unique_ptr<Storage>> Storage::FromDatabase(std::unique_ptr<Database> db) {
  RETURN_IF_ERROR(MigrateToCurrent(*db));
  return std::unique_ptr<Storage>(new Storage(std::move(db)));
}

absl::StatusOr<std::unique_ptr<PostgresListener>> Storage::ListenForChanges() {
  if (db_->dialect() != Dialect::kPostgres) {
    return absl::FailedPreconditionError("change notifications need a PostgreSQL database");
  }
  return static_cast<PostgresDatabase&>(*db_).Listen({kAlertsChannel, kEstimatesChannel});
}

int Storage::ConnectionPid() {
  if (db_->dialect() != Dialect::kPostgres) return 0;
  return static_cast<PostgresDatabase&>(*db_).BackendPid();
}

int Storage::FilterConnectionPid() {
  if (filter_db_ == nullptr) return ConnectionPid();
  return static_cast<PostgresDatabase&>(*filter_db_).BackendPid();
}

int Storage::RenewalConnectionPid() {
  if (renewal_db_ == nullptr) return ConnectionPid();
  return static_cast<PostgresDatabase&>(*renewal_db_).BackendPid();
}

absl::Status Storage::ArchiveFrames(
    const std::vector<ArchivedFrame>& frames,
    const std::map<std::string, std::vector<absl::Time>>& late_frames,
    const std::map<std::string, LeaseFence>& fences) {
  // Per spacecraft, in input order; a frame's place in `frames` names it in errors.
  std::map<std::string, std::vector<ArchivedFrame>> by_spacecraft;
  for (size_t i = 0; i < frames.size(); ++i) {
    RETURN_IF_ERROR(InBatch(ValidateSpacecraftId(frames[i].spacecraft_id, "spacecraft_id"),
                            absl::StrCat("frames[", i, "]")));
    by_spacecraft[frames[i].spacecraft_id].push_back(frames[i]);
  }
  if (by_spacecraft.empty()) return absl::OkStatus();
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  for (const auto& [id, fence] : fences) RETURN_IF_ERROR(leases_.CheckHeld(txn, id, fence));
  for (const auto& [id, list] : by_spacecraft) {
    ASSIGN_OR_RETURN(AppendResult appended, archive_.AppendBatch(txn, id, list));
    if (!appended.duplicate_sequences.empty()) {
      return absl::AlreadyExistsError(absl::StrCat(
          id, ": ", appended.duplicate_sequences.size(),
          " frames are already archived (first sequence ", appended.duplicate_sequences.front(),
          "); nothing of this commit is stored"));
    }
  }
  for (const auto& [id, times] : late_frames) {
    RETURN_IF_ERROR(reorder_.AddLateFrames(txn, id, times));
  }
  return txn.Commit();
}

absl::Status Storage::CheckFilterEffects(const FilterEffects& effects) {
  const std::string& id = effects.spacecraft_id;
  RETURN_IF_ERROR(ValidateSpacecraftId(id, "spacecraft_id"));
  if (!effects.checkpoint) return absl::InvalidArgumentError("checkpoint: required");
  // Cheap checks before taking the write lock.
  for (size_t i = 0; i < effects.coefficients.size(); ++i) {
    RETURN_IF_ERROR(CheckSpacecraft(effects.coefficients[i].spacecraft_id, id,
                                    absl::StrCat("coefficients[", i, "]")));
  }
  for (size_t i = 0; i < effects.estimates.size(); ++i) {
    RETURN_IF_ERROR(CheckSpacecraft(effects.estimates[i].spacecraft_id, id,
                                    absl::StrCat("estimates[", i, "]")));
  }
  for (size_t i = 0; i < effects.new_alerts.size(); ++i) {
    RETURN_IF_ERROR(CheckSpacecraft(effects.new_alerts[i].spacecraft_id, id,
                                    absl::StrCat("new_alerts[", i, "]")));
  }
  for (size_t i = 0; i < effects.repeats.size(); ++i) {
    RETURN_IF_ERROR(CheckSpacecraft(effects.repeats[i].spacecraft_id, id,
                                    absl::StrCat("repeats[", i, "]")));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<int64_t>> Storage::WriteFilterEffects(Transaction& txn,
                                                            const FilterEffects& effects) {
  const std::string& id = effects.spacecraft_id;
  if (effects.fence.has_value()) RETURN_IF_ERROR(leases_.CheckHeld(txn, id, *effects.fence));
  if (effects.revision.has_value()) {
    const FilterEffects::Revision& r = *effects.revision;
    RETURN_IF_ERROR(InBatch(
        reorder_.Revise(txn, id, r.after, r.revised_time, r.alerts, r.restores).status(),
        "revision"));
    RETURN_IF_ERROR(reorder_.DropCheckpointsFrom(
        txn, id, r.after == absl::InfinitePast() ? r.after : r.after + absl::Nanoseconds(1)));
    RETURN_IF_ERROR(InBatch(estimates_.DeleteAfter(txn, id, r.after).status(), "revision"));
  }
  for (size_t i = 0; i < effects.coefficients.size(); ++i) {
    RETURN_IF_ERROR(InBatch(coefficients_.Append(txn, effects.coefficients[i]),
                            absl::StrCat("coefficients[", i, "]")));
  }
  for (size_t i = 0; i < effects.estimates.size(); ++i) {
    RETURN_IF_ERROR(InBatch(estimates_.Put(txn, effects.estimates[i]),
                            absl::StrCat("estimates[", i, "]")));
  }
  if (effects.estimates_before != absl::InfinitePast()) {
    RETURN_IF_ERROR(InBatch(estimates_.DeleteBefore(txn, id, effects.estimates_before).status(),
                            "estimates_before"));
  }
  std::vector<int64_t> sequences;
  sequences.reserve(effects.new_alerts.size());
  for (size_t i = 0; i < effects.new_alerts.size(); ++i) {
    absl::StatusOr<int64_t> sequence = alerts_.Append(txn, effects.new_alerts[i]);
    if (!sequence.ok()) return InBatch(sequence.status(), absl::StrCat("new_alerts[", i, "]"));
    sequences.push_back(*sequence);
  }
  for (size_t i = 0; i < effects.repeats.size(); ++i) {
    RETURN_IF_ERROR(
        InBatch(alerts_.UpdateRepeat(txn, effects.repeats[i]), absl::StrCat("repeats[", i, "]")));
  }
  for (size_t i = 0; i < effects.clears.size(); ++i) {
    RETURN_IF_ERROR(
        InBatch(alerts_.Clear(txn, id, effects.clears[i].sequence, effects.clears[i].time),
                absl::StrCat("clears[", i, "]")));
  }
  RETURN_IF_ERROR(reorder_.RemoveLateFrames(txn, id, effects.late_frames_done));
  const CheckpointRecord checkpoint = effects.checkpoint(sequences);
  RETURN_IF_ERROR(CheckSpacecraft(checkpoint.spacecraft_id, id, "checkpoint"));
  RETURN_IF_ERROR(sessions_.PutCheckpoint(txn, checkpoint));
  if (effects.window_checkpoint.has_value()) {
    RETURN_IF_ERROR(InBatch(reorder_.PutCheckpoint(txn, id, *effects.window_checkpoint),
                            "window_checkpoint"));
  }
  if (effects.prune_before != absl::InfinitePast()) {
    RETURN_IF_ERROR(reorder_.Prune(txn, id, effects.prune_before));
  }
  return sequences;
}


absl::StatusOr<std::vector<int64_t>> Storage::CommitFilterEffects(const FilterEffects& effects) {
  RETURN_IF_ERROR(CheckFilterEffects(effects));
  ASSIGN_OR_RETURN(Transaction txn,
                   BeginFilterTransaction(filter_database(), filter_db_ != nullptr));
  ASSIGN_OR_RETURN(std::vector<int64_t> sequences, WriteFilterEffects(txn, effects));
  RETURN_IF_ERROR(txn.Commit());
  return sequences;
}

std::vector<absl::StatusOr<std::vector<int64_t>>> Storage::CommitFilterEffectsGroup(
    const std::vector<const FilterEffects*>& jobs) {
  std::vector<absl::StatusOr<std::vector<int64_t>>> results(jobs.size());
  // In spacecraft-id order, as the group commit of frames and the lease renewal lock the
  // lease rows (LeaseStore::CheckHeld), so that none of them deadlocks with another.
  std::vector<size_t> order(jobs.size());
  for (size_t j = 0; j < jobs.size(); ++j) order[j] = j;
  std::stable_sort(order.begin(), order.end(), [&jobs](size_t a, size_t b) {
    return jobs[a]->spacecraft_id < jobs[b]->spacecraft_id;
  });
  std::vector<size_t> valid;
  for (size_t j : order) {
    absl::Status checked = CheckFilterEffects(*jobs[j]);
    if (checked.ok()) {
      valid.push_back(j);
    } else {
      results[j] = std::move(checked);
    }
  }
  if (valid.empty()) return results;
  // Every job still waiting for an outcome gets `status` (a failure of the whole transaction).
  auto fail_all = [&](const absl::Status& status) {
    for (size_t j : valid) {
      if (results[j].ok()) results[j] = status;
    }
    return results;
  };
  absl::StatusOr<Transaction> txn =
      BeginFilterTransaction(filter_database(), filter_db_ != nullptr);
  if (!txn.ok()) return fail_all(txn.status());
  // Each job inside its own savepoint: a job that fails (its lease lost, a record refused) is
  // undone alone and the others' writes stay in the transaction. A savepoint that cannot be
  // rolled back (the connection is gone) fails them all.
  std::vector<size_t> written;
  for (size_t j : valid) {
    if (absl::Status s = txn->Execute("SAVEPOINT filter_job"); !s.ok()) return fail_all(s);
    absl::StatusOr<std::vector<int64_t>> sequences = WriteFilterEffects(*txn, *jobs[j]);
    if (sequences.ok()) {
      if (absl::Status s = txn->Execute("RELEASE SAVEPOINT filter_job"); !s.ok()) {
        return fail_all(s);
      }
      results[j] = std::move(*sequences);
      written.push_back(j);
      continue;
    }
    if (absl::Status s = txn->Execute("ROLLBACK TO SAVEPOINT filter_job"); !s.ok()) {
      return fail_all(s);
    }
    if (absl::Status s = txn->Execute("RELEASE SAVEPOINT filter_job"); !s.ok()) {
      return fail_all(s);
    }
    results[j] = sequences.status();
  }
  if (written.empty()) return results;
  if (absl::Status committed = txn->Commit(); !committed.ok()) {
    for (size_t j : written) results[j] = committed;
  }
  return results;
}

absl::StatusOr<std::vector<int64_t>> Storage::CommitConfiguration(
    const ConfigurationChange& change) {
  const std::string& id = change.config.spacecraft_id;
  RETURN_IF_ERROR(ValidateSpacecraftId(id, "config.spacecraft_id"));
  RETURN_IF_ERROR(CheckSpacecraft(change.checkpoint.spacecraft_id, id, "checkpoint"));
  for (size_t i = 0; i < change.new_alerts.size(); ++i) {
    RETURN_IF_ERROR(CheckSpacecraft(change.new_alerts[i].spacecraft_id, id,
                                    absl::StrCat("new_alerts[", i, "]")));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  if (change.fence.has_value()) RETURN_IF_ERROR(leases_.CheckHeld(txn, id, *change.fence));
  RETURN_IF_ERROR(InBatch(configs_.Put(txn, change.config, change.same_config).status(), "config"));
  RETURN_IF_ERROR(sessions_.PutCheckpoint(txn, change.checkpoint));
  if (change.new_session) {
    RETURN_IF_ERROR(reorder_.DropCheckpointsFrom(txn, id, absl::InfinitePast()));
    RETURN_IF_ERROR(reorder_.DropLateFrames(txn, id));
    RETURN_IF_ERROR(estimates_.DeleteAfter(txn, id, absl::InfinitePast()).status());
    RETURN_IF_ERROR(reorder_
                        .Revise(txn, id, absl::InfinitePast(), change.checkpoint.compute_time,
                                change.revised_alerts, {})
                        .status());
  }
  std::vector<int64_t> sequences;
  for (size_t i = 0; i < change.new_alerts.size(); ++i) {
    absl::StatusOr<int64_t> sequence = alerts_.Append(txn, change.new_alerts[i]);
    if (!sequence.ok()) return InBatch(sequence.status(), absl::StrCat("new_alerts[", i, "]"));
    sequences.push_back(*sequence);
  }
  for (size_t i = 0; i < change.clears.size(); ++i) {
    RETURN_IF_ERROR(InBatch(alerts_.Clear(txn, id, change.clears[i].sequence, change.clears[i].time),
                            absl::StrCat("clears[", i, "]")));
  }
  RETURN_IF_ERROR(txn.Commit());
  return sequences;
}

absl::Status Storage::CommitReadmission(const ReadmissionRecord& record,
                                        const std::optional<LeaseFence>& fence) {
  RETURN_IF_ERROR(ValidateSpacecraftId(record.spacecraft_id, "readmission.spacecraft_id"));
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  if (fence.has_value()) {
    RETURN_IF_ERROR(leases_.CheckHeld(txn, record.spacecraft_id, *fence));
  }
  RETURN_IF_ERROR(sessions_.PutReadmission(txn, record));
  return txn.Commit();
}

}  // namespace esg::storage
