// Diagnosis results; contract in diagnosis_store.h.
#include "storage/diagnosis_store.h"

#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/read_rows.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

#define ESG_DIAGNOSIS_COLUMNS                                                     \
  "id, spacecraft_id, from_time_unix_ns, to_time_unix_ns, compute_time_unix_ns, " \
  "verdict, report_json, frames, config_version, model_name, requested_by, answers_alert"
constexpr char kSelectById[] = "SELECT " ESG_DIAGNOSIS_COLUMNS " FROM diagnoses WHERE id = ?1";
constexpr char kSelectBySpacecraft[] =
    "SELECT " ESG_DIAGNOSIS_COLUMNS " FROM diagnoses WHERE spacecraft_id = ?1 ORDER BY id";
// The same columns with an empty report (summaries; the index diagnoses_by_spacecraft).
constexpr char kSelectSummaries[] =
    "SELECT id, spacecraft_id, from_time_unix_ns, to_time_unix_ns, compute_time_unix_ns, "
    "verdict, '', frames, config_version, model_name, requested_by, answers_alert "
    "FROM diagnoses WHERE spacecraft_id = ?1 AND id > ?2 ORDER BY id LIMIT ?3";
#undef ESG_DIAGNOSIS_COLUMNS

DiagnosisRecord ReadRow(const Statement& st) {
  DiagnosisRecord r;
  r.id = st.ColumnInt64(0);
  r.spacecraft_id = st.ColumnText(1);
  r.from_time = UnixNanosToTime(st.ColumnInt64(2));
  r.to_time = UnixNanosToTime(st.ColumnInt64(3));
  r.compute_time = UnixNanosToTime(st.ColumnInt64(4));
  r.verdict = st.ColumnText(5);
  r.report_json = st.ColumnText(6);
  r.frames = st.ColumnInt64(7);
  r.config_version = st.ColumnInt64(8);  // NULL (stored before version 11) reads as 0
  r.model_name = st.ColumnText(9);
  r.requested_by = st.ColumnText(10);
  r.answers_alert = st.ColumnInt64(11);
  return r;
}

}  // namespace

absl::StatusOr<int64_t> DiagnosisStore::Put(const DiagnosisRecord& record) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(int64_t id, Put(txn, record));
  RETURN_IF_ERROR(txn.Commit());
  return id;
}

absl::StatusOr<int64_t> DiagnosisStore::Put(Transaction& txn, const DiagnosisRecord& record) {
  RETURN_IF_ERROR(ValidateSpacecraftId(record.spacecraft_id, "diagnosis.spacecraft_id"));
  if (record.verdict.empty()) return absl::InvalidArgumentError("diagnosis.verdict: empty");
  RETURN_IF_ERROR(ValidateStorableTime(record.from_time, "diagnosis.from_time"));
  RETURN_IF_ERROR(ValidateStorableTime(record.to_time, "diagnosis.to_time"));
  RETURN_IF_ERROR(ValidateStorableTime(record.compute_time, "diagnosis.compute_time"));
  if (record.to_time < record.from_time) {
    return absl::InvalidArgumentError("diagnosis.to_time: earlier than from_time");
  }
  if (record.answers_alert < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("diagnosis.answers_alert: must be >= 0, got ", record.answers_alert));
  }
  if (record.frames < 0) {
    return absl::InvalidArgumentError(
        absl::StrCat("diagnosis.frames: must be >= 0, got ", record.frames));
  }
  ASSIGN_OR_RETURN(
      Statement * st,
      txn.Prepare("INSERT INTO diagnoses (spacecraft_id, from_time_unix_ns, "
                  "to_time_unix_ns, compute_time_unix_ns, verdict, report_json, frames, "
                  "config_version, model_name, requested_by, answers_alert) "
                  "VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11) RETURNING id"));
  st->BindText(1, record.spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(record.from_time))
      .BindInt64(3, TimeToUnixNanos(record.to_time))
      .BindInt64(4, TimeToUnixNanos(record.compute_time))
      .BindText(5, record.verdict)
      .BindText(6, record.report_json)
      .BindInt64(7, record.frames);
  // 0 and empty (not recorded) are stored as NULL, as for a diagnosis stored before version 11.
  if (record.config_version > 0) {
    st->BindInt64(8, record.config_version);
  } else {
    st->BindNull(8);
  }
  if (!record.model_name.empty()) {
    st->BindText(9, record.model_name);
  } else {
    st->BindNull(9);
  }
  st->BindText(10, record.requested_by).BindInt64(11, record.answers_alert);
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return absl::InternalError("INSERT INTO diagnoses returned no id");
  const int64_t id = st->ColumnInt64(0);
  st->Reset();
  if (const int64_t keep = max_per_spacecraft(); keep > 0) {
    // Kept: the one just stored, then the operators' newest, then the service's newest, `keep`
    // in all; the rest go (index diagnoses_by_spacecraft). So the service's own diagnoses are
    // dropped before any an operator asked for, and never the one this call returns.
    ASSIGN_OR_RETURN(
        Statement * drop,
        txn.Prepare("DELETE FROM diagnoses WHERE spacecraft_id = ?1 AND id NOT IN "
                    "(SELECT id FROM diagnoses WHERE spacecraft_id = ?1 ORDER BY CASE WHEN "
                    "id = ?3 THEN 0 WHEN requested_by = ?4 THEN 2 ELSE 1 END, id DESC "
                    "LIMIT ?2)"));
    drop->BindText(1, record.spacecraft_id)
        .BindInt64(2, keep)
        .BindInt64(3, id)
        .BindText(4, kRequestedByService);
    RETURN_IF_ERROR(drop->Run());
  }
  return id;
}

absl::StatusOr<std::vector<DiagnosisRecord>> DiagnosisStore::List(absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(kSelectBySpacecraft));
  st->BindText(1, spacecraft_id);
  return ReadRows(st, ReadRow);
}

absl::StatusOr<std::vector<DiagnosisRecord>> DiagnosisStore::ListSummaries(
    absl::string_view spacecraft_id, int64_t after_id, int64_t limit) {
  if (limit <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("limit = ", limit, ": must be positive"));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(kSelectSummaries));
  st->BindText(1, spacecraft_id).BindInt64(2, after_id).BindInt64(3, limit);
  return ReadRows(st, ReadRow);
}

absl::StatusOr<DiagnosisRecord> DiagnosisStore::Get(int64_t id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(kSelectById));
  st->BindInt64(1, id);
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return absl::NotFoundError(absl::StrCat("no diagnosis with id ", id));
  return ReadRow(*st);
}

absl::Status DiagnosisStore::PutAutoCancel(const AutoCancelRecord& record) {
  RETURN_IF_ERROR(ValidateSpacecraftId(record.spacecraft_id, "auto_cancel.spacecraft_id"));
  if (record.config_version < 1) {
    return absl::InvalidArgumentError(absl::StrCat(
        "auto_cancel.config_version: must be >= 1, got ", record.config_version));
  }
  RETURN_IF_ERROR(ValidateStorableTime(record.cancel_time, "auto_cancel.cancel_time"));
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("INSERT INTO auto_diagnosis_cancels (spacecraft_id, "
                               "config_version, answers_alert, cancel_time_unix_ns) "
                               "VALUES (?1, ?2, ?3, ?4) ON CONFLICT DO NOTHING"));
  st->BindText(1, record.spacecraft_id)
      .BindInt64(2, record.config_version)
      .BindInt64(3, record.answers_alert)
      .BindInt64(4, TimeToUnixNanos(record.cancel_time));
  RETURN_IF_ERROR(st->Run());
  return txn.Commit();
}

absl::StatusOr<bool> DiagnosisStore::AutoCancelled(absl::string_view spacecraft_id,
                                                   int64_t config_version) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT 1 FROM auto_diagnosis_cancels WHERE spacecraft_id = ?1 "
                               "AND config_version = ?2"));
  st->BindText(1, spacecraft_id).BindInt64(2, config_version);
  ASSIGN_OR_RETURN(bool row, st->Step());
  st->Reset();
  return row;
}

}  // namespace esg::storage
