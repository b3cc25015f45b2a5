// The diagnosis verbs against esgd (docs/cli.md):
//   esg diagnose --spacecraft ID [--from T] [--to T] [--model M]   the Diagnose RPC over the
//       spacecraft's archived telemetry; its progress on stderr as it streams, then the stored
//       diagnosis (id, verdict, span, findings, fit before and after).
//   esg diagnoses list --spacecraft ID      every stored diagnosis (ListDiagnoses, all pages).
//   esg diagnoses show --spacecraft ID --id N   one diagnosis with its full report (GetDiagnosis).
// --format json prints a DiagnosisResult in the proto JSON mapping, except that the report is
// the parsed document under "report" (the same document as the offline `esg diagnose --json`)
// instead of the string "reportJson".
// Exit codes: 0 success, 2 bad arguments, 1 server failure (NOT_FOUND for an unknown spacecraft
// or diagnosis id).
#ifndef ESG_CLIENT_COMMANDS_SERVER_DIAGNOSES_H_
#define ESG_CLIENT_COMMANDS_SERVER_DIAGNOSES_H_

#include <string>

#include "client/commands/commands.h"
#include "client/output_format.h"

namespace esg::client {

struct ServerDiagnoseOptions {
  std::string spacecraft_id;
  std::string from;   // RFC 3339; empty: from the first archived frame
  std::string to;     // RFC 3339; empty: to after the last archived frame
  std::string model;  // empty: the session's model
  double orbital_period_s = 0.0;  // 0: from the recording's orbital-orientation spans
  OutputFormat format = OutputFormat::kTable;
};

// `esg diagnose --spacecraft ID`: runs the Diagnose RPC and prints as above; returns the exit code.
int RunServerDiagnose(const ServerDiagnoseOptions& options, const GlobalOptions& global);

}  // namespace esg::client

#endif  // ESG_CLIENT_COMMANDS_SERVER_DIAGNOSES_H_
