// `esg predict --spacecraft ID --from T --to T --step S [--aem FILE]`: the attitude predicted by
// esgd from the calibrated state (PredictAttitude, docs/physics.md): per epoch q_in_b (scalar
// first), its 1-sigma about the body axes x, y, z [arcsec] and the predicted spin axes h_in of the
// gyros used; --aem also writes the returned CCSDS AEM (KVN, docs/formats.md) to FILE.
// Exit codes: 0 success, 2 bad arguments, 1 server or file failure (e.g. OUT_OF_RANGE when --from
// is not after the last applied frame or --to is beyond the prediction horizon).
#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <memory>
#include <optional>
#include <string>

#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

constexpr char kVerb[] = "predict";

struct PredictOptions {
  std::string spacecraft_id;
  std::string from;
  std::string to;
  double step_s = 0.0;
  std::string aem_path;
  bool json = false;
};

int RunPredict(const PredictOptions& o, const GlobalOptions& global) {
  const std::optional<absl::Time> from = ParseUtc(o.from);
  if (!from) return ReportBadArgument(kVerb, "--from '" + o.from + "': not an RFC 3339 time");
  const std::optional<absl::Time> to = ParseUtc(o.to);
  if (!to) return ReportBadArgument(kVerb, "--to '" + o.to + "': not an RFC 3339 time");
  if (*to < *from) {
    return ReportBadArgument(kVerb,
                             "--to " + FormatUtc(*to) + ": before --from " + FormatUtc(*from));
  }
  if (!(o.step_s > 0.0) || !std::isfinite(o.step_s)) {
    return ReportBadArgument(kVerb, "--step " + std::to_string(o.step_s) + ": must be > 0 seconds");
  }
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;

  esg::v1::PredictRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  *request.mutable_from() = proto_convert::TimeToProto(*from);
  *request.mutable_to() = proto_convert::TimeToProto(*to);
  request.set_step_s(o.step_s);
  request.set_aem(!o.aem_path.empty());
  absl::StatusOr<esg::v1::PredictResponse> response = client->PredictAttitude(request);
  if (!response.ok()) return ReportRpcError(kVerb, response.status(), global);

  if (!o.aem_path.empty()) {
    std::ofstream out(o.aem_path, std::ios::binary | std::ios::trunc);
    out << response->aem_text();
    out.close();
    if (!out) {
      std::fprintf(stderr, "esg %s: --aem %s: cannot write\n", kVerb, o.aem_path.c_str());
      return kExitFailure;
    }
  }
  if (o.json) {
    Json samples = Json::array();
    for (const esg::v1::AttitudeSample& s : response->samples()) samples.push_back(AttitudeJson(s));
    Json doc{{"spacecraftId", o.spacecraft_id}, {"stepS", o.step_s}, {"samples", samples}};
    if (!o.aem_path.empty()) doc["aemFile"] = o.aem_path;
    std::cout << doc.dump(2) << "\n";
    return kExitOk;
  }
  std::printf("%-24s %12s %12s %12s %12s %9s %9s %9s  %s\n", "time_utc", "q0", "q1", "q2", "q3",
              "sig_x\"", "sig_y\"", "sig_z\"", "spin axes h_in");
  for (const esg::v1::AttitudeSample& s : response->samples()) {
    std::printf("%-24s", FormatUtc(s.time(), s.has_time()).c_str());
    for (int i = 0; i < 4; ++i) std::printf(" %+12.9f", i < s.q_in_b_size() ? s.q_in_b(i) : 0.0);
    for (int i = 0; i < 3; ++i) {
      std::printf(" %9.2f", i < s.sigma_arcsec_size() ? s.sigma_arcsec(i) : 0.0);
    }
    std::printf(" ");
    for (const esg::v1::GyroAxis& axis : s.spin_axes()) {
      std::printf(" g%d[", axis.gyro_id());
      for (int i = 0; i < axis.h_in_size(); ++i) std::printf("%s%+.6f", i ? " " : "", axis.h_in(i));
      std::printf("]");
    }
    std::printf("\n");
  }
  std::printf("%d samples", response->samples_size());
  if (!o.aem_path.empty()) std::printf("; AEM written to %s", o.aem_path.c_str());
  std::printf("\n");
  return kExitOk;
}

}  // namespace

void RegisterPredict(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto options = std::make_shared<PredictOptions>();
  CLI::App* cmd = app.add_subcommand(
      kVerb, "predicted attitude with its 1-sigma envelope over an interval (PredictAttitude)");
  cmd->add_option("--spacecraft", options->spacecraft_id, "spacecraft id")->required();
  cmd->add_option("--from", options->from,
                  "first epoch, RFC 3339 UTC (after the last applied frame)")
      ->required();
  cmd->add_option("--to", options->to, "last epoch, RFC 3339 UTC")->required();
  cmd->add_option("--step", options->step_s, "step between epochs [s]")->required();
  cmd->add_option("--aem", options->aem_path,
                  "also write the prediction as a CCSDS AEM (KVN) file");
  cmd->add_flag("--json", options->json, "one JSON document on stdout");
  cmd->callback([options, &global, exit_code] { *exit_code = RunPredict(*options, global); });
}

}  // namespace esg::client
