// Output formats of the CLI (see output_format.h).
#include "client/output_format.h"

#include <cstdio>
#include <iostream>
#include <map>
#include <utility>

#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "google/protobuf/descriptor.h"
#include "google/protobuf/descriptor.pb.h"
#include "google/protobuf/util/json_util.h"
#include "google/protobuf/util/time_util.h"

namespace esg::client {
namespace {

using google::protobuf::Descriptor;
using google::protobuf::FieldDescriptor;
using google::protobuf::Message;
using google::protobuf::Reflection;

bool IsTimestamp(const Descriptor* d) { return d->full_name() == "google.protobuf.Timestamp"; }

std::string TimestampText(const Message& m) {
  google::protobuf::Timestamp t;
  t.CopyFrom(m);
  return FormatUtc(t);
}

// Whether a field of a message holds nothing: no entries, or not set (proto3: its default).
bool Empty(const Message& message, const FieldDescriptor* field) {
  const Reflection* reflection = message.GetReflection();
  return field->is_repeated() ? reflection->FieldSize(message, field) == 0
                              : !reflection->HasField(message, field);
}

// Rewrites the Timestamp fields of `json` (MessageToJsonString's form of `message`) with
// FormatUtc, and leaves out a deprecated field that holds nothing (a GyroDriftModel's fields of
// the release before its keyed coefficients, docs/formats.md), recursing into nested and
// repeated messages. Maps of messages are left alone (the service's messages have none with
// timestamps).
void TidyJson(const Message& message, Json& json) {
  if (!json.is_object()) return;
  const Descriptor* descriptor = message.GetDescriptor();
  const Reflection* reflection = message.GetReflection();
  for (int i = 0; i < descriptor->field_count(); ++i) {
    const FieldDescriptor* field = descriptor->field(i);
    if (field->options().deprecated() && Empty(message, field)) json.erase(field->json_name());
  }
  for (int i = 0; i < descriptor->field_count(); ++i) {
    const FieldDescriptor* field = descriptor->field(i);
    if (field->cpp_type() != FieldDescriptor::CPPTYPE_MESSAGE || field->is_map()) continue;
    auto it = json.find(field->json_name());
    if (it == json.end()) continue;
    const bool timestamp = IsTimestamp(field->message_type());
    if (field->is_repeated()) {
      if (!it->is_array()) continue;
      const int n = reflection->FieldSize(message, field);
      for (int k = 0; k < n && k < static_cast<int>(it->size()); ++k) {
        const Message& element = reflection->GetRepeatedMessage(message, field, k);
        if (timestamp) {
          (*it)[k] = TimestampText(element);
        } else {
          TidyJson(element, (*it)[k]);
        }
      }
    } else if (reflection->HasField(message, field)) {
      const Message& value = reflection->GetMessage(message, field);
      if (timestamp) {
        *it = TimestampText(value);
      } else {
        TidyJson(value, *it);
      }
    }
  }
}

std::string CsvCell(const Json& value) {
  std::string text;
  if (value.is_null()) return text;
  text = value.is_string() ? value.get<std::string>() : value.dump();
  if (text.find_first_of(",\"\r\n") == std::string::npos) return text;
  std::string quoted = "\"";
  for (char c : text) {
    if (c == '"') quoted += '"';
    quoted += c;
  }
  return quoted + "\"";
}

void Flatten(const std::string& prefix, const Json& value,
             std::vector<std::pair<std::string, Json>>& out) {
  if (value.is_object()) {
    for (const auto& [key, child] : value.items()) {
      Flatten(prefix.empty() ? key : absl::StrCat(prefix, ".", key), child, out);
    }
  } else if (value.is_array()) {
    for (size_t i = 0; i < value.size(); ++i) {
      Flatten(absl::StrCat(prefix, "[", i, "]"), value[i], out);
    }
  } else {
    out.emplace_back(prefix.empty() ? "value" : prefix, value);
  }
}

}  // namespace

void AddFormatOption(CLI::App* cmd, OutputFormat* format, const std::string& json_note) {
  std::string help =
      "output: table (text), json (one document, the proto JSON mapping) or csv (a header, "
      "then one row per record)";
  if (!json_note.empty()) absl::StrAppend(&help, "; json ", json_note);
  CLI::Option* option = cmd->add_option_function<std::string>(
                               "-o,--format",
                               [format](const std::string& name) {
                                 *format = name == "json"  ? OutputFormat::kJson
                                           : name == "csv" ? OutputFormat::kCsv
                                                           : OutputFormat::kTable;
                               },
                               help)
                            ->check([](const std::string& name) -> std::string {
                              if (name == "table" || name == "json" || name == "csv") return "";
                              return "must be table, json or csv (got " + name + ")";
                            })
                            ->type_name("table|json|csv");
  cmd->add_flag_callback(
         "--json", [format] { *format = OutputFormat::kJson; }, "short for --format json")
      ->excludes(option);
}

std::string FormatUtc(const google::protobuf::Timestamp& timestamp, bool present) {
  if (!present) return "-";
  if (timestamp.seconds() < google::protobuf::util::TimeUtil::kTimestampMinSeconds ||
      timestamp.seconds() > google::protobuf::util::TimeUtil::kTimestampMaxSeconds ||
      timestamp.nanos() < 0 || timestamp.nanos() > 999999999) {
    return "(invalid time)";
  }
  return FormatUtc(absl::FromUnixSeconds(timestamp.seconds()) +
                   absl::Nanoseconds(timestamp.nanos()));
}

std::string BasisTermLine(const estimator::BasisTerm& term, double sigma) {
  const double to_json = estimator::BasisValueToJson(term.kind);
  const std::string unit =
      absl::StrCat("deg/h per ", std::string(estimator::BasisScalarJsonUnit(term.kind)));
  const std::string label = estimator::BasisTermLabel(term);
  if (sigma > 0.0) {
    return absl::StrFormat("  basis %-18s %+9.5f +- %.5f %s", label, term.value * to_json,
                           sigma * to_json, unit);
  }
  return absl::StrFormat("  basis %-18s %+9.5f %s (held)", label, term.value * to_json, unit);
}

Json ProtoToJson(const google::protobuf::Message& message) {
  google::protobuf::util::JsonPrintOptions options;
  options.always_print_primitive_fields = true;
  options.preserve_proto_field_names = false;  // lowerCamelCase, the canonical mapping
  std::string text;
  if (!google::protobuf::util::MessageToJsonString(message, &text, options).ok()) {
    // Only an out-of-range Timestamp or Duration fails; keep the rest readable.
    return Json{{"error", "message not representable in JSON"}};
  }
  Json json = Json::parse(text, nullptr, /*allow_exceptions=*/false);
  TidyJson(message, json);
  return json;
}

void PrintJson(const Json& doc) { std::cout << doc.dump(2) << "\n" << std::flush; }

void PrintJsonLine(const Json& doc) { std::cout << doc.dump() << "\n" << std::flush; }

std::string CsvTable(const std::vector<Json>& records, const std::vector<std::string>& columns) {
  std::vector<std::string> header;
  std::map<std::string, size_t> column;
  for (const std::string& c : columns) {
    if (column.emplace(c, header.size()).second) header.push_back(c);
  }
  std::vector<std::vector<std::pair<std::string, Json>>> flat(records.size());
  for (size_t r = 0; r < records.size(); ++r) {
    Flatten("", records[r], flat[r]);
    for (const auto& [key, value] : flat[r]) {
      if (column.emplace(key, header.size()).second) header.push_back(key);
    }
  }
  std::vector<std::string> header_cells;
  for (const std::string& h : header) header_cells.push_back(CsvCell(Json(h)));
  std::string out = absl::StrCat(absl::StrJoin(header_cells, ","), "\n");
  for (const auto& row : flat) {
    std::vector<std::string> cells(header.size());
    for (const auto& [key, value] : row) cells[column.at(key)] = CsvCell(value);
    absl::StrAppend(&out, absl::StrJoin(cells, ","), "\n");
  }
  return out;
}

std::vector<std::string> ProtoCsvColumns(const Descriptor& descriptor) {
  std::vector<std::string> columns;
  for (int i = 0; i < descriptor.field_count(); ++i) {
    const FieldDescriptor* field = descriptor.field(i);
    if (field->is_repeated()) continue;
    if (field->cpp_type() == FieldDescriptor::CPPTYPE_MESSAGE &&
        !IsTimestamp(field->message_type())) {
      continue;
    }
    columns.push_back(field->json_name());
  }
  return columns;
}

std::string CsvLine(const std::vector<std::string>& columns) {
  std::vector<std::string> cells;
  for (const std::string& c : columns) cells.push_back(CsvCell(Json(c)));
  return absl::StrJoin(cells, ",");
}

std::string CsvRow(const Json& record, const std::vector<std::string>& columns) {
  std::vector<std::pair<std::string, Json>> flat;
  Flatten("", record, flat);
  std::map<std::string, const Json*> by_key;
  for (const auto& [key, value] : flat) by_key.emplace(key, &value);
  std::vector<std::string> cells;
  for (const std::string& c : columns) {
    auto it = by_key.find(c);
    cells.push_back(it == by_key.end() ? std::string() : CsvCell(*it->second));
  }
  return absl::StrJoin(cells, ",");
}

void PrintCsv(const std::vector<Json>& records, const std::vector<std::string>& columns) {
  std::cout << CsvTable(records, columns) << std::flush;
}

}  // namespace esg::client
