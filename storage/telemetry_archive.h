// The archive of accepted telemetry frames (table telemetry_frames, schema.h): the server's
// record of everything it acknowledged, so a session can be recalibrated or replayed.
// "Accepted" means written by a committed transaction; see the durability contract in
// sqlite_db.h. Frames are keyed by (spacecraft_id, station_id, sequence) and their measurement
// time is unique per spacecraft; a frame whose key or time is already stored is ignored, never
// overwritten (the server decides beforehand whether it is a duplicate or a conflict:
// docs/service.md "Ingest contract"). The filter reads frames in measurement-time order.
#ifndef ESG_STORAGE_TELEMETRY_ARCHIVE_H_
#define ESG_STORAGE_TELEMETRY_ARCHIVE_H_

#include <cstdint>
#include <map>
#include <string>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "storage/records.h"
#include "storage/database.h"

namespace esg::storage {

// Which frames of an AppendBatch call were new, in input order.
struct AppendResult {
  std::vector<int64_t> new_sequences;
  // Key or time already stored, or repeated earlier in the same batch. Payloads not compared.
  std::vector<int64_t> duplicate_sequences;
};

// Thread-safe (through Database). Methods without a Transaction argument run in their own
// transaction; the overloads taking one join the caller's.
class TelemetryArchive {
 public:
  explicit TelemetryArchive(Database* db) : db_(db) {}

  // Appends `frames` of one spacecraft in ONE transaction: when it returns OK, every frame of
  // the batch is durable (the unit of an acknowledgement); on error none is. InvalidArgument if
  // spacecraft_id is empty, a frame's spacecraft_id differs from it, or a measurement_time is
  // not storable (the message names frames[i]).
  absl::StatusOr<AppendResult> AppendBatch(absl::string_view spacecraft_id,
                                           const std::vector<ArchivedFrame>& frames);
  absl::StatusOr<AppendResult> AppendBatch(Transaction& txn, absl::string_view spacecraft_id,
                                           const std::vector<ArchivedFrame>& frames);

  // The highest stored sequence of the spacecraft over all stations, or nullopt if it has no
  // frames.
  absl::StatusOr<std::optional<int64_t>> HighestSequence(absl::string_view spacecraft_id);

  // Per station of the spacecraft, its highest stored sequence.
  absl::StatusOr<std::map<std::string, int64_t>> HighestSequences(absl::string_view spacecraft_id);

  // The frame with the latest measurement time, or nullopt.
  absl::StatusOr<std::optional<ArchivedFrame>> Latest(absl::string_view spacecraft_id);

  // The frame stored under (spacecraft, station, sequence), or nullopt.
  absl::StatusOr<std::optional<ArchivedFrame>> Find(absl::string_view spacecraft_id,
                                                    absl::string_view station_id,
                                                    int64_t sequence);
  // The frame of the spacecraft measured at `time`, or nullopt.
  absl::StatusOr<std::optional<ArchivedFrame>> FindAtTime(absl::string_view spacecraft_id,
                                                          absl::Time time);

  // Up to `limit` (> 0, else InvalidArgument) frames with sequence >= from_sequence, ascending
  // by sequence, over all stations.
  absl::StatusOr<std::vector<ArchivedFrame>> Read(absl::string_view spacecraft_id,
                                                  int64_t from_sequence, int64_t limit);

  // Up to `limit` (> 0) frames measured strictly after `after` (InfinitePast: from the first),
  // ascending by measurement time: the filter's order.
  absl::StatusOr<std::vector<ArchivedFrame>> ReadAfter(absl::string_view spacecraft_id,
                                                       absl::Time after, int64_t limit);

  // Up to `limit` (> 0) frames measured at or before `at_or_before`, DESCENDING by measurement
  // time (the latest first): where a look back for the last star-tracker fix starts.
  absl::StatusOr<std::vector<ArchivedFrame>> ReadAtOrBefore(absl::string_view spacecraft_id,
                                                            absl::Time at_or_before,
                                                            int64_t limit);

  // All frames with from <= measurement_time < to, in measurement-time order (InfinitePast /
  // InfiniteFuture are open bounds). The whole range is loaded into memory.
  absl::StatusOr<std::vector<ArchivedFrame>> ReadTimeRange(absl::string_view spacecraft_id,
                                                           absl::Time from, absl::Time to);

 private:
  Database* db_;  // not owned
};

}  // namespace esg::storage

#endif  // ESG_STORAGE_TELEMETRY_ARCHIVE_H_
