// Helpers shared by the server verbs (see server_common.h).
#include "client/commands/server_common.h"

#include <cstdio>
#include <cstdlib>
#include <string_view>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_replace.h"
#include "estimator/utc_time.h"
#include "proto/convert.h"

namespace esg::client {
namespace {

std::string StripPrefix(const std::string& name, absl::string_view prefix) {
  return absl::StartsWith(name, prefix) ? name.substr(prefix.size()) : name;
}

}  // namespace

ClientOptions ClientOptionsFrom(const GlobalOptions& global) {
  ClientOptions options;
  options.server = global.server;
  options.tls_ca = global.tls_ca;
  options.tls_cert = global.tls_cert;
  options.tls_key = global.tls_key;
  options.token = global.token;
  return options;
}

std::unique_ptr<EsgClient> Connect(const char* verb, const GlobalOptions& global) {
  absl::StatusOr<std::unique_ptr<EsgClient>> client = EsgClient::Create(ClientOptionsFrom(global));
  if (!client.ok()) {
    ReportBadArgument(verb, std::string(client.status().message()));
    return nullptr;
  }
  return *std::move(client);
}

int ReportRpcError(const char* verb, const absl::Status& status, const GlobalOptions& global) {
  std::string message(status.message());
  // esgd's own UNAVAILABLE of a session another server holds (docs/service.md "Several
  // servers") reached the server; anything else UNAVAILABLE did not.
  if (status.code() == absl::StatusCode::kUnavailable &&
      !absl::StrContains(message, "' is served by node ")) {
    message = absl::StrCat("server not reachable at ", global.server, " (", message, ")");
  }
  std::fprintf(stderr, "esg %s: %s: %s\n", verb, absl::StatusCodeToString(status.code()).c_str(),
               message.c_str());
  return kExitFailure;
}

int ReportBadArgument(const char* verb, const std::string& message) {
  std::fprintf(stderr, "esg %s: %s\n", verb, message.c_str());
  return kExitBadArguments;
}

std::optional<std::string> OperatorName(const char* verb, const std::string& given,
                                        const GlobalOptions& global) {
  if (!given.empty() || !global.token.empty()) return given;
  const char* user = std::getenv("USER");
  if (user != nullptr && *user != '\0') return std::string(user);
  ReportBadArgument(verb, "--operator: required when $USER is not set (or give --token)");
  return std::nullopt;
}

std::optional<absl::Time> TimeOption(const char* verb, const char* option,
                                     const std::string& text) {
  absl::StatusOr<absl::Time> time = estimator::ParseUtc(text, option);
  if (time.ok()) return *time;
  ReportBadArgument(verb, std::string(time.status().message()));
  return std::nullopt;
}

std::optional<OutputFormat> FormatWithCsvFlag(const char* verb, bool csv, OutputFormat format) {
  if (csv && format == OutputFormat::kJson) {
    ReportBadArgument(verb, "--csv and --json: give at most one");
    return std::nullopt;
  }
  return csv ? OutputFormat::kCsv : format;
}

std::string StateName(esg::v1::SessionState state) {
  return StripPrefix(esg::v1::SessionState_Name(state), "SESSION_STATE_");
}

std::string SeverityName(esg::v1::AlertSeverity severity) {
  return StripPrefix(esg::v1::AlertSeverity_Name(severity), "ALERT_SEVERITY_");
}

std::string ReasonName(esg::v1::AlertReason reason) {
  return StripPrefix(esg::v1::AlertReason_Name(reason), "ALERT_REASON_");
}

std::string ReasonWords(esg::v1::AlertReason reason) {
  return absl::StrReplaceAll(absl::AsciiStrToLower(ReasonName(reason)), {{"_", " "}});
}

std::optional<esg::v1::AlertSeverity> ParseSeverity(const std::string& name) {
  const std::string upper = absl::AsciiStrToUpper(name);
  for (esg::v1::AlertSeverity s : {esg::v1::ALERT_SEVERITY_INFO, esg::v1::ALERT_SEVERITY_WARNING,
                                   esg::v1::ALERT_SEVERITY_DISTRESS,
                                   esg::v1::ALERT_SEVERITY_CRITICAL}) {
    if (upper == SeverityName(s) || upper == esg::v1::AlertSeverity_Name(s)) return s;
  }
  return std::nullopt;
}

Json AttitudeJson(const esg::v1::AttitudeSample& sample) { return ProtoToJson(sample); }

Json SessionJson(const esg::v1::SessionInfo& session) { return ProtoToJson(session); }

Json AlertJson(const esg::v1::Alert& alert) { return ProtoToJson(alert); }

}  // namespace esg::client
