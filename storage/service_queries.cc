// Counting and clearing queries of the service (see service_queries.h).
#include "storage/service_queries.h"

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/schema.h"

namespace esg::storage {

absl::StatusOr<int64_t> CountArchivedFrames(Database& db, absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db.Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT COUNT(*) FROM telemetry_frames WHERE spacecraft_id = ?1"));
  st->BindText(1, spacecraft_id);
  ASSIGN_OR_RETURN(bool row, st->Step());
  const int64_t n = row ? st->ColumnInt64(0) : 0;
  RETURN_IF_ERROR(txn.Commit());
  return n;
}

absl::StatusOr<absl::Time> LatestEffectTime(Database& db, absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db.Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT MAX(t) FROM ("
                               "SELECT MAX(measurement_time_unix_ns) AS t FROM coefficients "
                               "WHERE spacecraft_id = ?1 UNION ALL "
                               "SELECT MAX(measurement_time_unix_ns) FROM alerts "
                               "WHERE spacecraft_id = ?1) AS latest"));
  st->BindText(1, spacecraft_id);
  ASSIGN_OR_RETURN(bool row, st->Step());
  const absl::Time t =
      !row || st->ColumnIsNull(0) ? absl::InfinitePast() : UnixNanosToTime(st->ColumnInt64(0));
  RETURN_IF_ERROR(txn.Commit());
  return t;
}

absl::Status ProbeWrite(Database& db, absl::Time now) {
  ASSIGN_OR_RETURN(Transaction txn, db.Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare("INSERT INTO service_state (key, value) "
                                               "VALUES ('storage_probe_unix_ns', ?1) "
                                               "ON CONFLICT (key) DO UPDATE "
                                               "SET value = excluded.value"));
  st->BindInt64(1, TimeToUnixNanos(now));
  RETURN_IF_ERROR(st->Run());
  return txn.Commit();
}

absl::StatusOr<AlertCounts> CountAlerts(Database& db, absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db.Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare("SELECT COALESCE(SUM(CASE WHEN cleared = 0 THEN 1 ELSE 0 END), 0), "
                                               "COALESCE(SUM(CASE WHEN acknowledged = 0 THEN 1 ELSE 0 END), 0) FROM alerts "
                                               "WHERE spacecraft_id = ?1 "
                                               "AND revised_time_unix_ns IS NULL"));
  st->BindText(1, spacecraft_id);
  ASSIGN_OR_RETURN(bool row, st->Step());
  AlertCounts counts;
  if (row) {
    counts.active = st->ColumnInt64(0);
    counts.unacknowledged = st->ColumnInt64(1);
  }
  RETURN_IF_ERROR(txn.Commit());
  return counts;
}

}  // namespace esg::storage
