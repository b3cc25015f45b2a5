// The output forms of every `esg` verb that prints data (docs/cli.md, "Output formats"), and the
// one function that formats a time for the CLI.
//
//   --format table  human-readable text (the default)
//   --format json   one JSON document on stdout. A proto message is printed in the proto3 JSON
//                   mapping (google::protobuf::util::MessageToJsonString): lowerCamelCase field
//                   names, enums by their full value name, 64-bit integers as strings, every
//                   scalar field present (defaults included), absent messages left out. Data that
//                   is not a proto message follows the same conventions for keys, enums and
//                   absent values; its numbers are JSON numbers.
//   --format csv    a header line, then one row per record; nested fields flattened to
//                   "a.b" and array elements to "a[0]" (RFC 4180 quoting).
//   --json          kept as a short form of --format json.
// Every time printed is RFC 3339 UTC with `Z` and exactly three fractional digits
// ("2019-03-01T00:00:00.000Z"), in every format, including the timestamps of proto messages.
#ifndef ESG_CLIENT_OUTPUT_FORMAT_H_
#define ESG_CLIENT_OUTPUT_FORMAT_H_

#include <string>
#include <vector>

#include "CLI/CLI.hpp"
#include "absl/time/time.h"
#include "estimator/basis_term.h"
#include "estimator/utc_time.h"
#include "google/protobuf/descriptor.h"
#include "google/protobuf/message.h"
#include "google/protobuf/timestamp.pb.h"
#include "nlohmann/json.hpp"

namespace esg::client {

using Json = nlohmann::ordered_json;

enum class OutputFormat { kTable, kJson, kCsv };

// Adds `--format table|json|csv` and its short form `--json` to the verb `cmd`; the parsed value
// is stored in *format, which must outlive the parse (e.g. a member of the verb's options held
// by a shared_ptr). `json_note`, when not empty, is appended to the help of --format (e.g. "with
// --follow: one JSON object per line").
void AddFormatOption(CLI::App* cmd, OutputFormat* format, const std::string& json_note = "");

// RFC 3339 UTC with `Z` and millisecond precision (truncated): "2019-03-01T00:00:00.000Z", the
// one time format of every output (estimator/utc_time.h).
using estimator::FormatUtc;
// The same for a wire timestamp; "-" when `present` is false (the field is absent), "(invalid
// time)" when it is out of the Timestamp range.
std::string FormatUtc(const google::protobuf::Timestamp& timestamp, bool present = true);

// One basis term of a table (`esg calibrate`, `esg history`), in the units of the configuration
// (deg/h per JSON unit of the regressor): "  basis orbit cos 1 -> y   +0.00120 +- 0.00004 deg/h
// per 1", or "... (held)" when `sigma` (SI, like term.value) is 0.
std::string BasisTermLine(const estimator::BasisTerm& term, double sigma);

// A proto message in the proto3 JSON mapping described above, its google.protobuf.Timestamp
// fields (at any depth) in FormatUtc's form.
Json ProtoToJson(const google::protobuf::Message& message);

// Prints `doc` on stdout, indented by 2, and a newline.
void PrintJson(const Json& doc);
// Prints `doc` on stdout on one line (for streams of objects, one per line).
void PrintJsonLine(const Json& doc);

// A CSV table from JSON records (objects): the header is the union of the flattened keys in the
// order of first appearance, a record without a key leaves its cell empty. null is an empty
// cell, a string is written as is (quoted when it holds a comma, quote or line break), numbers
// and booleans as in JSON. A record that is not an object is one column named "value".
// `columns` come first, in their order, so that the header is there even without records.
std::string CsvTable(const std::vector<Json>& records,
                     const std::vector<std::string>& columns = {});
// The leading CSV columns of a message type: the json_name of each singular scalar, enum, string
// and Timestamp field, in field order (repeated and other message fields are flattened from the
// records). For a header that is there without records, and for rows printed one at a time.
std::vector<std::string> ProtoCsvColumns(const google::protobuf::Descriptor& descriptor);
// One CSV line (without the newline) of `columns` joined, and of the cells of `record` (flattened
// as in CsvTable) under those columns; keys of the record outside `columns` are left out.
std::string CsvLine(const std::vector<std::string>& columns);
std::string CsvRow(const Json& record, const std::vector<std::string>& columns);
// Prints CsvTable(records, columns) on stdout.
void PrintCsv(const std::vector<Json>& records, const std::vector<std::string>& columns = {});

}  // namespace esg::client

#endif  // ESG_CLIENT_OUTPUT_FORMAT_H_
