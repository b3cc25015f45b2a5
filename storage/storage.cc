// The Storage facade; contract in storage.h.
#include "storage/storage.h"

#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

// Prefixes the field path of a store's InvalidArgument with the record's place in the batch.
absl::Status InBatch(absl::Status status, absl::string_view where) {
  if (status.ok()) return status;
  return absl::Status(status.code(), absl::StrCat(where, ": ", status.message()));
}

absl::Status CheckSpacecraft(const std::string& record_id, const std::string& batch_id,
                             absl::string_view where) {
  if (record_id == batch_id) return absl::OkStatus();
  return absl::InvalidArgumentError(absl::StrCat(where, ".spacecraft_id = '", record_id,
                                                 "': differs from the batch's '", batch_id,
                                                 "'"));
}

}  // namespace

Storage::Storage(std::unique_ptr<Database> db)
    : db_(std::move(db)),
      configs_(db_.get()),
      archive_(db_.get()),
      coefficients_(db_.get()),
      alerts_(db_.get()),
      sessions_(db_.get()),
      diagnoses_(db_.get()) {}

absl::StatusOr<std::unique_ptr<Storage>> Storage::Open(const std::string& path,
                                                       const DatabaseOptions& options) {
  ASSIGN_OR_RETURN(std::unique_ptr<Database> db, Database::Open(path, options));
  RETURN_IF_ERROR(MigrateToCurrent(*db));
  return std::unique_ptr<Storage>(new Storage(std::move(db)));
}

absl::StatusOr<BatchResult> Storage::CommitBatch(const Batch& batch) {
  RETURN_IF_ERROR(ValidateSpacecraftId(batch.spacecraft_id, "batch.spacecraft_id"));
  // Cheap checks before taking the write lock.
  for (size_t i = 0; i < batch.coefficients.size(); ++i) {
    RETURN_IF_ERROR(CheckSpacecraft(batch.coefficients[i].spacecraft_id, batch.spacecraft_id,
                                    absl::StrCat("coefficients[", i, "]")));
  }
  for (size_t i = 0; i < batch.alerts.size(); ++i) {
    RETURN_IF_ERROR(CheckSpacecraft(batch.alerts[i].spacecraft_id, batch.spacecraft_id,
                                    absl::StrCat("alerts[", i, "]")));
  }
  for (size_t i = 0; i < batch.alert_repeats.size(); ++i) {
    RETURN_IF_ERROR(CheckSpacecraft(batch.alert_repeats[i].spacecraft_id, batch.spacecraft_id,
                                    absl::StrCat("alert_repeats[", i, "]")));
  }
  if (batch.checkpoint.has_value()) {
    RETURN_IF_ERROR(
        CheckSpacecraft(batch.checkpoint->spacecraft_id, batch.spacecraft_id, "checkpoint"));
  }

  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  BatchResult result;
  {
    ASSIGN_OR_RETURN(AppendResult appended,
                     archive_.AppendBatch(txn, batch.spacecraft_id, batch.frames));
    result.new_frame_sequences = std::move(appended.new_sequences);
    result.duplicate_frame_sequences = std::move(appended.duplicate_sequences);
  }
  for (size_t i = 0; i < batch.coefficients.size(); ++i) {
    RETURN_IF_ERROR(InBatch(coefficients_.Append(txn, batch.coefficients[i]),
                            absl::StrCat("coefficients[", i, "]")));
  }
  result.alert_sequences.reserve(batch.alerts.size());
  for (size_t i = 0; i < batch.alerts.size(); ++i) {
    absl::StatusOr<int64_t> sequence = alerts_.Append(txn, batch.alerts[i]);
    if (!sequence.ok()) return InBatch(sequence.status(), absl::StrCat("alerts[", i, "]"));
    result.alert_sequences.push_back(*sequence);
  }
  for (size_t i = 0; i < batch.alert_repeats.size(); ++i) {
    RETURN_IF_ERROR(InBatch(alerts_.UpdateRepeat(txn, batch.alert_repeats[i]),
                            absl::StrCat("alert_repeats[", i, "]")));
  }
  if (batch.checkpoint.has_value()) {
    RETURN_IF_ERROR(sessions_.PutCheckpoint(txn, *batch.checkpoint));
  }
  RETURN_IF_ERROR(txn.Commit());
  return result;
}

}  // namespace esg::storage
