// `esg calibrate` and `esg gap`: the estimator run offline over a recording (estimator/offline.h).
// calibrate prints per gyro the final coefficients and their 1-sigma in the configuration's JSON
// keys, the configured basis terms (drift terms beyond eq. (1)/(10)) with their values and 1-sigma
// in deg/h per JSON unit of their regressor, the misalignments in arcsec, the rejections by kind
// and the events; gap calibrates up to a time, runs autonomously to the end and reports the
// attitude error against the withheld star tracker and its growth rate (the paper's Fig. 7/8
// measure).
// Exit codes: 0 success, 2 bad arguments or input files, 1 runtime failure.
#include <algorithm>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "client/commands/commands.h"
#include "client/output_format.h"
#include "client/progress.h"
#include "estimator/basis_term.h"
#include "estimator/calibration_model.h"
#include "estimator/channels.h"
#include "estimator/frame_gap.h"
#include "estimator/model_terms.h"
#include "estimator/offline.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"
#include "formats/column_mapping.h"
#include "formats/recording_csv.h"
#include "nlohmann/json.hpp"
#include "proto/convert.h"

namespace esg::client {
namespace {

using estimator::RadPerSecToDegPerHour;
using estimator::RadToArcmin;
using estimator::RadToArcsec;
using json = nlohmann::ordered_json;

struct Inputs {
  estimator::SpacecraftConfig config;
  estimator::Recording recording;
  estimator::SessionOptions options;
};

struct CommonOptions {
  std::string config_path;
  std::string recording_path;
  std::string columns_path;
  std::string model = "10+11";
  std::optional<double> kd;
  int consistency_window = 60;
  OutputFormat format = OutputFormat::kTable;
};

void AddCommon(CLI::App* cmd, CommonOptions& o) {
  cmd->add_option("--config", o.config_path, "spacecraft configuration JSON (docs/formats.md)")
      ->required();
  cmd->add_option("--recording", o.recording_path, "recording CSV (docs/formats.md)")->required();
  cmd->add_option("--columns", o.columns_path,
                  "column mapping JSON: read --recording as a CSV export with other column "
                  "names, units, quaternion order or time format (docs/formats.md)");
  cmd->add_option("--model", o.model, "drift model: 1, 10, 11 or a '+' set such as 10+11")
      ->capture_default_str();
  cmd->add_option("--kd", o.kd, "k_d of the innovation test, eq. (14) (default: configuration, 5)");
  cmd->add_option("--consistency-window", o.consistency_window,
                  "measurement steps per window of the model-consistency test (chi-square of "
                  "the innovations)")
      ->capture_default_str();
  AddFormatOption(cmd, &o.format);
}

// Loads and checks the inputs; prints the problem and returns nullopt on bad input.
std::optional<Inputs> Load(const CommonOptions& o) {
  Inputs in;
  auto config = proto_convert::ReadConfigFile(o.config_path);
  if (!config.ok()) {
    std::fprintf(stderr, "esg: --config %s: %s\n", o.config_path.c_str(),
                 std::string(config.status().message()).c_str());
    return std::nullopt;
  }
  in.config = *config;
  if (o.kd.has_value()) {
    if (!(*o.kd > 0.0)) {
      std::fprintf(stderr, "esg: --kd: must be > 0, got %g\n", *o.kd);
      return std::nullopt;
    }
    in.config.filter.innovation_kd = *o.kd;
  }
  auto model = estimator::ParseModel(o.model);
  if (!model.ok()) {
    std::fprintf(stderr, "esg: --%s\n", std::string(model.status().message()).c_str());
    return std::nullopt;
  }
  in.options.model = *model;
  if (o.consistency_window < 4) {
    std::fprintf(stderr, "esg: --consistency-window: must be >= 4 steps, got %d\n",
                 o.consistency_window);
    return std::nullopt;
  }
  in.options.consistency_window_steps = o.consistency_window;
  in.options.consistency_test_every_steps = o.consistency_window / 4;
  auto recording = storage::ReadRecording(
      o.recording_path, o.columns_path,
      // The limit esgd applies at ingest: one absurd time tag would keep the filter busy for
      // hours integrating across the gap (estimator/frame_gap.h).
      storage::RecordingReadOptions{.max_row_gap = estimator::kMaxFrameGap});
  if (!recording.ok()) {
    std::fprintf(stderr, "esg: --recording %s: %s\n", o.recording_path.c_str(),
                 std::string(recording.status().message()).c_str());
    return std::nullopt;
  }
  if (recording->frames.empty()) {
    std::fprintf(stderr, "esg: --recording %s: no frames\n", o.recording_path.c_str());
    return std::nullopt;
  }
  // Every channel declared by --config and within its range, as esgd checks at ingest.
  if (absl::Status channels =
          estimator::CheckRecordingChannels(recording->frames, in.config.channels);
      !channels.ok()) {
    std::fprintf(stderr, "esg: --recording %s: %s\n", o.recording_path.c_str(),
                 std::string(channels.message()).c_str());
    return std::nullopt;
  }
  in.recording = std::move(*recording);
  return in;
}

json Vec(const Eigen::Vector3d& v, double scale) {
  return json::array({v.x() * scale, v.y() * scale, v.z() * scale});
}

const double kDegH = RadPerSecToDegPerHour(1.0);
const double kArcsec = RadToArcsec(1.0);

// The coefficients as the configuration JSON writes them (deg/h, docs/formats.md): every term of
// estimator/model_terms.h keyed, {"coefficients": [{"term": "k0", "valueDegH": ...}, ...]}.
json ModelJson(const estimator::DriftCoefficients& c) {
  const estimator::DriftVector theta = c.AsVector();
  json keyed = json::array();
  for (const estimator::FixedTermDescriptor& term : estimator::kFixedTerms) {
    keyed.push_back(json{{"term", std::string(term.storage_key)},
                         {"valueDegH", theta(term.theta_index) * kDegH}});
  }
  return json{{"coefficients", keyed}};
}

// The gyro's basis terms as the configuration JSON writes them (deg/h per JSON unit of s), with
// their labels and 1-sigma (0: held).
json BasisTermsJson(const estimator::GyroEstimate& g) {
  json terms = json::array();
  for (size_t k = 0; k < g.basis_terms.size(); ++k) {
    const estimator::BasisTerm& t = g.basis_terms[k];
    const double to_json = estimator::BasisValueToJson(t.kind);
    const double sigma = k < g.basis_sigma.size() ? g.basis_sigma[k] : 0.0;
    terms.push_back(json{{"label", estimator::BasisTermLabel(t)},
                         {"kind", std::string(estimator::BasisKindName(t.kind))},
                         {"axis", t.axis},
                         {"valueDegH", t.value * to_json},
                         {"sigmaDegH", sigma * to_json},
                         {"unitOfS", std::string(estimator::BasisScalarJsonUnit(t.kind))},
                         {"estimated", sigma > 0.0}});
  }
  return terms;
}

// The model-consistency monitor's verdict from the run's MODEL_INCONSISTENT events
// (estimator/consistency_monitor.h).
struct Consistency {
  int failing_tests = 0;
  const estimator::Event* first = nullptr;
  const estimator::Event* worst = nullptr;  // largest value / threshold
};

Consistency ConsistencyOf(const estimator::CalibrationResult& r) {
  Consistency c;
  for (const estimator::Event& e : r.events) {
    if (e.kind != estimator::Event::Kind::kModelInconsistent) continue;
    ++c.failing_tests;
    if (c.first == nullptr) c.first = &e;
    if (c.worst == nullptr || e.value / e.threshold > c.worst->value / c.worst->threshold) {
      c.worst = &e;
    }
  }
  return c;
}

json ConsistencyJson(const Inputs& in, const estimator::CalibrationResult& r) {
  const Consistency c = ConsistencyOf(r);
  int widenings = 0;
  for (const estimator::Event& e : r.events) {
    widenings += e.kind == estimator::Event::Kind::kFilterWidened ? 1 : 0;
  }
  json doc{{"consistent", c.failing_tests == 0 && widenings == 0},
           {"windowSteps", in.options.consistency_window_steps},
           {"failingTests", c.failing_tests},
           {"widenedWindows", widenings},
           {"widenedDriftDegHAtEnd", r.widened_drift_deg_h}};
  if (c.first != nullptr) {
    doc["firstTime"] = FormatUtc(c.first->time);
    doc["value"] = c.first->value;
    doc["threshold"] = c.first->threshold;
    doc["worstValue"] = c.worst->value;
    doc["worstThreshold"] = c.worst->threshold;
    doc["message"] = c.first->message;
  }
  return doc;
}

json CalibrationJson(const Inputs& in, const estimator::CalibrationResult& r) {
  json gyros = json::array();
  for (const estimator::GyroEstimate& g : r.gyros) {
    json rel = json::object();
    for (const auto& [index, ratio] : r.relative_sigma.at(g.id)) {
      rel[estimator::CoefficientName(index)] = ratio;
    }
    gyros.push_back(json{{"id", g.id},
                         {"model", ModelJson(g.coefficients)},
                         {"modelSigma", ModelJson(g.sigma)},
                         {"misalignmentArcsec", Vec(g.misalignment_b, kArcsec)},
                         {"misalignmentSigmaArcsec", Vec(g.misalignment_sigma_b, kArcsec)},
                         {"relativeSigma", rel},
                         {"basisTerms", BasisTermsJson(g)},
                         {"residualDriftDegH", json::array({g.residual_drift.x() * kDegH,
                                                            g.residual_drift.y() * kDegH})},
                         {"faulty", g.faulty}});
    if (g.faulty) {
      gyros.back()["exclusion"] =
          json{{"reason", estimator::ExclusionReasonName(g.exclusion.reason)},
               {"time", FormatUtc(g.exclusion.time)},
               {"value", g.exclusion.value},
               {"threshold", g.exclusion.threshold},
               {"message", g.exclusion.Describe()}};
    }
  }
  json excluded = json::array();
  bool degraded = false;
  for (const estimator::GyroEstimate& g : r.gyros) {
    if (!g.faulty) continue;
    degraded = true;
    excluded.push_back(g.id);
  }
  json counts = json::object();
  for (const auto& [kind, n] : r.event_counts) counts[estimator::EventKindName(kind)] = n;
  json events = json::array();
  for (const estimator::Event& e : r.events) {
    events.push_back(json{{"time", FormatUtc(e.time)},
                          {"kind", estimator::EventKindName(e.kind)},
                          {"subsystem", e.subsystem},
                          {"value", e.value},
                          {"threshold", e.threshold},
                          {"unit", e.unit},
                          {"message", e.message}});
  }
  return json{{"spacecraftId", in.config.spacecraft_id},
              {"model", in.options.model.Name()},
              {"frames", r.frames},
              {"measurementSteps", r.measurement_steps},
              {"starTrackerStepsUsed", r.star_tracker_steps_used},
              {"state", estimator::SessionStateName(r.final_state)},
              {"degraded", degraded},
              {"excludedGyros", excluded},
              {"outputPair", json::array({r.final_attitude.pair[0], r.final_attitude.pair[1]})},
              {"outputValid", r.final_attitude.valid},
              {"innovationRmsArcsec", r.innovation_rms * kArcsec},
              {"modelConsistency", ConsistencyJson(in, r)},
              {"starTrackerLatency", json{{"latencyS", r.star_tracker_latency.latency_s},
                                          {"sigmaS", r.star_tracker_latency.sigma_s},
                                          {"estimated", r.star_tracker_latency.estimated}}},
              {"gyros", gyros},
              {"rejections", counts},
              {"events", events}};
}

void PrintCalibration(const Inputs& in, const estimator::CalibrationResult& r) {
  const auto& frames = in.recording.frames;
  std::printf("%s: model %s, %d frames over %.2f h, %d measurement steps, star tracker used in %d\n",
              in.config.spacecraft_id.c_str(), in.options.model.Name().c_str(), r.frames,
              absl::ToDoubleHours(frames.back().time - frames.front().time), r.measurement_steps,
              r.star_tracker_steps_used);
  std::printf("state %s%s, output pair [%d,%d], star-tracker innovation RMS %.2f arcsec\n",
              estimator::SessionStateName(r.final_state),
              std::any_of(r.gyros.begin(), r.gyros.end(),
                          [](const estimator::GyroEstimate& g) { return g.faulty; })
                  ? " (degraded: a gyro excluded, output from a clean pair)"
                  : "",
              r.final_attitude.pair[0], r.final_attitude.pair[1], r.innovation_rms * kArcsec);
  if (const Consistency c = ConsistencyOf(r); c.first != nullptr) {
    std::printf(
        "MODEL INCONSISTENT with the data: innovation chi-square over %d-step windows %.1f > %.1f "
        "first at %s (%d failing tests, worst %.1f > %.1f); run esg diagnose to find what the "
        "model leaves out\n",
        in.options.consistency_window_steps, c.first->value, c.first->threshold,
        FormatUtc(c.first->time).c_str(), c.failing_tests, c.worst->value, c.worst->threshold);
  }
  int widenings = 0;
  const estimator::Event* first_widening = nullptr;
  for (const estimator::Event& e : r.events) {
    if (e.kind != estimator::Event::Kind::kFilterWidened) continue;
    if (first_widening == nullptr) first_widening = &e;
    ++widenings;
  }
  if (first_widening != nullptr) {
    std::printf(
        "FILTER WIDENED: the star-tracker innovations exceeded what the configured model allows "
        "(first at %s, %d windows widened or kept widened; at the end as an unmodelled drift of "
        "%.3g deg/h): the model does not explain the data; run esg diagnose\n",
        FormatUtc(first_widening->time).c_str(), widenings, r.widened_drift_deg_h);
  }
  if (ConsistencyOf(r).first == nullptr && first_widening == nullptr) {
    std::printf("model consistent with the data (innovation chi-square over %d-step windows)\n",
                in.options.consistency_window_steps);
  }
  if (r.star_tracker_latency.estimated) {
    std::printf("star-tracker latency %+.4f +- %.4f s (estimated; prior %+.4f +- %.4f s)\n",
                r.star_tracker_latency.latency_s, r.star_tracker_latency.sigma_s,
                in.config.star_tracker.latency, in.config.star_tracker.latency_sigma);
  } else if (r.star_tracker_latency.latency_s != 0.0) {
    std::printf("star-tracker latency %+.4f s (configured, held)\n", r.star_tracker_latency.latency_s);
  }
  for (const estimator::GyroEstimate& g : r.gyros) {
    std::printf("gyro %d%s\n", g.id, g.faulty ? " (faulty, excluded)" : "");
    if (g.faulty) std::printf("  excluded: %s\n", g.exclusion.Describe().c_str());
    auto row = [&](const char* name, double v, double s, int index) {
      double ratio = -1;
      for (const auto& [i, q] : r.relative_sigma.at(g.id)) {
        if (i == index) ratio = q;
      }
      if (s > 0) {
        std::printf("  %-10s %+9.5f +- %.5f deg/h   sqrt(P/P0) %.3f\n", name, v * kDegH, s * kDegH, ratio);
      } else if (v != 0.0) {
        std::printf("  %-10s %+9.5f (held)\n", name, v * kDegH);
      }
    };
    const auto theta = g.coefficients.AsVector();
    const auto sigma = g.sigma.AsVector();
    for (int i = 0; i < estimator::kNumDriftCoefficients; ++i) {
      row(estimator::CoefficientName(i), theta(i), sigma(i), i);
    }
    for (size_t k = 0; k < g.basis_terms.size(); ++k) {
      const double sigma = k < g.basis_sigma.size() ? g.basis_sigma[k] : 0.0;
      std::printf("%s\n", BasisTermLine(g.basis_terms[k], sigma).c_str());
    }
    std::printf("  misalignment [%+.1f %+.1f %+.1f] +- [%.1f %.1f %.1f] arcsec (body axes)\n",
                g.misalignment_b.x() * kArcsec, g.misalignment_b.y() * kArcsec,
                g.misalignment_b.z() * kArcsec, g.misalignment_sigma_b.x() * kArcsec,
                g.misalignment_sigma_b.y() * kArcsec, g.misalignment_sigma_b.z() * kArcsec);
  }
  std::printf("rejections and switches:");
  if (r.event_counts.empty()) std::printf(" none");
  for (const auto& [kind, n] : r.event_counts) std::printf(" %s %d", estimator::EventKindName(kind), n);
  std::printf("\n");
  const size_t shown = std::min<size_t>(r.events.size(), 20);
  for (size_t i = 0; i < shown; ++i) {
    const auto& e = r.events[i];
    std::printf("  %s %-24s %-18s %.1f > %.1f %s\n", FormatUtc(e.time).c_str(),
                estimator::EventKindName(e.kind), e.subsystem.c_str(), e.value, e.threshold,
                e.unit.c_str());
  }
  if (r.events.size() > shown) std::printf("  ... and %zu more (--json lists all)\n", r.events.size() - shown);
}

int RunCalibrate(const CommonOptions& o) {
  auto in = Load(o);
  if (!in) return 2;
  Progress progress("calibrate");
  auto result = estimator::RunCalibration(in->config, in->options, in->recording.frames,
                                          [&](double f) { progress(f); });
  if (!result.ok()) {
    std::fprintf(stderr, "esg calibrate: %s\n", std::string(result.status().message()).c_str());
    return result.status().code() == absl::StatusCode::kInternal ? 1 : 2;
  }
  if (o.format == OutputFormat::kJson) {
    PrintJson(CalibrationJson(*in, *result));
  } else if (o.format == OutputFormat::kCsv) {
    // One row per gyro, with the run's identity; the events are in the JSON form.
    const Json doc = CalibrationJson(*in, *result);
    std::vector<Json> rows;
    for (const Json& gyro : doc["gyros"]) {
      Json row{{"spacecraftId", doc["spacecraftId"]}, {"model", doc["model"]},
               {"state", doc["state"]}};
      for (const auto& [key, value] : gyro.items()) row[key] = value;
      rows.push_back(row);
    }
    PrintCsv(rows, {"spacecraftId", "model", "state", "id"});
  } else {
    PrintCalibration(*in, *result);
  }
  return 0;
}

// --gap-start: hours from the first frame, or an RFC 3339 time (estimator::ParseUtc, whose
// refusal is completed with the other form).
absl::StatusOr<absl::Time> ParseGapStart(const std::string& text, absl::Time first) {
  double hours = 0.0;
  if (absl::SimpleAtod(text, &hours) && std::isfinite(hours)) {
    return first + absl::Seconds(estimator::HoursToSeconds(hours));
  }
  absl::StatusOr<absl::Time> t = estimator::ParseUtc(text, "--gap-start");
  if (t.ok()) return t;
  return absl::InvalidArgumentError(absl::StrCat(
      t.status().message(), ", nor a number of hours from the first frame (e.g. 1.5)"));
}

struct GapOptions {
  CommonOptions common;
  std::string gap_start;
  std::string series_csv;
};

int RunGap(const GapOptions& o) {
  auto in = Load(o.common);
  if (!in) return 2;
  const auto gap_start = ParseGapStart(o.gap_start, in->recording.frames.front().time);
  if (!gap_start.ok()) {
    std::fprintf(stderr, "esg gap: %s\n", std::string(gap_start.status().message()).c_str());
    return 2;
  }
  Progress progress("gap");
  auto result = estimator::RunGap(in->config, in->options, in->recording.frames, *gap_start,
                                  [&](double f) { progress(f); });
  if (!result.ok()) {
    std::fprintf(stderr, "esg gap: %s\n", std::string(result.status().message()).c_str());
    return result.status().code() == absl::StatusCode::kInternal ? 1 : 2;
  }
  if (!o.series_csv.empty()) {
    std::ofstream out(o.series_csv);
    out << "time_utc,hours_since_gap,err_x_arcmin,err_y_arcmin,err_z_arcmin,err_arcmin,"
           "sigma_x_arcmin,sigma_y_arcmin,sigma_z_arcmin\n";
    for (const auto& s : result->samples) {
      out << absl::StrFormat("%s,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f,%.6f\n", FormatUtc(s.time),
                             s.hours_since_gap, RadToArcmin(s.error_in.x()), RadToArcmin(s.error_in.y()),
                             RadToArcmin(s.error_in.z()), RadToArcmin(s.angle), RadToArcmin(s.sigma_b.x()),
                             RadToArcmin(s.sigma_b.y()), RadToArcmin(s.sigma_b.z()));
    }
    if (!out) {
      std::fprintf(stderr, "esg gap: --series-csv %s: cannot write\n", o.series_csv.c_str());
      return 1;
    }
  }
  const double rate_deg_h = RadPerSecToDegPerHour(result->drift_rate);
  if (o.common.format == OutputFormat::kCsv) {
    std::vector<Json> rows;
    for (const auto& s : result->samples) {
      rows.push_back(Json{{"time", FormatUtc(s.time)},
                          {"hours", s.hours_since_gap},
                          {"errorArcmin", Vec(s.error_in, RadToArcmin(1.0))},
                          {"angleArcmin", RadToArcmin(s.angle)},
                          {"sigmaArcmin", Vec(s.sigma_b, RadToArcmin(1.0))}});
    }
    PrintCsv(rows, {"time", "hours"});
  } else if (o.common.format == OutputFormat::kJson) {
    json series = json::array();
    for (const auto& s : result->samples) {
      series.push_back(json{{"time", FormatUtc(s.time)},
                            {"hours", s.hours_since_gap},
                            {"errorArcmin", Vec(s.error_in, RadToArcmin(1.0))},
                            {"angleArcmin", RadToArcmin(s.angle)}});
    }
    json doc{{"spacecraftId", in->config.spacecraft_id},
             {"model", in->options.model.Name()},
             {"gapStart", FormatUtc(*gap_start)},
             {"gapHours", result->gap_hours},
             {"driftRateDegH", rate_deg_h},
             {"slopeDegH", Vec(result->slope_in, RadPerSecToDegPerHour(1.0))},
             {"finalErrorArcmin", RadToArcmin(result->final_error)},
             {"calibration", CalibrationJson(*in, result->calibration)},
             {"series", series}};
    PrintJson(doc);
  } else {
    std::printf("%s: model %s calibrated up to %s, then %.2f h without the star tracker\n",
                in->config.spacecraft_id.c_str(), in->options.model.Name().c_str(),
                FormatUtc(*gap_start).c_str(), result->gap_hours);
    std::printf("drift-caused attitude error rate %.4f deg/h (inertial axes slope [%+.4f %+.4f %+.4f] deg/h)\n",
                rate_deg_h, RadPerSecToDegPerHour(result->slope_in.x()),
                RadPerSecToDegPerHour(result->slope_in.y()), RadPerSecToDegPerHour(result->slope_in.z()));
    std::printf("error at the end of the gap %.2f arcmin\n", RadToArcmin(result->final_error));
    std::printf("   hours   err_x'   err_y'   err_z'  |err|'\n");
    const size_t step = std::max<size_t>(1, result->samples.size() / 24);
    for (size_t i = 0; i < result->samples.size(); i += step) {
      const auto& s = result->samples[i];
      std::printf("  %6.2f %8.3f %8.3f %8.3f %7.3f\n", s.hours_since_gap, RadToArcmin(s.error_in.x()),
                  RadToArcmin(s.error_in.y()), RadToArcmin(s.error_in.z()), RadToArcmin(s.angle));
    }
  }
  return 0;
}

}  // namespace

void RegisterCalibrate(CLI::App& app, GlobalOptions& global, int* exit_code) {
  (void)global;  // offline verb: no server
  auto options = std::make_shared<CommonOptions>();
  CLI::App* cmd = app.add_subcommand("calibrate", "run the EKF over a recording and print the calibrated drift model");
  AddCommon(cmd, *options);
  cmd->callback([options, exit_code] { *exit_code = RunCalibrate(*options); });
}

void RegisterGap(CLI::App& app, GlobalOptions& global, int* exit_code) {
  (void)global;
  auto options = std::make_shared<GapOptions>();
  CLI::App* cmd = app.add_subcommand(
      "gap", "calibrate up to --gap-start, then predict without the star tracker and compare");
  AddCommon(cmd, options->common);
  cmd->add_option("--gap-start", options->gap_start, "RFC 3339 time or hours from the first frame")->required();
  cmd->add_option("--series-csv", options->series_csv, "write the error time series (arcmin) as CSV");
  cmd->callback([options, exit_code] { *exit_code = RunGap(*options); });
}

}  // namespace esg::client
