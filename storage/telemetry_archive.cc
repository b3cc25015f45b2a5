// Telemetry archive; contract in telemetry_archive.h.
#include "storage/telemetry_archive.h"

#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

constexpr absl::string_view kColumns =
    "SELECT spacecraft_id, station_id, sequence, measurement_time_unix_ns, payload "
    "FROM telemetry_frames ";

absl::StatusOr<std::optional<ArchivedFrame>> ReadOne(Statement* st);

absl::StatusOr<std::vector<ArchivedFrame>> ReadFrames(Statement* st) {
  std::vector<ArchivedFrame> out;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    ArchivedFrame f;
    f.spacecraft_id = st->ColumnText(0);
    f.station_id = st->ColumnText(1);
    f.sequence = st->ColumnInt64(2);
    f.measurement_time = UnixNanosToTime(st->ColumnInt64(3));
    f.payload = st->ColumnBlob(4);
    out.push_back(std::move(f));
  }
  return out;
}

absl::StatusOr<std::optional<ArchivedFrame>> ReadOne(Statement* st) {
  ASSIGN_OR_RETURN(std::vector<ArchivedFrame> frames, ReadFrames(st));
  if (frames.empty()) return std::optional<ArchivedFrame>();
  return std::optional<ArchivedFrame>(std::move(frames.front()));
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
    RETURN_IF_ERROR(
        ValidateSpacecraftId(frames[i].station_id, absl::StrCat("frames[", i, "].station_id")));
  }
  ASSIGN_OR_RETURN(Statement * insert,
                   txn.Prepare("INSERT INTO telemetry_frames "
                               "(spacecraft_id, station_id, sequence, measurement_time_unix_ns, "
                               "payload) VALUES (?1, ?2, ?3, ?4, ?5) ON CONFLICT DO NOTHING"));
  AppendResult result;
  result.new_sequences.reserve(frames.size());
  for (const ArchivedFrame& f : frames) {
    insert->Reset();
    insert->BindText(1, spacecraft_id)
        .BindText(2, f.station_id)
        .BindInt64(3, f.sequence)
        .BindInt64(4, TimeToUnixNanos(f.measurement_time))
        .BindBlob(5, f.payload);
    RETURN_IF_ERROR(insert->Run());
    // DO NOTHING turns only a key or time conflict into "0 rows changed".
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
                   txn.Prepare(absl::StrCat(kColumns,
                                            "WHERE spacecraft_id = ?1 AND sequence >= ?2 "
                                            "ORDER BY sequence, station_id LIMIT ?3")));
  st->BindText(1, spacecraft_id).BindInt64(2, from_sequence).BindInt64(3, limit);
  return ReadFrames(st);
}

absl::StatusOr<std::map<std::string, int64_t>> TelemetryArchive::HighestSequences(
    absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare("SELECT station_id, MAX(sequence) FROM telemetry_frames "
                               "WHERE spacecraft_id = ?1 GROUP BY station_id"));
  st->BindText(1, spacecraft_id);
  std::map<std::string, int64_t> out;
  while (true) {
    ASSIGN_OR_RETURN(bool row, st->Step());
    if (!row) break;
    out[st->ColumnText(0)] = st->ColumnInt64(1);
  }
  return out;
}

absl::StatusOr<std::optional<ArchivedFrame>> TelemetryArchive::Latest(
    absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare(absl::StrCat(kColumns,
                                            "WHERE spacecraft_id = ?1 "
                                            "ORDER BY measurement_time_unix_ns DESC LIMIT 1")));
  st->BindText(1, spacecraft_id);
  return ReadOne(st);
}

absl::StatusOr<std::optional<ArchivedFrame>> TelemetryArchive::Find(
    absl::string_view spacecraft_id, absl::string_view station_id, int64_t sequence) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare(absl::StrCat(kColumns,
                                            "WHERE spacecraft_id = ?1 AND station_id = ?2 "
                                            "AND sequence = ?3")));
  st->BindText(1, spacecraft_id).BindText(2, station_id).BindInt64(3, sequence);
  return ReadOne(st);
}

absl::StatusOr<std::optional<ArchivedFrame>> TelemetryArchive::FindAtTime(
    absl::string_view spacecraft_id, absl::Time time) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare(absl::StrCat(kColumns,
                                            "WHERE spacecraft_id = ?1 "
                                            "AND measurement_time_unix_ns = ?2")));
  st->BindText(1, spacecraft_id).BindInt64(2, TimeToUnixNanos(time));
  return ReadOne(st);
}

absl::StatusOr<std::vector<ArchivedFrame>> TelemetryArchive::ReadAfter(
    absl::string_view spacecraft_id, absl::Time after, int64_t limit) {
  if (limit <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("limit = ", limit, ": must be positive"));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare(absl::StrCat(kColumns,
                                            "WHERE spacecraft_id = ?1 "
                                            "AND measurement_time_unix_ns > ?2 "
                                            "ORDER BY measurement_time_unix_ns LIMIT ?3")));
  st->BindText(1, spacecraft_id).BindInt64(2, TimeToUnixNanos(after)).BindInt64(3, limit);
  return ReadFrames(st);
}

absl::StatusOr<std::vector<ArchivedFrame>> TelemetryArchive::ReadAtOrBefore(
    absl::string_view spacecraft_id, absl::Time at_or_before, int64_t limit) {
  if (limit <= 0) {
    return absl::InvalidArgumentError(absl::StrCat("limit = ", limit, ": must be positive"));
  }
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare(absl::StrCat(kColumns,
                                            "WHERE spacecraft_id = ?1 "
                                            "AND measurement_time_unix_ns <= ?2 "
                                            "ORDER BY measurement_time_unix_ns DESC LIMIT ?3")));
  st->BindText(1, spacecraft_id).BindInt64(2, TimeToUnixNanos(at_or_before)).BindInt64(3, limit);
  return ReadFrames(st);
}

absl::StatusOr<std::vector<ArchivedFrame>> TelemetryArchive::ReadTimeRange(
    absl::string_view spacecraft_id, absl::Time from, absl::Time to) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare(absl::StrCat(kColumns,
                                            "WHERE spacecraft_id = ?1 "
                                            "AND measurement_time_unix_ns >= ?2 "
                                            "AND measurement_time_unix_ns < ?3 "
                                            "ORDER BY measurement_time_unix_ns")));
  st->BindText(1, spacecraft_id)
      .BindInt64(2, TimeToUnixNanos(from))
      .BindInt64(3, TimeToUnixNanos(to));
  return ReadFrames(st);
}

}  // namespace esg::storage
