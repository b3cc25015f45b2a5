// Column mapping version 1 (docs/formats.md, "Column mapping"); rules in column_mapping.h.
#include "formats/column_mapping.h"

#include <algorithm>
#include <cerrno>
#include <charconv>
#include <cmath>
#include <cstring>
#include <fstream>
#include <map>
#include <set>
#include <sstream>
#include <system_error>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/channels.h"
#include "estimator/rotation.h"
#include "estimator/utc_time.h"
#include "formats/csv_lines.h"
#include "formats/csv_problems.h"
#include "formats/recording_csv.h"
#include "nlohmann/json.hpp"
#include "proto/strict_json.h"

namespace esg::storage {

namespace {

using json = nlohmann::json;

// Vectors closer to unit norm than this are kept bit for bit, as in the recording CSV.
constexpr double kRenormaliseAbove = 1e-12;
constexpr int64_t kSecondsPerWeek = 604800;
constexpr double kPi = 3.14159265358979323846;

// ---------------------------------------------------------------------------------------------
// Mapping JSON.

absl::Status FieldError(const std::string& field, const std::string& reason) {
  return absl::InvalidArgumentError(absl::StrCat(field, ": ", reason));
}

std::string Join(const std::string& path, const std::string& key) {
  return path.empty() ? key : absl::StrCat(path, ".", key);
}

// Unknown keys of an object are errors naming the first one and the known ones.
absl::Status CheckObject(const json& j, const std::string& path,
                         const std::vector<std::string>& known) {
  if (!j.is_object()) return FieldError(path.empty() ? "mapping" : path, "must be a JSON object");
  for (auto it = j.begin(); it != j.end(); ++it) {
    if (std::find(known.begin(), known.end(), it.key()) == known.end()) {
      return FieldError(
          Join(path, it.key()),
          absl::StrCat("unknown field (known here: ", absl::StrJoin(known, ", "), ")"));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<std::string> GetString(const json& j, const std::string& path) {
  if (!j.is_string()) return FieldError(path, "must be a string");
  return j.get<std::string>();
}

absl::StatusOr<std::string> GetColumnName(const json& j, const std::string& path) {
  absl::StatusOr<std::string> name = GetString(j, path);
  if (!name.ok()) return name.status();
  const std::string trimmed(absl::StripAsciiWhitespace(*name));
  if (trimmed.empty()) return FieldError(path, "empty column name");
  return trimmed;  // header fields are trimmed too
}

absl::StatusOr<std::vector<std::string>> GetColumns(const json& j, const std::string& path,
                                                    size_t count, const std::string& what) {
  if (!j.is_array() || j.size() != count) {
    return FieldError(path,
                      absl::StrFormat("must be an array of %d column names (%s)", count, what));
  }
  std::vector<std::string> columns;
  for (size_t i = 0; i < count; ++i) {
    absl::StatusOr<std::string> name = GetColumnName(j[i], absl::StrCat(path, "[", i, "]"));
    if (!name.ok()) return name.status();
    columns.push_back(*name);
  }
  return columns;
}

absl::StatusOr<std::vector<std::string>> GetStringList(const json& j, const std::string& path) {
  if (!j.is_array()) return FieldError(path, "must be an array of strings");
  std::vector<std::string> values;
  for (size_t i = 0; i < j.size(); ++i) {
    absl::StatusOr<std::string> v = GetString(j[i], absl::StrCat(path, "[", i, "]"));
    if (!v.ok()) return v.status();
    values.emplace_back(absl::StripAsciiWhitespace(*v));
  }
  return values;
}

// Looks `name` up in a unit table; the error lists the known names.
template <typename T>
absl::StatusOr<T> GetUnit(const json& j, const std::string& path,
                          const std::vector<std::pair<std::string, T>>& table) {
  absl::StatusOr<std::string> name = GetString(j, path);
  if (!name.ok()) return name.status();
  std::vector<std::string> known;
  for (const auto& [unit_name, value] : table) {
    if (unit_name == *name) return value;
    known.push_back(unit_name);
  }
  return FieldError(
      path, absl::StrFormat("'%s' is not a known unit (%s)", *name, absl::StrJoin(known, ", ")));
}

const std::vector<std::pair<std::string, absl::Duration>>& TimeUnits() {
  static const auto* units = new std::vector<std::pair<std::string, absl::Duration>>{
      {"s", absl::Seconds(1)}, {"ms", absl::Milliseconds(1)}, {"us", absl::Microseconds(1)}};
  return *units;
}
const std::vector<std::pair<std::string, double>>& AngleUnits() {
  static const auto* units =
      new std::vector<std::pair<std::string, double>>{{"rad", 1.0},
                                                      {"deg", kPi / 180.0},
                                                      {"arcmin", kPi / (180.0 * 60.0)},
                                                      {"arcsec", kPi / (180.0 * 3600.0)}};
  return *units;
}
const std::vector<std::pair<std::string, double>>& VoltageUnits() {
  static const auto* units =
      new std::vector<std::pair<std::string, double>>{{"V", 1000.0}, {"mV", 1.0}, {"uV", 1e-3}};
  return *units;
}

absl::Status ParseTime(const json& j, TimeMapping* time) {
  const std::string path = "time";
  if (absl::Status s = CheckObject(j, path,
                                   {"format", "column", "unit", "epoch", "weekColumn",
                                    "secondsColumn", "gpsMinusUtcS", "pattern"});
      !s.ok()) {
    return s;
  }
  if (!j.contains("format")) {
    return FieldError("time.format", "required: rfc3339, since_epoch, gps_week_seconds or pattern");
  }
  absl::StatusOr<std::string> format = GetString(j["format"], "time.format");
  if (!format.ok()) return format.status();
  // Which of the optional fields each format takes.
  std::vector<std::string> allowed;
  if (*format == "rfc3339") {
    time->format = TimeFormat::kRfc3339;
    allowed = {"format", "column"};
  } else if (*format == "since_epoch") {
    time->format = TimeFormat::kSinceEpoch;
    allowed = {"format", "column", "unit", "epoch"};
  } else if (*format == "gps_week_seconds") {
    time->format = TimeFormat::kGpsWeekSeconds;
    allowed = {"format", "weekColumn", "secondsColumn", "unit", "gpsMinusUtcS"};
  } else if (*format == "pattern") {
    time->format = TimeFormat::kPattern;
    allowed = {"format", "column", "pattern"};
  } else {
    return FieldError("time.format", absl::StrFormat("'%s' is not rfc3339, since_epoch, "
                                                     "gps_week_seconds or pattern",
                                                     *format));
  }
  for (auto it = j.begin(); it != j.end(); ++it) {
    if (std::find(allowed.begin(), allowed.end(), it.key()) == allowed.end()) {
      return FieldError(Join(path, it.key()),
                        absl::StrFormat("not used with format %s (fields of this format: %s)",
                                        *format, absl::StrJoin(allowed, ", ")));
    }
  }
  for (const std::string& key : allowed) {
    if (key != "unit" && !j.contains(key)) return FieldError(Join(path, key), "required");
  }
  if (j.contains("column")) {
    absl::StatusOr<std::string> column = GetColumnName(j["column"], "time.column");
    if (!column.ok()) return column.status();
    time->column = *column;
  }
  if (j.contains("unit")) {
    absl::StatusOr<absl::Duration> unit = GetUnit(j["unit"], "time.unit", TimeUnits());
    if (!unit.ok()) return unit.status();
    time->unit = *unit;
  }
  if (j.contains("epoch")) {
    absl::StatusOr<std::string> epoch = GetString(j["epoch"], "time.epoch");
    if (!epoch.ok()) return epoch.status();
    absl::StatusOr<absl::Time> epoch_time = estimator::ParseUtc(*epoch, "time.epoch");
    if (!epoch_time.ok()) return epoch_time.status();
    time->epoch = *epoch_time;
  }
  if (time->format == TimeFormat::kPattern) {
    absl::StatusOr<std::string> pattern = GetString(j["pattern"], "time.pattern");
    if (!pattern.ok()) return pattern.status();
    // The pattern must determine the instant: a known time must read back to itself.
    const absl::Time probe =
        absl::FromCivil(absl::CivilSecond(2019, 3, 1, 12, 34, 56), absl::UTCTimeZone());
    const std::string text = absl::FormatTime(*pattern, probe, absl::UTCTimeZone());
    absl::Time back;
    std::string error;
    if (pattern->empty() || !absl::ParseTime(*pattern, text, absl::UTCTimeZone(), &back, &error) ||
        back != probe) {
      return FieldError("time.pattern",
                        absl::StrFormat("'%s' does not determine a date and time to the second "
                                        "(2019-03-01T12:34:56Z written with it is '%s'%s)",
                                        *pattern, text,
                                        error.empty() ? ", which reads back otherwise"
                                                      : absl::StrCat(": ", error)));
    }
    time->pattern = *pattern;
  }
  if (time->format == TimeFormat::kGpsWeekSeconds) {
    absl::StatusOr<std::string> week = GetColumnName(j["weekColumn"], "time.weekColumn");
    if (!week.ok()) return week.status();
    absl::StatusOr<std::string> seconds = GetColumnName(j["secondsColumn"], "time.secondsColumn");
    if (!seconds.ok()) return seconds.status();
    time->week_column = *week;
    time->seconds_column = *seconds;
    const json& offset = j["gpsMinusUtcS"];
    if (!offset.is_number_integer() || offset.get<int64_t>() < 0 || offset.get<int64_t>() > 100) {
      return FieldError("time.gpsMinusUtcS",
                        absl::StrCat("must be a whole number of seconds in [0, 100] (GPS time "
                                     "minus UTC: 18 since 2017-01-01), got ",
                                     offset.dump()));
    }
    time->gps_minus_utc_s = offset.get<int>();
  }
  return absl::OkStatus();
}

absl::Status ParseGyro(const json& j, const std::string& path, GyroMapping* gyro) {
  if (absl::Status s = CheckObject(j, path, {"id", "spinAxis", "voltages"}); !s.ok()) return s;
  if (!j.contains("id")) return FieldError(Join(path, "id"), "required");
  const json& id = j["id"];
  if (!id.is_number_integer() || id.get<int64_t>() < 1 ||
      id.get<int64_t>() > estimator::kMaxGyros) {
    return FieldError(Join(path, "id"), absl::StrFormat("must be a gyro id 1..%d, got %s",
                                                        estimator::kMaxGyros, id.dump()));
  }
  gyro->id = id.get<int>();

  const std::string spin_path = Join(path, "spinAxis");
  if (!j.contains("spinAxis")) return FieldError(spin_path, "required");
  const json& spin = j["spinAxis"];
  if (absl::Status s = CheckObject(spin, spin_path, {"form", "columns", "unit"}); !s.ok()) return s;
  std::string form = "direction_cosines";
  if (spin.contains("form")) {
    absl::StatusOr<std::string> f = GetString(spin["form"], Join(spin_path, "form"));
    if (!f.ok()) return f.status();
    form = *f;
  }
  if (!spin.contains("columns")) return FieldError(Join(spin_path, "columns"), "required");
  if (form == "direction_cosines") {
    if (spin.contains("unit")) {
      return FieldError(Join(spin_path, "unit"),
                        "direction cosines have no unit (remove it, or set form "
                        "azimuth_elevation for angles)");
    }
    absl::StatusOr<std::vector<std::string>> columns =
        GetColumns(spin["columns"], Join(spin_path, "columns"), 3, "h1, h2, h3 along case x, y, z");
    if (!columns.ok()) return columns.status();
    gyro->spin_axis_columns = *columns;
  } else if (form == "azimuth_elevation") {
    gyro->spin_axis_angles = true;
    absl::StatusOr<std::vector<std::string>> columns = GetColumns(
        spin["columns"], Join(spin_path, "columns"), 2, "azimuth, elevation in the case frame");
    if (!columns.ok()) return columns.status();
    gyro->spin_axis_columns = *columns;
    if (!spin.contains("unit")) {
      return FieldError(Join(spin_path, "unit"), "required for angles: rad, deg, arcmin or arcsec");
    }
    absl::StatusOr<double> unit = GetUnit(spin["unit"], Join(spin_path, "unit"), AngleUnits());
    if (!unit.ok()) return unit.status();
    gyro->angle_unit_rad = *unit;
  } else {
    return FieldError(Join(spin_path, "form"),
                      absl::StrFormat("'%s' is not direction_cosines or azimuth_elevation", form));
  }

  if (j.contains("voltages")) {
    const std::string v_path = Join(path, "voltages");
    const json& v = j["voltages"];
    if (absl::Status s = CheckObject(v, v_path, {"columns", "unit"}); !s.ok()) return s;
    if (!v.contains("columns")) return FieldError(Join(v_path, "columns"), "required");
    if (!v.contains("unit")) return FieldError(Join(v_path, "unit"), "required: V, mV or uV");
    absl::StatusOr<std::vector<std::string>> columns =
        GetColumns(v["columns"], Join(v_path, "columns"), 3, "along case x, y, z");
    if (!columns.ok()) return columns.status();
    gyro->voltage_columns = *columns;
    absl::StatusOr<double> unit = GetUnit(v["unit"], Join(v_path, "unit"), VoltageUnits());
    if (!unit.ok()) return unit.status();
    gyro->voltage_unit_mv = *unit;
  }
  return absl::OkStatus();
}

absl::Status ParseStarTracker(const json& j, StarTrackerMapping* st) {
  const std::string path = "starTracker";
  if (absl::Status s = CheckObject(j, path, {"columns", "scalar", "rotation", "valid"}); !s.ok()) {
    return s;
  }
  for (const char* key : {"columns", "scalar", "rotation"}) {
    if (!j.contains(key)) return FieldError(Join(path, key), "required");
  }
  absl::StatusOr<std::vector<std::string>> columns =
      GetColumns(j["columns"], "starTracker.columns", 4, "the quaternion in the file's order");
  if (!columns.ok()) return columns.status();
  std::copy(columns->begin(), columns->end(), st->columns.begin());
  absl::StatusOr<std::string> scalar = GetString(j["scalar"], "starTracker.scalar");
  if (!scalar.ok()) return scalar.status();
  if (*scalar == "first") {
    st->scalar_first = true;
  } else if (*scalar == "last") {
    st->scalar_first = false;
  } else {
    return FieldError(
        "starTracker.scalar",
        absl::StrFormat("'%s' is not first or last (where the scalar part is)", *scalar));
  }
  absl::StatusOr<std::string> rotation = GetString(j["rotation"], "starTracker.rotation");
  if (!rotation.ok()) return rotation.status();
  if (*rotation == "q_in_b") {
    st->inverse = false;
  } else if (*rotation == "q_b_in") {
    st->inverse = true;
  } else {
    return FieldError("starTracker.rotation",
                      absl::StrFormat("'%s' is not q_in_b (v_in = q v_b q*: body coordinates to "
                                      "inertial, the project's) or q_b_in (v_b = q v_in q*: "
                                      "inertial coordinates to body, inverted on reading)",
                                      *rotation));
  }
  if (j.contains("valid")) {
    const std::string v_path = "starTracker.valid";
    const json& v = j["valid"];
    if (absl::Status s = CheckObject(v, v_path, {"column", "validValues", "invalidValues"});
        !s.ok()) {
      return s;
    }
    if (!v.contains("column")) return FieldError("starTracker.valid.column", "required");
    absl::StatusOr<std::string> column = GetColumnName(v["column"], "starTracker.valid.column");
    if (!column.ok()) return column.status();
    st->valid_column = *column;
    st->valid_values = {"1"};
    st->invalid_values = {"0"};
    if (v.contains("validValues")) {
      absl::StatusOr<std::vector<std::string>> values =
          GetStringList(v["validValues"], "starTracker.valid.validValues");
      if (!values.ok()) return values.status();
      st->valid_values = *values;
    }
    if (v.contains("invalidValues")) {
      absl::StatusOr<std::vector<std::string>> values =
          GetStringList(v["invalidValues"], "starTracker.valid.invalidValues");
      if (!values.ok()) return values.status();
      st->invalid_values = *values;
    }
    if (st->valid_values.empty()) {
      return FieldError("starTracker.valid.validValues", "needs at least one value");
    }
    for (const std::string& value : st->valid_values) {
      if (value.empty()) {
        return FieldError("starTracker.valid.validValues",
                          "an empty value (an empty field means no reading)");
      }
      if (std::find(st->invalid_values.begin(), st->invalid_values.end(), value) !=
          st->invalid_values.end()) {
        return FieldError("starTracker.valid.invalidValues",
                          absl::StrFormat("'%s' is also in validValues", value));
      }
    }
    for (const std::string& value : st->invalid_values) {
      if (value.empty()) {
        return FieldError("starTracker.valid.invalidValues",
                          "an empty value (an empty field means no reading)");
      }
    }
  }
  return absl::OkStatus();
}

// "channels": [{"name": "T_gyro2", "column": "TEMP_G2"}, ...]: the file's column holding each
// channel, its values already in the channel's declared unit (docs/formats.md "Channels").
absl::Status ParseChannels(const json& j, std::vector<ChannelMapping>* channels) {
  if (!j.is_array() || j.size() > static_cast<size_t>(estimator::kMaxChannels)) {
    return FieldError("channels", absl::StrFormat("must be an array of at most %d channels",
                                                  estimator::kMaxChannels));
  }
  std::set<std::string> names;
  for (size_t i = 0; i < j.size(); ++i) {
    const std::string path = absl::StrCat("channels[", i, "]");
    if (absl::Status s = CheckObject(j[i], path, {"name", "column"}); !s.ok()) return s;
    if (!j[i].contains("name")) return FieldError(path + ".name", "required");
    if (!j[i].contains("column")) return FieldError(path + ".column", "required");
    ChannelMapping channel;
    absl::StatusOr<std::string> name = GetString(j[i]["name"], path + ".name");
    if (!name.ok()) return name.status();
    if (absl::Status s = estimator::ValidateChannelName(*name, path + ".name"); !s.ok()) return s;
    if (!names.insert(*name).second) {
      return FieldError(path + ".name", absl::StrFormat("channel '%s' is mapped twice", *name));
    }
    absl::StatusOr<std::string> column = GetColumnName(j[i]["column"], path + ".column");
    if (!column.ok()) return column.status();
    channel.name = *name;
    channel.column = *column;
    channels->push_back(std::move(channel));
  }
  return absl::OkStatus();
}

// Every column of the mapping with the field that names it, in mapping order.
std::vector<std::pair<std::string, std::string>> MappedColumns(const ColumnMapping& m) {
  std::vector<std::pair<std::string, std::string>> out;
  switch (m.time.format) {
    case TimeFormat::kRfc3339:
    case TimeFormat::kSinceEpoch:
    case TimeFormat::kPattern:
      out.emplace_back(m.time.column, "time.column");
      break;
    case TimeFormat::kGpsWeekSeconds:
      out.emplace_back(m.time.week_column, "time.weekColumn");
      out.emplace_back(m.time.seconds_column, "time.secondsColumn");
      break;
  }
  for (size_t g = 0; g < m.gyros.size(); ++g) {
    const GyroMapping& gyro = m.gyros[g];
    for (size_t k = 0; k < gyro.spin_axis_columns.size(); ++k) {
      out.emplace_back(gyro.spin_axis_columns[k],
                       absl::StrFormat("gyros[%d].spinAxis.columns[%d]", g, k));
    }
    for (size_t k = 0; k < gyro.voltage_columns.size(); ++k) {
      out.emplace_back(gyro.voltage_columns[k],
                       absl::StrFormat("gyros[%d].voltages.columns[%d]", g, k));
    }
  }
  if (m.star_tracker.has_value()) {
    for (int k = 0; k < 4; ++k) {
      out.emplace_back(m.star_tracker->columns[k], absl::StrFormat("starTracker.columns[%d]", k));
    }
    if (!m.star_tracker->valid_column.empty()) {
      out.emplace_back(m.star_tracker->valid_column, "starTracker.valid.column");
    }
  }
  for (size_t i = 0; i < m.channels.size(); ++i) {
    out.emplace_back(m.channels[i].column, absl::StrFormat("channels[%d].column", i));
  }
  return out;
}

// ---------------------------------------------------------------------------------------------
// CSV rows.


// A mapped column resolved against the header.
struct Col {
  std::string name;
  std::string field;
  int index = -1;
  std::string Where() const { return absl::StrFormat("column %s (%s)", name, field); }
};

std::string GroupWhere(const std::vector<const Col*>& cols, const std::string& group_field) {
  std::vector<std::string> names;
  for (const Col* c : cols) names.push_back(c->name);
  return absl::StrFormat("column %s (%s)", absl::StrJoin(names, ","), group_field);
}

std::string Quote(absl::string_view s) {
  if (s.size() > 40) return absl::StrCat("'", s.substr(0, 37), "...'");
  return absl::StrCat("'", s, "'");
}

bool IsBlank(char c, char delimiter) { return c != delimiter && (c == ' ' || c == '\t'); }

// Splits at `delimiter` into trimmed fields. A field may be enclosed in double quotes (RFC 4180):
// the delimiter is then literal and "" stands for one quote. Returns an empty string, or what is
// wrong (a quote left open, text after a closing quote).
std::string SplitFields(absl::string_view line, char delimiter, std::vector<std::string>* fields) {
  fields->clear();
  size_t i = 0;
  while (true) {
    while (i < line.size() && IsBlank(line[i], delimiter)) ++i;
    std::string field;
    if (i < line.size() && line[i] == '"') {
      const size_t open = i++;
      bool closed = false;
      while (i < line.size()) {
        if (line[i] == '"') {
          if (i + 1 < line.size() && line[i + 1] == '"') {
            field += '"';
            i += 2;
            continue;
          }
          ++i;
          closed = true;
          break;
        }
        field += line[i++];
      }
      if (!closed)
        return absl::StrFormat("field %d: the quote at character %d is not closed",
                               fields->size() + 1, open + 1);
      while (i < line.size() && IsBlank(line[i], delimiter)) ++i;
      if (i < line.size() && line[i] != delimiter) {
        return absl::StrFormat("field %d: text after its closing quote", fields->size() + 1);
      }
    } else {
      size_t at = line.find(delimiter, i);
      if (at == absl::string_view::npos) at = line.size();
      field = std::string(absl::StripAsciiWhitespace(line.substr(i, at - i)));
      i = at;
    }
    fields->push_back(std::move(field));
    if (i >= line.size()) return "";
    ++i;  // the delimiter
  }
}

std::optional<double> ParseNumber(absl::string_view text, const Col& col, int line,
                                  CsvProblems* problems) {
  absl::string_view digits = text;
  if (!digits.empty() && digits.front() == '+') digits.remove_prefix(1);
  double value = 0.0;
  const auto [end, ec] = std::from_chars(digits.data(), digits.data() + digits.size(), value);
  if (ec != std::errc() || end != digits.data() + digits.size() || digits.empty() ||
      !std::isfinite(value)) {
    problems->Add(line, col.Where(), absl::StrCat(Quote(text), " is not a finite number"));
    return std::nullopt;
  }
  return value;
}

// A decimal count (sign, digits, optional fraction and exponent) times `unit`, exact to 1 ns
// (rounded to the nearest ns beyond). nullopt when malformed or beyond +-1e11 s.
std::optional<absl::Duration> ParseCount(absl::string_view text, absl::Duration unit) {
  size_t i = 0;
  bool negative = false;
  if (i < text.size() && (text[i] == '+' || text[i] == '-')) negative = text[i++] == '-';
  __int128 mantissa = 0;
  int exponent = 0;
  int significant = 0;
  int digits = 0;
  bool in_fraction = false;
  for (; i < text.size(); ++i) {
    const char c = text[i];
    if (c == '.' && !in_fraction) {
      in_fraction = true;
      continue;
    }
    if (!absl::ascii_isdigit(c)) break;
    ++digits;
    if (significant > 0 || c != '0') {
      if (++significant > 25) return std::nullopt;
      mantissa = mantissa * 10 + (c - '0');
      if (in_fraction) --exponent;
    } else if (in_fraction) {
      --exponent;  // leading zeros of a fraction
    }
  }
  if (digits == 0) return std::nullopt;
  if (i < text.size() && (text[i] == 'e' || text[i] == 'E')) {
    ++i;
    bool exp_negative = false;
    if (i < text.size() && (text[i] == '+' || text[i] == '-')) exp_negative = text[i++] == '-';
    int e = 0, exp_digits = 0;
    for (; i < text.size() && absl::ascii_isdigit(text[i]); ++i, ++exp_digits) {
      if ((e = e * 10 + (text[i] - '0')) > 1000) return std::nullopt;
    }
    if (exp_digits == 0) return std::nullopt;
    exponent += exp_negative ? -e : e;
  }
  if (i != text.size()) return std::nullopt;
  const int64_t unit_ns = absl::ToInt64Nanoseconds(unit);
  __int128 ns = mantissa * unit_ns;
  const __int128 limit = static_cast<__int128>(100000000000LL) * 1000000000LL;  // 1e11 s
  for (; exponent > 0; --exponent) {
    ns *= 10;
    if (ns > limit) return std::nullopt;
  }
  if (exponent < -36) return absl::ZeroDuration();  // below 1 ns for any count
  if (exponent < 0) {
    __int128 divisor = 1;
    for (; exponent < 0; ++exponent) divisor *= 10;
    ns = (ns + divisor / 2) / divisor;
  }
  if (ns > limit) return std::nullopt;
  const int64_t total = static_cast<int64_t>(ns);
  const absl::Duration d =
      absl::Seconds(total / 1000000000) + absl::Nanoseconds(total % 1000000000);
  return negative ? -d : d;
}

// Values of a group: nullopt on a problem (reported); an empty vector when all are empty.
std::optional<std::vector<double>> ParseGroup(const std::vector<std::string>& fields,
                                              const std::vector<const Col*>& cols,
                                              const std::string& group_field, int line,
                                              CsvProblems* problems) {
  std::vector<const Col*> empty;
  for (const Col* c : cols) {
    if (fields[c->index].empty()) empty.push_back(c);
  }
  if (empty.size() == cols.size()) return std::vector<double>();
  if (!empty.empty()) {
    problems->Add(line, GroupWhere(empty, group_field),
                  absl::StrFormat("empty while the rest of %s has values", group_field));
    return std::nullopt;
  }
  std::vector<double> values;
  bool ok = true;
  for (const Col* c : cols) {
    const std::optional<double> x = ParseNumber(fields[c->index], *c, line, problems);
    ok = ok && x.has_value();
    values.push_back(x.value_or(0.0));
  }
  if (!ok) return std::nullopt;
  return values;
}

// |norm - 1| check after conversion and renormalisation beyond kRenormaliseAbove.
template <typename Vector>
bool CheckUnit(Vector* v, const std::string& where, const std::string& what, int line,
               CsvProblems* problems) {
  const double norm = v->norm();
  if (!(std::abs(norm - 1.0) <= kUnitNormTolerance)) {
    problems->Add(
        line, where,
        absl::StrFormat("%s has norm %.6g, not 1 (tolerance %g)", what, norm, kUnitNormTolerance));
    return false;
  }
  if (std::abs(norm - 1.0) > kRenormaliseAbove) *v /= norm;
  return true;
}

}  // namespace

absl::StatusOr<ColumnMapping> ParseColumnMapping(std::string_view json_text) {
  json doc;
  try {
    doc = json::parse(json_text.begin(), json_text.end());
  } catch (const json::exception& e) {
    return FieldError("mapping", absl::StrCat("not valid JSON: ", e.what()));
  }
  // nlohmann-json keeps the last value of a repeated key: refused with its path.
  if (absl::Status strict = proto_convert::CheckStrictJson(json_text); !strict.ok()) return strict;
  if (absl::Status s = CheckObject(
          doc, "",
          {"format", "spacecraftId", "delimiter", "time", "gyros", "starTracker", "channels"});
      !s.ok()) {
    return s;
  }
  ColumnMapping mapping;
  if (doc.contains("format")) {
    absl::StatusOr<std::string> format = GetString(doc["format"], "format");
    if (!format.ok()) return format.status();
    if (*format != kColumnMappingFormat) {
      return FieldError("format", absl::StrFormat("'%s' is not supported (this reader reads '%s')",
                                                  *format, kColumnMappingFormat));
    }
  }
  if (doc.contains("spacecraftId")) {
    absl::StatusOr<std::string> id = GetString(doc["spacecraftId"], "spacecraftId");
    if (!id.ok()) return id.status();
    if (id->empty() || id->size() > 64)
      return FieldError("spacecraftId", "must be 1..64 characters");
    mapping.spacecraft_id = *id;
  }
  if (doc.contains("delimiter")) {
    absl::StatusOr<std::string> d = GetString(doc["delimiter"], "delimiter");
    if (!d.ok()) return d.status();
    if (d->size() != 1 || absl::ascii_isalnum((*d)[0]) || (*d)[0] == ' ' ||
        std::string_view(".+-\"#").find((*d)[0]) != std::string_view::npos) {
      return FieldError("delimiter",
                        absl::StrFormat("'%s' is not one character usable between numbers "
                                        "(e.g. \",\", \";\", \"\\t\", \"|\")",
                                        *d));
    }
    mapping.delimiter = (*d)[0];
  }
  if (!doc.contains("time")) return FieldError("time", "required");
  if (absl::Status s = ParseTime(doc["time"], &mapping.time); !s.ok()) return s;

  if (!doc.contains("gyros")) return FieldError("gyros", "required");
  const json& gyros = doc["gyros"];
  if (!gyros.is_array() || gyros.empty() || gyros.size() > estimator::kMaxGyros) {
    return FieldError("gyros",
                      absl::StrFormat("must be an array of 1..%d gyros", estimator::kMaxGyros));
  }
  std::set<int> ids;
  for (size_t g = 0; g < gyros.size(); ++g) {
    GyroMapping gyro;
    const std::string path = absl::StrCat("gyros[", g, "]");
    if (absl::Status s = ParseGyro(gyros[g], path, &gyro); !s.ok()) return s;
    if (!ids.insert(gyro.id).second) {
      return FieldError(path + ".id", absl::StrFormat("gyro %d is mapped twice", gyro.id));
    }
    mapping.gyros.push_back(std::move(gyro));
  }
  if (doc.contains("starTracker")) {
    StarTrackerMapping st;
    if (absl::Status s = ParseStarTracker(doc["starTracker"], &st); !s.ok()) return s;
    mapping.star_tracker = std::move(st);
  }
  if (doc.contains("channels")) {
    if (absl::Status s = ParseChannels(doc["channels"], &mapping.channels); !s.ok()) return s;
  }
  std::map<std::string, std::string> field_of;
  for (const auto& [column, field] : MappedColumns(mapping)) {
    if (auto [it, inserted] = field_of.emplace(column, field); !inserted) {
      return FieldError(field,
                        absl::StrFormat("column '%s' is already mapped by %s", column, it->second));
    }
  }
  return mapping;
}

absl::StatusOr<ColumnMapping> ReadColumnMapping(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::NotFoundError(
        absl::StrCat("column mapping ", path, ": cannot open: ", std::strerror(errno)));
  }
  std::ostringstream content;
  content << in.rdbuf();
  if (in.bad()) {
    return absl::UnavailableError(absl::StrCat("column mapping ", path, ": read failed"));
  }
  absl::StatusOr<ColumnMapping> mapping = ParseColumnMapping(content.str());
  if (!mapping.ok()) {
    return absl::Status(mapping.status().code(),
                        absl::StrCat("column mapping ", path, ": ", mapping.status().message()));
  }
  return mapping;
}

absl::StatusOr<estimator::Recording> ParseMappedRecordingCsv(std::string_view std_text,
                                                             const ColumnMapping& mapping,
                                                             const RecordingReadOptions& options) {
  const absl::string_view text(std_text.data(), std_text.size());
  estimator::Recording recording;
  CsvProblems problems("recording CSV through a column mapping", "");

  std::vector<Col> cols;
  for (const auto& [name, field] : MappedColumns(mapping)) cols.push_back({name, field, -1});
  // Columns of each quantity, in MappedColumns order.
  size_t next = 0;
  auto take = [&](size_t n) {
    std::vector<const Col*> out;
    for (size_t i = 0; i < n; ++i) out.push_back(&cols[next++]);
    return out;
  };
  const std::vector<const Col*> time_cols =
      take(mapping.time.format == TimeFormat::kGpsWeekSeconds ? 2 : 1);
  std::vector<std::vector<const Col*>> spin_cols, voltage_cols;
  for (const GyroMapping& gyro : mapping.gyros) {
    spin_cols.push_back(take(gyro.spin_axis_columns.size()));
    voltage_cols.push_back(take(gyro.voltage_columns.size()));
  }
  std::vector<const Col*> q_cols;
  const Col* valid_col = nullptr;
  if (mapping.star_tracker.has_value()) {
    q_cols = take(4);
    if (!mapping.star_tracker->valid_column.empty()) valid_col = take(1).front();
  }
  const std::vector<const Col*> channel_cols = take(mapping.channels.size());

  CsvMetadata metadata;  // the lines before the header
  bool have_header = false;
  size_t num_header_fields = 0;
  int header_line = 0;
  std::optional<absl::Time> previous_time;
  int previous_time_line = 0;
  std::vector<std::string> fields;

  CsvLines lines(text);  // a UTF-8 byte order mark dropped
  int line_no = 0;
  absl::string_view line;
  while (lines.Next(&line_no, &line)) {
    if (!have_header) {
      if (line.front() == '#') {
        if (auto entry = metadata.Read(line, line_no, problems); entry.has_value()) {
          recording.metadata[entry->first] = entry->second;
        }
        continue;
      }
      have_header = true;
      header_line = line_no;
      if (const std::string error = SplitFields(line, mapping.delimiter, &fields); !error.empty()) {
        problems.Add(line_no, "", absl::StrCat("header: ", error));
        return problems.ToStatus();
      }
      num_header_fields = fields.size();
      std::map<absl::string_view, int> index_of;
      for (size_t i = 0; i < fields.size(); ++i) {
        if (!index_of.emplace(fields[i], static_cast<int>(i)).second && !fields[i].empty()) {
          problems.Add(line_no, absl::StrCat("column ", fields[i]),
                       "column name appears twice in the header");
        }
      }
      if (fields.size() == 1 && cols.size() > 1) {
        problems.Add(line_no, "",
                     absl::StrFormat("the header is one field: is the delimiter '%s' right?",
                                     std::string(1, mapping.delimiter)));
      }
      for (Col& c : cols) {
        const auto it = index_of.find(c.name);
        if (it == index_of.end()) {
          problems.Add(line_no, "",
                       absl::StrFormat("the header has no column '%s' (named by the mapping's %s)",
                                       c.name, c.field));
        } else {
          c.index = it->second;
        }
      }
      if (!problems.empty()) return problems.ToStatus();  // rows cannot be interpreted
      continue;
    }

    if (line.front() == '#') {
      problems.Add(line_no, "", "comment or metadata line after the header");
      continue;
    }
    if (const std::string error = SplitFields(line, mapping.delimiter, &fields); !error.empty()) {
      problems.Add(line_no, "", error);
      continue;
    }
    if (fields.size() != num_header_fields) {
      problems.Add(line_no, "",
                   absl::StrFormat("expected %d fields as in the header (line %d), got %d",
                                   num_header_fields, header_line, fields.size()));
      continue;
    }
    const size_t problems_before = problems.size();
    estimator::TelemetryFrame frame;

    // Time.
    std::optional<absl::Time> time;
    const TimeMapping& tm = mapping.time;
    const Col& t0 = *time_cols[0];
    const absl::string_view t0_text = fields[t0.index];
    if (t0_text.empty()) {
      problems.Add(line_no, t0.Where(), "empty (every row needs its time)");
    } else if (tm.format == TimeFormat::kRfc3339) {
      // The column is named by the problem's place.
      if (absl::StatusOr<absl::Time> t = estimator::ParseUtc(t0_text, ""); t.ok()) {
        time = *t;
      } else {
        problems.Add(line_no, t0.Where(), std::string(t.status().message()));
      }
    } else if (tm.format == TimeFormat::kPattern) {
      absl::Time t;
      std::string error;
      if (absl::ParseTime(tm.pattern, t0_text, absl::UTCTimeZone(), &t, &error)) {
        time = t;
      } else {
        problems.Add(line_no, t0.Where(),
                     absl::StrFormat("%s does not match time.pattern '%s' (%s)", Quote(t0_text),
                                     tm.pattern, error));
      }
    } else if (tm.format == TimeFormat::kSinceEpoch) {
      if (const std::optional<absl::Duration> d = ParseCount(t0_text, tm.unit); d.has_value()) {
        time = tm.epoch + *d;
      } else {
        problems.Add(line_no, t0.Where(),
                     absl::StrCat(Quote(t0_text),
                                  " is not a decimal count since the epoch (at most 25 "
                                  "significant digits, within 1e11 s)"));
      }
    } else {
      const Col& t1 = *time_cols[1];
      const absl::string_view sow_text = fields[t1.index];
      int64_t week = -1;
      const auto [end, ec] = std::from_chars(t0_text.data(), t0_text.data() + t0_text.size(), week);
      const std::optional<absl::Duration> sow = ParseCount(sow_text, tm.unit);
      if (ec != std::errc() || end != t0_text.data() + t0_text.size() || week < 0 ||
          week > 100000) {
        problems.Add(line_no, t0.Where(),
                     absl::StrCat(Quote(t0_text), " is not a full GPS week number (0..100000)"));
      } else if (sow_text.empty()) {
        problems.Add(line_no, t1.Where(), "empty (every row needs its time)");
      } else if (!sow.has_value() || *sow < absl::ZeroDuration() ||
                 *sow >= absl::Seconds(kSecondsPerWeek)) {
        problems.Add(line_no, t1.Where(),
                     absl::StrCat(Quote(sow_text), " is not a time of week in [0, 604800) s"));
      } else {
        static const absl::Time kGpsEpoch =
            absl::FromCivil(absl::CivilSecond(1980, 1, 6, 0, 0, 0), absl::UTCTimeZone());
        time = kGpsEpoch + absl::Seconds(week * kSecondsPerWeek) + *sow -
               absl::Seconds(tm.gps_minus_utc_s);
      }
    }
    if (time.has_value()) {
      if (previous_time.has_value() && *time <= *previous_time) {
        problems.Add(
            line_no, t0.Where(),
            absl::StrFormat("%s is not after %s of line %d (times must increase)",
                            estimator::FormatUtc(*time), estimator::FormatUtc(*previous_time),
                            previous_time_line));
      } else if (previous_time.has_value() && *time - *previous_time > options.max_row_gap) {
        problems.Add(line_no, t0.Where(),
                     RowGapProblem(*time, *previous_time, previous_time_line, options.max_row_gap));
      }
      previous_time = time;
      previous_time_line = line_no;
      frame.time = *time;
    }

    // Gyros.
    for (size_t g = 0; g < mapping.gyros.size(); ++g) {
      const GyroMapping& gm = mapping.gyros[g];
      const std::string spin_field = absl::StrFormat("gyros[%d].spinAxis", g);
      const std::string voltage_field = absl::StrFormat("gyros[%d].voltages", g);
      auto spin = ParseGroup(fields, spin_cols[g], spin_field, line_no, &problems);
      std::optional<std::vector<double>> voltages = std::vector<double>();
      if (!voltage_cols[g].empty()) {
        voltages = ParseGroup(fields, voltage_cols[g], voltage_field, line_no, &problems);
      }
      if (!spin.has_value() || !voltages.has_value()) continue;
      if (spin->empty()) {
        if (!voltages->empty()) {
          problems.Add(
              line_no, GroupWhere(voltage_cols[g], voltage_field),
              absl::StrFormat("voltages given while gyro %d has no spin-axis reading", gm.id));
        }
        continue;  // gyro off
      }
      Eigen::Vector3d h_k;
      if (gm.spin_axis_angles) {
        const double azimuth = (*spin)[0] * gm.angle_unit_rad;
        const double elevation = (*spin)[1] * gm.angle_unit_rad;
        h_k = Eigen::Vector3d(std::cos(elevation) * std::cos(azimuth),
                              std::cos(elevation) * std::sin(azimuth), std::sin(elevation));
      } else {
        h_k = Eigen::Vector3d((*spin)[0], (*spin)[1], (*spin)[2]);
      }
      if (!CheckUnit(&h_k, GroupWhere(spin_cols[g], spin_field), "the spin axis", line_no,
                     &problems)) {
        continue;
      }
      estimator::GyroReading reading;
      reading.h_k = h_k;
      if (!voltages->empty()) {
        reading.u_k_mv =
            Eigen::Vector3d((*voltages)[0], (*voltages)[1], (*voltages)[2]) * gm.voltage_unit_mv;
      }
      frame.gyros[gm.id - 1] = reading;
    }

    // Star tracker.
    if (mapping.star_tracker.has_value()) {
      const StarTrackerMapping& st = *mapping.star_tracker;
      auto q = ParseGroup(fields, q_cols, "starTracker.columns", line_no, &problems);
      // Validity: from the flag column, or "a quaternion is a valid reading" without one.
      enum class Flag { kNone, kValid, kInvalid, kBad } flag = Flag::kNone;
      if (valid_col == nullptr) {
        flag = (q.has_value() && !q->empty()) ? Flag::kValid : Flag::kNone;
      } else {
        const absl::string_view v = fields[valid_col->index];
        if (v.empty()) {
          flag = Flag::kNone;
          if (q.has_value() && !q->empty()) {
            problems.Add(line_no, valid_col->Where(),
                         "empty while the quaternion has values (give a valid or invalid value)");
            flag = Flag::kBad;
          }
        } else if (std::find(st.valid_values.begin(), st.valid_values.end(), v) !=
                   st.valid_values.end()) {
          flag = Flag::kValid;
        } else if (std::find(st.invalid_values.begin(), st.invalid_values.end(), v) !=
                   st.invalid_values.end()) {
          flag = Flag::kInvalid;
        } else {
          problems.Add(line_no, valid_col->Where(),
                       absl::StrFormat("%s is neither valid (%s) nor invalid (%s)", Quote(v),
                                       absl::StrJoin(st.valid_values, ", "),
                                       absl::StrJoin(st.invalid_values, ", ")));
          flag = Flag::kBad;
        }
      }
      if (flag == Flag::kInvalid) {
        estimator::StarTrackerReading reading;
        reading.valid = false;
        frame.star_tracker = reading;
      } else if (flag == Flag::kValid && q.has_value()) {
        if (q->empty()) {
          problems.Add(line_no, GroupWhere(q_cols, "starTracker.columns"),
                       "empty while the validity flag says valid");
        } else {
          const std::vector<double>& c = *q;
          // To scalar first, then to q_in_b.
          Eigen::Vector4d q_in_b = st.scalar_first ? Eigen::Vector4d(c[0], c[1], c[2], c[3])
                                                   : Eigen::Vector4d(c[3], c[0], c[1], c[2]);
          if (st.inverse) q_in_b.tail<3>() = -q_in_b.tail<3>();
          if (CheckUnit(&q_in_b, GroupWhere(q_cols, "starTracker.columns"),
                        "the quaternion after conversion to q_in_b", line_no, &problems)) {
            estimator::StarTrackerReading reading;
            reading.valid = true;
            reading.q_in_b =
                estimator::QuaternionFromScalarFirst({q_in_b[0], q_in_b[1], q_in_b[2], q_in_b[3]});
            frame.star_tracker = reading;
          }
        }
      }
    }

    // Channels: an empty cell is a channel this frame does not carry.
    for (size_t i = 0; i < channel_cols.size(); ++i) {
      const std::optional<std::vector<double>> v =
          ParseGroup(fields, {channel_cols[i]}, channel_cols[i]->field, line_no, &problems);
      if (v.has_value() && !v->empty()) frame.channels.Set(mapping.channels[i].name, v->front());
    }

    if (problems.size() == problems_before) recording.frames.push_back(std::move(frame));
  }

  if (!have_header) problems.Add(line_no + 1, "", "no header line");
  if (!problems.empty()) return problems.ToStatus();
  if (!mapping.spacecraft_id.empty()) recording.metadata["spacecraft_id"] = mapping.spacecraft_id;
  return recording;
}

absl::StatusOr<estimator::Recording> ReadRecording(const std::string& path,
                                                   const std::string& columns_path,
                                                   const RecordingReadOptions& options) {
  if (columns_path.empty()) return ReadRecordingCsv(path, options);
  absl::StatusOr<ColumnMapping> mapping = ReadColumnMapping(columns_path);
  if (!mapping.ok()) return mapping.status();
  std::ifstream in(path, std::ios::binary);
  if (!in) {
    return absl::NotFoundError(
        absl::StrCat("recording ", path, ": cannot open: ", std::strerror(errno)));
  }
  std::ostringstream content;
  content << in.rdbuf();
  if (in.bad()) return absl::UnavailableError(absl::StrCat("recording ", path, ": read failed"));
  absl::StatusOr<estimator::Recording> recording = ParseMappedRecordingCsv(content.str(), *mapping, options);
  if (!recording.ok()) {
    return absl::Status(
        recording.status().code(),
        absl::StrCat(path, " (column mapping ", columns_path, "): ", recording.status().message()));
  }
  return recording;
}

}  // namespace esg::storage
