// `esg history --spacecraft ID [--gyro N] [--from T] [--to T] [--include-revised]
// [--format table|json|csv]`: the
// stored coefficient history of a spacecraft (GetCoefficientHistory, every page followed: a
// history of any length is read in pages under gRPC's default message limit, docs/service.md
// "Paging"): per measurement epoch and gyro the estimated
// drift model of eq. (1), (10) in the case frame k [deg/h] with its 1-sigma, and the estimated
// gyro-to-star-tracker misalignment about the body axes [arcsec] with its 1-sigma, and the
// gyro's configured basis terms (drift terms beyond eq. (1), (10)) with their 1-sigma.
// Output: a table (k0, C1, C2, mu, nu values and the misalignment, a line per basis term), or with --format csv (short
// form --csv) one row per snapshot with every value and sigma (columns in CsvHeader), or with
// --format json (--json) the HistoryResponse in the proto JSON mapping (basis terms in
// `basisTerms`, as the configuration writes them; the CSV leaves them out). --include-revised also
// returns the snapshots a re-run over a late frame superseded (docs/service.md "Several ground
// stations"): the table marks them "revised", the CSV gains a last column revised_time_utc.
// Exit codes: 0 success, 2 bad arguments, 1 server failure.
// Also `esg export history` (RunExportHistory, server_export.h): the same CSV columns from the
// ExportCoefficientHistory stream, every value with 17 significant digits.
#include <cmath>
#include <cstdio>
#include <iostream>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "client/commands/server_export.h"
#include "client/output_format.h"
#include "estimator/model_terms.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

constexpr char kVerb[] = "history";

struct HistoryOptions {
  std::string spacecraft_id;
  int gyro_id = 0;
  std::string from;
  std::string to;
  bool include_revised = false;
  bool csv = false;  // short form of --format csv
  OutputFormat format = OutputFormat::kTable;
};

// The drift terms of GyroDriftModel, one group per JSON key in theta order, each with the
// descriptors of its components (estimator/model_terms.h).
using TermGroup = std::vector<const estimator::FixedTermDescriptor*>;
const std::vector<TermGroup>& TermGroups() {
  static const std::vector<TermGroup>* const groups = [] {
    auto* out = new std::vector<TermGroup>;
    for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
      if (out->empty() || out->back().front()->json_key != term.json_key) out->emplace_back();
      out->back().push_back(&term);
    }
    return out;
  }();
  return *groups;
}

// Table heading of a group: "k0 +- sigma" for a number, "C1 x,y,z" or "mu 12,23,31" for a
// vector (the components named by their storage keys after the symbol).
std::string GroupHeading(const TermGroup& group) {
  const estimator::FixedTermDescriptor& first = *group.front();
  if (first.component < 0) return absl::StrCat(first.symbol, " +- sigma");
  std::string heading = absl::StrCat(first.symbol, " ");
  for (size_t i = 0; i < group.size(); ++i) {
    absl::StrAppend(&heading, i == 0 ? "" : ",", group[i]->storage_key.substr(first.symbol.size()));
  }
  return heading;
}

double At(const google::protobuf::RepeatedField<double>& v, int i) {
  return i < v.size() ? v[i] : 0.0;
}

// The last CSV column with --include-revised: when a re-run superseded the snapshot (empty:
// current).
constexpr char kRevisedColumn[] = ",revised_time_utc";
std::string RevisedCell(const esg::v1::CoefficientSnapshot& s) {
  return absl::StrCat(",", s.has_revised_time() ? FormatUtc(s.revised_time()) : "");
}

std::string CsvHeader() {
  std::string header = "time_utc,gyro";
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    absl::StrAppend(&header, ",", estimator::FixedTermValueColumn(term), ",",
                    estimator::FixedTermSigmaColumn(term));
  }
  for (const char* axis : {"x", "y", "z"}) {
    absl::StrAppend(&header, ",misalignment_", axis, "_arcsec,misalignment_", axis,
                    "_sigma_arcsec");
  }
  return header + ",compute_time_utc";
}

// `full`: every value with 17 significant digits (reads back the same double: the export);
// else 10 for the coefficients and 6 for the misalignment (`esg history --csv`).
std::string CsvRow(const esg::v1::CoefficientSnapshot& s, bool full = false) {
  std::string row =
      absl::StrCat(FormatUtc(s.measurement_time(), s.has_measurement_time()), ",", s.gyro_id());
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    const double value = proto_convert::DriftModelTermDegH(s.model(), term);
    const double sigma = proto_convert::DriftModelTermDegH(s.sigma(), term);
    absl::StrAppend(&row, full ? absl::StrFormat(",%.17g,%.17g", value, sigma)
                               : absl::StrFormat(",%.10g,%.10g", value, sigma));
  }
  for (int i = 0; i < 3; ++i) {
    const double m = At(s.misalignment_arcsec(), i);
    const double m_sigma = At(s.misalignment_sigma_arcsec(), i);
    absl::StrAppend(&row, full ? absl::StrFormat(",%.17g,%.17g", m, m_sigma)
                               : absl::StrFormat(",%.6g,%.6g", m, m_sigma));
  }
  return absl::StrCat(row, ",", FormatUtc(s.compute_time(), s.has_compute_time()));
}

void PrintTable(const esg::v1::HistoryResponse& history) {
  // A number takes 18 columns (value +- sigma), a vector 26 (its values).
  std::string heading = absl::StrFormat("%-22s %4s ", "time_utc", "gyro");
  for (size_t g = 0; g < TermGroups().size(); ++g) {
    const TermGroup& group = TermGroups()[g];
    absl::StrAppend(&heading, g == 0 ? "" : "  ",
                    group.front()->component < 0
                        ? absl::StrFormat("%18s", GroupHeading(group))
                        : absl::StrFormat("%-26s", GroupHeading(group)));
  }
  std::printf("%s  %s\n", heading.c_str(), "misalignment x,y,z [arcsec]");
  for (const esg::v1::CoefficientSnapshot& s : history.snapshots()) {
    std::string line = absl::StrFormat("%-22s %4d ",
                                       FormatUtc(s.measurement_time(), s.has_measurement_time()),
                                       s.gyro_id());
    for (size_t g = 0; g < TermGroups().size(); ++g) {
      const TermGroup& group = TermGroups()[g];
      if (group.front()->component < 0) {
        absl::StrAppend(&line, g == 0 ? "" : "  ",
                        absl::StrFormat("%+9.5f +-%7.5f",
                                        proto_convert::DriftModelTermDegH(s.model(), *group.front()),
                                        proto_convert::DriftModelTermDegH(s.sigma(), *group.front())));
        continue;
      }
      absl::StrAppend(&line, g == 0 ? "" : " ");
      for (const estimator::FixedTermDescriptor* term : group) {
        absl::StrAppend(&line, absl::StrFormat(" %+8.5f", proto_convert::DriftModelTermDegH(s.model(), *term)));
      }
    }
    absl::StrAppend(
        &line, absl::StrFormat("  %+7.1f %+7.1f %+7.1f", At(s.misalignment_arcsec(), 0),
                               At(s.misalignment_arcsec(), 1), At(s.misalignment_arcsec(), 2)));
    if (s.has_revised_time()) absl::StrAppend(&line, "  revised at ", FormatUtc(s.revised_time()));
    std::printf("%s\n", line.c_str());
    for (int k = 0; k < s.basis_terms_size(); ++k) {
      absl::StatusOr<estimator::BasisTerm> term =
          proto_convert::BasisTermFromProto(s.basis_terms(k), absl::StrCat("basisTerms[", k, "]"));
      std::printf("%s\n", term.ok() ? BasisTermLine(*term, term->sigma).c_str()
                                    : absl::StrCat("  basis ", term.status().message()).c_str());
    }
  }
  std::printf("%d snapshots (coefficients in deg/h, case frame k; --csv adds every 1-sigma)\n",
              history.snapshots_size());
}

int RunHistory(const HistoryOptions& o, const GlobalOptions& global) {
  const std::optional<OutputFormat> format = FormatWithCsvFlag(kVerb, o.csv, o.format);
  if (!format) return kExitBadArguments;
  if (o.gyro_id < 0 || o.gyro_id > 4) {
    return ReportBadArgument(kVerb, absl::StrCat("--gyro ", o.gyro_id, ": must be 1..4 (0: all)"));
  }
  esg::v1::HistoryRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  request.set_gyro_id(o.gyro_id);
  request.set_include_revised(o.include_revised);
  esg::v1::HistoryResponse history;
  if (int code = FetchHistory(kVerb, global, o.from, o.to, request,
                              &EsgClient::GetCoefficientHistory, &history);
      code != kExitOk) {
    return code;
  }

  if (*format == OutputFormat::kCsv) {
    std::printf("%s%s\n", CsvHeader().c_str(), o.include_revised ? kRevisedColumn : "");
    for (const esg::v1::CoefficientSnapshot& s : history.snapshots()) {
      std::printf("%s%s\n", CsvRow(s).c_str(), o.include_revised ? RevisedCell(s).c_str() : "");
    }
  } else if (*format == OutputFormat::kJson) {
    PrintJson(ProtoToJson(history));
  } else {
    PrintTable(history);
  }
  return kExitOk;
}

}  // namespace

int RunExportHistory(const ExportHistoryOptions& o, const GlobalOptions& global) {
  constexpr char kExportVerb[] = "export history";
  if (o.format != "csv" && o.format != "json") {
    return ReportBadArgument(kExportVerb,
                             absl::StrCat("--format ", o.format, ": must be csv or json"));
  }
  if (o.gyro_id < 0 || o.gyro_id > 4) {
    return ReportBadArgument(kExportVerb,
                             absl::StrCat("--gyro ", o.gyro_id, ": must be 1..4 (0: all)"));
  }
  esg::v1::ExportCoefficientHistoryRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  request.set_gyro_id(o.gyro_id);
  request.set_include_revised(o.include_revised);
  if (int code = SetTimeSpan(kExportVerb, o.from, o.to, &request); code != kExitOk) return code;
  std::unique_ptr<EsgClient> client = Connect(kExportVerb, global);
  if (client == nullptr) return kExitBadArguments;
  std::unique_ptr<OutputFile> out = OutputFile::Open(kExportVerb, o.out);
  if (out == nullptr) return kExitBadArguments;
  // CSV rows are written as the chunks arrive; JSON is one document, written at the end.
  const bool csv = o.format == "csv";
  bool header_written = false;  // once the first chunk (or the end) arrived: nothing on a refusal
  esg::v1::ExportCoefficientHistoryResponse all;
  int64_t snapshots = 0;
  std::unique_ptr<ReaderStream<esg::v1::ExportCoefficientHistoryResponse>> stream =
      client->ExportCoefficientHistory(request);
  esg::v1::ExportCoefficientHistoryResponse chunk;
  while (stream->Read(&chunk)) {
    snapshots += chunk.snapshots_size();
    if (csv) {
      const std::string revised_column = o.include_revised ? kRevisedColumn : "";
      std::string text = header_written ? "" : CsvHeader() + revised_column + "\n";
      header_written = true;
      for (const esg::v1::CoefficientSnapshot& s : chunk.snapshots()) {
        absl::StrAppend(&text, CsvRow(s, /*full=*/true), o.include_revised ? RevisedCell(s) : "",
                        "\n");
      }
      out->Write(text);
    } else {
      for (esg::v1::CoefficientSnapshot& s : *chunk.mutable_snapshots()) {
        *all.add_snapshots() = std::move(s);
      }
    }
  }
  const absl::Status status = stream->Finish();
  if (!status.ok()) return ReportRpcError(kExportVerb, status, global);
  if (csv && !header_written) {
    out->Write(CsvHeader() + (o.include_revised ? kRevisedColumn : "") + "\n");
  }
  if (!csv) out->Write(ProtoToJson(all).dump(2) + "\n");
  if (absl::Status closed = out->Commit(); !closed.ok()) {
    std::fprintf(stderr, "esg %s: %s\n", kExportVerb, std::string(closed.message()).c_str());
    return kExitFailure;
  }
  if (!o.out.empty()) {
    std::fprintf(stderr, "%s: %lld coefficient snapshots written to %s\n", o.spacecraft_id.c_str(),
                 static_cast<long long>(snapshots), o.out.c_str());
  }
  return kExitOk;
}

void RegisterHistory(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto options = std::make_shared<HistoryOptions>();
  CLI::App* cmd = app.add_subcommand(
      kVerb, "stored drift-coefficient history of a spacecraft (GetCoefficientHistory)");
  cmd->add_option("--spacecraft", options->spacecraft_id, "spacecraft id")->required();
  cmd->add_option("--gyro", options->gyro_id, "gyro id 1..4 (default 0: all)");
  cmd->add_option("--from", options->from, "first measurement time, RFC 3339 UTC");
  cmd->add_option("--to", options->to, "last measurement time, RFC 3339 UTC");
  cmd->add_flag("--include-revised", options->include_revised,
                "also the snapshots a re-run over a late frame superseded (marked revised)");
  AddFormatOption(cmd, &options->format);
  cmd->add_flag("--csv", options->csv,
                "short form of --format csv: one row per snapshot with every 1-sigma");
  cmd->callback([options, &global, exit_code] { *exit_code = RunHistory(*options, global); });
}

}  // namespace esg::client
