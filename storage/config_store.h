// Versioned spacecraft configurations (JSON of docs/formats.md, stored verbatim; table
// spacecraft_configs, schema.h). The server validates the JSON; this store only keeps it.
#ifndef ESG_STORAGE_CONFIG_STORE_H_
#define ESG_STORAGE_CONFIG_STORE_H_

#include <cstdint>
#include <functional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "storage/records.h"
#include "storage/database.h"

namespace esg::storage {

// Thread-safe (through Database). Each method without a Transaction argument runs in its own
// transaction; the overloads taking one join the caller's transaction (nothing is durable until
// the caller commits). Errors of the underlying Database calls are passed through
// (Unavailable, DataLoss, ...; sqlite_db.h).
class ConfigStore {
 public:
  explicit ConfigStore(Database* db) : db_(db) {}

  // Whether the latest stored JSON says the same configuration as the new one. The server's
  // parses both (the same values written in another form, key order or layout are the same
  // configuration); nullptr: the texts are byte-identical.
  using SameConfig =
      std::function<bool(absl::string_view stored_json, absl::string_view new_json)>;

  // Stores `record` as the spacecraft's newest version (record.version is ignored) and returns
  // its version number (1, 2, ...). Earlier versions are kept as history. If config_json is the
  // same as the latest version's (`same`), nothing is written and the latest version number is
  // returned (a restart re-submitting the same file creates no noise; the stored text is kept as
  // it was written). InvalidArgument for an empty spacecraft_id or an unstorable updated_time.
  absl::StatusOr<int64_t> Put(const ConfigRecord& record, const SameConfig& same = nullptr);
  absl::StatusOr<int64_t> Put(Transaction& txn, const ConfigRecord& record,
                              const SameConfig& same = nullptr);

  // The latest version; NotFound if the spacecraft has none.
  absl::StatusOr<ConfigRecord> Get(absl::string_view spacecraft_id);
  // The latest version of every spacecraft, ordered by spacecraft_id.
  absl::StatusOr<std::vector<ConfigRecord>> List();
  // Every version of one spacecraft, oldest first (empty if none).
  absl::StatusOr<std::vector<ConfigRecord>> History(absl::string_view spacecraft_id);

 private:
  Database* db_;  // not owned
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_CONFIG_STORE_H_
