// `esg configure --config F [--model 10+11] [--replace]`: sends a spacecraft configuration (the
// JSON file of docs/formats.md) to esgd (ConfigureSpacecraft) and prints the resulting session.
// Exit codes: 0 success, 2 bad arguments or configuration file, 1 server failure (e.g.
// FAILED_PRECONDITION when the configuration of a spacecraft with archived telemetry would change
// without --replace).
#include <cstdio>
#include <iostream>
#include <memory>
#include <string>

#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "estimator/calibration_model.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

constexpr char kVerb[] = "configure";

struct ConfigureOptions {
  std::string config_path;
  std::string model = "10+11";
  bool replace = false;
  OutputFormat format = OutputFormat::kTable;
};

std::string Pair(const google::protobuf::RepeatedField<int32_t>& ids) {
  std::string out = "[";
  for (int i = 0; i < ids.size(); ++i) out += (i ? "," : "") + std::to_string(ids[i]);
  return out + "]";
}

int RunConfigure(const ConfigureOptions& o, const GlobalOptions& global) {
  absl::StatusOr<estimator::SpacecraftConfig> config = proto_convert::ReadConfigFile(o.config_path);
  if (!config.ok()) {
    return ReportBadArgument(
        kVerb, "--config " + o.config_path + ": " + std::string(config.status().message()));
  }
  absl::StatusOr<estimator::ModelSpec> model = estimator::ParseModel(o.model);
  if (!model.ok()) {
    return ReportBadArgument(kVerb, "--" + std::string(model.status().message()));
  }
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;

  esg::v1::ConfigureRequest request;
  *request.mutable_config() = proto_convert::ConfigToProto(*config);
  request.set_model(model->Name());
  request.set_replace(o.replace);
  absl::StatusOr<esg::v1::ConfigureResponse> response = client->ConfigureSpacecraft(request);
  if (!response.ok()) return ReportRpcError(kVerb, response.status(), global);

  const esg::v1::SessionInfo& s = response->session();
  if (o.format == OutputFormat::kJson) {
    PrintJson(ProtoToJson(*response));
  } else if (o.format == OutputFormat::kCsv) {
    Json record = ProtoToJson(*response);
    record["session"].erase("config");  // the file just sent
    PrintCsv({record}, {"created"});
  } else {
    std::printf(
        "%s: %s, model %s, state %s, working pair %s, reserve pair %s, %lld frames "
        "archived\n",
        s.spacecraft_id().c_str(), response->created() ? "created" : "configured",
        s.model().c_str(), StateName(s.state()).c_str(), Pair(s.working_pair()).c_str(),
        Pair(s.reserve_pair()).c_str(), static_cast<long long>(s.frames_accepted()));
  }
  return kExitOk;
}

}  // namespace

void RegisterConfigure(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto options = std::make_shared<ConfigureOptions>();
  CLI::App* cmd = app.add_subcommand(
      kVerb, "create or reconfigure a spacecraft session on esgd (ConfigureSpacecraft)");
  cmd->add_option("--config", options->config_path,
                  "spacecraft configuration JSON (docs/formats.md)")
      ->required();
  cmd->add_option("--model", options->model, "drift model: 1, 10, 11 or a '+' set such as 10+11")
      ->capture_default_str();
  cmd->add_flag("--replace", options->replace,
                "allow changing the configuration of a spacecraft with archived telemetry (the "
                "archive is applied again under the new one)");
  AddFormatOption(cmd, &options->format);
  cmd->callback([options, &global, exit_code] { *exit_code = RunConfigure(*options, global); });
}

}  // namespace esg::client
