// Small queries the gRPC service needs beyond the stores' APIs (docs/service.md): counts for
// session summaries and clearing an alert inside the caller's transaction. Same tables and
// error contract as the stores (sqlite_db.h).
#ifndef ESG_STORAGE_SERVICE_QUERIES_H_
#define ESG_STORAGE_SERVICE_QUERIES_H_

#include <cstdint>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/database.h"

namespace esg::storage {

// Number of archived telemetry frames of the spacecraft.
absl::StatusOr<int64_t> CountArchivedFrames(Database& db, absl::string_view spacecraft_id);

struct AlertCounts {
  int64_t active = 0;          // not cleared
  int64_t unacknowledged = 0;  // not acknowledged
};
absl::StatusOr<AlertCounts> CountAlerts(Database& db, absl::string_view spacecraft_id);

// The latest measurement time of any stored coefficient snapshot or alert of the spacecraft
// (InfinitePast when there is none): what a session rebuilt from the archive must not store
// again.
absl::StatusOr<absl::Time> LatestEffectTime(Database& db, absl::string_view spacecraft_id);

// A small write that proves the database can commit (table service_state); the error of the
// commit otherwise.
absl::Status ProbeWrite(Database& db, absl::Time now);

}  // namespace esg::storage

#endif  // ESG_STORAGE_SERVICE_QUERIES_H_
