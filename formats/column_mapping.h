// Column mapping, version 1 (docs/formats.md, "Column mapping"): a JSON file that says where each
// quantity of a recording is in a user's own CSV telemetry export and in which unit, frame,
// quaternion order and time format, so that the export loads as it is, into the same
// estimator::Recording the project's recording CSV (formats/recording_csv.h) gives.
//
//     {"format": "esg-column-mapping 1",
//      "spacecraftId": "RDK-1",
//      "time": {"column": "t", "format": "since_epoch", "epoch": "1970-01-01T00:00:00Z",
//               "unit": "s"},
//      "gyros": [{"id": 1,
//                 "spinAxis": {"form": "azimuth_elevation", "columns": ["az1", "el1"],
//                              "unit": "deg"},
//                 "voltages": {"columns": ["u1x", "u1y", "u1z"], "unit": "V"}}, ...],
//      "starTracker": {"columns": ["qx", "qy", "qz", "qw"], "scalar": "last", "rotation": "q_b_in",
//                      "valid": {"column": "st_ok", "validValues": ["1"], "invalidValues": ["0"]}},
//      "channels": [{"name": "T_gyro2", "column": "TEMP_G2"}]}
//
// Mapping rules (ParseColumnMapping): every field is checked, unknown fields are errors, and an
// error is InvalidArgument whose message starts with the field, e.g.
// "time.unit: 'h' is not a known unit (s, ms, us)". A column may be mapped once.
//
// CSV rules (ParseMappedRecordingCsv), as for the recording CSV where not stated otherwise:
// a UTF-8 byte order mark is skipped; '#' lines before the header are metadata or comments, then
// a header naming the columns (order free, extra columns ignored), then one row per frame, fields
// split at the mapping's delimiter and trimmed. A field may be enclosed in double quotes (RFC
// 4180: the delimiter is literal inside, "" is one quote; no line break inside). Times are read
// in the mapping's TimeFormat. Every column the mapping names must be in the header (the error
// names the mapping field and the column). Groups (a gyro's spin axis, its voltages, the
// quaternion) are all empty or all numbers; times strictly increase. Converted values are checked
// as in the recording CSV: spin axes and a valid quaternion, after conversion, have unit norm
// within kUnitNormTolerance (1e-3) and are renormalised beyond 1e-12. Every problem is reported
// as "line <n>, column <csv column> (<mapping field>): <reason>", the file refused as a whole.
#ifndef ESG_FORMATS_COLUMN_MAPPING_H_
#define ESG_FORMATS_COLUMN_MAPPING_H_

#include <array>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/conventions.h"
#include "estimator/telemetry.h"
#include "formats/recording_csv.h"

namespace esg::storage {

inline constexpr char kColumnMappingFormat[] = "esg-column-mapping 1";

// How the time of a row is written.
enum class TimeFormat {
  kRfc3339,         // one column, e.g. 2019-03-01T00:00:00Z or with a numeric offset
  kSinceEpoch,      // one column, a decimal count of `unit` since `epoch` (no leap seconds)
  kGpsWeekSeconds,  // two columns: full GPS week number and seconds of week (GPS time scale)
  kPattern,         // one column read with an absl::ParseTime pattern, UTC unless it has %z
};

struct TimeMapping {
  TimeFormat format = TimeFormat::kRfc3339;
  std::string column;          // kRfc3339, kSinceEpoch, kPattern
  std::string pattern;         // kPattern, e.g. "%Y-%m-%d %H:%M:%E*S"
  std::string week_column;     // kGpsWeekSeconds
  std::string seconds_column;  // kGpsWeekSeconds
  // Length of one unit of the count (kSinceEpoch) or of the seconds of week (kGpsWeekSeconds).
  absl::Duration unit = absl::Seconds(1);
  absl::Time epoch = absl::UnixEpoch();  // kSinceEpoch
  int gps_minus_utc_s = 0;               // kGpsWeekSeconds: GPS - UTC [s] (18 since 2017)
};

struct GyroMapping {
  int id = 0;  // 1..kMaxGyros
  // Spin axis: 3 direction-cosine columns (h1, h2, h3 in case axes), or 2 angle columns
  // (azimuth from case x toward case y, elevation from the case x-y plane toward +z):
  // h_k = (cos el cos az, cos el sin az, sin el).
  bool spin_axis_angles = false;
  std::vector<std::string> spin_axis_columns;
  double angle_unit_rad = 1.0;  // radians per unit of the angle columns
  // Suspension voltages along case x, y, z; empty when the export has none.
  std::vector<std::string> voltage_columns;
  double voltage_unit_mv = 1.0;  // millivolts per unit of the voltage columns
};

struct StarTrackerMapping {
  std::array<std::string, 4> columns;  // in the file's order
  bool scalar_first = true;
  // False: the file's quaternion is the project's q_in_b (C_in_b: body coordinates to inertial).
  // True: the file holds q_b_in (inertial coordinates to body), inverted on reading.
  bool inverse = false;
  // Validity flag column; empty: a row with a quaternion is valid, one without is an outage.
  std::string valid_column;
  std::vector<std::string> valid_values;
  std::vector<std::string> invalid_values;
};

// One auxiliary housekeeping channel (estimator/channels.h): the file's column holding it, its
// values in the channel's declared unit; an empty cell is a frame without the channel.
struct ChannelMapping {
  std::string name;    // the channel's name, as the configuration declares it
  std::string column;  // the CSV column
};

struct ColumnMapping {
  std::string spacecraft_id;  // empty: none (recording metadata "spacecraft_id" when given)
  char delimiter = ',';
  TimeMapping time;
  std::vector<GyroMapping> gyros;
  std::optional<StarTrackerMapping> star_tracker;  // absent: no star-tracker columns
  std::vector<ChannelMapping> channels;             // at most estimator::kMaxChannels
};

// Parses a mapping JSON document. InvalidArgument "<field>: <reason>" on the first problem.
absl::StatusOr<ColumnMapping> ParseColumnMapping(std::string_view json_text);

// Reads and parses a mapping file. NotFound when it cannot be opened; other errors as
// ParseColumnMapping, prefixed with "column mapping <path>: ".
absl::StatusOr<ColumnMapping> ReadColumnMapping(const std::string& path);

// Parses a CSV export through `mapping` (rules above). InvalidArgument listing every problem.
// The recording's metadata are the file's "# key: value" lines, plus "spacecraft_id" from the
// mapping when it states one (the mapping wins). options.max_row_gap as for ParseRecordingCsv.
absl::StatusOr<estimator::Recording> ParseMappedRecordingCsv(
    std::string_view text, const ColumnMapping& mapping, const RecordingReadOptions& options = {});

// Reads a recording for the CLI: the project's recording CSV when columns_path is empty
// (ReadRecordingCsv), otherwise the mapping at columns_path applied to the file at path.
// NotFound when a file cannot be opened; InvalidArgument "column mapping <path>: <field>: ..."
// for a bad mapping and "<path>: ..." with the problems of the CSV (options as for
// ParseRecordingCsv: the offline verbs set max_row_gap to estimator::kMaxFrameGap).
absl::StatusOr<estimator::Recording> ReadRecording(const std::string& path,
                                                   const std::string& columns_path,
                                                   const RecordingReadOptions& options = {});

}  // namespace esg::storage

#endif  // ESG_FORMATS_COLUMN_MAPPING_H_
