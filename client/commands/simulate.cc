// `esg simulate`: runs the seeded simulator (estimator/simulator.h) for a configuration, an
// attitude profile and an optional scenario (client/scenario.h, docs/scenario.md), and writes the
// recording CSV of docs/formats.md (storage::WriteRecordingCsv). Optionally writes the
// configuration used (--write-config) and the truth (--truth: time, true q_in_b, true h_in per
// gyro, the true coefficients in the metadata) so experiments can compare estimates against it.
// Exit codes: 0 success, 2 bad arguments (missing or bad files, bad values), 1 runtime failure.
#include <unistd.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <iostream>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/time/time.h"
#include "client/commands/commands.h"
#include "client/output_format.h"
#include "client/progress.h"
#include "client/scenario.h"
#include "estimator/model_terms.h"
#include "estimator/orbit.h"
#include "estimator/rotation.h"
#include "estimator/simulator.h"
#include "estimator/units.h"
#include "estimator/utc_time.h"
#include "formats/ccsds_kvn.h"
#include "formats/oem.h"
#include "formats/recording_csv.h"
#include "nlohmann/json.hpp"
#include "proto/convert.h"

namespace esg::client {
namespace {

using estimator::kMaxGyros;

struct SimulateOptions {
  std::string config_path;
  std::string profile;
  std::string scenario_path;
  double hours = 0.0;
  uint64_t seed = 0;
  std::string out_path;
  std::string write_config_path;
  std::string start = "2019-03-01T00:00:00Z";
  double telemetry_step = 60.0;
  double integration_rate_hz = 8.0;
  std::string truth_path;
  std::string orbit_out_path;
  OutputFormat format = OutputFormat::kTable;
};

// The circular orbit of `orbital` (the scenario's orbital elements, orbit.h CircularOrbitState)
// as a CCSDS OEM of `spacecraft_id` (formats/oem.h): states every 60 s from a minute before
// `start` to a minute after `start + duration_s`, so that it covers the whole recording.
absl::StatusOr<std::string> OrbitOem(const estimator::OrbitalOptions& orbital,
                                     const std::string& spacecraft_id, absl::Time start,
                                     double duration_s) {
  std::vector<estimator::OrbitState> states;
  for (double t = -60.0; t <= duration_s + 60.0 + 1e-9; t += 60.0) {
    states.push_back(estimator::CircularOrbitState(orbital.inclination, orbital.raan,
                                                   orbital.period, orbital.arg_latitude0, start, t));
  }
  storage::OemHeader header;
  header.object_name = spacecraft_id;
  header.object_id = spacecraft_id;
  header.creation_date = start;
  header.comments = {absl::StrFormat(
      "circular orbit simulated by esg simulate: inclination %.4g deg, period %.6g min, raan "
      "%.4g deg, argument of latitude %.4g deg at %s",
      estimator::RadToDeg(orbital.inclination), orbital.period / 60.0,
      estimator::RadToDeg(orbital.raan), estimator::RadToDeg(orbital.arg_latitude0),
      storage::FormatCcsdsTime(start))};
  return storage::WriteOem(header, states);
}

std::string Num(double x) { return absl::StrFormat("%.17g", x); }

// Coefficients in deg/h to 15 significant digits (0.015, not 0.014999999999999998).
std::string VecDegH(const Eigen::Vector3d& v) {
  return absl::StrFormat("[%.15g, %.15g, %.15g]", estimator::RadPerSecToDegPerHour(v.x()),
                         estimator::RadPerSecToDegPerHour(v.y()),
                         estimator::RadPerSecToDegPerHour(v.z()));
}

// A setting converted back to its JSON unit, to 15 significant digits (30, not 29.999999999999996).
std::string Num15(double x) { return absl::StrFormat("%.15g", x); }

std::string Vec15(const Eigen::Vector3d& v) {
  return absl::StrCat("[", absl::StrJoin({Num15(v.x()), Num15(v.y()), Num15(v.z())}, ", "), "]");
}

// Whether the rotor displacement changes over the run (a rate, a turn or both): the truth file
// then has its columns.
bool DisplacementVaries(const estimator::GyroEffectsTruth& e) {
  return !e.rotor_displacement_rate_k_m_s.isZero(0.0) || e.rotor_displacement_turn.has_value();
}

// Metadata lines of gyro g's effects beyond the paper's models (docs/scenario.md, "Truth file").
void WriteEffectMetadata(std::ostream& out, int g, const estimator::GyroEffectsTruth& e) {
  const int n = g + 1;
  if (e.orbital_drift) {
    out << absl::StrFormat("# g%d_orbital_drift_amplitude_deg_h: %s\n", n,
                           VecDegH(e.orbital_drift->amplitude_k_rad_s));
    out << absl::StrFormat("# g%d_orbital_drift_period_min: %.15g\n", n,
                           *e.orbital_drift->period_s / estimator::kSecondsPerMinute);
    out << absl::StrFormat("# g%d_orbital_drift_phase_deg: %.15g\n", n,
                           estimator::RadToDeg(e.orbital_drift->phase_rad));
  }
  if (!e.rotor_displacement_rate_k_m_s.isZero(0.0)) {
    out << absl::StrFormat("# g%d_rotor_displacement_rate_um_h: %s\n", n,
                           Vec15(e.rotor_displacement_rate_k_m_s * estimator::kSecondsPerHour /
                               estimator::kMetresPerUm));
  }
  if (e.rotor_displacement_turn) {
    out << absl::StrFormat("# g%d_rotor_displacement_turn_axis: %s\n", n,
                           Vec15(e.rotor_displacement_turn->axis_k));
    out << absl::StrFormat("# g%d_rotor_displacement_turn_period_h: %.15g\n", n,
                           estimator::SecondsToHours(e.rotor_displacement_turn->period_s));
  }
  if (!e.readout_distortion_k.isZero(0.0)) {
    const Eigen::Matrix3d ppm = e.readout_distortion_k / 1e-6;
    out << absl::StrFormat(
        "# g%d_readout_distortion_ppm: [%s]\n", n,
        absl::StrJoin({Num15(ppm(0, 0)), Num15(ppm(1, 1)), Num15(ppm(2, 2)), Num15(ppm(0, 1)),
                       Num15(ppm(1, 2)), Num15(ppm(2, 0))},
                      ", "));
  }
  if (e.switching_drift) {
    out << absl::StrFormat("# g%d_switching_drift_amplitude_deg_h: %s\n", n,
                           VecDegH(e.switching_drift->amplitude_k_rad_s));
    out << absl::StrFormat("# g%d_switching_drift_mean_dwell_h: %.15g\n", n,
                           estimator::SecondsToHours(e.switching_drift->mean_dwell_s));
    out << absl::StrFormat("# g%d_switching_initial_level: %+.0f\n", n,
                           e.switching_initial_level);
    std::vector<std::string> times;
    for (double t : e.switch_times_s) times.push_back(Num(estimator::SecondsToHours(t)));
    out << absl::StrFormat("# g%d_switch_times_h: [%s]\n", n, absl::StrJoin(times, ", "));
  }
  if (e.hidden_driver_drift) {
    out << absl::StrFormat("# g%d_hidden_driver_amplitude_deg_h: %s\n", n,
                           VecDegH(e.hidden_driver_drift->amplitude_k_rad_s));
    out << absl::StrFormat("# g%d_hidden_driver_correlation_h: %.15g\n", n,
                           estimator::SecondsToHours(e.hidden_driver_drift->correlation_time_s));
  }
  if (e.rate_drift) {
    const Eigen::Matrix3d per_deg_s = e.rate_drift->gain_k * estimator::kSecondsPerHour;
    std::vector<std::string> gains;  // row by row, as in the scenario
    for (int i = 0; i < 9; ++i) gains.push_back(Num15(per_deg_s(i / 3, i % 3)));
    out << absl::StrFormat("# g%d_rate_drift_deg_h_per_deg_s: [%s]\n", n,
                           absl::StrJoin(gains, ", "));
  }
  if (e.transient_drift) {
    out << absl::StrFormat("# g%d_transient_drift_amplitude_deg_h: %s\n", n,
                           VecDegH(e.transient_drift->amplitude_k_rad_s));
    out << absl::StrFormat("# g%d_transient_drift_time_constant_h: %.15g\n", n,
                           estimator::SecondsToHours(e.transient_drift->time_constant_s));
    out << absl::StrFormat("# g%d_transient_drift_start_h: %.15g\n", n,
                           estimator::SecondsToHours(e.transient_drift->start_s));
  }
  if (e.sun_face_drift) {
    out << absl::StrFormat("# g%d_sun_face_drift_amplitude_deg_h: %s\n", n,
                           VecDegH(e.sun_face_drift->amplitude_k_rad_s));
    out << absl::StrFormat(
        "# g%d_sun_face_drift_face: %s\n", n,
        e.sun_face_drift->face_axis == estimator::kSunlitFaceAxis
            ? std::string("sunlit")
            : absl::StrFormat("%c%c", e.sun_face_drift->face_sign > 0 ? '+' : '-',
                              "xyz"[e.sun_face_drift->face_axis]));
    out << absl::StrFormat("# g%d_sun_face_drift_time_constant_h: %.15g\n", n,
                           estimator::SecondsToHours(e.sun_face_drift->time_constant_s));
  }
}

// Truth CSV: metadata lines (the recording's, plus the true coefficients [deg/h] and true
// mountings per running gyro, plus the settings of any effect beyond the paper's models), then
// time_utc, q0..q3 (true q_in_b, scalar first), per gyro gN_hin_x..z (true inertial spin axis;
// empty when off), st_outlier (0/1) and st_outlier_arcsec, then one group of columns per gyro and
// effect that is on (none when every effect is off, so such files keep their old layout):
// gN_displacement_x..z_um, gN_orbital_dw_x..z_deg_h, gN_switching_level,
// gN_hidden_driver and gN_hidden_dw_x..z_deg_h, gN_rate_dw_x..z_deg_h,
// gN_transient_dw_x..z_deg_h.
absl::Status WriteTruthCsv(const std::string& path, const estimator::SimulationResult& result) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  if (!out) return absl::UnavailableError(absl::StrCat(path, ": cannot open for writing"));
  out << "# format: esg-truth-csv 1\n";
  for (const auto& [key, value] : result.recording.metadata) {
    out << "# " << key << ": " << value << "\n";
  }
  for (int g = 0; g < kMaxGyros; ++g) {
    if (!result.true_coefficients[g]) continue;
    const estimator::DriftCoefficients& c = *result.true_coefficients[g];
    // One line per key of estimator/model_terms.h: "# g1_true_c1_deg_h: [..., ..., ...]".
    const estimator::DriftVector theta = c.AsVector();
    for (const estimator::FixedTermKey& key : estimator::FixedTermKeys()) {
      const int first = key.first_theta_index;
      std::string value;
      if (key.components == 0) {
        value = absl::StrFormat("%.15g", estimator::RadPerSecToDegPerHour(theta(first)));
      } else {
        std::vector<std::string> parts;
        for (int i = first; i < first + key.components; ++i) {
          parts.push_back(absl::StrFormat("%.15g", estimator::RadPerSecToDegPerHour(theta(i))));
        }
        value = absl::StrCat("[", absl::StrJoin(parts, ", "), "]");
      }
      out << absl::StrFormat("# g%d_true_%s: %s\n", g + 1,
                             estimator::FixedTermFieldName(key.json_key), value);
    }
    if (!result.truth.empty() && result.truth.front().gyros[g]) {
      const Eigen::Matrix3d& C = result.truth.front().gyros[g]->C_b_k;
      out << absl::StrFormat(
          "# g%d_true_case_to_body: [%s]\n", g + 1,
          absl::StrJoin({Num(C(0, 0)), Num(C(0, 1)), Num(C(0, 2)), Num(C(1, 0)), Num(C(1, 1)),
                         Num(C(1, 2)), Num(C(2, 0)), Num(C(2, 1)), Num(C(2, 2))},
                        ", "));
    }
    WriteEffectMetadata(out, g, result.effects[g]);
  }
  out << "time_utc,q0,q1,q2,q3";
  for (int g = 1; g <= kMaxGyros; ++g) {
    out << absl::StrFormat(",g%d_hin_x,g%d_hin_y,g%d_hin_z", g, g, g);
  }
  out << ",st_outlier,st_outlier_arcsec";
  for (int g = 0; g < kMaxGyros; ++g) {
    const estimator::GyroEffectsTruth& e = result.effects[g];
    const int n = g + 1;
    if (DisplacementVaries(e)) {
      out << absl::StrFormat(",g%d_displacement_x_um,g%d_displacement_y_um,g%d_displacement_z_um",
                             n, n, n);
    }
    if (e.orbital_drift) {
      out << absl::StrFormat(
          ",g%d_orbital_dw_x_deg_h,g%d_orbital_dw_y_deg_h,g%d_orbital_dw_z_deg_h", n, n, n);
    }
    if (e.switching_drift) out << absl::StrFormat(",g%d_switching_level", n);
    if (e.hidden_driver_drift) {
      out << absl::StrFormat(
          ",g%d_hidden_driver,g%d_hidden_dw_x_deg_h,g%d_hidden_dw_y_deg_h,g%d_hidden_dw_z_deg_h",
          n, n, n, n);
    }
    if (e.rate_drift) {
      out << absl::StrFormat(",g%d_rate_dw_x_deg_h,g%d_rate_dw_y_deg_h,g%d_rate_dw_z_deg_h", n, n,
                             n);
    }
    if (e.transient_drift) {
      out << absl::StrFormat(
          ",g%d_transient_dw_x_deg_h,g%d_transient_dw_y_deg_h,g%d_transient_dw_z_deg_h", n, n, n);
    }
    if (e.sun_face_drift) {
      out << absl::StrFormat(
          ",g%d_sun_illumination,g%d_sun_lagged_illumination,g%d_sun_dw_x_deg_h,"
          "g%d_sun_dw_y_deg_h,g%d_sun_dw_z_deg_h",
          n, n, n, n, n);
    }
  }
  out << "\n";
  for (const estimator::TruthSample& t : result.truth) {
    const estimator::ScalarFirst q = estimator::ToScalarFirst(estimator::Canonical(t.q_in_b));
    out << storage::FormatRecordingTime(t.time) << ","
        << absl::StrJoin({Num(q[0]), Num(q[1]), Num(q[2]), Num(q[3])}, ",");
    for (int g = 0; g < kMaxGyros; ++g) {
      if (t.gyros[g]) {
        const Eigen::Vector3d& h = t.gyros[g]->h_in;
        out << "," << Num(h.x()) << "," << Num(h.y()) << "," << Num(h.z());
      } else {
        out << ",,,";
      }
    }
    out << "," << (t.star_tracker_outlier ? 1 : 0) << ","
        << Num(estimator::RadToArcsec(t.star_tracker_outlier_angle));
    // Effect columns; empty while the gyro has no truth sample (off or before its switch-on).
    auto deg_h = [](const Eigen::Vector3d& v) {
      return absl::StrCat(Num(estimator::RadPerSecToDegPerHour(v.x())), ",",
                          Num(estimator::RadPerSecToDegPerHour(v.y())), ",",
                          Num(estimator::RadPerSecToDegPerHour(v.z())));
    };
    for (int g = 0; g < kMaxGyros; ++g) {
      const estimator::GyroEffectsTruth& e = result.effects[g];
      const std::optional<estimator::GyroTruthSample>& s = t.gyros[g];
      if (DisplacementVaries(e)) {
        if (s) {
          const Eigen::Vector3d um = s->rotor_displacement_k_m / estimator::kMetresPerUm;
          out << "," << Num(um.x()) << "," << Num(um.y()) << "," << Num(um.z());
        } else {
          out << ",,,";
        }
      }
      if (e.orbital_drift) out << "," << (s ? deg_h(s->dw_orbital_k_rad_s) : std::string(",,"));
      if (e.switching_drift) {
        out << "," << (s ? absl::StrFormat("%+.0f", s->switching_level) : std::string());
      }
      if (e.hidden_driver_drift) {
        out << "," << (s ? absl::StrCat(Num(s->hidden_driver), ",", deg_h(s->dw_hidden_k_rad_s))
                         : std::string(",,,"));
      }
      if (e.rate_drift) out << "," << (s ? deg_h(s->dw_rate_k_rad_s) : std::string(",,"));
      if (e.transient_drift) {
        out << "," << (s ? deg_h(s->dw_transient_k_rad_s) : std::string(",,"));
      }
      if (e.sun_face_drift) {
        out << "," << (s ? absl::StrCat(Num(s->sun_illumination), ",",
                                        Num(s->sun_lagged_illumination), ",",
                                        deg_h(s->dw_sun_k_rad_s))
                         : std::string(",,,,"));
      }
    }
    out << "\n";
  }
  out.flush();
  if (!out) return absl::UnavailableError(absl::StrCat(path, ": write failed"));
  return absl::OkStatus();
}

// Bad input (exit 2) versus a failure while running (exit 1).
int ExitCodeFor(const absl::Status& s) {
  switch (s.code()) {
    case absl::StatusCode::kInvalidArgument:
    case absl::StatusCode::kNotFound:
    case absl::StatusCode::kOutOfRange:
    case absl::StatusCode::kFailedPrecondition:
      return 2;
    default:
      return 1;
  }
}

int Fail(const std::string& what, const absl::Status& s) {
  std::cerr << "esg simulate: " << what << ": " << s.message() << "\n";
  return ExitCodeFor(s);
}

int BadArgument(const std::string& message) {
  std::cerr << "esg simulate: " << message << "\n";
  return 2;
}

int RunSimulate(const SimulateOptions& o) {
  // Argument checks first (exit 2).
  if (!std::isfinite(o.hours) || !(o.hours > 0.0)) {
    return BadArgument(absl::StrFormat("--hours: must be > 0, got %g", o.hours));
  }
  if (!std::isfinite(o.telemetry_step) || !(o.telemetry_step > 0.0)) {
    return BadArgument(
        absl::StrFormat("--telemetry-step: must be > 0 s, got %g", o.telemetry_step));
  }
  if (!std::isfinite(o.integration_rate_hz) || !(o.integration_rate_hz > 0.0)) {
    return BadArgument(
        absl::StrFormat("--integration-rate: must be > 0 Hz, got %g", o.integration_rate_hz));
  }
  const absl::StatusOr<absl::Time> start = estimator::ParseUtc(o.start, "--start");
  if (!start.ok()) return BadArgument(std::string(start.status().message()));

  absl::StatusOr<estimator::SpacecraftConfig> config = proto_convert::ReadConfigFile(o.config_path);
  if (!config.ok()) return Fail("--config", config.status());

  Scenario scenario;
  if (!o.scenario_path.empty()) {
    absl::StatusOr<Scenario> s = ReadScenarioFile(o.scenario_path);
    if (!s.ok()) return Fail("--scenario", s.status());
    scenario = *std::move(s);
  }

  estimator::SimulationSpec spec;
  spec.config = *std::move(config);
  spec.start = *start;
  spec.duration = estimator::HoursToSeconds(o.hours);
  spec.telemetry_step = o.telemetry_step;
  spec.integration_rate_hz = o.integration_rate_hz;
  spec.seed = o.seed;
  if (absl::Status s = ApplyScenario(scenario, &spec); !s.ok()) return Fail("--scenario", s);
  absl::StatusOr<estimator::ProfilePtr> profile =
      MakeScenarioProfile(scenario, o.profile, spec.duration);
  if (!profile.ok())
    return Fail(o.profile.empty() ? "scenario profile" : "--profile", profile.status());
  spec.profile = *profile;
  if (absl::Status s = CheckScenarioAgainstProfile(scenario, *spec.profile); !s.ok()) {
    return Fail("--scenario", s);
  }

  Progress progress("simulate");
  absl::StatusOr<estimator::SimulationResult> result =
      estimator::Simulate(spec, [&progress](double f) { progress(f); });
  if (!result.ok()) return Fail("simulation", result.status());
  if (!o.scenario_path.empty()) {
    result->recording.metadata["scenario"] =
        scenario.description.empty() ? o.scenario_path : scenario.description;
  }

  if (absl::Status s = storage::WriteRecordingCsv(o.out_path, result->recording); !s.ok()) {
    std::cerr << "esg simulate: --out: " << s.message() << "\n";
    return 1;
  }
  if (!o.write_config_path.empty()) {
    if (absl::Status s = proto_convert::WriteConfigFile(o.write_config_path, spec.config);
        !s.ok()) {
      std::cerr << "esg simulate: --write-config: " << s.message() << "\n";
      return 1;
    }
  }
  if (!o.truth_path.empty()) {
    if (absl::Status s = WriteTruthCsv(o.truth_path, *result); !s.ok()) {
      std::cerr << "esg simulate: --truth: " << s.message() << "\n";
      return 1;
    }
  }
  if (!o.orbit_out_path.empty()) {
    absl::StatusOr<std::string> oem = OrbitOem(scenario.profile_options.orbital,
                                               spec.config.spacecraft_id, *start, spec.duration);
    if (!oem.ok()) return Fail("--orbit-out", oem.status());
    std::ofstream out(o.orbit_out_path, std::ios::binary);
    out << *oem;
    if (!out.good()) {
      std::cerr << "esg simulate: --orbit-out " << o.orbit_out_path << ": cannot write\n";
      return 1;
    }
  }

  std::vector<int> running;
  for (int id = 1; id <= kMaxGyros; ++id) {
    if (result->true_coefficients[id - 1]) running.push_back(id);
  }
  if (o.format != OutputFormat::kTable) {
    Json j;
    j["out"] = o.out_path;
    j["frames"] = result->recording.frames.size();
    j["hours"] = o.hours;
    j["seed"] = o.seed;
    j["profile"] = spec.profile->Describe();
    j["runningGyros"] = running;
    if (!o.truth_path.empty()) j["truth"] = o.truth_path;
    if (o.format == OutputFormat::kJson) {
      PrintJson(j);
    } else {
      PrintCsv({j});
    }
  } else {
    std::cout << absl::StrFormat("wrote %d frames (%g h, gyros %s running, seed %d) to %s\n",
                                 result->recording.frames.size(), o.hours,
                                 absl::StrJoin(running, ","), o.seed, o.out_path);
  }
  return 0;
}

}  // namespace

void RegisterSimulate(CLI::App& app, GlobalOptions& global, int* exit_code) {
  (void)global;  // offline verb: no server
  auto options = std::make_shared<SimulateOptions>();
  CLI::App* sub = app.add_subcommand(
      "simulate",
      "Simulate ESG and star-tracker telemetry into a recording CSV (docs/formats.md)");
  sub->add_option("--config", options->config_path,
                  "spacecraft configuration JSON (docs/formats.md)")
      ->required();
  sub->add_option("--profile", options->profile,
                  "attitude profile: inertial, orbital, calibration, mixed (default: the "
                  "scenario's, else calibration)");
  sub->add_option("--scenario", options->scenario_path, "scenario JSON (docs/scenario.md)");
  sub->add_option("--hours", options->hours, "simulated duration [h]")->required();
  sub->add_option("--seed", options->seed, "random seed (same seed, same file)")->required();
  sub->add_option("--out", options->out_path, "recording CSV to write")->required();
  sub->add_option("--write-config", options->write_config_path,
                  "also write the configuration used (JSON)");
  sub->add_option("--start", options->start, "start time, RFC 3339 UTC")->capture_default_str();
  sub->add_option("--telemetry-step", options->telemetry_step, "telemetry step [s]")
      ->capture_default_str();
  sub->add_option("--integration-rate", options->integration_rate_hz, "truth integration rate [Hz]")
      ->capture_default_str();
  sub->add_option("--truth", options->truth_path,
                  "also write the truth CSV (true q_in_b, h_in per gyro, true coefficients)");
  sub->add_option("--orbit-out", options->orbit_out_path,
                  "also write the orbit flown as a CCSDS OEM (the scenario's inclinationDeg, "
                  "orbitPeriodMin, raanDeg, argLatitudeDeg; docs/scenario.md), covering the "
                  "recording, for esg diagnose --orbit");
  AddFormatOption(sub, &options->format);
  sub->callback([options, exit_code]() { *exit_code = RunSimulate(*options); });
}

}  // namespace esg::client
