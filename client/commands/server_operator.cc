// The operators' actions on a session against esgd (docs/cli.md "model apply, gyro readmit"):
//   esg model apply --spacecraft ID --diagnosis N   applies stored diagnosis N (ApplyDiagnosis):
//       its findings that map to configuration, as `esg configure --replace` of the configuration
//       it ran on with them; prints what was applied and what was not, and the session.
//   esg gyro readmit --spacecraft ID --gyro N [--operator NAME]   readmits gyro N, which the
//       filter excluded (ReadmitGyro); it rejoins at the next measurement step. Without
//       --operator the name is the token's (the service takes it from --token / $ESG_TOKEN), or
//       $USER when no token is given.
// --format json prints the response in the proto JSON mapping, csv one row.
// Exit codes: 0 success, 2 bad arguments, 1 server failure (the service's refusal on stderr:
// "esg model apply: FAILED_PRECONDITION: diagnosis_id: ...").
#include <cstdio>
#include <memory>
#include <string>

#include "absl/strings/str_cat.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "client/esg_client.h"
#include "client/output_format.h"

namespace esg::client {
namespace {

struct ApplyOptions {
  std::string spacecraft_id;
  int64_t diagnosis_id = 0;
  OutputFormat format = OutputFormat::kTable;
};

struct ReadmitOptions {
  std::string spacecraft_id;
  int gyro_id = 0;
  std::string operator_name;
  OutputFormat format = OutputFormat::kTable;
};

int RunApply(const ApplyOptions& o, const GlobalOptions& global) {
  constexpr char kVerb[] = "model apply";
  if (o.diagnosis_id < 1) {
    return ReportBadArgument(kVerb, absl::StrCat("--diagnosis ", o.diagnosis_id, ": must be >= 1"));
  }
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  esg::v1::ApplyDiagnosisRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  request.set_diagnosis_id(o.diagnosis_id);
  absl::StatusOr<esg::v1::ApplyDiagnosisResponse> applied = client->ApplyDiagnosis(request);
  if (!applied.ok()) return ReportRpcError(kVerb, applied.status(), global);
  if (o.format == OutputFormat::kJson) {
    PrintJson(ProtoToJson(*applied));
  } else if (o.format == OutputFormat::kCsv) {
    PrintCsv({ProtoToJson(*applied)},
             ProtoCsvColumns(*esg::v1::ApplyDiagnosisResponse::descriptor()));
  } else {
    std::printf(
        "diagnosis %lld applied to %s as configuration version %lld; the session is "
        "recreated and the archive applied again\n",
        static_cast<long long>(o.diagnosis_id), o.spacecraft_id.c_str(),
        static_cast<long long>(applied->config_version()));
    for (const std::string& line : applied->applied()) std::printf("applied: %s\n", line.c_str());
    for (const std::string& line : applied->not_applied()) {
      std::printf("not applied: %s\n", line.c_str());
    }
  }
  return kExitOk;
}

int RunReadmit(const ReadmitOptions& o, const GlobalOptions& global) {
  constexpr char kVerb[] = "gyro readmit";
  if (o.gyro_id < 1 || o.gyro_id > 4) {
    return ReportBadArgument(kVerb, absl::StrCat("--gyro ", o.gyro_id, ": must be 1..4"));
  }
  // With a token the service takes the operator's name from it (an empty name); --operator
  // still wins.
  const std::optional<std::string> name = OperatorName(kVerb, o.operator_name, global);
  if (!name.has_value()) return kExitBadArguments;
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  esg::v1::ReadmitGyroRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  request.set_gyro_id(o.gyro_id);
  request.set_operator_name(*name);
  absl::StatusOr<esg::v1::ReadmitGyroResponse> readmitted = client->ReadmitGyro(request);
  if (!readmitted.ok()) return ReportRpcError(kVerb, readmitted.status(), global);
  if (o.format == OutputFormat::kJson) {
    PrintJson(ProtoToJson(*readmitted));
  } else if (o.format == OutputFormat::kCsv) {
    PrintCsv({ProtoToJson(*readmitted)},
             ProtoCsvColumns(*esg::v1::ReadmitGyroResponse::descriptor()));
  } else {
    std::printf(
        "gyro %d of %s readmitted after %s: it rejoins at the next measurement step "
        "(esg status --spacecraft %s)\n",
        o.gyro_id, o.spacecraft_id.c_str(),
        FormatUtc(readmitted->after_time(), readmitted->has_after_time()).c_str(),
        o.spacecraft_id.c_str());
  }
  return kExitOk;
}

}  // namespace

void RegisterModel(CLI::App& app, GlobalOptions& global, int* exit_code) {
  CLI::App* cmd = app.add_subcommand("model", "the model of a spacecraft on esgd");
  cmd->require_subcommand(1);
  cmd->fallthrough();
  auto apply = std::make_shared<ApplyOptions>();
  CLI::App* apply_cmd = cmd->add_subcommand(
      "apply", "apply a stored diagnosis's findings to the configuration (ApplyDiagnosis)");
  apply_cmd->add_option("--spacecraft", apply->spacecraft_id, "spacecraft id")->required();
  apply_cmd->add_option("--diagnosis", apply->diagnosis_id, "diagnosis id (esg diagnoses list)")
      ->required();
  AddFormatOption(apply_cmd, &apply->format);
  apply_cmd->callback([apply, &global, exit_code] { *exit_code = RunApply(*apply, global); });
}

void RegisterGyro(CLI::App& app, GlobalOptions& global, int* exit_code) {
  CLI::App* cmd = app.add_subcommand("gyro", "the gyros of a spacecraft on esgd");
  cmd->require_subcommand(1);
  cmd->fallthrough();
  auto readmit = std::make_shared<ReadmitOptions>();
  CLI::App* readmit_cmd =
      cmd->add_subcommand("readmit", "readmit a gyro the filter excluded (ReadmitGyro)");
  readmit_cmd->add_option("--spacecraft", readmit->spacecraft_id, "spacecraft id")->required();
  readmit_cmd->add_option("--gyro", readmit->gyro_id, "gyro id, 1..4")->required();
  readmit_cmd->add_option("--operator", readmit->operator_name,
                          "operator name (default: the token's, or $USER)");
  AddFormatOption(readmit_cmd, &readmit->format);
  readmit_cmd->callback(
      [readmit, &global, exit_code] { *exit_code = RunReadmit(*readmit, global); });
}

}  // namespace esg::client
