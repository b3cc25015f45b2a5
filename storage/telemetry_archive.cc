// Telemetry archive; contract in telemetry_archive.h.
#include "storage/telemetry_archive.h"

#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

absl::StatusOr<std::vector<ArchivedFrame>> ReadFrames(Statement* st) {
  std::vector<ArchivedFrame> out;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    ArchivedFrame f;
    f.spacecraft_id = st->ColumnText(0);
    f.sequence = st->ColumnInt64(1);
    f.measurement_time = UnixNanosToTime(st->ColumnInt64(2));
    f.payload = st->ColumnBlob(3);
    out.push_back(std::move(f));
  }
  return out;
}

}  // namespace

absl::StatusOr<AppendResult> TelemetryArchive::AppendBatch(
    absl::string_view spacecraft_id, const std::vector<ArchivedFrame>& frames) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(AppendResult result, AppendBatch(txn, spacecraft_id, frames));
  RETURN_IF_ERROR(txn.Commit());
  return result;
}

absl::StatusOr<AppendResult> TelemetryArchive::AppendBatch(
    Transaction& txn, absl::string_view spacecraft_id, const std::vector<ArchivedFrame>& frames) {
  RETURN_IF_ERROR(ValidateSpacecraftId(spacecraft_id, "spacecraft_id"));
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].spacecraft_id != spacecraft_id) {
      return absl::InvalidArgumentError(
          absl::StrCat("frames[", i, "].spacecraft_id = '", frames[i].spacecraft_id,
                       "': differs from the batch's '", spacecraft_id, "'"));
    }
    RETURN_IF_ERROR(ValidateStorableTime(frames[i].measurement_time,
                                         absl::StrCat("frames[", i, "].measurement_time")));
  }
  ASSIGN_OR_RETURN(Statement * insert,
                   txn.Prepare("INSERT OR IGNORE INTO telemetry_frames "
                               "(spacecraft_id, sequence, measurement_time_unix_ns, payload) "
                               "VALUES (?1, ?2, ?3, ?4)"));
  AppendResult result;
  result.new_sequences.reserve(frames.size());
  for (const ArchivedFrame& f : frames) {
    insert->Reset();
    insert->BindText(1, spacecraft_id)
        .BindInt64(2, f.sequence)
        .BindInt64(3, TimeToUnixNanos(f.measurement_time))
        .BindBlob(4, f.payload);
    RETURN_IF_ERROR(insert->Run());
    // OR IGNORE turns only the primary-key conflict into "0 rows changed".
    (txn.ChangedRows() == 1 ? result.new_sequences : result.duplicate_sequences)
        .push_back(f.sequence);
  }
  return result;
}

absl::StatusOr<std::optional<int64_t>> TelemetryArchive::HighestSequence(
    absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT MAX(sequence) FROM telemetry_frames "
                               "WHERE spacecraft_id = ?1"));
  st->BindText(1, spacecraft_id);
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row || st->ColumnIsNull(0)) return std::optional<int64_t>();
  return std::optional<int64_t>(st->ColumnInt64(0));
}

absl::StatusOr<std::vector<ArchivedFrame>> TelemetryArchive::Read(absl::string_view spacecraft_id,
                                                                  int64_t from_sequence,
                                                                  int64_t limit) {
  if (limit <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("limit = ", limit, ": must be positive"));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT spacecraft_id, sequence, measurement_time_unix_ns, payload "
                               "FROM telemetry_frames WHERE spacecraft_id = ?1 AND sequence >= ?2 "
                               "ORDER BY sequence LIMIT ?3"));
  st->BindText(1, spacecraft_id).BindInt64(2, from_sequence).BindInt64(3, limit);
  return ReadFrames(st);
}

absl::StatusOr<std::vector<ArchivedFrame>> TelemetryArchive::ReadTimeRange(
    absl::string_view spacecraft_id, absl::Time from, absl::Time to) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT spacecraft_id, sequence, measurement_time_unix_ns, payload "
                               "FROM telemetry_frames WHERE spacecraft_id = ?1 "
                               "AND measurement_time_unix_ns >= ?2 "
                               "AND measurement_time_unix_ns < ?3 ORDER BY sequence"));
  st->BindText(1, spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(from))
      .BindInt64(3, TimeToUnixNanos(to));
  return ReadFrames(st);
}

}  // namespace esg::storage
