// Reader and writer of the telemetry recording CSV, version 1 (docs/formats.md): `# key: value`
// metadata lines, a header, then one row per telemetry frame.
//
//     # format: esg-recording-csv 1
//     # spacecraft_id: RDK-1
//     time_utc,g1_hx,g1_hy,g1_hz,g1_ux,g1_uy,g1_uz,...,g4_uz,st_q0,st_q1,st_q2,st_q3,st_valid
//     2019-03-01T00:00:00Z,0.6,0.8,0,12.5,-3,0.25,...
//
// Columns: gN_h* spin-axis direction cosines of gyro N in its case frame [1]; gN_u* suspension
// offset voltages along its case axes [mV]; st_q0..st_q3 star-tracker q_in_b, scalar first;
// st_valid 1 or 0. Times are RFC 3339 (written with `Z`, UTC). Optional channel columns
// `ch:NAME`: the auxiliary housekeeping channel NAME (estimator/channels.h), a number in its
// declared unit, an empty cell where the frame does not carry it.
//
// Reading rules (the contract the writer follows too):
// - Lines starting with '#' before the header are metadata "# key: value" (kept in
//   Recording::metadata, key and value trimmed); a '#' line without ':' is a free comment.
//   A "format" entry other than "esg-recording-csv 1" is an error. Empty lines are skipped
//   anywhere; '#' lines after the header are errors.
// - The header names the columns; order is free, extra columns are ignored, every column of
//   docs/formats.md is required (the error lists the missing ones). Fields are trimmed of spaces;
//   there is no quoting.
// - An empty field means "no value". Gyro N: all three gN_h* empty = gyro absent from the frame
//   (then its gN_u* must be empty too); all three gN_u* empty = u_k_mv absent; a partly empty
//   group is an error. Star tracker: all five st_* empty = outage (star_tracker absent);
//   st_valid 0 = reading present with valid = false, its quaternion (empty or 4 finite numbers)
//   not carried; st_valid 1 = the 4 quaternion values required.
// - Direction cosines and the valid quaternion need |norm - 1| <= kUnitNormTolerance (1e-3, far
//   looser than any real readout; it catches swapped, missing or mis-scaled components). Accepted
//   vectors are renormalised when their norm differs from 1 by more than 1e-12; closer ones are
//   kept bit for bit, so a written recording reads back exactly.
// - A header column `ch:NAME` is a channel column: NAME must be a channel name
//   (estimator::ValidateChannelName), or the header is refused. A non-empty cell is a finite
//   number; at most estimator::kMaxChannels non-empty channel cells in a row. Whether a channel
//   is declared, and its range, is checked where the configuration is known (the offline verbs,
//   esgd at ingest).
// - Times strictly increasing, and with RecordingReadOptions::max_row_gap set (the offline runs:
//   estimator/frame_gap.h) at most that much after the previous row. Numbers must parse
//   completely and be finite.
// - Every problem is reported, never a row dropped: a file with any problem gives
//   InvalidArgument listing all of them (up to kMaxReportedProblems, then "... and N more"),
//   one per line as "line <n>, column <name>: <reason>".
#ifndef ESG_FORMATS_RECORDING_CSV_H_
#define ESG_FORMATS_RECORDING_CSV_H_

#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "estimator/telemetry.h"

namespace esg::storage {

inline constexpr char kRecordingCsvFormat[] = "esg-recording-csv 1";
inline constexpr double kUnitNormTolerance = 1e-3;  // same as proto_convert::kUnitNormTolerance
inline constexpr int kMaxReportedProblems = 50;
// A header column with this prefix carries the channel named by the rest (docs/formats.md).
inline constexpr absl::string_view kChannelColumnPrefix = "ch:";

struct RecordingReadOptions {
  // A row more than this after the previous row is a problem of the file ("line <n>, column
  // time_utc: <time> is more than 7 days after the previous row (line <m>, <time>) ...").
  // Infinite: no limit (the reader as a format reader; esg replay leaves the rule to esgd).
  absl::Duration max_row_gap = absl::InfiniteDuration();
};

// Parses CSV text. InvalidArgument with every problem found (see the rules above).
absl::StatusOr<estimator::Recording> ParseRecordingCsv(std::string_view text,
                                                       const RecordingReadOptions& options = {});

// Reads and parses a file. NotFound when it cannot be opened, Unavailable on a read failure,
// InvalidArgument "<path>: ..." with the problems of ParseRecordingCsv.
absl::StatusOr<estimator::Recording> ReadRecordingCsv(const std::string& path,
                                                      const RecordingReadOptions& options = {});

// Formats a recording: "# format: esg-recording-csv 1", then the metadata as the reader reads
// them back: each key and value cleaned (line breaks become spaces, ':' in keys becomes '_',
// trimmed), entries whose key is then empty or "format" dropped, of keys that clean to the same
// key the first in key order kept; "# spacecraft_id: ..." first when present, then the others in
// the order of their cleaned keys. Then the header in
// the order of docs/formats.md, then a `ch:NAME` column for every channel any frame carries (in
// name order; none without channels, so such a recording is written as before), one row per
// frame. Times are RFC 3339 UTC with `Z` and as many
// fractional digits as needed to read back the same absl::Time; numbers in the shortest form that
// reads back the same double. An invalid star-tracker reading is written with an empty quaternion
// and st_valid 0. Values are written as given (a non-finite value would make the file unreadable).
std::string FormatRecordingCsv(const estimator::Recording& recording);

// FormatRecordingCsv in parts, for a recording written as it arrives (esg export telemetry holds
// one chunk of frames at a time): the format and metadata lines and the header with the given
// channel columns (names in name order, as RecordingChannelNames gives them), then the rows of
// each part's frames with the same columns (a channel a frame lacks: an empty cell). Head + the
// rows of every part equal FormatRecordingCsv of the whole when the names are those of all frames.
std::string FormatRecordingCsvHead(const std::map<std::string, std::string>& metadata,
                                   const std::vector<std::string>& channel_names);
std::string FormatRecordingCsvRows(const std::vector<estimator::TelemetryFrame>& frames,
                                   const std::vector<std::string>& channel_names);
// Every channel any of the frames carries, in name order.
std::vector<std::string> RecordingChannelNames(
    const std::vector<estimator::TelemetryFrame>& frames);

// Writes FormatRecordingCsv to path (through "<path>.tmp" and a rename). Unavailable on I/O failure.
absl::Status WriteRecordingCsv(const std::string& path, const estimator::Recording& recording);

// The time of a recording row: RFC 3339 in UTC with `Z` and as many fractional digits as the
// instant needs (none on a whole second, up to 9), so that it reads back the same absl::Time
// ("2019-03-01T00:00:00Z", "2019-03-01T00:00:00.25Z"). Also the time column of the simulator's
// truth file, whose rows are the recording's times (client/commands/simulate.cc). Not the
// millisecond form of messages and tables (estimator/utc_time.h FormatUtc).
std::string FormatRecordingTime(absl::Time time);

}  // namespace esg::storage

#endif  // ESG_FORMATS_RECORDING_CSV_H_
