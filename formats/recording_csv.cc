// Recording CSV version 1 reader and writer (docs/formats.md); rules in recording_csv.h.
#include "formats/recording_csv.h"

#include <algorithm>
#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <system_error>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/time/time.h"
#include "estimator/channels.h"
#include "estimator/conventions.h"
#include "estimator/rotation.h"
#include "estimator/utc_time.h"
#include "formats/csv_lines.h"
#include "formats/csv_problems.h"

namespace esg::storage {

namespace {

using estimator::kMaxGyros;

// Vectors closer to unit norm than this are kept bit for bit (see recording_csv.h).
constexpr double kRenormaliseAbove = 1e-12;
constexpr int kNumGyroColumns = 6;  // hx hy hz ux uy uz
constexpr int kNumStColumns = 5;    // q0 q1 q2 q3 valid
constexpr int kNumColumns = 1 + kMaxGyros * kNumGyroColumns + kNumStColumns;

// Required columns in the order of docs/formats.md (also the written order).
const std::array<std::string, kNumColumns>& ColumnNames() {
  static const std::array<std::string, kNumColumns> names = [] {
    std::array<std::string, kNumColumns> n;
    int i = 0;
    n[i++] = "time_utc";
    for (int g = 1; g <= kMaxGyros; ++g) {
      for (const char* suffix : {"hx", "hy", "hz", "ux", "uy", "uz"}) {
        n[i++] = absl::StrCat("g", g, "_", suffix);
      }
    }
    for (const char* name : {"st_q0", "st_q1", "st_q2", "st_q3", "st_valid"}) n[i++] = name;
    return n;
  }();
  return names;
}
constexpr int kTimeColumn = 0;
constexpr int GyroColumn(int gyro_index, int k) { return 1 + gyro_index * kNumGyroColumns + k; }
constexpr int StColumn(int k) { return 1 + kMaxGyros * kNumGyroColumns + k; }


absl::string_view Trim(absl::string_view s) { return absl::StripAsciiWhitespace(s); }

// Splits on ',' into `fields` (reused to avoid allocation), trimming each field.
void SplitFields(absl::string_view line, std::vector<absl::string_view>* fields) {
  fields->clear();
  size_t start = 0;
  while (true) {
    const size_t comma = line.find(',', start);
    if (comma == absl::string_view::npos) {
      fields->push_back(Trim(line.substr(start)));
      return;
    }
    fields->push_back(Trim(line.substr(start, comma - start)));
    start = comma + 1;
  }
}

// Field text for messages, shortened when long.
std::string Quote(absl::string_view s) {
  if (s.size() > 40) return absl::StrCat("'", s.substr(0, 37), "...'");
  return absl::StrCat("'", s, "'");
}

// Parses a complete, finite number; on failure adds a problem and returns nullopt.
std::optional<double> ParseNumber(absl::string_view text, int line, const std::string& column,
                                  CsvProblems* problems) {
  absl::string_view digits = text;
  if (!digits.empty() && digits.front() == '+') digits.remove_prefix(1);
  double value = 0.0;
  const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
  if (ec == std::errc::result_out_of_range) {
    problems->Add(line, column, absl::StrCat(Quote(text), " is out of the range of a double"));
    return std::nullopt;
  }
  if (ec != std::errc() || end != digits.data() + digits.size() || digits.empty()) {
    problems->Add(line, column, absl::StrCat(Quote(text), " is not a number"));
    return std::nullopt;
  }
  if (!std::isfinite(value)) {
    problems->Add(line, column, absl::StrCat(Quote(text), " is not finite"));
    return std::nullopt;
  }
  return value;
}

// A group of N columns that is either all empty or all numbers.
// Returns: nullopt on a problem (reported); an empty optional inside when all fields are empty.
template <int N>
std::optional<std::optional<Eigen::Matrix<double, N, 1>>> ParseGroup(
    const std::vector<absl::string_view>& fields, const std::array<int, N>& columns,
    const std::array<int, N>& field_index, int line, CsvProblems* problems) {
  const std::array<std::string, kNumColumns>& names = ColumnNames();
  int empty_count = 0;
  for (int k = 0; k < N; ++k) empty_count += fields[field_index[k]].empty() ? 1 : 0;
  if (empty_count == N) return std::optional<Eigen::Matrix<double, N, 1>>();
  if (empty_count > 0) {
    std::vector<std::string> empty_names;
    for (int k = 0; k < N; ++k) {
      if (fields[field_index[k]].empty()) empty_names.push_back(names[columns[k]]);
    }
    problems->Add(line, absl::StrJoin(empty_names, ","),
                  absl::StrFormat("empty while the rest of its group %s..%s has values",
                                  names[columns.front()], names[columns.back()]));
    return std::nullopt;
  }
  Eigen::Matrix<double, N, 1> v;
  bool ok = true;
  for (int k = 0; k < N; ++k) {
    const std::optional<double> x =
        ParseNumber(fields[field_index[k]], line, names[columns[k]], problems);
    if (x.has_value()) {
      v[k] = *x;
    } else {
      ok = false;
    }
  }
  if (!ok) return std::nullopt;
  return std::optional<Eigen::Matrix<double, N, 1>>(v);
}

// Checks |norm - 1| and renormalises beyond kRenormaliseAbove. False (reported) when off.
template <int N>
bool CheckUnit(Eigen::Matrix<double, N, 1>* v, const std::string& group, int line,
               CsvProblems* problems) {
  const double norm = v->norm();
  if (!(std::abs(norm - 1.0) <= kUnitNormTolerance)) {
    problems->Add(line, group,
                  absl::StrFormat("norm %.6g is not 1 (tolerance %g)", norm, kUnitNormTolerance));
    return false;
  }
  if (std::abs(norm - 1.0) > kRenormaliseAbove) *v /= norm;
  return true;
}

void AppendNumber(double x, std::string* out) {
  char buf[32];
  const auto [end, ec] = std::to_chars(buf, buf + sizeof(buf), x);
  out->append(buf, ec == std::errc() ? end : buf);
}

std::string CleanMetadata(absl::string_view s, bool is_key) {
  std::string clean(s);
  for (char& c : clean) {
    if (c == '\n' || c == '\r') c = ' ';
    if (is_key && c == ':') c = '_';
  }
  return std::string(Trim(clean));
}

}  // namespace

absl::StatusOr<estimator::Recording> ParseRecordingCsv(std::string_view std_text,
                                                       const RecordingReadOptions& options) {
  // Abseil 20220623 in Debian has its own absl::string_view (not std::string_view).
  const absl::string_view text(std_text.data(), std_text.size());
  estimator::Recording recording;
  CsvProblems problems("recording CSV", "column ");
  const std::array<std::string, kNumColumns>& names = ColumnNames();

  CsvMetadata metadata;  // the lines before the header
  std::array<int, kNumColumns> field_index;  // column -> index in a row
  std::vector<std::pair<std::string, int>> channel_columns;  // channel name, index in a row
  size_t num_header_fields = 0;
  bool have_header = false;
  int header_line = 0;
  std::optional<absl::Time> previous_time;
  int previous_time_line = 0;
  std::vector<absl::string_view> fields;
  fields.reserve(kNumColumns + 8);

  CsvLines lines(text);
  int line_no = 0;
  absl::string_view line;
  while (lines.Next(&line_no, &line)) {
    if (!have_header) {
      if (line.front() == '#') {
        const auto entry = metadata.Read(line, line_no, problems);
        if (!entry.has_value()) continue;  // a free comment, or a repeated key (reported)
        const auto& [key, value] = *entry;
        if (key == "format" && value != kRecordingCsvFormat) {
          problems.Add(line_no, "",
                       absl::StrFormat("unsupported format '%s' (this reader reads '%s')", value,
                                       kRecordingCsvFormat));
        }
        recording.metadata[key] = value;
        continue;
      }
      // Header.
      have_header = true;
      header_line = line_no;
      SplitFields(line, &fields);
      num_header_fields = fields.size();
      std::map<absl::string_view, int> index_of;
      for (size_t i = 0; i < fields.size(); ++i) {
        if (!index_of.emplace(fields[i], static_cast<int>(i)).second && !fields[i].empty()) {
          problems.Add(line_no, std::string(fields[i]), "column name appears twice in the header");
        }
      }
      std::vector<std::string> missing;
      for (int c = 0; c < kNumColumns; ++c) {
        const auto it = index_of.find(names[c]);
        if (it == index_of.end()) {
          missing.push_back(names[c]);
        } else {
          field_index[c] = it->second;
        }
      }
      if (!missing.empty()) {
        problems.Add(line_no, "",
                     absl::StrCat("header lacks required column", missing.size() == 1 ? "" : "s",
                                  " ", absl::StrJoin(missing, ", ")));
      }
      // Channel columns `ch:NAME` (docs/formats.md "Channels"), in header order.
      for (size_t i = 0; i < fields.size(); ++i) {
        if (!absl::StartsWith(fields[i], kChannelColumnPrefix)) continue;
        const absl::string_view name = fields[i].substr(kChannelColumnPrefix.size());
        const absl::Status valid = estimator::ValidateChannelName(name, "name");
        if (!valid.ok()) {
          problems.Add(line_no, std::string(fields[i]), std::string(valid.message()));
        } else {
          channel_columns.push_back({std::string(name), static_cast<int>(i)});
        }
      }
      if (!problems.empty()) return problems.ToStatus();  // rows cannot be interpreted
      continue;
    }

    // Data row.
    if (line.front() == '#') {
      problems.Add(line_no, "", "comment or metadata line after the header");
      continue;
    }
    SplitFields(line, &fields);
    if (fields.size() != num_header_fields) {
      problems.Add(line_no, "",
                   absl::StrFormat("expected %d fields as in the header (line %d), got %d",
                                   num_header_fields, header_line, fields.size()));
      continue;
    }
    const size_t problems_before = problems.size();
    estimator::TelemetryFrame frame;

    // Time.
    const absl::string_view time_text = fields[field_index[kTimeColumn]];
    // The column is named by the problem's place.
    const absl::StatusOr<absl::Time> parsed = estimator::ParseUtc(time_text, "");
    if (time_text.empty()) {
      problems.Add(line_no, names[kTimeColumn], "empty (every row needs its time)");
    } else if (!parsed.ok()) {
      problems.Add(line_no, names[kTimeColumn], std::string(parsed.status().message()));
    } else {
      const absl::Time time = *parsed;
      if (previous_time.has_value() && time <= *previous_time) {
        problems.Add(line_no, names[kTimeColumn],
                     absl::StrFormat("%s is not after %s of line %d (times must increase)",
                                     time_text, estimator::FormatUtc(*previous_time),
                                     previous_time_line));
      } else if (previous_time.has_value() && time - *previous_time > options.max_row_gap) {
        problems.Add(line_no, names[kTimeColumn],
                     RowGapProblem(time, *previous_time, previous_time_line, options.max_row_gap));
      }
      previous_time = time;
      previous_time_line = line_no;
      frame.time = time;
    }

    // Gyros.
    for (int g = 0; g < kMaxGyros; ++g) {
      const std::array<int, 3> h_columns = {GyroColumn(g, 0), GyroColumn(g, 1), GyroColumn(g, 2)};
      const std::array<int, 3> u_columns = {GyroColumn(g, 3), GyroColumn(g, 4), GyroColumn(g, 5)};
      const std::array<int, 3> h_fields = {field_index[h_columns[0]], field_index[h_columns[1]],
                                           field_index[h_columns[2]]};
      const std::array<int, 3> u_fields = {field_index[u_columns[0]], field_index[u_columns[1]],
                                           field_index[u_columns[2]]};
      auto h = ParseGroup<3>(fields, h_columns, h_fields, line_no, &problems);
      auto u = ParseGroup<3>(fields, u_columns, u_fields, line_no, &problems);
      if (!h.has_value() || !u.has_value()) continue;
      if (!h->has_value()) {
        if (u->has_value()) {
          problems.Add(line_no, absl::StrFormat("g%d_ux..g%d_uz", g + 1, g + 1),
                       absl::StrFormat("voltages given while gyro %d has no spin-axis reading "
                                       "(g%d_hx..g%d_hz empty)",
                                       g + 1, g + 1, g + 1));
        }
        continue;  // gyro off
      }
      Eigen::Vector3d h_k = **h;
      if (!CheckUnit<3>(&h_k, absl::StrFormat("g%d_hx..g%d_hz", g + 1, g + 1), line_no,
                        &problems)) {
        continue;
      }
      estimator::GyroReading reading;
      reading.h_k = h_k;
      if (u->has_value()) reading.u_k_mv = **u;
      frame.gyros[g] = reading;
    }

    // Star tracker.
    const std::array<int, 4> q_columns = {StColumn(0), StColumn(1), StColumn(2), StColumn(3)};
    const std::array<int, 4> q_fields = {field_index[q_columns[0]], field_index[q_columns[1]],
                                         field_index[q_columns[2]], field_index[q_columns[3]]};
    const std::string& valid_name = names[StColumn(4)];
    const absl::string_view valid_text = fields[field_index[StColumn(4)]];
    auto q = ParseGroup<4>(fields, q_columns, q_fields, line_no, &problems);
    if (valid_text.empty()) {
      if (q.has_value() && q->has_value()) {
        problems.Add(line_no, valid_name, "empty while st_q0..st_q3 have values (give 0 or 1)");
      }
      // All empty: outage.
    } else if (valid_text == "1") {
      if (q.has_value()) {
        if (!q->has_value()) {
          problems.Add(line_no, "st_q0..st_q3", "empty while st_valid is 1");
        } else {
          Eigen::Vector4d q_in_b = **q;
          if (CheckUnit<4>(&q_in_b, "st_q0..st_q3", line_no, &problems)) {
            estimator::StarTrackerReading reading;
            reading.valid = true;
            reading.q_in_b =
                estimator::QuaternionFromScalarFirst({q_in_b[0], q_in_b[1], q_in_b[2], q_in_b[3]});
            frame.star_tracker = reading;
          }
        }
      }
    } else if (valid_text == "0") {
      estimator::StarTrackerReading reading;  // quaternion not carried
      reading.valid = false;
      frame.star_tracker = reading;
    } else {
      problems.Add(line_no, valid_name, absl::StrCat(Quote(valid_text), " is not 0 or 1"));
    }

    // Channels: an empty cell is a channel this frame does not carry.
    for (const auto& [name, index] : channel_columns) {
      const absl::string_view text = fields[index];
      if (text.empty()) continue;
      const std::string column = absl::StrCat(kChannelColumnPrefix, name);
      if (const std::optional<double> v = ParseNumber(text, line_no, column, &problems)) {
        frame.channels.Set(name, *v);
      }
    }
    if (frame.channels.size() > estimator::kMaxChannels) {
      problems.Add(line_no, "",
                   absl::StrFormat("%d channels, at most %d in a frame", frame.channels.size(),
                                   estimator::kMaxChannels));
    }

    if (problems.size() == problems_before) recording.frames.push_back(std::move(frame));
  }

  if (!have_header) {
    problems.Add(line_no + 1, "", "no header line (expected time_utc,g1_hx,...,st_valid)");
  }
  if (!problems.empty()) return problems.ToStatus();
  return recording;
}

absl::StatusOr<estimator::Recording> ReadRecordingCsv(const std::string& path,
                                                      const RecordingReadOptions& options) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::NotFoundError(
        absl::StrCat("recording ", path, ": cannot open: ", std::strerror(errno)));
  }
  std::ostringstream content;
  content << in.rdbuf();
  if (in.bad()) return absl::UnavailableError(absl::StrCat("recording ", path, ": read failed"));
  absl::StatusOr<estimator::Recording> recording = ParseRecordingCsv(content.str(), options);
  if (!recording.ok()) {
    return absl::Status(recording.status().code(),
                        absl::StrCat(path, ": ", recording.status().message()));
  }
  return recording;
}

std::string FormatRecordingCsvHead(const std::map<std::string, std::string>& recording_metadata,
                                   const std::vector<std::string>& channel_names) {
  const std::array<std::string, kNumColumns>& names = ColumnNames();
  std::string out;
  absl::StrAppend(&out, "# format: ", kRecordingCsvFormat, "\n");
  // Cleaned first, then written in the cleaned keys' order: cleaning can reorder keys ("a\rb"
  // sorts before "a b!" but cleans to "a b", after it) or make two equal, and the reader reads
  // the lines back into a map by cleaned key, so the text must be that map's (a fixed point).
  std::map<std::string, std::string> metadata;
  for (const auto& [key, value] : recording_metadata) {
    std::string clean_key = CleanMetadata(key, true);
    if (clean_key.empty() || clean_key == "format") continue;
    metadata.emplace(std::move(clean_key), CleanMetadata(value, false));
  }
  if (const auto it = metadata.find("spacecraft_id"); it != metadata.end()) {
    absl::StrAppend(&out, "# spacecraft_id: ", it->second, "\n");
  }
  for (const auto& [key, value] : metadata) {
    if (key == "spacecraft_id") continue;
    absl::StrAppend(&out, "# ", key, ": ", value, "\n");
  }
  absl::StrAppend(&out, absl::StrJoin(names, ","));
  for (const std::string& name : channel_names) {
    absl::StrAppend(&out, ",", kChannelColumnPrefix, name);
  }
  out += '\n';
  return out;
}

std::string FormatRecordingCsvRows(const std::vector<estimator::TelemetryFrame>& frames,
                                   const std::vector<std::string>& channel_names) {
  std::string out;
  out.reserve(frames.size() * 400);
  for (const estimator::TelemetryFrame& frame : frames) {
    out += FormatRecordingTime(frame.time);
    for (int g = 0; g < kMaxGyros; ++g) {
      const std::optional<estimator::GyroReading>& reading = frame.gyros[g];
      for (int k = 0; k < 3; ++k) {
        out += ',';
        if (reading.has_value()) AppendNumber(reading->h_k[k], &out);
      }
      for (int k = 0; k < 3; ++k) {
        out += ',';
        if (reading.has_value() && reading->u_k_mv.has_value()) {
          AppendNumber((*reading->u_k_mv)[k], &out);
        }
      }
    }
    if (!frame.star_tracker.has_value()) {
      out += ",,,,,";
    } else if (!frame.star_tracker->valid) {
      out += ",,,,,0";
    } else {
      for (double v : estimator::ToScalarFirst(frame.star_tracker->q_in_b)) {
        out += ',';
        AppendNumber(v, &out);
      }
      out += ",1";
    }
    for (const std::string& name : channel_names) {
      out += ',';
      if (const double* v = frame.channels.Find(name)) AppendNumber(*v, &out);
    }
    out += '\n';
  }
  return out;
}

std::vector<std::string> RecordingChannelNames(
    const std::vector<estimator::TelemetryFrame>& frames) {
  std::set<std::string> names;
  for (const estimator::TelemetryFrame& frame : frames) {
    for (const estimator::ChannelValue& c : frame.channels) names.insert(c.name);
  }
  return std::vector<std::string>(names.begin(), names.end());
}

std::string FormatRecordingCsv(const estimator::Recording& recording) {
  // Every channel any frame carries, one `ch:NAME` column each after st_valid, in name order.
  const std::vector<std::string> channel_names = RecordingChannelNames(recording.frames);
  std::string out = FormatRecordingCsvHead(recording.metadata, channel_names);
  out += FormatRecordingCsvRows(recording.frames, channel_names);
  return out;
}

absl::Status WriteRecordingCsv(const std::string& path, const estimator::Recording& recording) {
  const std::string text = FormatRecordingCsv(recording);
  const std::string tmp_path = path + ".tmp";
  {
    std::ofstream out(tmp_path, std::ios::binary | std::ios::trunc);
    if (!out) {
      return absl::UnavailableError(
          absl::StrCat("recording ", tmp_path, ": cannot create: ", std::strerror(errno)));
    }
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
    out.flush();
    if (!out) return absl::UnavailableError(absl::StrCat("recording ", tmp_path, ": write failed"));
  }
  if (std::rename(tmp_path.c_str(), path.c_str()) != 0) {
    const int err = errno;
    std::remove(tmp_path.c_str());
    return absl::UnavailableError(
        absl::StrCat("recording ", path, ": cannot rename: ", std::strerror(err)));
  }
  return absl::OkStatus();
}

std::string FormatRecordingTime(absl::Time time) {
  return absl::FormatTime("%Y-%m-%d%ET%H:%M:%E*SZ", time, absl::UTCTimeZone());
}

}  // namespace esg::storage
