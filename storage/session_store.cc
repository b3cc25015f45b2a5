// Session checkpoints; contract in session_store.h.
#include "storage/session_store.h"

#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/schema.h"

namespace esg::storage {

absl::Status SessionStore::PutCheckpoint(const CheckpointRecord& record) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  RETURN_IF_ERROR(PutCheckpoint(txn, record));
  return txn.Commit();
}

absl::Status SessionStore::PutCheckpoint(Transaction& txn, const CheckpointRecord& record) {
  RETURN_IF_ERROR(ValidateSpacecraftId(record.spacecraft_id, "checkpoint.spacecraft_id"));
  RETURN_IF_ERROR(ValidateStorableTime(record.measurement_time, "checkpoint.measurement_time"));
  RETURN_IF_ERROR(ValidateStorableTime(record.compute_time, "checkpoint.compute_time"));
  ASSIGN_OR_RETURN(
      Statement * st,
      txn.Prepare("INSERT INTO checkpoints (spacecraft_id, last_sequence, "
                  "measurement_time_unix_ns, compute_time_unix_ns, state_blob) "
                  "VALUES (?1, ?2, ?3, ?4, ?5) ON CONFLICT (spacecraft_id) DO UPDATE SET "
                  "last_sequence = excluded.last_sequence, "
                  "measurement_time_unix_ns = excluded.measurement_time_unix_ns, "
                  "compute_time_unix_ns = excluded.compute_time_unix_ns, "
                  "state_blob = excluded.state_blob"));
  st->BindText(1, record.spacecraft_id)
      .BindInt64(2, record.last_sequence)
      .BindInt64(3, TimeToUnixNanos(record.measurement_time))
      .BindInt64(4, TimeToUnixNanos(record.compute_time))
      .BindBlob(5, record.state_blob);
  return st->Run();
}

absl::StatusOr<CheckpointRecord> SessionStore::GetCheckpoint(absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT spacecraft_id, last_sequence, measurement_time_unix_ns, "
                               "compute_time_unix_ns, state_blob FROM checkpoints "
                               "WHERE spacecraft_id = ?1"));
  st->BindText(1, spacecraft_id);
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) {
    return absl::NotFoundError(absl::StrCat("no checkpoint for spacecraft '", spacecraft_id, "'"));
  }
  CheckpointRecord r;
  r.spacecraft_id = st->ColumnText(0);
  r.last_sequence = st->ColumnInt64(1);
  r.measurement_time = UnixNanosToTime(st->ColumnInt64(2));
  r.compute_time = UnixNanosToTime(st->ColumnInt64(3));
  r.state_blob = st->ColumnBlob(4);
  return r;
}

absl::StatusOr<std::vector<std::string>> SessionStore::ListSpacecraft() {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT spacecraft_id FROM checkpoints ORDER BY spacecraft_id"));
  std::vector<std::string> out;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    out.push_back(st->ColumnText(0));
  }
  return out;
}

absl::Status SessionStore::PutReadmission(const ReadmissionRecord& record) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  RETURN_IF_ERROR(PutReadmission(txn, record));
  return txn.Commit();
}

absl::Status SessionStore::PutReadmission(Transaction& txn, const ReadmissionRecord& record) {
  RETURN_IF_ERROR(ValidateSpacecraftId(record.spacecraft_id, "readmission.spacecraft_id"));
  if (record.gyro_id < 1 || record.gyro_id > 4) {
    return absl::InvalidArgumentError(
        absl::StrCat("readmission.gyro_id: ", record.gyro_id, " is not in 1..4"));
  }
  if (record.operator_name.empty()) {
    return absl::InvalidArgumentError("readmission.operator_name: empty");
  }
  RETURN_IF_ERROR(ValidateStorableTime(record.after_time, "readmission.after_time"));
  RETURN_IF_ERROR(ValidateStorableTime(record.compute_time, "readmission.compute_time"));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("INSERT INTO gyro_readmissions (spacecraft_id, after_time_unix_ns, "
                               "gyro_id, compute_time_unix_ns, operator_name) "
                               "VALUES (?1, ?2, ?3, ?4, ?5) ON CONFLICT DO NOTHING RETURNING 1"));
  st->BindText(1, record.spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(record.after_time))
      .BindInt64(3, record.gyro_id)
      .BindInt64(4, TimeToUnixNanos(record.compute_time))
      .BindText(5, record.operator_name);
  ASSIGN_OR_RETURN(bool inserted, st->Step());
  st->Reset();
  if (!inserted) {
    return absl::AlreadyExistsError(absl::StrCat("gyro_id: gyro ", record.gyro_id,
                                                 " is readmitted already after this time"));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<ReadmissionRecord>> SessionStore::ListReadmissions(
    absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT gyro_id, after_time_unix_ns, compute_time_unix_ns, "
                               "operator_name FROM gyro_readmissions WHERE spacecraft_id = ?1 "
                               "ORDER BY after_time_unix_ns, gyro_id"));
  st->BindText(1, spacecraft_id);
  std::vector<ReadmissionRecord> out;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    ReadmissionRecord r;
    r.spacecraft_id = std::string(spacecraft_id);
    r.gyro_id = static_cast<int>(st->ColumnInt64(0));
    r.after_time = UnixNanosToTime(st->ColumnInt64(1));
    r.compute_time = UnixNanosToTime(st->ColumnInt64(2));
    r.operator_name = st->ColumnText(3);
    out.push_back(std::move(r));
  }
  return out;
}

}  // namespace esg::storage
