// The server's checkpoint of one spacecraft (storage CheckpointRecord::state_blob): the
// calibration model, the apply-side counters, the alert-collapse tracks, and the estimator's
// SessionCheckpoint values stored bit for bit (persistence as data), so a restart
// resumes exactly where the last committed step left off (docs/service.md "Durability").
#ifndef ESG_SERVER_CHECKPOINT_CODEC_H_
#define ESG_SERVER_CHECKPOINT_CODEC_H_

#include <cstdint>
#include <optional>
#include <string>
#include "absl/strings/string_view.h"
#include <vector>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/session.h"

namespace esg::server {

// An alert still inside its collapse window: a new occurrence of the same (reason, subsystem)
// within the window is a repeat of it (docs/service.md "Alerts").
struct AlertTrack {
  std::string reason;
  std::string subsystem;
  int64_t sequence = 0;      // assigned by the alert store
  int64_t repeat_count = 1;
  absl::Time last_time;      // measurement epoch of the latest occurrence
};

struct ServerCheckpoint {
  std::string model;  // canonical model name, e.g. "10+11"
  // The apply cursor: the measurement time of the last applied frame (InfinitePast: none), and
  // that frame's identity (for display).
  absl::Time applied_time = absl::InfinitePast();
  std::string applied_station;
  int64_t applied_sequence = 0;
  // Coefficient snapshots and alerts up to this measurement time are already stored: a session
  // rebuilt from the archive does not write them again (InfinitePast: nothing stored before).
  absl::Time effects_written_until = absl::InfinitePast();
  // Measurement time of the latest step that applied the star tracker (EstimateRecord
  // last_star_tracker_time; InfinitePast: none yet, or restored from a checkpoint of format 2,
  // which did not keep it). Kept here, not derived from the stored estimates, so that it
  // survives a restart, the restore of a window checkpoint by a re-run and the retention of the
  // estimates alike.
  absl::Time last_star_tracker_time = absl::InfinitePast();
  // Why the session is quarantined (docs/service.md "Session states"); empty: it is not.
  std::string quarantine_reason;
  // Quarantined while being rebuilt from the archive (ends by itself when caught up); false
  // with a reason: the filter is stopped until a reconfiguration.
  bool rebuilding = false;
  // Quarantined and being rebuilt; quarantined with the filter stopped until a reconfiguration.
  bool Rebuilding() const { return !quarantine_reason.empty() && rebuilding; }
  bool FilterStopped() const { return !quarantine_reason.empty() && !rebuilding; }
  // Decoded from the first format, which kept no apply time: the caller derives it from the
  // stored last sequence (station "default").
  bool cursor_from_sequence = false;
  int64_t frames_applied = 0;
  int64_t frames_apply_failed = 0;
  int64_t star_tracker_rejections = 0;
  std::vector<AlertTrack> alert_tracks;
  // Absent: a fresh session (configured, nothing applied yet).
  std::optional<estimator::SessionCheckpoint> session;
};

// Little-endian binary, starting with the magic "ESGSRV03" (format 3: with the apply cursor, the
// effects watermark and the last star-tracker time). Blobs of format 1 ("ESGSRV01") and 2
// ("ESGSRV02", no last star-tracker time) are still read.
std::string EncodeCheckpoint(const ServerCheckpoint& checkpoint);
// DataLoss for a blob that is not a complete checkpoint of a known format.
absl::StatusOr<ServerCheckpoint> DecodeCheckpoint(absl::string_view blob);

}  // namespace esg::server

#endif  // ESG_SERVER_CHECKPOINT_CODEC_H_
