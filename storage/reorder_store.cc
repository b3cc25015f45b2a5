// The reorder window's storage; contract in reorder_store.h.
#include "storage/reorder_store.h"

#include <limits>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

// InfinitePast as the lowest stored instant (every stored time is above it).
int64_t NanosOrMin(absl::Time t) {
  return t == absl::InfinitePast() ? std::numeric_limits<int64_t>::min() : TimeToUnixNanos(t);
}

// The instants (column 0, Unix ns) `sql` selects for the spacecraft bound to ?1, in one read
// transaction.
absl::StatusOr<std::vector<absl::Time>> Times(Database* db, const char* sql,
                                              absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare(sql));
  st->BindText(1, spacecraft_id);
  std::vector<absl::Time> out;
  for (;;) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    out.push_back(UnixNanosToTime(st->ColumnInt64(0)));
  }
  return out;
}

}  // namespace

absl::Status ReorderStore::AddLateFrames(Transaction& txn, absl::string_view spacecraft_id,
                                         const std::vector<absl::Time>& times) {
  if (times.empty()) return absl::OkStatus();
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("INSERT INTO late_frames "
                               "(spacecraft_id, measurement_time_unix_ns) VALUES (?1, ?2) "
                               "ON CONFLICT DO NOTHING"));
  for (size_t i = 0; i < times.size(); ++i) {
    RETURN_IF_ERROR(ValidateStorableTime(times[i], absl::StrCat("late_frames[", i, "]")));
    st->Reset();
    st->BindText(1, spacecraft_id).BindInt64(2, TimeToUnixNanos(times[i]));
    RETURN_IF_ERROR(st->Run());
  }
  return absl::OkStatus();
}

absl::StatusOr<std::vector<absl::Time>> ReorderStore::LateFrames(absl::string_view spacecraft_id) {
  return Times(db_,
               "SELECT measurement_time_unix_ns FROM late_frames WHERE spacecraft_id = ?1 "
               "ORDER BY measurement_time_unix_ns",
               spacecraft_id);
}

absl::Status ReorderStore::RemoveLateFrames(Transaction& txn, absl::string_view spacecraft_id,
                                            const std::vector<absl::Time>& times) {
  if (times.empty()) return absl::OkStatus();
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare("DELETE FROM late_frames WHERE spacecraft_id = ?1 "
                                               "AND measurement_time_unix_ns = ?2"));
  for (absl::Time t : times) {
    st->Reset();
    st->BindText(1, spacecraft_id).BindInt64(2, TimeToUnixNanos(t));
    RETURN_IF_ERROR(st->Run());
  }
  return absl::OkStatus();
}

absl::Status ReorderStore::DropLateFrames(Transaction& txn, absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Statement * st, txn.Prepare("DELETE FROM late_frames WHERE spacecraft_id = ?1"));
  st->BindText(1, spacecraft_id);
  return st->Run();
}

absl::Status ReorderStore::PutCheckpoint(Transaction& txn, absl::string_view spacecraft_id,
                                         const WindowCheckpoint& checkpoint) {
  RETURN_IF_ERROR(ValidateStorableTime(checkpoint.applied_time, "window_checkpoint.applied_time"));
  RETURN_IF_ERROR(ValidateStorableTime(checkpoint.compute_time, "window_checkpoint.compute_time"));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("INSERT INTO window_checkpoints (spacecraft_id, "
                               "applied_time_unix_ns, compute_time_unix_ns, state_blob) "
                               "VALUES (?1, ?2, ?3, ?4) "
                               "ON CONFLICT (spacecraft_id, applied_time_unix_ns) DO UPDATE SET "
                               "compute_time_unix_ns = excluded.compute_time_unix_ns, "
                               "state_blob = excluded.state_blob"));
  st->BindText(1, spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(checkpoint.applied_time))
      .BindInt64(3, TimeToUnixNanos(checkpoint.compute_time))
      .BindBlob(4, checkpoint.state_blob);
  return st->Run();
}

absl::StatusOr<std::optional<WindowCheckpoint>> ReorderStore::CheckpointBefore(
    absl::string_view spacecraft_id, absl::Time time) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT applied_time_unix_ns, compute_time_unix_ns, state_blob "
                               "FROM window_checkpoints WHERE spacecraft_id = ?1 "
                               "AND applied_time_unix_ns < ?2 "
                               "ORDER BY applied_time_unix_ns DESC LIMIT 1"));
  st->BindText(1, spacecraft_id).BindInt64(2, NanosOrMin(time));
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) return std::optional<WindowCheckpoint>();
  WindowCheckpoint c;
  c.applied_time = UnixNanosToTime(st->ColumnInt64(0));
  c.compute_time = UnixNanosToTime(st->ColumnInt64(1));
  c.state_blob = st->ColumnBlob(2);
  return std::optional<WindowCheckpoint>(std::move(c));
}

absl::StatusOr<std::vector<absl::Time>> ReorderStore::CheckpointTimes(
    absl::string_view spacecraft_id) {
  return Times(db_,
               "SELECT applied_time_unix_ns FROM window_checkpoints WHERE spacecraft_id = ?1 "
               "ORDER BY applied_time_unix_ns",
               spacecraft_id);
}

absl::Status ReorderStore::DropCheckpointsFrom(Transaction& txn, absl::string_view spacecraft_id,
                                               absl::Time from) {
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("DELETE FROM window_checkpoints WHERE spacecraft_id = ?1 "
                               "AND applied_time_unix_ns >= ?2"));
  st->BindText(1, spacecraft_id).BindInt64(2, NanosOrMin(from));
  return st->Run();
}

absl::Status ReorderStore::Prune(Transaction& txn, absl::string_view spacecraft_id,
                                 absl::Time oldest_late) {
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("DELETE FROM window_checkpoints WHERE spacecraft_id = ?1 "
                               "AND applied_time_unix_ns < (SELECT MAX(applied_time_unix_ns) "
                               "FROM window_checkpoints WHERE spacecraft_id = ?1 "
                               "AND applied_time_unix_ns < ?2)"));
  st->BindText(1, spacecraft_id).BindInt64(2, NanosOrMin(oldest_late));
  return st->Run();
}

absl::StatusOr<int64_t> ReorderStore::Revise(Transaction& txn, absl::string_view spacecraft_id,
                                             absl::Time after, absl::Time revised_time,
                                             const std::vector<int64_t>& alert_sequences,
                                             const std::vector<AlertRestore>& restores) {
  RETURN_IF_ERROR(ValidateStorableTime(revised_time, "revised_time"));
  ASSIGN_OR_RETURN(Statement * coefficients,
                   txn.Prepare("UPDATE coefficients SET revised_time_unix_ns = ?3 "
                               "WHERE spacecraft_id = ?1 AND measurement_time_unix_ns > ?2 "
                               "AND revised_time_unix_ns IS NULL"));
  coefficients->BindText(1, spacecraft_id)
      .BindInt64(2, NanosOrMin(after))
      .BindInt64(3, TimeToUnixNanos(revised_time));
  RETURN_IF_ERROR(coefficients->Run());
  const int64_t revised = txn.ChangedRows();
  ASSIGN_OR_RETURN(Statement * alerts, txn.Prepare("UPDATE alerts SET revised_time_unix_ns = ?3 "
                                                   "WHERE spacecraft_id = ?1 AND sequence = ?2 "
                                                   "AND revised_time_unix_ns IS NULL"));
  for (int64_t sequence : alert_sequences) {
    alerts->Reset();
    alerts->BindText(1, spacecraft_id)
        .BindInt64(2, sequence)
        .BindInt64(3, TimeToUnixNanos(revised_time));
    RETURN_IF_ERROR(alerts->Run());
  }
  ASSIGN_OR_RETURN(Statement * restore, txn.Prepare("UPDATE alerts SET repeat_count = ?3, "
                                                    "measurement_time_unix_ns = ?4, cleared = 0, "
                                                    "cleared_time_unix_ns = NULL "
                                                    "WHERE spacecraft_id = ?1 AND sequence = ?2"));
  for (const AlertRestore& r : restores) {
    RETURN_IF_ERROR(ValidateStorableTime(r.last_time, "restores.last_time"));
    restore->Reset();
    restore->BindText(1, spacecraft_id)
        .BindInt64(2, r.sequence)
        .BindInt64(3, r.repeat_count)
        .BindInt64(4, TimeToUnixNanos(r.last_time));
    RETURN_IF_ERROR(restore->Run());
  }
  return revised;
}

absl::StatusOr<std::vector<int64_t>> ReorderStore::CurrentAlertsAfter(
    absl::string_view spacecraft_id, absl::Time after) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT sequence FROM alerts WHERE spacecraft_id = ?1 "
                               "AND first_time_unix_ns > ?2 AND revised_time_unix_ns IS NULL "
                               "ORDER BY sequence"));
  st->BindText(1, spacecraft_id).BindInt64(2, NanosOrMin(after));
  std::vector<int64_t> out;
  for (;;) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    out.push_back(st->ColumnInt64(0));
  }
  return out;
}

}  // namespace esg::storage
