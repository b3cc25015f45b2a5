// `esg diagnose`: find the physics a model left out (docs/discovery.md,
// estimator/discovery/diagnose.h). Runs the discovery over a recording with the configuration as
// the user's model, prints the verdict, the findings with their physics and the fit before and
// after (or one JSON document with --json, proto/diagnosis_json.h), and with --out DIR writes a
// Markdown report with gnuplot plots: residuals before and after, held-out attitude error before
// and after (the paper's Fig. 7/8 measure), and where the mismatch sits in time and regime.
// Progress goes to stderr. With --spacecraft instead of --config and --recording, the diagnosis
// runs on the server's archive (Diagnose RPC, client/commands/server_diagnoses.h).
// Exit codes: 0 success, 2 bad arguments or input files, 1 runtime failure.
#include "estimator/discovery/diagnose.h"

#include <unistd.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <fstream>
#include <iostream>
#include <map>
#include <memory>
#include <optional>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "absl/time/time.h"
#include "client/commands/commands.h"
#include "client/commands/server_common.h"
#include "client/commands/server_diagnoses.h"
#include "client/output_format.h"
#include "proto/diagnosis_json.h"
#include "estimator/units.h"
#include "proto/convert.h"
#include "storage/column_mapping.h"
#include "storage/recording_csv.h"

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
};

std::string Utc(absl::Time t) { return FormatUtc(t); }

std::optional<std::vector<disc::Effect>> ParseEffects(const std::string& text) {
  std::vector<disc::Effect> out;
  if (text.empty()) return out;
  const disc::Effect all[] = {
      disc::Effect::kRotorDisplacement,       disc::Effect::kFourthHarmonic,
      disc::Effect::kUnequalStiffness,        disc::Effect::kGyroMisalignment,
      disc::Effect::kStarTrackerMisalignment, disc::Effect::kStarTrackerLatency,
      disc::Effect::kRandomWalkDrift,         disc::Effect::kDriftStep};
  for (absl::string_view part : absl::StrSplit(text, ',', absl::SkipEmpty())) {
    bool found = false;
    for (disc::Effect e : all) {
      if (part == disc::EffectId(e)) {
        out.push_back(e);
        found = true;
      }
    }
    if (!found) return std::nullopt;
  }
  return out;
}

// Progress: "diagnose:  42% round 1: rotor_displacement[2] fitted (3/12)", a line per stage
// (in place on a terminal).
class StageProgress {
 public:
  StageProgress() : tty_(::isatty(STDERR_FILENO) == 1) {}
  void operator()(double fraction, const std::string& stage) {
    if (stage == last_stage_) return;
    last_stage_ = stage;
    if (tty_) {
      std::fprintf(stderr, "\r\033[Kdiagnose: %3.0f%% %s", 100.0 * fraction, stage.c_str());
      if (fraction >= 1.0) std::fprintf(stderr, "\n");
    } else {
      std::fprintf(stderr, "diagnose: %3.0f%% %s\n", 100.0 * fraction, stage.c_str());
    }
    std::fflush(stderr);
  }

 private:
  bool tty_;
  std::string last_stage_;
};

void PrintHuman(const disc::DiagnosisReport& r) {
  std::printf("verdict: %s\n", r.verdict.c_str());
  for (size_t i = 0; i < r.findings.size(); ++i) {
    const disc::Finding& f = r.findings[i];
    std::printf("%zu. %s%s: %s\n", i + 1, f.effect.c_str(),
                f.gyro > 0 ? absl::StrCat(" (gyro ", f.gyro, ")").c_str() : "",
                f.explanation.c_str());
    for (const std::string& n : f.evidence.notes) std::printf("     - %s\n", n.c_str());
  }
  const disc::Mismatch& m = r.mismatch;
  if (m.span >= 0) {
    std::printf(
        "mismatch of the configured model: %s, %s - %s (%s), residual RMS %.1f arcsec "
        "against %.1f expected (p = %.2g, %s)\n",
        m.gyro > 0 ? absl::StrCat("gyro ", m.gyro).c_str() : "all gyros", Utc(m.start).c_str(),
        Utc(m.end).c_str(), m.regime.c_str(), m.size_arcsec, m.expected_arcsec, m.p_value,
        m.source.c_str());
  }
  std::printf("fit before: residual RMS %.2f arcsec, held-out drift rate %.4f deg/h (%s)\n",
              r.before.residual_rms_arcsec, r.before.gap_drift_rate_deg_h, r.before.model.c_str());
  std::printf("fit after:  residual RMS %.2f arcsec, held-out drift rate %.4f deg/h (%s)\n",
              r.after.residual_rms_arcsec, r.after.gap_drift_rate_deg_h, r.after.model.c_str());
  std::printf("%d frames, %zu regime spans, %d filter runs\n", r.frames, r.regimes.size(),
              r.filter_runs);
}

bool WriteFile(const std::filesystem::path& path, const std::string& text) {
  std::ofstream out(path);
  out << text;
  return static_cast<bool>(out);
}

// Gnuplot data and script; returns the Markdown report text.
std::string WritePlots(const disc::DiagnosisReport& r, const std::filesystem::path& dir,
                       bool& plotted) {
  // Data files.
  auto residuals = [&](const std::vector<disc::ResidualPoint>& v, const std::string& name) {
    std::map<int, std::ostringstream> by_gyro;
    for (const auto& p : v)
      by_gyro[p.gyro] << absl::StrFormat("%.5f %.3f\n", p.hours, p.residual_arcsec);
    std::string text;
    for (int id : r.gyros) {
      absl::StrAppend(&text, "# gyro ", id, "\n", by_gyro[id].str(), "\n\n");
    }
    WriteFile(dir / name, text);
  };
  residuals(r.residuals_before, "residuals_before.dat");
  residuals(r.residuals_after, "residuals_after.dat");
  auto held = [&](const std::vector<disc::HeldOutPoint>& v, const std::string& name) {
    std::string text;
    int gap = -1;
    for (const auto& p : v) {
      if (p.gap != gap && gap >= 0) text += "\n\n";
      gap = p.gap;
      absl::StrAppend(&text, absl::StrFormat("%.5f %.4f\n", p.hours,
                                             estimator::ArcsecToRad(p.error_arcsec) /
                                                 estimator::kRadPerArcmin));
    }
    WriteFile(dir / name, text);
  };
  held(r.held_out_before, "held_out_before.dat");
  held(r.held_out_after, "held_out_after.dat");
  std::string regimes_dat;
  for (const auto& s : r.regimes) {
    const double a = absl::ToDoubleHours(s.start - r.first_frame_time);
    const double b = absl::ToDoubleHours(s.end - r.first_frame_time);
    const double rate = estimator::RadToDeg(s.mean_rate);
    absl::StrAppend(&regimes_dat, absl::StrFormat("%.5f %.6f %d\n%.5f %.6f %d\n\n", a, rate,
                                                  static_cast<int>(s.regime) + 1, b, rate,
                                                  static_cast<int>(s.regime) + 1));
  }
  WriteFile(dir / "regimes.dat", regimes_dat);

  // Shaded spans: held-out gaps (grey) and the mismatch (red).
  std::string objects;
  int object = 1;
  for (const auto& g : r.before.gaps) {
    absl::StrAppend(&objects,
                    absl::StrFormat("set object %d rect from %.4f, graph 0 to %.4f, graph 1 fc rgb "
                                    "'#dddddd' fs solid 0.5 noborder behind\n",
                                    object++, absl::ToDoubleHours(g.start - r.first_frame_time),
                                    absl::ToDoubleHours(g.end - r.first_frame_time)));
  }
  if (r.mismatch.span >= 0) {
    absl::StrAppend(
        &objects,
        absl::StrFormat("set object %d rect from %.4f, graph 0 to %.4f, graph 1 fc rgb '#ffcccc' "
                        "fs solid 0.6 noborder behind\n",
                        object++, absl::ToDoubleHours(r.mismatch.start - r.first_frame_time),
                        absl::ToDoubleHours(r.mismatch.end - r.first_frame_time)));
  }
  std::string gp = "set terminal pngcairo size 1200,800 font ',10'\nset grid\n";
  absl::StrAppend(&gp, "set output 'residuals.png'\nset multiplot layout 2,1\n", objects,
                  "set ylabel 'star-tracker residual, arcsec'\nset title 'Before: ", r.before.model,
                  "'\n", "set logscale y\n");
  std::vector<std::string> plots;
  for (size_t k = 0; k < r.gyros.size(); ++k) {
    plots.push_back(absl::StrFormat(
        "'residuals_before.dat' index %d using 1:2 with points pt 7 ps 0.3 title 'gyro %d'", k,
        r.gyros[k]));
  }
  absl::StrAppend(&gp, "plot ", absl::StrJoin(plots, ", "), "\n");
  plots.clear();
  for (size_t k = 0; k < r.gyros.size(); ++k) {
    plots.push_back(absl::StrFormat(
        "'residuals_after.dat' index %d using 1:2 with points pt 7 ps 0.3 title 'gyro %d'", k,
        r.gyros[k]));
  }
  absl::StrAppend(&gp, "set title 'After: ", r.after.model, "'\nset xlabel 'time, h'\nplot ",
                  absl::StrJoin(plots, ", "), "\nunset multiplot\nunset logscale y\n");
  absl::StrAppend(
      &gp,
      "set output 'held_out.png'\nset title 'Held-out attitude error against the withheld star "
      "tracker "
      "(grey: held-out spans)'\nset xlabel 'time, h'\nset ylabel 'attitude error, arcmin'\n");
  const bool have_before = !r.held_out_before.empty(), have_after = !r.held_out_after.empty();
  if (have_before || have_after) {
    std::vector<std::string> hp;
    if (have_before)
      hp.push_back(
          absl::StrFormat("'held_out_before.dat' using 1:2 with lines lw 2 lc rgb '#cc3333' title "
                          "'before (%.4f deg/h)'",
                          r.before.gap_drift_rate_deg_h));
    if (have_after)
      hp.push_back(
          absl::StrFormat("'held_out_after.dat' using 1:2 with lines lw 2 lc rgb '#3366cc' title "
                          "'after (%.4f deg/h)'",
                          r.after.gap_drift_rate_deg_h));
    absl::StrAppend(&gp, "plot ", absl::StrJoin(hp, ", "), "\n");
  } else {
    absl::StrAppend(&gp,
                    "set label 1 'no held-out span' at graph 0.4, graph 0.5\nplot [0:1] NaN "
                    "notitle\nunset label 1\n");
  }
  absl::StrAppend(
      &gp,
      "set output 'regimes.png'\nset title 'Attitude regimes from the body rate (red: mismatch of "
      "the "
      "configured model)'\nset ylabel 'body rate, deg/s'\nset xlabel 'time, h'\n",
      "plot 'regimes.dat' using 1:2:3 with lines lw 4 lc variable notitle, "
      "NaN with lines lw 4 lt 1 title 'inertial hold', NaN with lines lw 4 lt 2 title 'orbital', "
      "NaN with lines lw 4 lt 3 title 'rotation', NaN with lines lw 4 lt 4 title 'slew'\n");
  WriteFile(dir / "plots.gp", gp);
  const std::string command =
      absl::StrCat("cd '", dir.string(), "' && gnuplot plots.gp > gnuplot.log 2>&1");
  plotted = std::system(command.c_str()) == 0;

  // Markdown.
  std::string md = absl::StrCat("# Diagnosis: ", r.verdict, "\n\n");
  absl::StrAppend(
      &md, absl::StrFormat("Recording: %d frames from %s; running gyros %s; %d filter runs.\n\n",
                           r.frames, Utc(r.first_frame_time), absl::StrJoin(r.gyros, ", "),
                           r.filter_runs));
  absl::StrAppend(&md, "## Findings\n\n");
  if (r.findings.empty())
    absl::StrAppend(&md, "None: the configured model explains the recording.\n\n");
  for (size_t i = 0; i < r.findings.size(); ++i) {
    const disc::Finding& f = r.findings[i];
    absl::StrAppend(&md, absl::StrFormat("%d. **%s**%s: %s\n", i + 1, f.effect,
                                         f.gyro > 0 ? absl::StrCat(" (gyro ", f.gyro, ")") : "",
                                         f.explanation));
    for (const std::string& n : f.evidence.notes) absl::StrAppend(&md, "   - ", n, "\n");
    if (!f.parameters.empty()) {
      absl::StrAppend(&md, "\n   | parameter | value | 1-sigma | unit |\n   |---|---|---|---|\n");
      for (const auto& p : f.parameters) {
        absl::StrAppend(
            &md, absl::StrFormat("   | %s | %.5g | %s | %s |\n", p.name, p.value,
                                 p.sigma > 0 ? absl::StrFormat("%.2g", p.sigma) : "", p.unit));
      }
    }
    absl::StrAppend(&md, "\n");
  }
  const disc::Mismatch& m = r.mismatch;
  absl::StrAppend(&md, "## Where the configured model and the recording disagree\n\n");
  if (m.span >= 0) {
    absl::StrAppend(
        &md, absl::StrFormat("%s, %s to %s (%s span): star-tracker residual RMS %.1f arcsec "
                             "against %.1f arcsec expected "
                             "(p = %.2g, from %s); lag-1 autocorrelation %.2f.\n\n",
                             m.gyro > 0 ? absl::StrCat("Gyro ", m.gyro) : "All gyros", Utc(m.start),
                             Utc(m.end), m.regime, m.size_arcsec, m.expected_arcsec, m.p_value,
                             m.source, m.lag1_autocorrelation));
  }
  absl::StrAppend(&md, "![regimes](regimes.png)\n\n## Fit before and after\n\n",
                  "| | model | residual RMS, arcsec | held-out drift rate, deg/h | dispersion | "
                  "held-out NEES | held-out -2 log predictive density |\n",
                  "|---|---|---|---|---|---|---|\n");
  for (const auto& [name, f] :
       {std::pair<const char*, const disc::FitSummary*>{"before", &r.before},
        {"after", &r.after}}) {
    absl::StrAppend(&md, absl::StrFormat("| %s | %s | %.2f | %.4f | %.3f | %.1f / %d | %.1f |\n",
                                         name, f->model, f->residual_rms_arcsec,
                                         f->gap_drift_rate_deg_h, f->dispersion, f->held_out_nees,
                                         f->held_out_dof, f->held_out_deviance));
  }
  absl::StrAppend(
      &md, "\nHeld-out spans (star tracker withheld, model predicting):\n\n",
      "| span | regime | drift rate before, deg/h | after, deg/h |\n|---|---|---|---|\n");
  for (size_t k = 0; k < r.before.gaps.size(); ++k) {
    const auto& b = r.before.gaps[k];
    const double after = k < r.after.gaps.size() ? r.after.gaps[k].drift_rate_deg_h : 0.0;
    absl::StrAppend(&md, absl::StrFormat("| %s - %s | %s | %.4f | %.4f |\n", Utc(b.start),
                                         Utc(b.end), b.regime, b.drift_rate_deg_h, after));
  }
  absl::StrAppend(
      &md,
      "\n![residuals](residuals.png)\n\n![held-out error](held_out.png)\n\n## Candidates tried\n\n",
      "| round | effect | gyro | time behaviour | k | delta -2 log L | prior cost | evidence 2 ln B "
      "| 1/B | significant | selected |\n",
      "|---|---|---|---|---|---|---|---|---|---|---|\n");
  for (const auto& c : r.candidates) {
    const std::string behaviour =
        c.onset_hours >= 0 ? absl::StrFormat("step at %.2f h", c.onset_hours) : c.time_behaviour;
    absl::StrAppend(
        &md, absl::StrFormat("| %d | %s | %s | %s | %d | %.1f | %.1f | %.1f | %.2g | %s | %s |\n",
                             c.round + 1, c.effect, c.gyro > 0 ? absl::StrCat(c.gyro) : "",
                             behaviour, c.parameters, c.delta_deviance, c.penalty, c.score,
                             c.p_value,
                             c.significant ? "yes" : "", c.selected ? "**yes**" : ""));
  }
  absl::StrAppend(&md,
                  "\n## Regimes\n\n| start | end | regime | rate, deg/s |\n|---|---|---|---|\n");
  for (const auto& s : r.regimes) {
    absl::StrAppend(&md,
                    absl::StrFormat("| %s | %s | %s | %.4f |\n", Utc(s.start), Utc(s.end),
                                    disc::RegimeName(s.regime), estimator::RadToDeg(s.mean_rate)));
  }
  if (!plotted)
    absl::StrAppend(&md,
                    "\n(gnuplot failed or is missing: see gnuplot.log; the data files are beside "
                    "this report.)\n");
  return md;
}

int RunDiagnose(const DiagnoseCliOptions& o) {
  const auto effects = ParseEffects(o.effects);
  if (!effects) {
    std::fprintf(
        stderr,
        "esg: --effects '%s': unknown effect (use rotor_displacement, fourth_harmonic, "
        "unequal_stiffness, gyro_misalignment, star_tracker_misalignment, star_tracker_latency, "
        "random_walk_drift)\n",
        o.effects.c_str());
    return 2;
  }
  auto config = proto_convert::ReadConfigFile(o.config_path);
  if (!config.ok()) {
    std::fprintf(stderr, "esg: --config %s: %s\n", o.config_path.c_str(),
                 std::string(config.status().message()).c_str());
    return 2;
  }
  auto recording = storage::ReadRecording(o.recording_path, o.columns_path);
  if (!recording.ok()) {
    std::fprintf(stderr, "esg: --recording %s: %s\n", o.recording_path.c_str(),
                 std::string(recording.status().message()).c_str());
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
  StageProgress progress;
  auto report = disc::Diagnose(*config, recording->frames, options,
                               [&](double f, const std::string& stage) { progress(f, stage); });
  if (!report.ok()) {
    std::fprintf(stderr, "esg diagnose: %s\n", std::string(report.status().message()).c_str());
    return report.status().code() == absl::StatusCode::kInvalidArgument ? 2 : 1;
  }
  if (!o.out_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(o.out_dir, ec);
    if (ec) {
      std::fprintf(stderr, "esg diagnose: --out %s: %s\n", o.out_dir.c_str(), ec.message().c_str());
      return 1;
    }
    bool plotted = false;
    const std::string md = WritePlots(*report, o.out_dir, plotted);
    if (!WriteFile(std::filesystem::path(o.out_dir) / "report.md", md) ||
        !WriteFile(std::filesystem::path(o.out_dir) / "diagnosis.json",
                   proto_convert::DiagnosisToJson(*report, true))) {
      std::fprintf(stderr, "esg diagnose: --out %s: cannot write the report\n", o.out_dir.c_str());
      return 1;
    }
    if (!plotted)
      std::fprintf(stderr, "esg diagnose: gnuplot failed; see %s/gnuplot.log\n", o.out_dir.c_str());
    std::fprintf(stderr, "diagnose: report written to %s/report.md\n", o.out_dir.c_str());
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
    PrintHuman(*report);
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
    ServerDiagnoseOptions request = server;
    if (model_given) request.model = o.model;  // else the session's model
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
                  "with --spacecraft: end of the span, RFC 3339, exclusive (default: after the "
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
  cmd->callback([o, server, model, &global, exit_code] {
    *exit_code = RunDiagnoseVerb(*o, *server, model->count() > 0, global);
  });
}

}  // namespace esg::client
