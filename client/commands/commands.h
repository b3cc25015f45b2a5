// The `esg` CLI verbs. Each Register* adds one CLI11 subcommand to the app; its callback runs the
// command and stores the process exit code in *exit_code (0 success, 1 runtime failure, 2 bad
// arguments). Output: --format table|json|csv (client/output_format.h), table by default.
#ifndef ESG_CLIENT_COMMANDS_COMMANDS_H_
#define ESG_CLIENT_COMMANDS_COMMANDS_H_

#include <string>

#include "CLI/CLI.hpp"

namespace esg::client {

struct GlobalOptions {
  std::string server = "127.0.0.1:50051";  // --server or $ESG_SERVER, before or after the verb
  // Server verbs only (client/esg_client.h): TLS PEM files and the bearer token (--token or
  // $ESG_TOKEN).
  std::string tls_ca;
  std::string tls_cert;
  std::string tls_key;
  std::string token;
};

void RegisterSimulate(CLI::App& app, GlobalOptions& global, int* exit_code);
void RegisterCalibrate(CLI::App& app, GlobalOptions& global, int* exit_code);
void RegisterGap(CLI::App& app, GlobalOptions& global, int* exit_code);
// `esg diagnose`: of a recording offline, or of a server's archive (Diagnose RPC) with
// --spacecraft.
void RegisterDiagnose(CLI::App& app, GlobalOptions& global, int* exit_code);

// Server verbs (client/commands/server_*.cc, docs/cli.md).
void RegisterConfigure(CLI::App& app, GlobalOptions& global, int* exit_code);
void RegisterReplay(CLI::App& app, GlobalOptions& global, int* exit_code);
void RegisterStatus(CLI::App& app, GlobalOptions& global, int* exit_code);
void RegisterPredict(CLI::App& app, GlobalOptions& global, int* exit_code);
void RegisterAlerts(CLI::App& app, GlobalOptions& global, int* exit_code);
void RegisterHistory(CLI::App& app, GlobalOptions& global, int* exit_code);
// `esg estimates` (GetEstimateHistory).
void RegisterEstimates(CLI::App& app, GlobalOptions& global, int* exit_code);
// `esg diagnoses list|show` (ListDiagnoses).
void RegisterDiagnoses(CLI::App& app, GlobalOptions& global, int* exit_code);
// `esg orbit upload|list` (UploadOrbit, ListOrbits; server_orbits.cc).
void RegisterOrbit(CLI::App& app, GlobalOptions& global, int* exit_code);
// `esg export history|telemetry` (ExportCoefficientHistory, ExportTelemetry; server_export.h).
void RegisterExport(CLI::App& app, GlobalOptions& global, int* exit_code);
// server_operator.cc: `esg model apply` (ApplyDiagnosis) and `esg gyro readmit` (ReadmitGyro).
void RegisterModel(CLI::App& app, GlobalOptions& global, int* exit_code);
void RegisterGyro(CLI::App& app, GlobalOptions& global, int* exit_code);
// `esg __complete spacecraft` (hidden): ids for the bash completion (server_complete.cc).
void RegisterComplete(CLI::App& app, GlobalOptions& global, int* exit_code);

}  // namespace esg::client

#endif  // ESG_CLIENT_COMMANDS_COMMANDS_H_
