// `esg export` (docs/cli.md): the service's export streams written to a file.
//   esg export history --spacecraft ID [--gyro N] [--from T] [--to T] [--out FILE]
//                      [--format csv|json] [--include-revised]
//       the stored coefficient history (ExportCoefficientHistory): CSV with the columns of
//       `esg history --csv`, every value with 17 significant digits (it reads back the same
//       double), or JSON {"snapshots": [...]} in the proto JSON mapping; stdout without --out.
//   esg export telemetry --spacecraft ID [--from T] [--to T] --out FILE
//       the archived frames measured in [from, to) (ExportTelemetry) as a recording CSV,
//       version 1 (docs/formats.md) with `# spacecraft_id: ID`, which `esg calibrate
//       --recording`, `esg replay` and the other offline verbs read. Numbers are written in the
//       shortest form that reads back the same double, so the file holds the archived values
//       exactly; what a recording has no column for is not written: the station and sequence
//       of each frame, and the quaternion of a star-tracker sample flagged invalid.
// A file is written as FILE.tmp and renamed when complete: a failed export leaves no FILE.
// Exit codes: 0 success, 2 bad arguments (the message names the option), 1 a server or file
// failure.
#ifndef ESG_CLIENT_COMMANDS_SERVER_EXPORT_H_
#define ESG_CLIENT_COMMANDS_SERVER_EXPORT_H_

#include <cstdio>
#include <memory>
#include <string>

#include "absl/status/status.h"
#include "client/commands/commands.h"

namespace esg::client {

struct ExportHistoryOptions {
  std::string spacecraft_id;
  int gyro_id = 0;
  std::string from;  // RFC 3339; empty: unbounded
  std::string to;    // RFC 3339, inclusive; empty: unbounded
  std::string out;   // empty: stdout
  std::string format = "csv";
  bool include_revised = false;  // also superseded snapshots; CSV gains revised_time_utc
};

struct ExportTelemetryOptions {
  std::string spacecraft_id;
  std::string from;  // RFC 3339; empty: from the first archived frame
  std::string to;    // RFC 3339, exclusive; empty: to after the last archived frame
  std::string out;
};

// Runs `esg export history`; returns the exit code (server_history.cc).
int RunExportHistory(const ExportHistoryOptions& options, const GlobalOptions& global);

// The output of an export: stdout for an empty path, else PATH.tmp renamed to PATH by Commit.
// An OutputFile destroyed without a successful Commit removes PATH.tmp.
class OutputFile {
 public:
  // nullptr after printing "esg VERB: --out PATH: cannot create ..." (exit 2).
  static std::unique_ptr<OutputFile> Open(const char* verb, const std::string& path);
  ~OutputFile();
  OutputFile(const OutputFile&) = delete;
  OutputFile& operator=(const OutputFile&) = delete;

  // Appends; a failure is remembered and reported by Commit.
  void Write(const std::string& text);
  // Flushes and closes (and renames onto PATH). Unavailable naming the file on a write failure.
  absl::Status Commit();

 private:
  OutputFile(std::string path, std::FILE* file) : path_(std::move(path)), file_(file) {}
  std::string path_;  // empty: stdout
  std::FILE* file_;
  bool failed_ = false;
  bool committed_ = false;
};

}  // namespace esg::client

#endif  // ESG_CLIENT_COMMANDS_SERVER_EXPORT_H_
