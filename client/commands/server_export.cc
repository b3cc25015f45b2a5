// `esg export history|telemetry` (see server_export.h); the history export itself is in
// server_history.cc beside `esg history`, whose CSV columns it shares.
#include "client/commands/server_export.h"

#include <cerrno>
#include <cstdint>
#include <cstdio>
#include <cstring>
#include <memory>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/commands/server_common.h"
#include "client/esg_client.h"
#include "estimator/telemetry.h"
#include "formats/recording_csv.h"
#include "google/protobuf/util/time_util.h"  // Timestamp comparison
#include "proto/convert.h"

namespace esg::client {

std::unique_ptr<OutputFile> OutputFile::Open(const char* verb, const std::string& path) {
  if (path.empty()) return std::unique_ptr<OutputFile>(new OutputFile("", stdout));
  const std::string tmp = path + ".tmp";
  std::FILE* file = std::fopen(tmp.c_str(), "wb");
  if (file == nullptr) {
    ReportBadArgument(
        verb, absl::StrCat("--out ", path, ": cannot create ", tmp, ": ", std::strerror(errno)));
    return nullptr;
  }
  return std::unique_ptr<OutputFile>(new OutputFile(path, file));
}

OutputFile::~OutputFile() {
  if (path_.empty() || committed_) return;
  std::fclose(file_);
  std::remove((path_ + ".tmp").c_str());
}

void OutputFile::Write(const std::string& text) {
  if (failed_ || text.empty()) return;
  if (std::fwrite(text.data(), 1, text.size(), file_) != text.size()) failed_ = true;
}

absl::Status OutputFile::Commit() {
  if (path_.empty()) {
    committed_ = true;
    if (std::fflush(stdout) != 0 || failed_) return absl::UnavailableError("stdout: write failed");
    return absl::OkStatus();
  }
  const std::string tmp = path_ + ".tmp";
  const bool flushed = std::fflush(file_) == 0 && !failed_;
  const int error = errno;
  committed_ = true;
  if (std::fclose(file_) != 0 || !flushed) {
    std::remove(tmp.c_str());
    return absl::UnavailableError(
        absl::StrCat("--out ", path_, ": write failed: ", std::strerror(error)));
  }
  if (std::rename(tmp.c_str(), path_.c_str()) != 0) {
    const int rename_error = errno;
    std::remove(tmp.c_str());
    return absl::UnavailableError(
        absl::StrCat("--out ", path_, ": cannot rename ", tmp, ": ", std::strerror(rename_error)));
  }
  return absl::OkStatus();
}

namespace {

// Frames formatted at a time from the export's spill file.
constexpr int kSpillBatch = 1000;

int RunExportTelemetry(const ExportTelemetryOptions& o, const GlobalOptions& global) {
  constexpr char kVerb[] = "export telemetry";
  esg::v1::ExportTelemetryRequest request;
  request.set_spacecraft_id(o.spacecraft_id);
  if (int code = SetTimeSpan(kVerb, o.from, o.to, &request); code != kExitOk) return code;
  std::unique_ptr<EsgClient> client = Connect(kVerb, global);
  if (client == nullptr) return kExitBadArguments;
  std::unique_ptr<OutputFile> out = OutputFile::Open(kVerb, o.out);
  if (out == nullptr) return kExitBadArguments;

  // The header must name every channel column (`ch:NAME`) any frame of the span carries, which
  // the first chunk cannot tell (docs/formats.md "Channels"): the frames go to an anonymous spill
  // file as they arrive (each checked, its channels noted), and are formatted from it after the
  // stream ends, kSpillBatch at a time, so memory stays at a chunk whatever the span's length.
  std::unique_ptr<ReaderStream<esg::v1::ExportTelemetryResponse>> stream =
      client->ExportTelemetry(request);
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> spill(std::tmpfile(), &std::fclose);
  if (spill == nullptr) {
    stream->Cancel();
    stream->Finish().IgnoreError();
    std::fprintf(stderr, "esg %s: cannot create a temporary file: %s\n", kVerb,
                 std::strerror(errno));
    return kExitFailure;
  }
  esg::v1::ExportTelemetryResponse chunk;
  std::set<std::string> channel_names;
  int64_t frames = 0;
  absl::Time first_time, last_time;
  std::string problem;
  std::string bytes;
  while (problem.empty() && stream->Read(&chunk)) {
    for (const esg::v1::TelemetryFrame& proto : chunk.frames()) {
      absl::StatusOr<estimator::TelemetryFrame> frame = proto_convert::FrameFromProto(proto);
      if (!frame.ok()) {
        problem = absl::StrCat("archived frame (station ", proto.station_id(), ", sequence ",
                               proto.sequence(), ") cannot be written: ", frame.status().message());
        break;
      }
      for (const estimator::ChannelValue& c : frame->channels) channel_names.insert(c.name);
      if (frames == 0) first_time = frame->time;
      last_time = frame->time;
      ++frames;
      bytes.clear();
      proto.SerializeToString(&bytes);
      const uint32_t size = static_cast<uint32_t>(bytes.size());
      if (std::fwrite(&size, sizeof size, 1, spill.get()) != 1 ||
          std::fwrite(bytes.data(), 1, bytes.size(), spill.get()) != bytes.size()) {
        problem = absl::StrCat("cannot write the temporary file: ", std::strerror(errno));
        break;
      }
    }
  }
  if (!problem.empty()) {
    stream->Cancel();
    stream->Finish().IgnoreError();  // CANCELLED: the problem above is the reason
    std::fprintf(stderr, "esg %s: %s\n", kVerb, problem.c_str());
    return kExitFailure;
  }
  const absl::Status status = stream->Finish();
  if (!status.ok()) return ReportRpcError(kVerb, status, global);
  if (frames == 0) {
    std::fprintf(stderr, "esg %s: no archived frame of %s in [%s, %s]: nothing written\n", kVerb,
                 o.spacecraft_id.c_str(), o.from.empty() ? "the first" : o.from.c_str(),
                 o.to.empty() ? "the last" : o.to.c_str());
    return kExitFailure;
  }
  const std::vector<std::string> columns(channel_names.begin(), channel_names.end());
  out->Write(storage::FormatRecordingCsvHead({{"spacecraft_id", o.spacecraft_id}}, columns));
  std::rewind(spill.get());
  std::vector<estimator::TelemetryFrame> batch;
  esg::v1::TelemetryFrame proto;
  for (int64_t read = 0; read < frames; ++read) {
    uint32_t size = 0;
    bytes.resize(0);
    if (std::fread(&size, sizeof size, 1, spill.get()) == 1) {
      bytes.resize(size);
      if (std::fread(bytes.data(), 1, size, spill.get()) != size) bytes.clear();
    }
    absl::StatusOr<estimator::TelemetryFrame> frame =
        proto.ParseFromString(bytes) && bytes.size() == size
            ? proto_convert::FrameFromProto(proto)
            : absl::DataLossError("the temporary file reads back short");
    if (!frame.ok()) {
      std::fprintf(stderr, "esg %s: %s\n", kVerb, std::string(frame.status().message()).c_str());
      return kExitFailure;
    }
    batch.push_back(*std::move(frame));
    if (static_cast<int>(batch.size()) == kSpillBatch || read + 1 == frames) {
      out->Write(storage::FormatRecordingCsvRows(batch, columns));
      batch.clear();
    }
  }
  if (absl::Status closed = out->Commit(); !closed.ok()) {
    std::fprintf(stderr, "esg %s: %s\n", kVerb, std::string(closed.message()).c_str());
    return kExitFailure;
  }
  std::fprintf(stderr, "%s: %lld frames (%s .. %s) written to %s\n", o.spacecraft_id.c_str(),
               static_cast<long long>(frames), FormatUtc(first_time).c_str(),
               FormatUtc(last_time).c_str(),
               o.out.c_str());
  return kExitOk;
}

}  // namespace

void RegisterExport(CLI::App& app, GlobalOptions& global, int* exit_code) {
  CLI::App* cmd =
      app.add_subcommand("export",
                         "write a spacecraft's stored history or archived telemetry to a file "
                         "(ExportCoefficientHistory, ExportTelemetry)");
  cmd->require_subcommand(1);
  cmd->fallthrough();

  auto history = std::make_shared<ExportHistoryOptions>();
  CLI::App* history_cmd = cmd->add_subcommand(
      "history", "the stored drift-coefficient history, every snapshot, as CSV or JSON");
  history_cmd->add_option("--spacecraft", history->spacecraft_id, "spacecraft id")->required();
  history_cmd->add_option("--gyro", history->gyro_id, "gyro id 1..4 (default 0: all)");
  history_cmd->add_option("--from", history->from, "first measurement time, RFC 3339 UTC");
  history_cmd->add_option("--to", history->to, "last measurement time (inclusive), RFC 3339 UTC");
  history_cmd
      ->add_option("--out", history->out,
                   "file to write (written as FILE.tmp, renamed when complete); "
                   "default: stdout")
      ->type_name("FILE");
  history_cmd
      ->add_option("-o,--format", history->format,
                   "csv: the columns of esg history --csv with 17 significant digits; json: "
                   "{\"snapshots\": [...]} in the proto JSON mapping")
      ->type_name("csv|json")
      ->capture_default_str();
  history_cmd->add_flag("--include-revised", history->include_revised,
                        "also the snapshots a re-run over a late frame superseded (CSV: a last "
                        "column revised_time_utc)");
  history_cmd->callback(
      [history, &global, exit_code] { *exit_code = RunExportHistory(*history, global); });

  auto telemetry = std::make_shared<ExportTelemetryOptions>();
  CLI::App* telemetry_cmd = cmd->add_subcommand(
      "telemetry",
      "the archived frames as a recording CSV (version 1) that esg calibrate --recording reads");
  telemetry_cmd->add_option("--spacecraft", telemetry->spacecraft_id, "spacecraft id")->required();
  telemetry_cmd->add_option("--from", telemetry->from,
                            "first measurement time, RFC 3339 UTC (default: the first frame)");
  telemetry_cmd->add_option("--to", telemetry->to,
                            "last measurement time (inclusive), RFC 3339 UTC (default: the last "
                            "frame)");
  telemetry_cmd
      ->add_option("--out", telemetry->out,
                   "recording CSV to write (written as FILE.tmp, renamed when complete)")
      ->type_name("FILE")
      ->required();
  telemetry_cmd->callback(
      [telemetry, &global, exit_code] { *exit_code = RunExportTelemetry(*telemetry, global); });
}

}  // namespace esg::client
