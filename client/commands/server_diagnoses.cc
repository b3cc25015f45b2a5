// `esg diagnose --spacecraft ID` (Diagnose) and `esg diagnoses list|show|cancel-auto`
// (ListDiagnoses, GetDiagnosis, CancelAutoDiagnosis); see server_diagnoses.h.
#include "client/commands/server_diagnoses.h"

#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/clock.h"
#include "client/commands/server_common.h"
#include "client/esg_client.h"
#include "client/progress.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

using esg::v1::DiagnosisResult;

// The JSON form: the proto mapping, the report parsed under "report" (null when absent).
Json ResultJson(const DiagnosisResult& result) {
  Json doc = ProtoToJson(result);
  doc.erase("reportJson");
  doc["report"] = result.report_json().empty()
                      ? Json()
                      : Json::parse(result.report_json(), nullptr, /*allow_exceptions=*/false);
  return doc;
}

std::vector<std::string> SummaryColumns() {
  std::vector<std::string> columns;
  for (const std::string& c : ProtoCsvColumns(*DiagnosisResult::descriptor())) {
    if (c != "reportJson") columns.push_back(c);
  }
  return columns;
}

// "#ID spacecraft verdict first .. last, N frames, computed T", and ", automatic: answers alert
// #N" for the service's own diagnosis (docs/service.md "Automatic diagnosis").
std::string SummaryLine(const DiagnosisResult& d) {
  const std::string origin =
      d.requested_by().empty()
          ? std::string()
          : absl::StrCat(", ", d.requested_by() == "service" ? "automatic" : d.requested_by(),
                         d.answers_alert() > 0 ? absl::StrCat(": answers alert #", d.answers_alert())
                                               : std::string());
  return absl::StrFormat("#%d %s %-20s %s .. %s, %d frames, computed %s%s", d.id(),
                         d.spacecraft_id(), d.verdict(),
                         FormatUtc(d.first_frame_time(), d.has_first_frame_time()),
                         FormatUtc(d.last_frame_time(), d.has_last_frame_time()), d.frames(),
                         FormatUtc(d.compute_time(), d.has_compute_time()), origin);
}

// The human form of a result with its report: the summary line, the findings and the fit.
void PrintResult(const DiagnosisResult& d) {
  std::printf("diagnosis %s\n", SummaryLine(d).c_str());
  const Json report = Json::parse(d.report_json(), nullptr, /*allow_exceptions=*/false);
  if (!report.is_object()) return;
  std::printf("verdict: %s\n", d.verdict().c_str());
  int n = 0;
  for (const Json& f : report.value("findings", Json::array())) {
    std::string gyro = f.contains("gyro") ? absl::StrCat(" (gyro ", f["gyro"].dump(), ")") : "";
    std::printf("%d. %s%s: %s\n", ++n, f.value("effect", "").c_str(), gyro.c_str(),
                f.value("explanation", "").c_str());
  }
  if (report.contains("fit")) {
    for (const char* when : {"before", "after"}) {
      const Json& fit = report["fit"][when];
      if (!fit.is_object()) continue;
      std::printf("fit %-7s residual RMS %.2f arcsec, held-out drift rate %.4f deg/h (%s)\n",
                  (std::string(when) + ":").c_str(), fit.value("residualRmsArcsec", NAN),
                  fit.value("gapDriftRateDegH", NAN), fit.value("model", "").c_str());
    }
  }
}

// CSV of results with reports: one row per finding (a row without effect when none).
void PrintResultCsv(const DiagnosisResult& d) {
  Json base = ProtoToJson(d);
  base.erase("reportJson");
  const Json report = Json::parse(d.report_json(), nullptr, /*allow_exceptions=*/false);
  std::vector<Json> rows;
  if (report.is_object()) {
    for (const Json& f : report.value("findings", Json::array())) {
      Json row = base;
      row["effect"] = f.value("effect", "");
      row["gyro"] = f.contains("gyro") ? f["gyro"] : Json();
      row["explanation"] = f.value("explanation", "");
      rows.push_back(row);
    }
  }
  if (rows.empty()) rows.push_back(base);
  std::vector<std::string> columns = SummaryColumns();
  for (const char* c : {"effect", "gyro", "explanation"}) columns.push_back(c);
  PrintCsv(rows, columns);
}

void PrintOne(const DiagnosisResult& d, OutputFormat format) {
  switch (format) {
    case OutputFormat::kJson:
      PrintJson(ResultJson(d));
      break;
    case OutputFormat::kCsv:
      PrintResultCsv(d);
      break;
    case OutputFormat::kTable:
      PrintResult(d);
      break;
  }
}

struct ListOptions {
  std::string spacecraft_id;
  int64_t id = 0;
  int page_size = 0;
  OutputFormat format = OutputFormat::kTable;
};

int RunList(const ListOptions& o, const GlobalOptions& global) {
  constexpr char kVerb[] = "diagnoses list";
  if (o.page_size < 0) {
    return ReportBadArgument(kVerb, absl::StrCat("--page-size ", o.page_size, ": must be >= 0"));
  }
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  // Every page, in the server's order (oldest first).
  esg::v1::ListDiagnosesRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  request.set_page_size(o.page_size);
  absl::StatusOr<esg::v1::ListDiagnosesResponse> listed = client->ListDiagnoses(request);
  if (!listed.ok()) return ReportRpcError(kVerb, listed.status(), global);
  const esg::v1::ListDiagnosesResponse& all = *listed;
  if (o.format == OutputFormat::kJson) {
    Json doc = ProtoToJson(all);
    doc.erase("nextPageToken");
    for (Json& d : doc["diagnoses"]) d.erase("reportJson");  // summaries: always empty
    PrintJson(doc);
  } else if (o.format == OutputFormat::kCsv) {
    std::vector<Json> rows;
    for (const DiagnosisResult& d : all.diagnoses()) {
      Json row = ProtoToJson(d);
      row.erase("reportJson");
      rows.push_back(row);
    }
    PrintCsv(rows, SummaryColumns());
  } else {
    for (const DiagnosisResult& d : all.diagnoses()) std::printf("%s\n", SummaryLine(d).c_str());
    std::printf("%d diagnoses of %s (esg diagnoses show --spacecraft %s --id N for a report)\n",
                all.diagnoses_size(), o.spacecraft_id.c_str(), o.spacecraft_id.c_str());
  }
  return kExitOk;
}

int RunCancelAuto(const ListOptions& o, const GlobalOptions& global) {
  constexpr char kVerb[] = "diagnoses cancel-auto";
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  esg::v1::CancelAutoDiagnosisRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  absl::StatusOr<esg::v1::CancelAutoDiagnosisResponse> r = client->CancelAutoDiagnosis(request);
  if (!r.ok()) return ReportRpcError(kVerb, r.status(), global);
  if (o.format == OutputFormat::kJson) {
    PrintJson(ProtoToJson(*r));
  } else if (o.format == OutputFormat::kCsv) {
    PrintCsv({ProtoToJson(*r)}, ProtoCsvColumns(*r->GetDescriptor()));
  } else if (r->cancelled()) {
    std::printf("automatic diagnosis of %s (answering alert #%lld) cancelled; none starts again "
                "under this configuration\n",
                o.spacecraft_id.c_str(), static_cast<long long>(r->answers_alert()));
  } else {
    std::printf("no automatic diagnosis of %s waits or runs\n", o.spacecraft_id.c_str());
  }
  return kExitOk;
}

int RunShow(const ListOptions& o, const GlobalOptions& global) {
  constexpr char kVerb[] = "diagnoses show";
  if (o.id < 1) return ReportBadArgument(kVerb, absl::StrCat("--id ", o.id, ": must be >= 1"));
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  absl::StatusOr<DiagnosisResult> result = client->GetDiagnosis(o.spacecraft_id, o.id);
  if (!result.ok()) return ReportRpcError(kVerb, result.status(), global);
  PrintOne(*result, o.format);
  return kExitOk;
}

}  // namespace

int RunServerDiagnose(const ServerDiagnoseOptions& o, const GlobalOptions& global) {
  constexpr char kVerb[] = "diagnose";
  esg::v1::DiagnoseRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  request.set_model(o.model);
  request.set_orbital_period_s(o.orbital_period_s);
  if (int code = SetTimeSpan(kVerb, o.from, o.to, &request); code != kExitOk) return code;
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  std::unique_ptr<ReaderStream<esg::v1::DiagnoseUpdate>> reader = client->Diagnose(request);
  StageProgress progress("diagnose");
  std::optional<DiagnosisResult> result;
  esg::v1::DiagnoseUpdate update;
  while (reader->Read(&update)) {
    progress(update.progress(), update.stage());
    if (update.has_result()) result = update.result();
  }
  progress.End();
  const absl::Status status = reader->Finish();
  if (!status.ok()) return ReportRpcError(kVerb, status, global);
  if (!result) {
    std::fprintf(stderr, "esg %s: the stream ended without a result\n", kVerb);
    return kExitFailure;
  }
  PrintOne(*result, o.format);
  return kExitOk;
}

void RegisterDiagnoses(CLI::App& app, GlobalOptions& global, int* exit_code) {
  CLI::App* cmd = app.add_subcommand(
      "diagnoses", "stored diagnoses of a spacecraft on esgd (ListDiagnoses, GetDiagnosis)");
  cmd->require_subcommand(1);
  cmd->fallthrough();

  auto list = std::make_shared<ListOptions>();
  CLI::App* list_cmd = cmd->add_subcommand(
      "list", "every stored diagnosis of a spacecraft, oldest first (all pages)");
  list_cmd->add_option("--spacecraft", list->spacecraft_id, "spacecraft id")->required();
  list_cmd->add_option("--page-size", list->page_size,
                       "diagnoses per request (0: the server's default); pages are followed");
  AddFormatOption(list_cmd, &list->format);
  list_cmd->callback([list, &global, exit_code] { *exit_code = RunList(*list, global); });

  auto show = std::make_shared<ListOptions>();
  CLI::App* show_cmd =
      cmd->add_subcommand("show", "one stored diagnosis with its full report (GetDiagnosis)");
  show_cmd->add_option("--spacecraft", show->spacecraft_id, "spacecraft id")->required();
  show_cmd->add_option("--id", show->id, "diagnosis id (esg diagnoses list)")->required();
  AddFormatOption(show_cmd, &show->format);
  show_cmd->callback([show, &global, exit_code] { *exit_code = RunShow(*show, global); });

  auto cancel = std::make_shared<ListOptions>();
  CLI::App* cancel_cmd = cmd->add_subcommand(
      "cancel-auto",
      "cancel the service's own diagnosis of a spacecraft while it waits or runs "
      "(CancelAutoDiagnosis, write role)");
  cancel_cmd->add_option("--spacecraft", cancel->spacecraft_id, "spacecraft id")->required();
  AddFormatOption(cancel_cmd, &cancel->format);
  cancel_cmd->callback(
      [cancel, &global, exit_code] { *exit_code = RunCancelAuto(*cancel, global); });
}

}  // namespace esg::client
