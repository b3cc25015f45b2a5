// Small queries the gRPC service needs beyond the stores' APIs (DESIGN §8 storage/): counts for
// session summaries and clearing an alert inside the caller's transaction. Same tables and
// error contract as the stores (sqlite_db.h).
#ifndef ESG_STORAGE_SERVICE_QUERIES_H_
#define ESG_STORAGE_SERVICE_QUERIES_H_

#include <cstdint>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "storage/sqlite_db.h"

namespace esg::storage {

// Number of archived telemetry frames of the spacecraft.
absl::StatusOr<int64_t> CountArchivedFrames(Database& db, absl::string_view spacecraft_id);

struct AlertCounts {
  int64_t active = 0;          // not cleared
  int64_t unacknowledged = 0;  // not acknowledged
};
absl::StatusOr<AlertCounts> CountAlerts(Database& db, absl::string_view spacecraft_id);

// Marks the alert cleared (the condition is over) inside `txn`. NotFound if it does not exist.
absl::Status ClearAlert(Transaction& txn, absl::string_view spacecraft_id, int64_t sequence);

}  // namespace esg::storage

#endif  // ESG_STORAGE_SERVICE_QUERIES_H_
