// Per-spacecraft estimation-session checkpoints (table checkpoints, schema.h): the latest
// serialized session state and the last telemetry sequence it includes, so a restarted server
// resumes each session and replays archived frames after last_sequence
// (persistence as data: the estimator exports the state, the server serializes it). Also the
// operators' readmissions of excluded gyros (table gyro_readmissions, schema.h), which a re-run
// of the session from the archive applies again.
#ifndef ESG_STORAGE_SESSION_STORE_H_
#define ESG_STORAGE_SESSION_STORE_H_

#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "storage/records.h"
#include "storage/database.h"

namespace esg::storage {

// Thread-safe (through Database). Methods without a Transaction argument run in their own
// transaction; the overloads taking one join the caller's.
class SessionStore {
 public:
  explicit SessionStore(Database* db) : db_(db) {}

  // Replaces the spacecraft's checkpoint (only the latest is kept). InvalidArgument for an
  // empty spacecraft_id or an unstorable time.
  absl::Status PutCheckpoint(const CheckpointRecord& record);
  absl::Status PutCheckpoint(Transaction& txn, const CheckpointRecord& record);

  // The spacecraft's checkpoint; NotFound if it has none.
  absl::StatusOr<CheckpointRecord> GetCheckpoint(absl::string_view spacecraft_id);

  // Ids of all spacecraft with a checkpoint, sorted (the sessions to resume at start-up).
  absl::StatusOr<std::vector<std::string>> ListSpacecraft();

  // Stores a readmission. InvalidArgument for an empty spacecraft_id or operator_name, a gyro_id
  // outside 1..4, an unstorable time; AlreadyExists when the same gyro's readmission after the
  // same time is stored.
  absl::Status PutReadmission(const ReadmissionRecord& record);
  absl::Status PutReadmission(Transaction& txn, const ReadmissionRecord& record);
  // The spacecraft's readmissions by after_time, then gyro_id.
  absl::StatusOr<std::vector<ReadmissionRecord>> ListReadmissions(absl::string_view spacecraft_id);

 private:
  Database* db_;  // not owned
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_SESSION_STORE_H_
