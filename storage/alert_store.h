// Alert history with acknowledge/clear state and repeat collapsing (table alerts, schema.h;
// docs/formats.md "Alerts", after Yamcs/COSMOS/Open MCT). Each spacecraft's alerts are
// numbered 1, 2, ... by the store in commit order; numbers are never reused.
#ifndef ESG_STORAGE_ALERT_STORE_H_
#define ESG_STORAGE_ALERT_STORE_H_

#include <cstdint>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/records.h"
#include "storage/database.h"

namespace esg::storage {

// Where a paged read of AlertStore::Since stopped: the last alert it returned, in Since's order.
struct AlertPosition {
  absl::Time measurement_time;
  std::string spacecraft_id;
  int64_t sequence = 0;
};

// Thread-safe (through Database). Methods without a Transaction argument run in their own
// transaction; the overloads taking one join the caller's.
class AlertStore {
 public:
  explicit AlertStore(Database* db) : db_(db) {}

  // Stores a new alert and returns the sequence number assigned to it (record.sequence is
  // ignored). The acknowledge/clear fields are stored as given (normally false/empty).
  // InvalidArgument (naming the field) if spacecraft_id, severity or reason is empty,
  // repeat_count < 1, or a time is not storable.
  absl::StatusOr<int64_t> Append(const AlertRecord& record);
  absl::StatusOr<int64_t> Append(Transaction& txn, const AlertRecord& record);

  // Alerts with measurement_time >= since, ordered by (measurement_time, sequence) for one
  // spacecraft, or by (measurement_time, spacecraft_id, sequence) over all spacecraft when
  // spacecraft_id is empty. At most `limit` (> 0, else InvalidArgument). Current alerts only,
  // unless include_revised (then also those a re-run over a late frame superseded).
  absl::StatusOr<std::vector<AlertRecord>> Since(absl::string_view spacecraft_id, absl::Time since,
                                                 int64_t limit, bool include_revised = false);
  // The same read continued strictly after `after` (a page of a paged read: at most `limit`
  // alerts; the next page continues after the last alert of this one).
  absl::StatusOr<std::vector<AlertRecord>> Since(absl::string_view spacecraft_id, absl::Time since,
                                                 const AlertPosition& after, int64_t limit,
                                                 bool include_revised = false);

  // One alert; NotFound if missing.
  absl::StatusOr<AlertRecord> Get(absl::string_view spacecraft_id, int64_t sequence);

  // Marks the alert acknowledged by `operator_name` at `time` and returns the updated record.
  // Acknowledging an acknowledged alert changes nothing (the first acknowledgement stands; the
  // caller compares acknowledged_by to tell, and the service refuses another operator's:
  // AcknowledgeAlert).
  // NotFound if missing; InvalidArgument for an empty operator_name or unstorable time.
  absl::StatusOr<AlertRecord> Acknowledge(absl::string_view spacecraft_id, int64_t sequence,
                                          absl::string_view operator_name, absl::Time time);

  // Marks the alert cleared (the condition is over) at the measurement epoch `cleared_time`
  // (InfinitePast: not known, stored as NULL) and returns the updated record. Clearing a cleared
  // alert keeps its first cleared_time. NotFound if missing; InvalidArgument for an unstorable
  // time.
  absl::StatusOr<AlertRecord> Clear(absl::string_view spacecraft_id, int64_t sequence,
                                    absl::Time cleared_time = absl::InfinitePast());
  absl::Status Clear(Transaction& txn, absl::string_view spacecraft_id, int64_t sequence,
                     absl::Time cleared_time);

  // Collapses a repeat into an existing alert: sets its repeat_count (the new total, >= 1) and
  // its measurement_time to last_time (the latest occurrence). NotFound if missing;
  // InvalidArgument for repeat_count < 1 or an unstorable time.
  absl::Status UpdateRepeat(absl::string_view spacecraft_id, int64_t sequence,
                            int64_t repeat_count, absl::Time last_time);
  absl::Status UpdateRepeat(Transaction& txn, const AlertRepeat& repeat);

 private:
  Database* db_;  // not owned
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_ALERT_STORE_H_
