// What the reorder window keeps (docs/service.md "Several ground stations", docs/decisions.md
// D60-D62): the late frames archived but not yet applied by a re-run (table late_frames), the
// periodic session checkpoints a re-run starts from (table window_checkpoints), and the marking
// of the coefficient estimates and alerts a re-run supersedes (revised_time_unix_ns of tables
// coefficients and alerts: kept for audit, never deleted). Blobs are the server's; this store
// never decodes them.
#ifndef ESG_STORAGE_REORDER_STORE_H_
#define ESG_STORAGE_REORDER_STORE_H_

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/records.h"
#include "storage/database.h"

namespace esg::storage {

// A session checkpoint kept for re-runs: the state after every frame measured at or before
// applied_time.
struct WindowCheckpoint {
  absl::Time applied_time = absl::InfinitePast();
  absl::Time compute_time = absl::UnixEpoch();
  std::string state_blob;
};

// A stored alert set back to the state a window checkpoint recorded (a re-run replays what came
// after it): its repeat count and latest occurrence, not cleared.
struct AlertRestore {
  int64_t sequence = 0;
  int64_t repeat_count = 1;
  absl::Time last_time;
};

// Thread-safe (through Database). Methods without a Transaction argument run in their own
// transaction; the overloads taking one join the caller's.
class ReorderStore {
 public:
  explicit ReorderStore(Database* db) : db_(db) {}

  // Records late frames (measurement times) of a spacecraft: a re-run must apply them. Times
  // already recorded are kept. InvalidArgument for an unstorable time.
  absl::Status AddLateFrames(Transaction& txn, absl::string_view spacecraft_id,
                             const std::vector<absl::Time>& times);
  // The recorded late frames of a spacecraft, in time order.
  absl::StatusOr<std::vector<absl::Time>> LateFrames(absl::string_view spacecraft_id);
  // Forgets the given late frames (a re-run applied them, or they were after the filter).
  absl::Status RemoveLateFrames(Transaction& txn, absl::string_view spacecraft_id,
                                const std::vector<absl::Time>& times);
  // Forgets all late frames of the spacecraft (a new session applies the whole archive).
  absl::Status DropLateFrames(Transaction& txn, absl::string_view spacecraft_id);

  // Keeps a checkpoint (replacing one at the same applied_time).
  absl::Status PutCheckpoint(Transaction& txn, absl::string_view spacecraft_id,
                             const WindowCheckpoint& checkpoint);
  // The latest kept checkpoint with applied_time strictly before `time`, or nullopt.
  absl::StatusOr<std::optional<WindowCheckpoint>> CheckpointBefore(absl::string_view spacecraft_id,
                                                                   absl::Time time);
  // Applied times of the kept checkpoints, ascending.
  absl::StatusOr<std::vector<absl::Time>> CheckpointTimes(absl::string_view spacecraft_id);
  // Drops the checkpoints with applied_time >= `from` (InfinitePast: all): they miss a late
  // frame, or belong to a session that was replaced.
  absl::Status DropCheckpointsFrom(Transaction& txn, absl::string_view spacecraft_id,
                                   absl::Time from);
  // Drops the checkpoints a late frame at or after `oldest_late` can no longer need: all older
  // than the latest one before `oldest_late`.
  absl::Status Prune(Transaction& txn, absl::string_view spacecraft_id, absl::Time oldest_late);

  // Marks superseded (revised_time = `revised_time`) the current coefficient estimates measured
  // after `after` and the alerts `alert_sequences`; sets the alerts of `restores` back to their
  // checkpointed state. Returns how many coefficient rows were marked.
  absl::StatusOr<int64_t> Revise(Transaction& txn, absl::string_view spacecraft_id,
                                 absl::Time after, absl::Time revised_time,
                                 const std::vector<int64_t>& alert_sequences,
                                 const std::vector<AlertRestore>& restores);
  // Sequences of the current alerts first raised after `after`.
  absl::StatusOr<std::vector<int64_t>> CurrentAlertsAfter(absl::string_view spacecraft_id,
                                                          absl::Time after);

 private:
  Database* db_;  // not owned
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_REORDER_STORE_H_
