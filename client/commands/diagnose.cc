// `esg diagnose`: find the physics a model left out (docs/discovery.md,
// estimator/discovery/diagnose.h). The command: its options, running the discovery over a
// recording with the configuration as the user's model (or, with --spacecraft, on the server's
// archive: Diagnose RPC, client/commands/server_diagnoses.h), the output and the exit codes. The
// human text is client/diagnosis_text.h, the JSON proto/diagnosis_json.h, and with --out DIR the
// plots client/diagnosis_plots.h and the Markdown report client/diagnosis_markdown.h.
// Progress goes to stderr. Exit codes: 0 success, 2 bad arguments or input files, 1 runtime
// failure.
#include "estimator/discovery/diagnose.h"

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iostream>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "client/commands/server_diagnoses.h"
#include "client/diagnosis_markdown.h"
#include "client/diagnosis_plots.h"
#include "client/diagnosis_text.h"
#include "client/output_format.h"
#include "client/progress.h"
#include "estimator/discovery/apply_findings.h"
#include "estimator/channels.h"
#include "estimator/frame_gap.h"
#include "estimator/orbit.h"
#include "formats/column_mapping.h"
#include "formats/oem.h"
#include "formats/recording_csv.h"
#include "proto/convert.h"
#include "proto/diagnosis_json.h"

namespace esg::client {
namespace {

namespace disc = estimator::discovery;

struct DiagnoseCliOptions {
  std::string config_path;
  std::string recording_path;
  std::string columns_path;
  std::string out_dir;
  OutputFormat format = OutputFormat::kTable;
  std::string model = "10+11";
  double alpha = 0.01;
  int max_effects = 3;
  int threads = 2;
  double integration_rate_hz = 0.2;
  std::string effects;
  double orbital_period_min = 0.0;  // 0: from the recording
  std::string orbit_path;           // CCSDS OEM of the spacecraft's orbit (formats/oem.h)
};

// The orbit of `spacecraft_id` in the OEM at `path`; InvalidArgument "--orbit PATH: line N: ..."
// (storage::ParseOemOrbit's rules), NotFound when the file cannot be read.
absl::StatusOr<std::shared_ptr<const estimator::Orbit>> ReadOrbit(const std::string& path,
                                                                 const std::string& spacecraft_id) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat("--orbit ", path, ": cannot read"));
  std::stringstream buffer;
  buffer << in.rdbuf();
  absl::StatusOr<estimator::Orbit> orbit = storage::ParseOemOrbit(buffer.str(), spacecraft_id);
  if (!orbit.ok()) {
    return absl::InvalidArgumentError(absl::StrCat("--orbit ", path, ": ", orbit.status().message()));
  }
  return std::make_shared<const estimator::Orbit>(*std::move(orbit));
}

std::optional<std::vector<disc::Effect>> ParseEffects(const std::string& text) {
  std::vector<disc::Effect> out;
  if (text.empty()) return out;
  for (absl::string_view part : absl::StrSplit(text, ',', absl::SkipEmpty())) {
    const std::optional<disc::Effect> e = disc::EffectFromId(part);
    if (!e.has_value()) return std::nullopt;
    out.push_back(*e);
  }
  return out;
}

// Every effect id the diagnosis tries (report.h Effect, kLastEffect last), comma-separated.
std::string KnownEffectIds() {
  std::vector<std::string> ids;
  for (int e = 0; e <= static_cast<int>(disc::kLastEffect); ++e) {
    ids.push_back(disc::EffectId(static_cast<disc::Effect>(e)));
  }
  return absl::StrJoin(ids, ", ");
}

bool WriteFile(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  out.close();
  return static_cast<bool>(out);
}

// The report directory: plots (data, script, PNGs), report.md and diagnosis.json; with findings
// that map to configuration, model.json: the configuration with them (estimator/discovery/
// apply_findings.h, the mapping esgd's ApplyDiagnosis applies; for esg calibrate --config).
int WriteReport(const disc::DiagnosisReport& report, const estimator::SpacecraftConfig& config,
                const std::string& out_dir) {
  std::error_code ec;
  std::filesystem::create_directories(out_dir, ec);
  if (ec) {
    std::fprintf(stderr, "esg diagnose: --out %s: %s\n", out_dir.c_str(), ec.message().c_str());
    return 1;
  }
  const std::filesystem::path dir(out_dir);
  auto plots = WriteDiagnosisPlots(report, dir);
  if (!plots.ok()) {
    std::fprintf(stderr, "esg diagnose: --out %s: %s\n", out_dir.c_str(),
                 std::string(plots.status().message()).c_str());
    return 1;
  }
  const bool plotted = RunGnuplot(dir);
  if (!WriteFile(dir / "report.md", DiagnosisMarkdown(report, *plots, plotted)) ||
      !WriteFile(dir / "diagnosis.json", proto_convert::DiagnosisToJson(report, true))) {
    std::fprintf(stderr, "esg diagnose: --out %s: cannot write the report\n", out_dir.c_str());
    return 1;
  }
  const disc::AppliedFindings applied = disc::WithFindings(config, report);
  if (!applied.applied.empty() &&
      !WriteFile(dir / "model.json", proto_convert::ConfigToJson(applied.config) + "\n")) {
    std::fprintf(stderr, "esg diagnose: --out %s: cannot write model.json\n", out_dir.c_str());
    return 1;
  }
  if (!plotted)
    std::fprintf(stderr, "esg diagnose: gnuplot failed; see %s/gnuplot.log\n", out_dir.c_str());
  std::fprintf(stderr, "diagnose: report written to %s/report.md\n", out_dir.c_str());
  return 0;
}

int RunDiagnose(const DiagnoseCliOptions& o) {
  const auto effects = ParseEffects(o.effects);
  if (!effects) {
    std::fprintf(stderr, "esg: --effects '%s': unknown effect (use %s)\n", o.effects.c_str(),
                 KnownEffectIds().c_str());
    return 2;
  }
  auto config = proto_convert::ReadConfigFile(o.config_path);
  if (!config.ok()) {
    std::fprintf(stderr, "esg: --config %s: %s\n", o.config_path.c_str(),
                 std::string(config.status().message()).c_str());
    return 2;
  }
  auto recording = storage::ReadRecording(
      o.recording_path, o.columns_path,
      // The limit esgd applies at ingest: one absurd time tag would keep the filter busy for
      // hours integrating across the gap (estimator/frame_gap.h).
      storage::RecordingReadOptions{.max_row_gap = estimator::kMaxFrameGap});
  if (!recording.ok()) {
    std::fprintf(stderr, "esg: --recording %s: %s\n", o.recording_path.c_str(),
                 std::string(recording.status().message()).c_str());
    return 2;
  }
  // Every channel declared by --config and within its range, as esgd checks at ingest.
  if (absl::Status channels =
          estimator::CheckRecordingChannels(recording->frames, config->channels);
      !channels.ok()) {
    std::fprintf(stderr, "esg: --recording %s: %s\n", o.recording_path.c_str(),
                 std::string(channels.message()).c_str());
    return 2;
  }
  disc::DiagnoseOptions options;
  options.model = o.model;
  options.alpha = o.alpha;
  options.max_effects = o.max_effects;
  options.threads = o.threads;
  // The estimator starts no threads: the CLI lends it --threads, the calling one included.
  options.run_parallel = [](int count, const std::function<void(int)>& task) {
    std::vector<std::thread> helpers;
    for (int i = 1; i < count; ++i) helpers.emplace_back(task, i);
    task(0);
    for (std::thread& t : helpers) t.join();
  };
  options.integration_rate_hz = o.integration_rate_hz;
  options.effects = *effects;
  options.orbital_period_s = 60.0 * o.orbital_period_min;
  if (!o.orbit_path.empty()) {
    absl::StatusOr<std::shared_ptr<const estimator::Orbit>> orbit =
        ReadOrbit(o.orbit_path, config->spacecraft_id);
    if (!orbit.ok()) {
      std::fprintf(stderr, "esg: %s\n", std::string(orbit.status().message()).c_str());
      return 2;
    }
    options.orbit = *std::move(orbit);
    options.orbit_source = absl::StrCat("the OEM file ", o.orbit_path);
  }
  StageProgress progress("diagnose");
  auto report = disc::Diagnose(*config, recording->frames, options,
                               [&](double f, const std::string& stage) { progress(f, stage); });
  if (!report.ok()) {
    std::fprintf(stderr, "esg diagnose: %s\n", std::string(report.status().message()).c_str());
    return report.status().code() == absl::StatusCode::kInvalidArgument ? 2 : 1;
  }
  if (!o.out_dir.empty()) {
    if (const int code = WriteReport(*report, *config, o.out_dir); code != 0) return code;
  }
  if (o.format == OutputFormat::kJson) {
    std::cout << proto_convert::DiagnosisToJson(*report) << "\n";
  } else if (o.format == OutputFormat::kCsv) {
    // One row per finding (one without an effect when there is none).
    const Json doc = proto_convert::DiagnosisJsonValue(*report);
    std::vector<Json> rows;
    for (const Json& f : doc["findings"]) {
      rows.push_back(Json{{"verdict", doc["verdict"]},
                          {"effect", f["effect"]},
                          {"gyro", f.contains("gyro") ? f["gyro"] : Json()},
                          {"explanation", f["explanation"]}});
    }
    if (rows.empty()) rows.push_back(Json{{"verdict", doc["verdict"]}});
    PrintCsv(rows, {"verdict", "effect", "gyro", "explanation"});
  } else {
    std::fputs(DiagnosisText(*report).c_str(), stdout);
  }
  return 0;
}

// Offline over --config and --recording, or on the server's archive with --spacecraft.
int RunDiagnoseVerb(const DiagnoseCliOptions& o, const ServerDiagnoseOptions& server,
                    bool model_given, const GlobalOptions& global) {
  if (!server.spacecraft_id.empty()) {
    if (!o.config_path.empty() || !o.recording_path.empty() || !o.columns_path.empty() ||
        !o.out_dir.empty()) {
      return ReportBadArgument("diagnose",
                               "--spacecraft: diagnoses the server's archive; --config, "
                               "--recording, --columns and --out are for a recording offline");
    }
    if (!o.orbit_path.empty()) {
      return ReportBadArgument("diagnose",
                               "--orbit: read for a recording diagnosed offline (--config, "
                               "--recording); the server takes the orbit it stores (esg orbit "
                               "upload --spacecraft ID --oem FILE)");
    }
    ServerDiagnoseOptions request = server;
    if (model_given) request.model = o.model;  // else the session's model
    request.orbital_period_s = 60.0 * o.orbital_period_min;
    request.format = o.format;
    return RunServerDiagnose(request, global);
  }
  if (!server.from.empty() || !server.to.empty()) {
    return ReportBadArgument("diagnose", "--from/--to: need --spacecraft (the server's archive)");
  }
  if (o.config_path.empty() || o.recording_path.empty()) {
    return ReportBadArgument("diagnose",
                             "--config and --recording: required offline (or --spacecraft ID "
                             "to diagnose the archive of the --server)");
  }
  return RunDiagnose(o);
}

}  // namespace

void RegisterDiagnose(CLI::App& app, GlobalOptions& global, int* exit_code) {
  auto o = std::make_shared<DiagnoseCliOptions>();
  auto server = std::make_shared<ServerDiagnoseOptions>();
  CLI::App* cmd = app.add_subcommand(
      "diagnose",
      "find the physics the configured model leaves out of a recording (docs/discovery.md), "
      "offline or on esgd's archive (--spacecraft; Diagnose)");
  cmd->add_option("--config", o->config_path,
                  "offline: spacecraft configuration JSON (docs/formats.md), the model");
  cmd->add_option("--recording", o->recording_path, "offline: recording CSV (docs/formats.md)");
  cmd->add_option("--spacecraft", server->spacecraft_id,
                  "diagnose this spacecraft's telemetry archived on the --server instead "
                  "(Diagnose RPC; progress on stderr)");
  cmd->add_option("--from", server->from,
                  "with --spacecraft: first measurement time, RFC 3339 (default: the first frame)");
  cmd->add_option("--to", server->to,
                  "with --spacecraft: last measurement time (inclusive), RFC 3339 (default: the "
                  "last frame)");
  cmd->add_option("--columns", o->columns_path,
                  "column mapping JSON: read --recording as a CSV export with other column "
                  "names, units, quaternion order or time format (docs/formats.md)");
  cmd->add_option("--out", o->out_dir,
                  "write report.md, plots (gnuplot) and diagnosis.json into DIR");
  AddFormatOption(cmd, &o->format);
  CLI::Option* model =
      cmd->add_option("--model", o->model,
                      "drift model terms of the configuration: 1, 10, 11 or a '+' set (with "
                      "--spacecraft default: the session's model)")
          ->capture_default_str();
  cmd->add_option("--alpha", o->alpha, "false-finding level per selection round")
      ->capture_default_str()
      ->check(CLI::Range(1e-9, 0.5));
  cmd->add_option("--max-effects", o->max_effects, "forward-selection rounds")
      ->capture_default_str()
      ->check(CLI::Range(1, 7));
  cmd->add_option("--threads", o->threads, "filter runs in parallel")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  cmd->add_option("--integration-rate", o->integration_rate_hz,
                  "filter integration rate during diagnosis, Hz (<= 0: the configuration's)")
      ->capture_default_str();
  cmd->add_option("--effects", o->effects, "comma-separated effect ids to try (default: all)");
  cmd->add_option("--orbital-period", o->orbital_period_min,
                  "the spacecraft's orbital period, minutes, for the orbital-phase terms of the "
                  "open-ended stage (default: the period of the recording's orbital-orientation "
                  "spans; a recording without them has no such terms)")
      ->check(CLI::Range(1.0, 1e5));
  cmd->add_option("--orbit", o->orbit_path,
                  "offline: the spacecraft's orbit, a CCSDS OEM covering the recording "
                  "(docs/formats.md): the sun's illumination is then zero in the Earth's shadow, "
                  "and the orbital-phase terms take its period unless --orbital-period is given");
  cmd->callback([o, server, model, &global, exit_code] {
    *exit_code = RunDiagnoseVerb(*o, *server, model->count() > 0, global);
  });
}

}  // namespace esg::client
