// Alert history; contract in alert_store.h.
#include "storage/alert_store.h"

#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/read_rows.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

#define ESG_ALERT_COLUMNS                                                                    \
  "spacecraft_id, sequence, severity, reason, subsystem, value, threshold, unit, "          \
  "repeat_count, first_time_unix_ns, measurement_time_unix_ns, compute_time_unix_ns, "      \
  "message, acknowledged, acknowledged_by, acknowledged_time_unix_ns, cleared, "             \
  "cleared_time_unix_ns"
#define ESG_ALERT_READ_COLUMNS ESG_ALERT_COLUMNS ", revised_time_unix_ns"

constexpr char kSelectOne[] = "SELECT " ESG_ALERT_READ_COLUMNS
                              " FROM alerts WHERE spacecraft_id = ?1 AND sequence = ?2";
// Current alerts only, unless ?9 is 1 (revised ones too).
constexpr char kSinceOne[] = "SELECT " ESG_ALERT_READ_COLUMNS
                             " FROM alerts WHERE spacecraft_id = ?1 AND "
                             "measurement_time_unix_ns >= ?2 "
                             "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) "
                             "ORDER BY measurement_time_unix_ns, sequence LIMIT ?3";
constexpr char kSinceAll[] = "SELECT " ESG_ALERT_READ_COLUMNS
                             " FROM alerts WHERE measurement_time_unix_ns >= ?1 "
                             "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) "
                             "ORDER BY measurement_time_unix_ns, spacecraft_id, sequence LIMIT ?2";
// Since continued after a position ?4 (time), ?5 (sequence), ?6 (spacecraft): the redundant
// "measurement_time_unix_ns >= ?4" bounds the range the index is read from.
constexpr char kSinceOneAfter[] =
    "SELECT " ESG_ALERT_READ_COLUMNS
    " FROM alerts WHERE spacecraft_id = ?1 AND measurement_time_unix_ns >= ?2 "
    "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) AND measurement_time_unix_ns >= ?4 "
    "AND (measurement_time_unix_ns > ?4 OR sequence > ?5) "
    "ORDER BY measurement_time_unix_ns, sequence LIMIT ?3";
constexpr char kSinceAllAfter[] =
    "SELECT " ESG_ALERT_READ_COLUMNS
    " FROM alerts WHERE measurement_time_unix_ns >= ?1 "
    "AND (?9 <> 0 OR revised_time_unix_ns IS NULL) AND measurement_time_unix_ns >= ?4 "
    "AND (measurement_time_unix_ns > ?4 OR spacecraft_id > ?6 "
    "OR (spacecraft_id = ?6 AND sequence > ?5)) "
    "ORDER BY measurement_time_unix_ns, spacecraft_id, sequence LIMIT ?2";
constexpr char kInsert[] = "INSERT INTO alerts (" ESG_ALERT_COLUMNS
                           ") VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7, ?8, ?9, ?10, ?11, ?12, ?13, "
                           "?14, ?15, ?16, ?17, ?18)";
#undef ESG_ALERT_READ_COLUMNS
#undef ESG_ALERT_COLUMNS

AlertRecord ReadRow(const Statement& st) {
  AlertRecord r;
  r.spacecraft_id = st.ColumnText(0);
  r.sequence = st.ColumnInt64(1);
  r.severity = st.ColumnText(2);
  r.reason = st.ColumnText(3);
  r.subsystem = st.ColumnText(4);
  r.value = st.ColumnDoubleOrNaN(5);
  r.threshold = st.ColumnDoubleOrNaN(6);
  r.unit = st.ColumnText(7);
  r.repeat_count = st.ColumnInt64(8);
  r.first_time = UnixNanosToTime(st.ColumnInt64(9));
  r.measurement_time = UnixNanosToTime(st.ColumnInt64(10));
  r.compute_time = UnixNanosToTime(st.ColumnInt64(11));
  r.message = st.ColumnText(12);
  r.acknowledged = st.ColumnInt64(13) != 0;
  r.acknowledged_by = st.ColumnText(14);
  r.acknowledged_time =
      st.ColumnIsNull(15) ? absl::InfinitePast() : UnixNanosToTime(st.ColumnInt64(15));
  r.cleared = st.ColumnInt64(16) != 0;
  r.cleared_time =
      st.ColumnIsNull(17) ? absl::InfinitePast() : UnixNanosToTime(st.ColumnInt64(17));
  r.revised_time =
      st.ColumnIsNull(18) ? absl::InfinitePast() : UnixNanosToTime(st.ColumnInt64(18));
  return r;
}

absl::StatusOr<AlertRecord> GetIn(Transaction& txn, absl::string_view spacecraft_id,
                                  int64_t sequence) {
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(kSelectOne));
  st->BindText(1, spacecraft_id).BindInt64(2, sequence);
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) {
    return absl::NotFoundError(
        absl::StrCat("no alert ", sequence, " for spacecraft '", spacecraft_id, "'"));
  }
  AlertRecord r = ReadRow(*st);
  st->Reset();
  return r;
}

// Runs an UPDATE keyed by ?1 spacecraft_id, ?2 sequence (already bound) and turns "no row"
// into NotFound.
absl::Status RunKeyedUpdate(Transaction& txn, Statement* st, absl::string_view spacecraft_id,
                            int64_t sequence) {
  RETURN_IF_ERROR(st->Run());
  if (txn.ChangedRows() == 0) {
    return absl::NotFoundError(
        absl::StrCat("no alert ", sequence, " for spacecraft '", spacecraft_id, "'"));
  }
  return absl::OkStatus();
}

absl::Status Validate(const AlertRecord& r) {
  RETURN_IF_ERROR(ValidateSpacecraftId(r.spacecraft_id, "alert.spacecraft_id"));
  if (r.severity.empty()) return absl::InvalidArgumentError("alert.severity: empty");
  if (r.reason.empty()) return absl::InvalidArgumentError("alert.reason: empty");
  if (r.repeat_count < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("alert.repeat_count = ", r.repeat_count, ": must be >= 1"));
  }
  RETURN_IF_ERROR(ValidateStorableTime(r.first_time, "alert.first_time"));
  RETURN_IF_ERROR(ValidateStorableTime(r.measurement_time, "alert.measurement_time"));
  RETURN_IF_ERROR(ValidateStorableTime(r.compute_time, "alert.compute_time"));
  if (r.acknowledged) {
    RETURN_IF_ERROR(ValidateStorableTime(r.acknowledged_time, "alert.acknowledged_time"));
  }
  if (r.cleared && r.cleared_time != absl::InfinitePast()) {
    RETURN_IF_ERROR(ValidateStorableTime(r.cleared_time, "alert.cleared_time"));
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<int64_t> AlertStore::Append(const AlertRecord& record) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(int64_t sequence, Append(txn, record));
  RETURN_IF_ERROR(txn.Commit());
  return sequence;
}

absl::StatusOr<int64_t> AlertStore::Append(Transaction& txn, const AlertRecord& record) {
  RETURN_IF_ERROR(Validate(record));
  // No race between MAX() and INSERT: both run in one transaction; in an IMMEDIATE one no other
  // connection can write in between, and a DEFERRED one whose snapshot another writer has
  // overtaken cannot upgrade (SQLITE_BUSY_SNAPSHOT -> Unavailable). The primary key backs this.
  ASSIGN_OR_RETURN(Statement * next,
                   txn.Prepare("SELECT COALESCE(MAX(sequence), 0) + 1 FROM alerts "
                               "WHERE spacecraft_id = ?1"));
  next->BindText(1, record.spacecraft_id);
  ASSIGN_OR_RETURN(bool row, next->Step());
  if (!row) return absl::InternalError("MAX(sequence) returned no row");
  const int64_t sequence = next->ColumnInt64(0);
  next->Reset();

  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(kInsert));
  st->BindText(1, record.spacecraft_id)
      .BindInt64(2, sequence)
      .BindText(3, record.severity)
      .BindText(4, record.reason)
      .BindText(5, record.subsystem)
      .BindDouble(6, record.value)
      .BindDouble(7, record.threshold)
      .BindText(8, record.unit)
      .BindInt64(9, record.repeat_count)
      .BindInt64(10, TimeToUnixNanos(record.first_time))
      .BindInt64(11, TimeToUnixNanos(record.measurement_time))
      .BindInt64(12, TimeToUnixNanos(record.compute_time))
      .BindText(13, record.message)
      .BindInt64(14, record.acknowledged ? 1 : 0)
      .BindInt64(17, record.cleared ? 1 : 0);
  if (record.acknowledged) {
    st->BindText(15, record.acknowledged_by)
        .BindInt64(16, TimeToUnixNanos(record.acknowledged_time));
  } else {
    st->BindNull(15).BindNull(16);
  }
  if (record.cleared && record.cleared_time != absl::InfinitePast()) {
    st->BindInt64(18, TimeToUnixNanos(record.cleared_time));
  } else {
    st->BindNull(18);
  }
  RETURN_IF_ERROR(st->Run());
  return sequence;
}

absl::StatusOr<std::vector<AlertRecord>> AlertStore::Since(absl::string_view spacecraft_id,
                                                           absl::Time since, int64_t limit,
                                                           bool include_revised) {
  if (limit <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("limit = ", limit, ": must be positive"));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  if (spacecraft_id.empty()) {
    ASSIGN_OR_RETURN(Statement * st, txn.Prepare(kSinceAll));
    st->BindInt64(1, TimeToUnixNanos(since)).BindInt64(2, limit);
    st->BindInt64(9, include_revised ? 1 : 0);
    return ReadRows(st, ReadRow);
  }
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(kSinceOne));
  st->BindText(1, spacecraft_id).BindInt64(2, TimeToUnixNanos(since)).BindInt64(3, limit);
  st->BindInt64(9, include_revised ? 1 : 0);
  return ReadRows(st, ReadRow);
}

absl::StatusOr<std::vector<AlertRecord>> AlertStore::Since(absl::string_view spacecraft_id,
                                                           absl::Time since,
                                                           const AlertPosition& after,
                                                           int64_t limit, bool include_revised) {
  if (limit <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("limit = ", limit, ": must be positive"));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  const bool all = spacecraft_id.empty();
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(all ? kSinceAllAfter : kSinceOneAfter));
  if (all) {
    st->BindInt64(1, TimeToUnixNanos(since)).BindInt64(2, limit);
    st->BindText(6, after.spacecraft_id);
  } else {
    st->BindText(1, spacecraft_id).BindInt64(2, TimeToUnixNanos(since)).BindInt64(3, limit);
  }
  st->BindInt64(4, TimeToUnixNanos(after.measurement_time)).BindInt64(5, after.sequence);
  st->BindInt64(9, include_revised ? 1 : 0);
  return ReadRows(st, ReadRow);
}

absl::StatusOr<AlertRecord> AlertStore::Get(absl::string_view spacecraft_id, int64_t sequence) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  return GetIn(txn, spacecraft_id, sequence);
}

absl::StatusOr<AlertRecord> AlertStore::Acknowledge(absl::string_view spacecraft_id,
                                                    int64_t sequence,
                                                    absl::string_view operator_name,
                                                    absl::Time time) {
  if (operator_name.empty()) return absl::InvalidArgumentError("operator: empty");
  RETURN_IF_ERROR(ValidateStorableTime(time, "acknowledge time"));
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("UPDATE alerts SET acknowledged = 1, acknowledged_by = ?3, "
                               "acknowledged_time_unix_ns = ?4 "
                               "WHERE spacecraft_id = ?1 AND sequence = ?2 AND acknowledged = 0"));
  st->BindText(1, spacecraft_id)
      .BindInt64(2, sequence)
      .BindText(3, operator_name)
      .BindInt64(4, TimeToUnixNanos(time));
  // Zero rows changed means missing or already acknowledged; GetIn tells which.
  RETURN_IF_ERROR(st->Run());
  ASSIGN_OR_RETURN(AlertRecord record, GetIn(txn, spacecraft_id, sequence));
  RETURN_IF_ERROR(txn.Commit());
  return record;
}

absl::StatusOr<AlertRecord> AlertStore::Clear(absl::string_view spacecraft_id, int64_t sequence,
                                              absl::Time cleared_time) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  RETURN_IF_ERROR(Clear(txn, spacecraft_id, sequence, cleared_time));
  ASSIGN_OR_RETURN(AlertRecord record, GetIn(txn, spacecraft_id, sequence));
  RETURN_IF_ERROR(txn.Commit());
  return record;
}

absl::Status AlertStore::Clear(Transaction& txn, absl::string_view spacecraft_id,
                               int64_t sequence, absl::Time cleared_time) {
  if (cleared_time != absl::InfinitePast()) {
    RETURN_IF_ERROR(ValidateStorableTime(cleared_time, "cleared_time"));
  }
  // A second clear keeps the first time.
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("UPDATE alerts SET cleared = 1, cleared_time_unix_ns = "
                               "CASE WHEN cleared = 1 THEN cleared_time_unix_ns ELSE ?3 END "
                               "WHERE spacecraft_id = ?1 AND sequence = ?2"));
  st->BindText(1, spacecraft_id).BindInt64(2, sequence);
  if (cleared_time != absl::InfinitePast()) {
    st->BindInt64(3, TimeToUnixNanos(cleared_time));
  } else {
    st->BindNull(3);
  }
  return RunKeyedUpdate(txn, st, spacecraft_id, sequence);
}

absl::Status AlertStore::UpdateRepeat(absl::string_view spacecraft_id, int64_t sequence,
                                      int64_t repeat_count, absl::Time last_time) {
  AlertRepeat repeat;
  repeat.spacecraft_id = std::string(spacecraft_id);
  repeat.sequence = sequence;
  repeat.repeat_count = repeat_count;
  repeat.last_time = last_time;
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  RETURN_IF_ERROR(UpdateRepeat(txn, repeat));
  return txn.Commit();
}

absl::Status AlertStore::UpdateRepeat(Transaction& txn, const AlertRepeat& repeat) {
  RETURN_IF_ERROR(ValidateSpacecraftId(repeat.spacecraft_id, "alert_repeat.spacecraft_id"));
  if (repeat.repeat_count < 1) {
    return absl::InvalidArgumentError(
        absl::StrCat("alert_repeat.repeat_count = ", repeat.repeat_count, ": must be >= 1"));
  }
  RETURN_IF_ERROR(ValidateStorableTime(repeat.last_time, "alert_repeat.last_time"));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("UPDATE alerts SET repeat_count = ?3, measurement_time_unix_ns = ?4 "
                               "WHERE spacecraft_id = ?1 AND sequence = ?2"));
  st->BindText(1, repeat.spacecraft_id)
      .BindInt64(2, repeat.sequence)
      .BindInt64(3, repeat.repeat_count)
      .BindInt64(4, TimeToUnixNanos(repeat.last_time));
  return RunKeyedUpdate(txn, st, repeat.spacecraft_id, repeat.sequence);
}

}  // namespace esg::storage
