// Orbit deliveries; contract in orbit_store.h.
#include "storage/orbit_store.h"

#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/read_rows.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

OrbitRecord ReadRow(const Statement& st) {
  OrbitRecord r;
  r.id = st.ColumnInt64(0);
  r.spacecraft_id = st.ColumnText(1);
  r.from_time = UnixNanosToTime(st.ColumnInt64(2));
  r.to_time = UnixNanosToTime(st.ColumnInt64(3));
  r.upload_time = UnixNanosToTime(st.ColumnInt64(4));
  r.states = st.ColumnInt64(5);
  r.uploaded_by = st.ColumnText(6);
  r.oem_text = st.ColumnText(7);
  return r;
}

}  // namespace

absl::StatusOr<int64_t> OrbitStore::Put(const OrbitRecord& record) {
  RETURN_IF_ERROR(ValidateSpacecraftId(record.spacecraft_id, "orbit.spacecraft_id"));
  if (record.oem_text.empty()) return absl::InvalidArgumentError("orbit.oem_text: empty");
  RETURN_IF_ERROR(ValidateStorableTime(record.from_time, "orbit.from_time"));
  RETURN_IF_ERROR(ValidateStorableTime(record.to_time, "orbit.to_time"));
  RETURN_IF_ERROR(ValidateStorableTime(record.upload_time, "orbit.upload_time"));
  if (record.to_time < record.from_time) {
    return absl::InvalidArgumentError("orbit.to_time: earlier than from_time");
  }
  if (record.states < 2) {
    return absl::InvalidArgumentError(
        absl::StrCat("orbit.states: an orbit needs at least 2 states, got ", record.states));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("INSERT INTO orbits (spacecraft_id, from_time_unix_ns, "
                               "to_time_unix_ns, upload_time_unix_ns, states, uploaded_by, "
                               "oem_text) VALUES (?1, ?2, ?3, ?4, ?5, ?6, ?7) RETURNING id"));
  st->BindText(1, record.spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(record.from_time))
      .BindInt64(3, TimeToUnixNanos(record.to_time))
      .BindInt64(4, TimeToUnixNanos(record.upload_time))
      .BindInt64(5, record.states)
      .BindText(6, record.uploaded_by)
      .BindText(7, record.oem_text);
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return absl::InternalError("INSERT INTO orbits returned no id");
  const int64_t id = st->ColumnInt64(0);
  st->Reset();
  if (const int64_t keep = max_per_spacecraft(); keep > 0) {
    ASSIGN_OR_RETURN(Statement * drop,
                     txn.Prepare("DELETE FROM orbits WHERE spacecraft_id = ?1 AND id NOT IN "
                                 "(SELECT id FROM orbits WHERE spacecraft_id = ?1 ORDER BY "
                                 "CASE WHEN id = ?3 THEN 0 ELSE 1 END, id DESC LIMIT ?2)"));
    drop->BindText(1, record.spacecraft_id).BindInt64(2, keep).BindInt64(3, id);
    RETURN_IF_ERROR(drop->Run());
  }
  RETURN_IF_ERROR(txn.Commit());
  return id;
}

absl::StatusOr<std::vector<OrbitRecord>> OrbitStore::ListSummaries(
    absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT id, spacecraft_id, from_time_unix_ns, to_time_unix_ns, "
                               "upload_time_unix_ns, states, uploaded_by, '' FROM orbits "
                               "WHERE spacecraft_id = ?1 ORDER BY id"));
  st->BindText(1, spacecraft_id);
  return ReadRows(st, ReadRow);
}

absl::StatusOr<std::vector<OrbitRecord>> OrbitStore::Covering(absl::string_view spacecraft_id,
                                                              absl::Time from, absl::Time to) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT id, spacecraft_id, from_time_unix_ns, to_time_unix_ns, "
                               "upload_time_unix_ns, states, uploaded_by, oem_text FROM orbits "
                               "WHERE spacecraft_id = ?1 AND to_time_unix_ns >= ?2 AND "
                               "from_time_unix_ns <= ?3 ORDER BY id"));
  st->BindText(1, spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(from))
      .BindInt64(3, TimeToUnixNanos(to));
  return ReadRows(st, ReadRow);
}

}  // namespace esg::storage
