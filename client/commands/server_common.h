// Helpers shared by the server verbs of `esg` (configure, replay, status, predict, alerts,
// history; docs/cli.md): connecting with the global options, the one error format
// `esg VERB: <CODE>: <message>` (exit 1), UTC times in RFC 3339 at the edges (conventions.h §9),
// names of the esg.v1 enums without their prefixes for tables, and the JSON forms of the service's
// messages. --format, the JSON mapping and the time format are in client/output_format.h.
#ifndef ESG_CLIENT_COMMANDS_SERVER_COMMON_H_
#define ESG_CLIENT_COMMANDS_SERVER_COMMON_H_

#include <memory>
#include <optional>
#include <string>
#include <utility>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "client/commands/commands.h"
#include "client/esg_client.h"
#include "client/output_format.h"
#include "esg/v1/attitude.pb.h"
#include "esg/v1/estimation_service.pb.h"
#include "google/protobuf/timestamp.pb.h"
#include "nlohmann/json.hpp"
#include "proto/convert.h"

namespace esg::client {

// Exit codes of every verb (commands.h).
inline constexpr int kExitOk = 0;
inline constexpr int kExitFailure = 1;
inline constexpr int kExitBadArguments = 2;

// The connection options the global flags give (address, TLS files, token).
ClientOptions ClientOptionsFrom(const GlobalOptions& global);

// Builds the client from the global options (--server, --tls-*, --token / $ESG_TOKEN). On bad
// options prints "esg VERB: <message>" and returns nullptr (the verb exits 2).
std::unique_ptr<EsgClient> Connect(const char* verb, const GlobalOptions& global);

// Prints "esg VERB: <CODE>: <message>" on stderr and returns kExitFailure. UNAVAILABLE says that
// the server is not reachable at the --server address.
int ReportRpcError(const char* verb, const absl::Status& status, const GlobalOptions& global);

// Prints "esg VERB: <message>" on stderr and returns kExitBadArguments.
int ReportBadArgument(const char* verb, const std::string& message);

// Times are printed with FormatUtc of output_format.h (RFC 3339 UTC, `Z`, milliseconds).
// The value of a time option (--from, --to, --since, --start): RFC 3339 read by the one parser,
// estimator::ParseUtc ("2019-03-01T00:00:00Z", "...+03:00", fractional seconds allowed). Anything
// else is nullopt after ReportBadArgument in its wording, naming the option:
//   esg predict: --from: 'yesterday' is not an RFC 3339 time such as 2019-03-01T00:00:00Z
// (the verb exits 2).
std::optional<absl::Time> TimeOption(const char* verb, const char* option, const std::string& text);

// Sets request->from and request->to from the --from and --to option values (an empty value
// leaves that bound unset): the span [--from, --to], both ends inclusive, as the service reads
// it (docs/cli.md "Time spans"). Returns kExitOk, or ReportBadArgument's code naming the option
// whose value is not an RFC 3339 time (TimeOption), or --to before --from (the request is then
// not to be sent).
template <typename Request>
int SetTimeSpan(const char* verb, const std::string& from, const std::string& to,
                Request* request) {
  std::optional<absl::Time> from_time;
  if (!from.empty()) {
    from_time = TimeOption(verb, "--from", from);
    if (!from_time) return kExitBadArguments;
    *request->mutable_from() = proto_convert::TimeToProto(*from_time);
  }
  if (!to.empty()) {
    const std::optional<absl::Time> t = TimeOption(verb, "--to", to);
    if (!t) return kExitBadArguments;
    if (from_time && *t < *from_time) {
      return ReportBadArgument(verb, "--to '" + to + "': is before --from '" + from + "'");
    }
    *request->mutable_to() = proto_convert::TimeToProto(*t);
  }
  return kExitOk;
}

// The output format of a verb with --format and the short form --csv: csv if --csv is given. Both
// The operator name an acknowledgement or a readmission is stored under: `given` (--operator);
// with a token and no --operator, empty (the service takes the token's name); else $USER.
// nullopt after ReportBadArgument when none applies (the verb exits 2).
std::optional<std::string> OperatorName(const char* verb, const std::string& given,
                                        const GlobalOptions& global);

// --csv and --json: nullopt after ReportBadArgument (the verb exits 2).
std::optional<OutputFormat> FormatWithCsvFlag(const char* verb, bool csv, OutputFormat format);

// The whole stored history of a paged call that follows every page (`fetch`:
// &EsgClient::GetCoefficientHistory or &EsgClient::GetEstimateHistory) for `request`, its span
// set from the --from and --to values first (SetTimeSpan). Returns kExitOk with *response set,
// or the exit code after printing why: a bad time or bad connection options (kExitBadArguments),
// the call's error (ReportRpcError, kExitFailure).
template <typename Request, typename Response>
int FetchHistory(const char* verb, const GlobalOptions& global, const std::string& from,
                 const std::string& to, Request& request,
                 absl::StatusOr<Response> (EsgClient::*fetch)(const Request&, const CallOptions&),
                 Response* response) {
  if (int code = SetTimeSpan(verb, from, to, &request); code != kExitOk) return code;
  std::unique_ptr<EsgClient> client = Connect(verb, global);
  if (client == nullptr) return kExitBadArguments;
  absl::StatusOr<Response> fetched = ((*client).*fetch)(request, CallOptions{});
  if (!fetched.ok()) return ReportRpcError(verb, fetched.status(), global);
  *response = *std::move(fetched);
  return kExitOk;
}

// Enum names without the type prefix: "CALIBRATING", "DISTRESS", "STAR_TRACKER_FAULT".
std::string StateName(esg::v1::SessionState state);
std::string SeverityName(esg::v1::AlertSeverity severity);
std::string ReasonName(esg::v1::AlertReason reason);

// An alert reason in words, for tables: "star tracker innovation", "gyro data rejected".
std::string ReasonWords(esg::v1::AlertReason reason);

// The severity a user names (as the proto and docs/service.md do: INFO, WARNING, DISTRESS,
// CRITICAL, any case, or the full ALERT_SEVERITY_... name); nullopt for anything else.
std::optional<esg::v1::AlertSeverity> ParseSeverity(const std::string& name);

// JSON forms: the proto JSON mapping (ProtoToJson of output_format.h).
Json SessionJson(const esg::v1::SessionInfo& session);
Json AttitudeJson(const esg::v1::AttitudeSample& sample);
Json AlertJson(const esg::v1::Alert& alert);

}  // namespace esg::client

#endif  // ESG_CLIENT_COMMANDS_SERVER_COMMON_H_
