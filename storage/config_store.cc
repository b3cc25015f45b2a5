// Versioned spacecraft configurations; contract in config_store.h.
#include "storage/config_store.h"

#include <string>
#include <utility>

#include "absl/strings/str_cat.h"
#include "estimator/status_macros.h"
#include "storage/read_rows.h"
#include "storage/schema.h"

namespace esg::storage {
namespace {

constexpr absl::string_view kColumns =
    "spacecraft_id, version, updated_time_unix_ns, config_json";

ConfigRecord ReadRow(const Statement& st) {
  ConfigRecord r;
  r.spacecraft_id = st.ColumnText(0);
  r.version = st.ColumnInt64(1);
  r.updated_time = UnixNanosToTime(st.ColumnInt64(2));
  r.config_json = st.ColumnText(3);
  return r;
}

}  // namespace

absl::StatusOr<int64_t> ConfigStore::Put(const ConfigRecord& record, const SameConfig& same) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kImmediate));
  ASSIGN_OR_RETURN(int64_t version, Put(txn, record, same));
  RETURN_IF_ERROR(txn.Commit());
  return version;
}

absl::StatusOr<int64_t> ConfigStore::Put(Transaction& txn, const ConfigRecord& record,
                                         const SameConfig& same) {
  RETURN_IF_ERROR(ValidateSpacecraftId(record.spacecraft_id, "config.spacecraft_id"));
  RETURN_IF_ERROR(ValidateStorableTime(record.updated_time, "config.updated_time"));
  ASSIGN_OR_RETURN(Statement * latest,
                   txn.Prepare("SELECT version, config_json FROM spacecraft_configs "
                               "WHERE spacecraft_id = ?1 ORDER BY version DESC LIMIT 1"));
  latest->BindText(1, record.spacecraft_id);
  ASSIGN_OR_RETURN(bool row, latest->Step());
  int64_t version = 0;
  if (row) {
    version = latest->ColumnInt64(0);
    const std::string stored = latest->ColumnText(1);
    if (same ? same(stored, record.config_json) : stored == record.config_json) return version;
  }
  latest->Reset();
  ASSIGN_OR_RETURN(Statement * insert,
                   txn.Prepare(absl::StrCat("INSERT INTO spacecraft_configs (", kColumns,
                                            ") VALUES (?1, ?2, ?3, ?4)")));
  insert->BindText(1, record.spacecraft_id)
      .BindInt64(2, version + 1)
      .BindInt64(3, TimeToUnixNanos(record.updated_time))
      .BindText(4, record.config_json);
  RETURN_IF_ERROR(insert->Run());
  return version + 1;
}

absl::StatusOr<ConfigRecord> ConfigStore::Get(absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare(absl::StrCat("SELECT ", kColumns,
                                            " FROM spacecraft_configs WHERE spacecraft_id = ?1 "
                                            "ORDER BY version DESC LIMIT 1")));
  st->BindText(1, spacecraft_id);
  ASSIGN_OR_RETURN(bool row, st->Step());
  if (!row) {
    return absl::NotFoundError(absl::StrCat("no configuration for spacecraft '", spacecraft_id, "'"));
  }
  return ReadRow(*st);
}

absl::StatusOr<std::vector<ConfigRecord>> ConfigStore::List() {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(
      Statement * st,
      txn.Prepare(absl::StrCat("SELECT ", kColumns,
                               " FROM spacecraft_configs AS c WHERE version = "
                               "(SELECT MAX(version) FROM spacecraft_configs "
                               "WHERE spacecraft_id = c.spacecraft_id) ORDER BY spacecraft_id")));
  return ReadRows(st, ReadRow);
}

absl::StatusOr<std::vector<ConfigRecord>> ConfigStore::History(absl::string_view spacecraft_id) {
  ASSIGN_OR_RETURN(Transaction txn, db_->Begin(TransactionMode::kDeferred));
  ASSIGN_OR_RETURN(Statement * st,
                   txn.Prepare(absl::StrCat("SELECT ", kColumns,
                                            " FROM spacecraft_configs WHERE spacecraft_id = ?1 "
                                            "ORDER BY version")));
  st->BindText(1, spacecraft_id);
  return ReadRows(st, ReadRow);
}

}  // namespace esg::storage
