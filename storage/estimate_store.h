// The per-step estimate archive (table estimates, schema version 7, the attitude error estimate
// since version 9; docs/service.md "Per-step estimates"): one EstimateRecord (records.h) per
// spacecraft and measurement step, keyed by (spacecraft_id, measurement_time), so a step applied
// again (a re-run over a late frame, a session replaced by ConfigureSpacecraft) replaces its row.
// Records are SI; the columns carry the units operators read (sigma, innovations and the
// attitude error estimate in arcsec), converted here.
#ifndef ESG_STORAGE_ESTIMATE_STORE_H_
#define ESG_STORAGE_ESTIMATE_STORE_H_

#include <cstdint>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/records.h"
#include "storage/database.h"

namespace esg::storage {

struct EstimatePage {
  std::vector<EstimateRecord> records;
  // Measurement time of the last record when more records follow in the range (a page of a
  // paged read continues strictly after it); nullopt on the last page.
  std::optional<absl::Time> next;
};

// Thread-safe (through Database). Methods without a Transaction argument run in their own
// transaction; the overloads taking one join the caller's.
class EstimateStore {
 public:
  explicit EstimateStore(Database* db) : db_(db) {}

  // Stores `record`, replacing the one of the same spacecraft and measurement time.
  // InvalidArgument (naming the field, "estimates.<field>") for an empty spacecraft id or state,
  // an unstorable time, a valid attitude with a non-finite value or a pair outside 1..4, or an
  // innovation of a gyro id outside 1..4 or repeated, or an attitude error estimate with a
  // non-finite value or a negative 1-sigma. NaN test ratios are stored as NULL and read back as
  // NaN.
  absl::Status Put(const EstimateRecord& record);
  absl::Status Put(Transaction& txn, const EstimateRecord& record);

  // Deletes the spacecraft's estimates measured strictly after `after` (InfinitePast: all of
  // them); returns how many.
  absl::StatusOr<int64_t> DeleteAfter(Transaction& txn, absl::string_view spacecraft_id,
                                      absl::Time after);
  // Deletes the spacecraft's estimates measured strictly before `before`; returns how many.
  absl::StatusOr<int64_t> DeleteBefore(Transaction& txn, absl::string_view spacecraft_id,
                                       absl::Time before);

  // Up to `limit` (> 0, else InvalidArgument naming limit) estimates of the spacecraft with
  // from <= measurement_time < to, strictly after `after` (nullopt: from the first), in
  // measurement-time order. Reads limit + 1 rows to know whether more follow; a page costs the
  // same wherever it starts (the table is clustered on its key). DataLoss for a row that cannot
  // be read back (an innovation order naming a gyro without values).
  absl::StatusOr<EstimatePage> Page(absl::string_view spacecraft_id, absl::Time from,
                                    absl::Time to, const std::optional<absl::Time>& after,
                                    int64_t limit);

  // Number of the spacecraft's estimates with from <= measurement_time < to.
  absl::StatusOr<int64_t> Count(absl::string_view spacecraft_id,
                                absl::Time from = absl::InfinitePast(),
                                absl::Time to = absl::InfiniteFuture());

 private:
  Database* db_;  // not owned
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_ESTIMATE_STORE_H_
