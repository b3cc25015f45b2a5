#include "client/scenario.h"

#include <algorithm>
#include <cmath>
#include <fstream>
#include <set>
#include <sstream>
#include <utility>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/channels.h"
#include "estimator/model_terms.h"
#include "estimator/rotation.h"
#include "estimator/status_macros.h"
#include "estimator/units.h"
#include "nlohmann/json.hpp"
#include "proto/strict_json.h"

namespace esg::client {

using Eigen::Vector3d;
using estimator::GyroFault;
using json = nlohmann::json;

namespace {

// Limits of the accepted values (generous: they catch unit mistakes, not physics).
constexpr double kMaxDriftDegH = 100.0;
constexpr double kMaxDisplacementUm = 20.0;
constexpr double kMaxPerUmDegH = 10.0;
constexpr double kMaxMisalignmentArcsec = 3600.0;
constexpr double kMaxNoiseArcsec = 3600.0;
constexpr double kMaxRandomWalkDegHSqrtH = 1.0;
constexpr double kMaxVoltageNoiseMv = 1000.0;
constexpr double kMaxHours = 1e5;
constexpr int64_t kMaxBurstCount = 100000;
constexpr double kMaxDisplacementRateUmH = 20.0;
constexpr double kMaxDisplacementTurnHours = 8784.0;  // a leap year
constexpr double kMaxDistortionPpm = 1e5;  // 10 %
constexpr double kMinCorrelationHours = 1e-3;
constexpr double kMaxRateGainDegHPerDegS = 100.0;  // 100 deg/h of drift at 1 deg/s
constexpr double kMaxChannelValue = 1e6;             // a channel's mean, spread, noise, heater step
// A channel drift's lag: the range of the filter's channel term (estimator/basis_term.h), 60 s to
// 366 d.
constexpr double kMinChannelTauMinutes = 1.0;
constexpr double kMaxChannelTauMinutes = 366.0 * 24.0 * 60.0;

absl::Status Invalid(const std::string& path, const std::string& reason) {
  return absl::InvalidArgumentError(absl::StrCat(path, ": ", reason));
}

absl::Status CheckObject(const json& v, const std::string& path) {
  if (!v.is_object()) return Invalid(path, absl::StrCat("expected an object, got ", v.type_name()));
  return absl::OkStatus();
}

absl::Status CheckKeys(const json& obj, const std::string& path,
                       const std::set<std::string>& allowed) {
  for (auto it = obj.begin(); it != obj.end(); ++it) {
    if (allowed.count(it.key()) == 0) {
      return Invalid(
          path.empty() ? it.key() : absl::StrCat(path, ".", it.key()),
          absl::StrCat("unknown key; allowed keys here are ", absl::StrJoin(allowed, ", ")));
    }
  }
  return absl::OkStatus();
}

std::string Key(const std::string& path, const std::string& key) {
  return path.empty() ? key : absl::StrCat(path, ".", key);
}

absl::StatusOr<double> Number(const json& v, const std::string& path, double lo, double hi) {
  if (!v.is_number()) return Invalid(path, absl::StrCat("expected a number, got ", v.type_name()));
  const double x = v.get<double>();
  if (!std::isfinite(x) || x < lo || x > hi) {
    return Invalid(path, absl::StrFormat("%g is outside [%g, %g]", x, lo, hi));
  }
  return x;
}

// An array of exactly n numbers, each in [lo, hi].
absl::StatusOr<std::vector<double>> Numbers(const json& v, const std::string& path, int n,
                                            double lo, double hi) {
  if (!v.is_array() || v.size() != static_cast<size_t>(n)) {
    return Invalid(path, absl::StrCat("expected an array of ", n, " numbers, got ",
                                      v.is_array() ? absl::StrCat(v.size(), " values")
                                                   : std::string(v.type_name())));
  }
  std::vector<double> out(n);
  for (int i = 0; i < n; ++i) {
    ASSIGN_OR_RETURN(out[i], Number(v[i], absl::StrCat(path, "[", i, "]"), lo, hi));
  }
  return out;
}

absl::StatusOr<Vector3d> Vec3(const json& v, const std::string& path, double lo, double hi) {
  ASSIGN_OR_RETURN(std::vector<double> xyz, Numbers(v, path, 3, lo, hi));
  return Vector3d(xyz[0], xyz[1], xyz[2]);
}

absl::StatusOr<Vector3d> NonZeroVec3(const json& v, const std::string& path) {
  ASSIGN_OR_RETURN(Vector3d out, Vec3(v, path, -1e6, 1e6));
  if (out.norm() < 1e-9) return Invalid(path, "must not be the zero vector");
  return out;
}

absl::StatusOr<bool> Bool(const json& v, const std::string& path) {
  if (!v.is_boolean())
    return Invalid(path, absl::StrCat("expected true or false, got ", v.type_name()));
  return v.get<bool>();
}

absl::StatusOr<std::string> String(const json& v, const std::string& path) {
  if (!v.is_string()) return Invalid(path, absl::StrCat("expected a string, got ", v.type_name()));
  return v.get<std::string>();
}

Vector3d DegHToSi(const Vector3d& v) { return v.unaryExpr(&estimator::DegPerHourToRadPerSec); }

absl::StatusOr<GyroFault> ParseFault(const json& v, const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path, {"timeHours", "kind", "arcsec", "degH", "endHours"}));
  GyroFault fault;
  if (!v.contains("timeHours")) return Invalid(Key(path, "timeHours"), "required");
  ASSIGN_OR_RETURN(double hours, Number(v["timeHours"], Key(path, "timeHours"), 0.0, kMaxHours));
  fault.time = estimator::HoursToSeconds(hours);
  if (!v.contains("kind")) return Invalid(Key(path, "kind"), "required");
  ASSIGN_OR_RETURN(std::string kind, String(v["kind"], Key(path, "kind")));
  const bool windowed = kind == "reading_frozen" || kind == "readings_missing";
  if (windowed) {
    for (const char* unused : {"arcsec", "degH"}) {
      if (v.contains(unused)) {
        return Invalid(Key(path, unused), absl::StrCat("not used by kind ", kind));
      }
    }
    if (!v.contains("endHours")) {
      return Invalid(Key(path, "endHours"), absl::StrCat("required for kind ", kind));
    }
    ASSIGN_OR_RETURN(double end, Number(v["endHours"], Key(path, "endHours"), 0.0, kMaxHours));
    if (!(end > hours)) {
      return Invalid(Key(path, "endHours"),
                     absl::StrFormat("%g must be after timeHours %g", end, hours));
    }
    fault.end = estimator::HoursToSeconds(end);
    fault.kind = kind == "reading_frozen" ? GyroFault::Kind::kReadingFrozen
                                          : GyroFault::Kind::kReadingsMissing;
    return fault;
  }
  if (v.contains("endHours") && (kind == "readout_jump" || kind == "drift_step")) {
    return Invalid(Key(path, "endHours"),
                   absl::StrCat("not used by kind ", kind,
                                " (only by reading_frozen and readings_missing)"));
  }
  if (kind == "readout_jump") {
    fault.kind = GyroFault::Kind::kReadoutJump;
    if (v.contains("degH"))
      return Invalid(Key(path, "degH"), "not used by kind readout_jump (use arcsec)");
    if (!v.contains("arcsec"))
      return Invalid(Key(path, "arcsec"), "required for kind readout_jump");
    ASSIGN_OR_RETURN(Vector3d arcsec, Vec3(v["arcsec"], Key(path, "arcsec"), -36000.0, 36000.0));
    fault.value = estimator::kRadPerArcsec * arcsec;
  } else if (kind == "drift_step") {
    fault.kind = GyroFault::Kind::kDriftStep;
    if (v.contains("arcsec"))
      return Invalid(Key(path, "arcsec"), "not used by kind drift_step (use degH)");
    if (!v.contains("degH")) return Invalid(Key(path, "degH"), "required for kind drift_step");
    ASSIGN_OR_RETURN(Vector3d deg_h,
                     Vec3(v["degH"], Key(path, "degH"), -kMaxDriftDegH, kMaxDriftDegH));
    fault.value = DegHToSi(deg_h);
  } else {
    return Invalid(Key(path, "kind"),
                   absl::StrCat("unknown kind '", kind,
                                "'; valid kinds are readout_jump, drift_step, reading_frozen, "
                                "readings_missing"));
  }
  return fault;
}

// {"amplitudeDegH": [x,y,z], "periodMin": P, "phaseDeg": p}; periodMin optional (default: the
// profile's orbital period), phaseDeg optional (0).
absl::StatusOr<estimator::OrbitalDrift> ParseOrbitalDrift(const json& v, const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path, {"amplitudeDegH", "periodMin", "phaseDeg"}));
  if (!v.contains("amplitudeDegH")) return Invalid(Key(path, "amplitudeDegH"), "required");
  estimator::OrbitalDrift o;
  ASSIGN_OR_RETURN(Vector3d deg_h, Vec3(v["amplitudeDegH"], Key(path, "amplitudeDegH"),
                                        -kMaxDriftDegH, kMaxDriftDegH));
  o.amplitude_k_rad_s = DegHToSi(deg_h);
  if (v.contains("periodMin")) {
    ASSIGN_OR_RETURN(double min, Number(v["periodMin"], Key(path, "periodMin"), 1.0, 1e5));
    o.period_s = min * estimator::kSecondsPerMinute;
  }
  if (v.contains("phaseDeg")) {
    ASSIGN_OR_RETURN(double deg, Number(v["phaseDeg"], Key(path, "phaseDeg"), -360.0, 360.0));
    o.phase_rad = estimator::DegToRad(deg);
  }
  return o;
}

// {"axis": [x, y, z], "periodH": P}: the rotor displacement turning right-handed about the case
// axis (any non-zero length, normalised) once every P hours (simulator.h DisplacementTurn).
absl::StatusOr<estimator::DisplacementTurn> ParseDisplacementTurn(const json& v,
                                                                  const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path, {"axis", "periodH"}));
  for (const char* key : {"axis", "periodH"}) {
    if (!v.contains(key)) return Invalid(Key(path, key), "required");
  }
  estimator::DisplacementTurn turn;
  ASSIGN_OR_RETURN(Vector3d axis, NonZeroVec3(v["axis"], Key(path, "axis")));
  turn.axis_k = axis.normalized();
  ASSIGN_OR_RETURN(double hours,
                   Number(v["periodH"], Key(path, "periodH"), 0.0, kMaxDisplacementTurnHours));
  if (!(hours > 0.0)) return Invalid(Key(path, "periodH"), "must be > 0");
  turn.period_s = estimator::HoursToSeconds(hours);
  return turn;
}

// {"amplitudeDegH": [x,y,z], "<time_key>": hours} -> amplitude [rad/s] and time [s], both
// required; the time in [kMinCorrelationHours, kMaxHours]. `optional_key`, when not empty, may
// also appear (its caller reads it).
absl::Status ParseAmplitudeAndTime(const json& v, const std::string& path,
                                   const std::string& time_key, Vector3d* amplitude_rad_s,
                                   double* time_s, const std::string& optional_key = "") {
  RETURN_IF_ERROR(CheckObject(v, path));
  std::set<std::string> keys = {"amplitudeDegH", time_key};
  if (!optional_key.empty()) keys.insert(optional_key);
  RETURN_IF_ERROR(CheckKeys(v, path, keys));
  for (const std::string& key : {std::string("amplitudeDegH"), time_key}) {
    if (!v.contains(key)) return Invalid(Key(path, key), "required");
  }
  ASSIGN_OR_RETURN(Vector3d deg_h, Vec3(v["amplitudeDegH"], Key(path, "amplitudeDegH"),
                                        -kMaxDriftDegH, kMaxDriftDegH));
  *amplitude_rad_s = DegHToSi(deg_h);
  ASSIGN_OR_RETURN(double hours,
                   Number(v[time_key], Key(path, time_key), kMinCorrelationHours, kMaxHours));
  *time_s = estimator::HoursToSeconds(hours);
  return absl::OkStatus();
}

// {"degHPerDegS": [gxx, gxy, gxz, gyx, gyy, gyz, gzx, gzy, gzz]}: the gain of a rate-dependent
// drift row by row (row i: drift component i per body rate x, y, z, case axes), drift [deg/h]
// per body rate [deg/s] -> [1] (1 deg/h per deg/s = 1/3600).
absl::StatusOr<estimator::RateDrift> ParseRateDrift(const json& v, const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path, {"degHPerDegS"}));
  if (!v.contains("degHPerDegS")) return Invalid(Key(path, "degHPerDegS"), "required");
  const json& g = v["degHPerDegS"];
  const std::string p = Key(path, "degHPerDegS");
  if (!g.is_array() || g.size() != 9) {
    return Invalid(p, absl::StrCat("expected an array of 9 numbers (the gain row by row: drift x, "
                                   "y, z per body rate x, y, z in case axes), got ",
                                   g.is_array() ? absl::StrCat(g.size(), " values")
                                                : std::string(g.type_name())));
  }
  estimator::RateDrift d;
  for (int i = 0; i < 9; ++i) {
    ASSIGN_OR_RETURN(double x, Number(g[i], absl::StrCat(p, "[", i, "]"),
                                      -kMaxRateGainDegHPerDegS, kMaxRateGainDegHPerDegS));
    d.gain_k(i / 3, i % 3) = x / estimator::kSecondsPerHour;
  }
  return d;
}

// {"amplitudeDegH": [x, y, z], "timeConstantHours": tau, "startHours": t0 (default 0)}.
absl::StatusOr<estimator::TransientDrift> ParseTransientDrift(const json& v,
                                                             const std::string& path) {
  estimator::TransientDrift d;
  RETURN_IF_ERROR(ParseAmplitudeAndTime(v, path, "timeConstantHours", &d.amplitude_k_rad_s,
                                        &d.time_constant_s, "startHours"));
  if (v.contains("startHours")) {
    ASSIGN_OR_RETURN(double hours, Number(v["startHours"], Key(path, "startHours"), 0.0, kMaxHours));
    d.start_s = estimator::HoursToSeconds(hours);
  }
  return d;
}

// {"startHours": t0, "k0DegH": dk0, "c1DegH": [..], ...}: a step of the drift coefficients of
// eq. (1), (10) at t0 (required), by the keys of estimator/model_terms.h (at least one; the
// others step by 0).
absl::StatusOr<estimator::CoefficientStep> ParseCoefficientStep(const json& v,
                                                                const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  std::set<std::string> keys = {"startHours"};
  for (const estimator::FixedTermKey& key : estimator::FixedTermKeys()) {
    keys.insert(std::string(key.json_key));
  }
  RETURN_IF_ERROR(CheckKeys(v, path, keys));
  if (!v.contains("startHours")) return Invalid(Key(path, "startHours"), "required");
  estimator::CoefficientStep step;
  ASSIGN_OR_RETURN(double hours, Number(v["startHours"], Key(path, "startHours"), 0.0, kMaxHours));
  step.time_s = estimator::HoursToSeconds(hours);
  estimator::DriftVector delta = estimator::DriftVector::Zero();
  bool any = false;
  for (const estimator::FixedTermKey& key : estimator::FixedTermKeys()) {
    const std::string k(key.json_key);
    if (!v.contains(k)) continue;
    any = true;
    const std::string p = Key(path, k);
    if (key.components == 0) {
      ASSIGN_OR_RETURN(double deg_h, Number(v[k], p, -kMaxDriftDegH, kMaxDriftDegH));
      delta(key.first_theta_index) = estimator::DegPerHourToRadPerSec(deg_h);
    } else {
      ASSIGN_OR_RETURN(std::vector<double> deg_h,
                       Numbers(v[k], p, key.components, -kMaxDriftDegH, kMaxDriftDegH));
      for (int i = 0; i < key.components; ++i) {
        delta(key.first_theta_index + i) = estimator::DegPerHourToRadPerSec(deg_h[i]);
      }
    }
  }
  if (!any) {
    std::vector<std::string> keys;
    for (const estimator::FixedTermKey& key : estimator::FixedTermKeys()) {
      keys.emplace_back(key.json_key);
    }
    const std::string last = keys.back();
    keys.pop_back();
    return Invalid(path, absl::StrCat("names no coefficient (", absl::StrJoin(keys, ", "), " or ",
                                      last, ")"));
  }
  step.delta = estimator::DriftCoefficients::FromVector(delta);
  return step;
}

// v["face"]: "+x" | "-x" | "+y" | "-y" | "+z" | "-z" (the body face whose outward normal is that
// axis) or "sunlit" (no face: the sunlit fraction of the orbit), required, into *axis, *sign.
absl::Status ParseSunFace(const json& v, const std::string& path, int* axis, int* sign) {
  const std::string p = Key(path, "face");
  if (!v.contains("face")) return Invalid(p, "required (+x, -x, +y, -y, +z, -z or sunlit)");
  const json& f = v["face"];
  const std::string face = f.is_string() ? f.get<std::string>() : f.dump();
  if (face == "sunlit") {
    *axis = estimator::kSunlitFaceAxis;
    return absl::OkStatus();
  }
  if (!f.is_string() || face.size() != 2 || (face[0] != '+' && face[0] != '-') ||
      face[1] < 'x' || face[1] > 'z') {
    return Invalid(p, absl::StrCat("expected one of +x, -x, +y, -y, +z, -z (the body face whose "
                                   "outward normal is that axis) or sunlit (the fraction of the "
                                   "sun's disc seen from the orbit, with earthShadow), got ",
                                   f.is_string() ? absl::StrCat("'", face, "'") : face));
  }
  *sign = face[0] == '+' ? 1 : -1;
  *axis = face[1] - 'x';
  return absl::OkStatus();
}

// {"amplitudeDegH": [x, y, z], "face": F, "timeConstantHours": tau}, all required.
absl::StatusOr<estimator::SunFaceDrift> ParseSunFaceDrift(const json& v, const std::string& path) {
  estimator::SunFaceDrift d;
  RETURN_IF_ERROR(ParseAmplitudeAndTime(v, path, "timeConstantHours", &d.amplitude_k_rad_s,
                                        &d.time_constant_s, "face"));
  RETURN_IF_ERROR(ParseSunFace(v, path, &d.face_axis, &d.face_sign));
  return d;
}

// {"channel": name, "gainDegH": [x, y, z], "form": "value" | "lag" | "derivative",
// "timeConstantMinutes": tau, "unit", "mean", "spread", "correlationHours", "noise",
// "telemetered", "heater": {...}}: a drift that follows a housekeeping temperature
// (estimator/simulator.h ChannelDrift; docs/scenario.md). channel and gainDegH are required, tau
// for lag and derivative (and refused for value); the unit goes to *unit.
absl::StatusOr<estimator::ChannelDrift> ParseChannelDrift(const json& v, const std::string& path,
                                                          std::string* unit) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path,
                            {"channel", "unit", "mean", "spread", "correlationHours", "noise",
                             "form", "timeConstantMinutes", "gainDegH", "telemetered",
                             "heater"}));
  for (const char* key : {"channel", "gainDegH"}) {
    if (!v.contains(key)) return Invalid(Key(path, key), "required");
  }
  estimator::ChannelDrift d;
  ASSIGN_OR_RETURN(d.channel, String(v["channel"], Key(path, "channel")));
  RETURN_IF_ERROR(estimator::ValidateChannelName(d.channel, Key(path, "channel")));
  ASSIGN_OR_RETURN(Vector3d gain, Vec3(v["gainDegH"], Key(path, "gainDegH"), -kMaxDriftDegH,
                                       kMaxDriftDegH));
  d.gain_k_rad_s_per_unit = DegHToSi(gain);
  if (v.contains("unit")) {
    ASSIGN_OR_RETURN(*unit, String(v["unit"], Key(path, "unit")));
    bool printable =
        !unit->empty() && unit->size() <= static_cast<size_t>(estimator::kMaxChannelUnitLength);
    for (char ch : *unit) printable = printable && absl::ascii_isprint(ch);
    if (!printable) {
      return Invalid(Key(path, "unit"),
                     absl::StrCat("must be 1..", estimator::kMaxChannelUnitLength,
                                  " printable ASCII characters (\"1\" for a dimensionless "
                                  "channel)"));
    }
  }
  if (v.contains("mean")) {
    ASSIGN_OR_RETURN(d.mean, Number(v["mean"], Key(path, "mean"), -kMaxChannelValue,
                                    kMaxChannelValue));
  }
  if (v.contains("spread")) {
    ASSIGN_OR_RETURN(d.spread, Number(v["spread"], Key(path, "spread"), 0.0, kMaxChannelValue));
    if (!(d.spread > 0.0)) return Invalid(Key(path, "spread"), "must be > 0");
  }
  if (v.contains("correlationHours")) {
    ASSIGN_OR_RETURN(double hours, Number(v["correlationHours"], Key(path, "correlationHours"),
                                          kMinCorrelationHours, kMaxHours));
    d.correlation_time_s = estimator::HoursToSeconds(hours);
  }
  if (v.contains("noise")) {
    ASSIGN_OR_RETURN(d.noise, Number(v["noise"], Key(path, "noise"), 0.0, kMaxChannelValue));
  }
  std::string form = "value";
  if (v.contains("form")) {
    ASSIGN_OR_RETURN(form, String(v["form"], Key(path, "form")));
    if (form != "value" && form != "lag" && form != "derivative") {
      return Invalid(Key(path, "form"), absl::StrCat("unknown form '", form,
                                                     "'; valid forms are value, lag, derivative"));
    }
  }
  const std::string tau_key = Key(path, "timeConstantMinutes");
  if (form == "value") {
    if (v.contains("timeConstantMinutes")) {
      return Invalid(tau_key, "not used by form value (the drift follows the channel itself)");
    }
  } else {
    if (!v.contains("timeConstantMinutes")) {
      return Invalid(tau_key, absl::StrCat("required for form ", form));
    }
    ASSIGN_OR_RETURN(double minutes, Number(v["timeConstantMinutes"], tau_key,
                                            kMinChannelTauMinutes, kMaxChannelTauMinutes));
    d.lag_s = minutes * estimator::kSecondsPerMinute;
    d.derivative = form == "derivative";
  }
  if (v.contains("telemetered")) {
    ASSIGN_OR_RETURN(d.telemetered, Bool(v["telemetered"], Key(path, "telemetered")));
  }
  if (v.contains("heater")) {
    const json& h = v["heater"];
    const std::string hp = Key(path, "heater");
    RETURN_IF_ERROR(CheckObject(h, hp));
    RETURN_IF_ERROR(CheckKeys(h, hp, {"periodHours", "onFraction", "step", "channel"}));
    for (const char* key : {"periodHours", "step"}) {
      if (!h.contains(key)) return Invalid(Key(hp, key), "required");
    }
    estimator::ChannelHeater heater;
    ASSIGN_OR_RETURN(double hours, Number(h["periodHours"], Key(hp, "periodHours"),
                                          kMinCorrelationHours, kMaxHours));
    heater.period_s = estimator::HoursToSeconds(hours);
    ASSIGN_OR_RETURN(heater.step,
                     Number(h["step"], Key(hp, "step"), -kMaxChannelValue, kMaxChannelValue));
    if (h.contains("onFraction")) {
      ASSIGN_OR_RETURN(heater.on_fraction, Number(h["onFraction"], Key(hp, "onFraction"), 0.0, 1.0));
      if (!(heater.on_fraction > 0.0 && heater.on_fraction < 1.0)) {
        return Invalid(Key(hp, "onFraction"),
                       absl::StrFormat("%g: must be strictly between 0 and 1 (a heater that "
                                       "cycles)",
                                       heater.on_fraction));
      }
    }
    if (h.contains("channel")) {
      ASSIGN_OR_RETURN(heater.channel, String(h["channel"], Key(hp, "channel")));
      RETURN_IF_ERROR(estimator::ValidateChannelName(heater.channel, Key(hp, "channel")));
      if (heater.channel == d.channel) {
        return Invalid(Key(hp, "channel"),
                       absl::StrCat("\"", heater.channel, "\" is the temperature's channel too"));
      }
    }
    d.heater = heater;
  }
  return d;
}

// [Dxx, Dyy, Dzz, Dxy, Dyz, Dzx] in ppm -> the symmetric D [1].
absl::StatusOr<Eigen::Matrix3d> ParseDistortionPpm(const json& v, const std::string& path) {
  if (!v.is_array() || v.size() != 6) {
    return Invalid(path, absl::StrCat("expected an array of 6 numbers (Dxx, Dyy, Dzz, Dxy, Dyz, "
                                      "Dzx) in ppm, got ",
                                      v.is_array() ? absl::StrCat(v.size(), " values")
                                                   : std::string(v.type_name())));
  }
  double ppm[6];
  for (int i = 0; i < 6; ++i) {
    ASSIGN_OR_RETURN(ppm[i], Number(v[i], absl::StrCat(path, "[", i, "]"), -kMaxDistortionPpm,
                                    kMaxDistortionPpm));
  }
  constexpr double kPerPpm = 1e-6;
  Eigen::Matrix3d D;
  D << ppm[0], ppm[3], ppm[5],  //
      ppm[3], ppm[1], ppm[4],   //
      ppm[5], ppm[4], ppm[2];
  return Eigen::Matrix3d(kPerPpm * D);
}

absl::StatusOr<ScenarioGyro> ParseGyro(const json& v, const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  // The keys of the drift model's fixed terms (estimator/model_terms.h) and the others.
  std::set<std::string> keys = {
      "id", "running", "rotorDisplacementUm", "c10DegHPerUm", "c20DegHPerUm",
      "misalignmentArcsec", "randomWalkDegHSqrtH", "readoutNoiseArcsec", "voltageNoiseMv",
      "initialSpinAxis", "fault", "switchOnHours", "orbitalDrift", "rotorDisplacementRateUmH",
      "rotorDisplacementTurn", "readoutDistortionPpm", "switchingDrift", "hiddenDriverDrift",
      "rateDrift", "transientDrift", "sunFaceDrift", "coefficientStep", "channelDrift"};
  for (const estimator::FixedTermKey& key : estimator::FixedTermKeys()) {
    keys.insert(std::string(key.json_key));
  }
  RETURN_IF_ERROR(CheckKeys(v, path, keys));
  ScenarioGyro g;
  if (!v.contains("id")) return Invalid(Key(path, "id"), "required");
  if (!v["id"].is_number_integer()) {
    return Invalid(Key(path, "id"),
                   absl::StrCat("expected an integer gyro id, got ", v["id"].dump()));
  }
  g.id = v["id"].get<int>();
  if (g.id < 1 || g.id > estimator::kMaxGyros) {
    return Invalid(Key(path, "id"),
                   absl::StrFormat("%d is outside 1..%d", g.id, estimator::kMaxGyros));
  }
  for (auto it = v.begin(); it != v.end(); ++it) {
    const std::string& k = it.key();
    const json& x = it.value();
    const std::string p = Key(path, k);
    if (k == "id") continue;
    if (k == "running") {
      ASSIGN_OR_RETURN(g.running, Bool(x, p));
    } else if (k == "rotorDisplacementUm") {
      ASSIGN_OR_RETURN(Vector3d um, Vec3(x, p, -kMaxDisplacementUm, kMaxDisplacementUm));
      g.rotor_displacement_k = estimator::kMetresPerUm * um;
    } else if (k == "c10DegHPerUm" || k == "c20DegHPerUm") {
      ASSIGN_OR_RETURN(double per_um, Number(x, p, -kMaxPerUmDegH, kMaxPerUmDegH));
      const double per_m = estimator::DegPerHourToRadPerSec(per_um) / estimator::kMetresPerUm;
      (k == "c10DegHPerUm" ? g.c10_per_m : g.c20_per_m) = per_m;
    } else if (const auto term = estimator::FindFixedTermKey(k); term.has_value()) {
      // A fixed term of the drift model (deg/h): one number, or an array of as many numbers as
      // the term has components (estimator/model_terms.h FixedTermKeys()).
      const int first = term->first_theta_index;
      if (term->components == 0) {
        ASSIGN_OR_RETURN(double deg_h, Number(x, p, -kMaxDriftDegH, kMaxDriftDegH));
        g.drift_coefficients[first] = estimator::DegPerHourToRadPerSec(deg_h);
      } else {
        ASSIGN_OR_RETURN(std::vector<double> deg_h,
                         Numbers(x, p, term->components, -kMaxDriftDegH, kMaxDriftDegH));
        for (int i = 0; i < term->components; ++i) {
          g.drift_coefficients[first + i] = estimator::DegPerHourToRadPerSec(deg_h[i]);
        }
      }
    } else if (k == "misalignmentArcsec") {
      ASSIGN_OR_RETURN(Vector3d arcsec,
                       Vec3(x, p, -kMaxMisalignmentArcsec, kMaxMisalignmentArcsec));
      g.misalignment_b = estimator::kRadPerArcsec * arcsec;
    } else if (k == "randomWalkDegHSqrtH") {
      ASSIGN_OR_RETURN(double rw, Number(x, p, 0.0, kMaxRandomWalkDegHSqrtH));
      g.random_walk = estimator::DegPerHourSqrtHourToSi(rw);
    } else if (k == "readoutNoiseArcsec") {
      ASSIGN_OR_RETURN(double arcsec, Number(x, p, 0.0, kMaxNoiseArcsec));
      g.readout_noise = estimator::ArcsecToRad(arcsec);
    } else if (k == "voltageNoiseMv") {
      ASSIGN_OR_RETURN(double mv, Number(x, p, 0.0, kMaxVoltageNoiseMv));
      g.voltage_noise = mv * estimator::kVoltsPerMv;
    } else if (k == "initialSpinAxis") {
      ASSIGN_OR_RETURN(g.initial_h_k, NonZeroVec3(x, p));
    } else if (k == "fault") {
      ASSIGN_OR_RETURN(g.fault, ParseFault(x, p));
    } else if (k == "switchOnHours") {
      ASSIGN_OR_RETURN(double hours, Number(x, p, 0.0, kMaxHours));
      g.switch_on_time = estimator::HoursToSeconds(hours);
    } else if (k == "orbitalDrift") {
      ASSIGN_OR_RETURN(g.orbital_drift, ParseOrbitalDrift(x, p));
    } else if (k == "rotorDisplacementRateUmH") {
      ASSIGN_OR_RETURN(Vector3d um_h,
                       Vec3(x, p, -kMaxDisplacementRateUmH, kMaxDisplacementRateUmH));
      g.rotor_displacement_rate_k_m_s =
          estimator::kMetresPerUm * um_h / estimator::kSecondsPerHour;
    } else if (k == "rotorDisplacementTurn") {
      ASSIGN_OR_RETURN(g.rotor_displacement_turn, ParseDisplacementTurn(x, p));
    } else if (k == "readoutDistortionPpm") {
      ASSIGN_OR_RETURN(g.readout_distortion_k, ParseDistortionPpm(x, p));
    } else if (k == "switchingDrift") {
      estimator::SwitchingDrift d;
      RETURN_IF_ERROR(
          ParseAmplitudeAndTime(x, p, "meanDwellHours", &d.amplitude_k_rad_s, &d.mean_dwell_s));
      g.switching_drift = d;
    } else if (k == "hiddenDriverDrift") {
      estimator::HiddenDriverDrift d;
      RETURN_IF_ERROR(ParseAmplitudeAndTime(x, p, "correlationHours", &d.amplitude_k_rad_s,
                                            &d.correlation_time_s));
      g.hidden_driver_drift = d;
    } else if (k == "rateDrift") {
      ASSIGN_OR_RETURN(g.rate_drift, ParseRateDrift(x, p));
    } else if (k == "transientDrift") {
      ASSIGN_OR_RETURN(g.transient_drift, ParseTransientDrift(x, p));
    } else if (k == "sunFaceDrift") {
      ASSIGN_OR_RETURN(g.sun_face_drift, ParseSunFaceDrift(x, p));
    } else if (k == "coefficientStep") {
      ASSIGN_OR_RETURN(g.coefficient_step, ParseCoefficientStep(x, p));
    } else if (k == "channelDrift") {
      ASSIGN_OR_RETURN(g.channel_drift, ParseChannelDrift(x, p, &g.channel_unit));
    }
  }
  if (g.rotor_displacement_turn &&
      (!g.rotor_displacement_k || g.rotor_displacement_k->isZero(0.0))) {
    return Invalid(Key(path, "rotorDisplacementTurn"),
                   "needs a non-zero rotorDisplacementUm (the displacement that turns)");
  }
  return g;
}

// [{"startHours": a, "endHours": b}, ...] -> [start, end) in seconds.
absl::StatusOr<std::vector<std::pair<double, double>>> ParseWindows(const json& x,
                                                                    const std::string& p) {
  if (!x.is_array()) return Invalid(p, absl::StrCat("expected an array, got ", x.type_name()));
  std::vector<std::pair<double, double>> windows;
  for (size_t i = 0; i < x.size(); ++i) {
    const std::string pi = absl::StrCat(p, "[", i, "]");
    RETURN_IF_ERROR(CheckObject(x[i], pi));
    RETURN_IF_ERROR(CheckKeys(x[i], pi, {"startHours", "endHours"}));
    if (!x[i].contains("startHours")) return Invalid(Key(pi, "startHours"), "required");
    if (!x[i].contains("endHours")) return Invalid(Key(pi, "endHours"), "required");
    ASSIGN_OR_RETURN(double start,
                     Number(x[i]["startHours"], Key(pi, "startHours"), 0.0, kMaxHours));
    ASSIGN_OR_RETURN(double end, Number(x[i]["endHours"], Key(pi, "endHours"), 0.0, kMaxHours));
    if (!(end > start)) {
      return Invalid(Key(pi, "endHours"),
                     absl::StrFormat("%g must be after startHours %g", end, start));
    }
    windows.emplace_back(estimator::HoursToSeconds(start), estimator::HoursToSeconds(end));
  }
  return windows;
}

absl::StatusOr<estimator::StarTrackerOutlierBurst> ParseOutlierBurst(const json& v,
                                                                     const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path, {"timeHours", "count", "arcmin"}));
  for (const char* key : {"timeHours", "count", "arcmin"}) {
    if (!v.contains(key)) return Invalid(Key(path, key), "required");
  }
  estimator::StarTrackerOutlierBurst burst;
  ASSIGN_OR_RETURN(double hours, Number(v["timeHours"], Key(path, "timeHours"), 0.0, kMaxHours));
  burst.time = estimator::HoursToSeconds(hours);
  const json& count = v["count"];
  if (!count.is_number_integer() || count.get<int64_t>() < 1 ||
      count.get<int64_t>() > kMaxBurstCount) {
    return Invalid(Key(path, "count"),
                   absl::StrCat("expected an integer in 1..", kMaxBurstCount, ", got ",
                                count.dump()));
  }
  burst.count = count.get<int>();
  ASSIGN_OR_RETURN(double arcmin, Number(v["arcmin"], Key(path, "arcmin"), 0.0, 600.0));
  if (!(arcmin > 0.0)) return Invalid(Key(path, "arcmin"), "must be > 0");
  burst.angle = estimator::ArcminToRad(arcmin);
  return burst;
}

absl::StatusOr<estimator::StarTrackerMisalignmentJump> ParseMisalignmentJump(
    const json& v, const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path, {"timeHours", "arcsec"}));
  for (const char* key : {"timeHours", "arcsec"}) {
    if (!v.contains(key)) return Invalid(Key(path, key), "required");
  }
  estimator::StarTrackerMisalignmentJump jump;
  ASSIGN_OR_RETURN(double hours, Number(v["timeHours"], Key(path, "timeHours"), 0.0, kMaxHours));
  jump.time = estimator::HoursToSeconds(hours);
  ASSIGN_OR_RETURN(Vector3d arcsec, Vec3(v["arcsec"], Key(path, "arcsec"),
                                         -kMaxMisalignmentArcsec, kMaxMisalignmentArcsec));
  jump.rotation_b = estimator::kRadPerArcsec * arcsec;
  return jump;
}

// {"arcsec": [x, y, z], "periodMin": P, "phaseDeg": p}: the mount turning by
// arcsec sin(2 pi t / P + p), body axes (simulator.h StarTrackerMisalignmentCycle).
absl::StatusOr<estimator::StarTrackerMisalignmentCycle> ParseMisalignmentCycle(
    const json& v, const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path, {"arcsec", "periodMin", "phaseDeg"}));
  for (const char* key : {"arcsec", "periodMin"}) {
    if (!v.contains(key)) return Invalid(Key(path, key), "required");
  }
  estimator::StarTrackerMisalignmentCycle cycle;
  ASSIGN_OR_RETURN(Vector3d arcsec, Vec3(v["arcsec"], Key(path, "arcsec"),
                                         -kMaxMisalignmentArcsec, kMaxMisalignmentArcsec));
  cycle.amplitude_b = estimator::kRadPerArcsec * arcsec;
  ASSIGN_OR_RETURN(double minutes,
                   Number(v["periodMin"], Key(path, "periodMin"), 0.0, kMaxHours * 60.0));
  if (!(minutes > 0.0)) return Invalid(Key(path, "periodMin"), "must be > 0");
  cycle.period_s = minutes * 60.0;
  if (v.contains("phaseDeg")) {
    ASSIGN_OR_RETURN(double deg, Number(v["phaseDeg"], Key(path, "phaseDeg"), -360.0, 360.0));
    cycle.phase_rad = estimator::DegToRad(deg);
  }
  return cycle;
}

// {"arcsec": [x, y, z], "face": F, "timeConstantHours": tau}, all required: the mount turning by
// arcsec y(t), body axes, y the face's lagged illumination (simulator.h StarTrackerSunMount).
absl::StatusOr<estimator::StarTrackerSunMount> ParseSunMount(const json& v,
                                                             const std::string& path) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path, {"arcsec", "face", "timeConstantHours"}));
  for (const char* key : {"arcsec", "timeConstantHours"}) {
    if (!v.contains(key)) return Invalid(Key(path, key), "required");
  }
  estimator::StarTrackerSunMount mount;
  ASSIGN_OR_RETURN(Vector3d arcsec, Vec3(v["arcsec"], Key(path, "arcsec"),
                                         -kMaxMisalignmentArcsec, kMaxMisalignmentArcsec));
  mount.rotation_b = estimator::kRadPerArcsec * arcsec;
  ASSIGN_OR_RETURN(double hours, Number(v["timeConstantHours"], Key(path, "timeConstantHours"),
                                        kMinCorrelationHours, kMaxHours));
  mount.time_constant_s = estimator::HoursToSeconds(hours);
  RETURN_IF_ERROR(ParseSunFace(v, path, &mount.face_axis, &mount.face_sign));
  return mount;
}

absl::Status ParseStarTracker(const json& v, const std::string& path,
                              estimator::StarTrackerTruth* st) {
  RETURN_IF_ERROR(CheckObject(v, path));
  RETURN_IF_ERROR(CheckKeys(v, path,
                            {"noiseArcsec", "latencyMs", "misalignmentArcsec", "outlierRate",
                             "outlierArcmin", "outages", "invalidRate", "outlierBurst", "frozen",
                             "misalignmentJump", "misalignmentCycle", "sunMount"}));
  for (auto it = v.begin(); it != v.end(); ++it) {
    const std::string& k = it.key();
    const json& x = it.value();
    const std::string p = Key(path, k);
    if (k == "noiseArcsec") {
      ASSIGN_OR_RETURN(Vector3d arcsec, Vec3(x, p, 0.0, kMaxNoiseArcsec));
      st->noise = estimator::kRadPerArcsec * arcsec;
    } else if (k == "latencyMs") {
      ASSIGN_OR_RETURN(double ms, Number(x, p, -10000.0, 10000.0));
      st->latency = ms * 1e-3;
    } else if (k == "misalignmentArcsec") {
      ASSIGN_OR_RETURN(Vector3d arcsec,
                       Vec3(x, p, -kMaxMisalignmentArcsec, kMaxMisalignmentArcsec));
      st->misalignment_b = estimator::kRadPerArcsec * arcsec;
    } else if (k == "outlierRate") {
      ASSIGN_OR_RETURN(st->outlier_probability, Number(x, p, 0.0, 1.0));
    } else if (k == "outlierArcmin") {
      ASSIGN_OR_RETURN(double arcmin, Number(x, p, 0.0, 600.0));
      st->outlier_size = estimator::ArcminToRad(arcmin);
    } else if (k == "invalidRate") {
      ASSIGN_OR_RETURN(st->invalid_probability, Number(x, p, 0.0, 1.0));
    } else if (k == "outages") {
      ASSIGN_OR_RETURN(st->outages, ParseWindows(x, p));
    } else if (k == "frozen") {
      ASSIGN_OR_RETURN(st->frozen, ParseWindows(x, p));
    } else if (k == "outlierBurst") {
      ASSIGN_OR_RETURN(st->outlier_burst, ParseOutlierBurst(x, p));
    } else if (k == "misalignmentJump") {
      ASSIGN_OR_RETURN(st->misalignment_jump, ParseMisalignmentJump(x, p));
    } else if (k == "misalignmentCycle") {
      ASSIGN_OR_RETURN(st->misalignment_cycle, ParseMisalignmentCycle(x, p));
    } else if (k == "sunMount") {
      ASSIGN_OR_RETURN(st->sun_mount, ParseSunMount(x, p));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<Scenario> ParseTop(const json& root) {
  RETURN_IF_ERROR(CheckObject(root, "scenario"));
  RETURN_IF_ERROR(CheckKeys(
      root, "",
      {"description", "gyros", "starTracker", "readoutNoiseArcsec", "randomWalkDegHSqrtH",
       "profile", "profileSeed", "inclinationDeg", "orbitPeriodMin", "raanDeg", "argLatitudeDeg",
       "sunDirection", "spinPeriodMin", "segmentHours", "slewMin", "inertialQuaternion",
       "mixedOrbitalHours", "mixedCalibrationHours", "mixedInertialHours", "earthShadow"}));
  Scenario s;
  estimator::ProfileOptions& po = s.profile_options;
  for (auto it = root.begin(); it != root.end(); ++it) {
    const std::string& k = it.key();
    const json& x = it.value();
    if (k == "description") {
      ASSIGN_OR_RETURN(s.description, String(x, k));
    } else if (k == "gyros") {
      if (!x.is_array()) return Invalid(k, absl::StrCat("expected an array, got ", x.type_name()));
      std::set<int> ids;
      for (size_t i = 0; i < x.size(); ++i) {
        const std::string p = absl::StrCat("gyros[", i, "]");
        ASSIGN_OR_RETURN(ScenarioGyro g, ParseGyro(x[i], p));
        if (!ids.insert(g.id).second) {
          return Invalid(Key(p, "id"), absl::StrCat("gyro ", g.id, " appears twice"));
        }
        s.gyros.push_back(std::move(g));
      }
    } else if (k == "starTracker") {
      RETURN_IF_ERROR(ParseStarTracker(x, k, &s.star_tracker));
    } else if (k == "readoutNoiseArcsec") {
      ASSIGN_OR_RETURN(double arcsec, Number(x, k, 0.0, kMaxNoiseArcsec));
      s.readout_noise = estimator::ArcsecToRad(arcsec);
    } else if (k == "randomWalkDegHSqrtH") {
      ASSIGN_OR_RETURN(double rw, Number(x, k, 0.0, kMaxRandomWalkDegHSqrtH));
      s.random_walk = estimator::DegPerHourSqrtHourToSi(rw);
    } else if (k == "profile") {
      ASSIGN_OR_RETURN(std::string name, String(x, k));
      const std::vector<std::string> names = estimator::NamedProfileNames();
      if (std::find(names.begin(), names.end(), name) == names.end()) {
        return Invalid(k, absl::StrCat("unknown profile '", name, "'; valid names are ",
                                       absl::StrJoin(names, ", ")));
      }
      s.profile = name;
    } else if (k == "profileSeed") {
      if (!x.is_number_unsigned()) {
        return Invalid(k, absl::StrCat("expected a non-negative integer, got ", x.dump()));
      }
      s.profile_seed = x.get<uint64_t>();
    } else if (k == "inclinationDeg") {
      ASSIGN_OR_RETURN(double deg, Number(x, k, 0.0, 180.0));
      po.orbital.inclination = estimator::DegToRad(deg);
    } else if (k == "orbitPeriodMin") {
      ASSIGN_OR_RETURN(double min, Number(x, k, 1.0, 1e5));
      po.orbital.period = min * estimator::kSecondsPerMinute;
    } else if (k == "raanDeg") {
      ASSIGN_OR_RETURN(double deg, Number(x, k, -360.0, 360.0));
      po.orbital.raan = estimator::DegToRad(deg);
    } else if (k == "argLatitudeDeg") {
      ASSIGN_OR_RETURN(double deg, Number(x, k, -360.0, 360.0));
      po.orbital.arg_latitude0 = estimator::DegToRad(deg);
    } else if (k == "earthShadow") {
      ASSIGN_OR_RETURN(s.earth_shadow, Bool(x, k));
    } else if (k == "sunDirection") {
      ASSIGN_OR_RETURN(Vector3d sun, NonZeroVec3(x, k));
      po.calibration.sun_in = sun.normalized();
    } else if (k == "spinPeriodMin") {
      ASSIGN_OR_RETURN(double min, Number(x, k, 1.0, 1e5));
      po.calibration.spin_period = min * estimator::kSecondsPerMinute;
    } else if (k == "segmentHours") {
      ASSIGN_OR_RETURN(double hours, Number(x, k, 0.01, kMaxHours));
      po.calibration.segment_duration = estimator::HoursToSeconds(hours);
    } else if (k == "slewMin") {
      ASSIGN_OR_RETURN(double min, Number(x, k, 0.0, 600.0));
      po.calibration.slew_duration = min * estimator::kSecondsPerMinute;
    } else if (k == "inertialQuaternion") {
      if (!x.is_array() || x.size() != 4) {
        return Invalid(k, "expected an array of 4 numbers (q0, q1, q2, q3), scalar first");
      }
      estimator::ScalarFirst q;
      for (int i = 0; i < 4; ++i) {
        ASSIGN_OR_RETURN(q[i], Number(x[i], absl::StrCat(k, "[", i, "]"), -1.0, 1.0));
      }
      const Eigen::Quaterniond eq = estimator::QuaternionFromScalarFirst(q);
      if (std::abs(eq.norm() - 1.0) > 1e-3) {
        return Invalid(k, absl::StrFormat("norm %g is not 1 (tolerance 1e-3)", eq.norm()));
      }
      po.inertial_q_in_b = eq.normalized();
    } else if (k == "mixedOrbitalHours" || k == "mixedCalibrationHours" ||
               k == "mixedInertialHours") {
      ASSIGN_OR_RETURN(double hours, Number(x, k, 0.01, kMaxHours));
      double& target = k == "mixedOrbitalHours"       ? po.mixed_orbital_duration
                       : k == "mixedCalibrationHours" ? po.mixed_calibration_duration
                                                      : po.mixed_inertial_duration;
      target = estimator::HoursToSeconds(hours);
    }
  }
  const double slew = po.calibration.slew_duration;
  if (slew > po.calibration.segment_duration) {
    return Invalid("slewMin",
                   absl::StrFormat("%g min is longer than segmentHours (%g h)",
                                   slew / estimator::kSecondsPerMinute,
                                   estimator::SecondsToHours(po.calibration.segment_duration)));
  }
  // Each channel a channel drift writes (its temperature, its heater's state) written by one
  // drift only: two would set one channel to two values in a frame.
  std::vector<std::pair<std::string, std::string>> written;  // channel, its key path
  for (size_t i = 0; i < s.gyros.size(); ++i) {
    const auto& c = s.gyros[i].channel_drift;
    if (!c) continue;
    const std::string p = absl::StrCat("gyros[", i, "].channelDrift");
    std::vector<std::pair<std::string, std::string>> own = {{c->channel, Key(p, "channel")}};
    if (c->heater && !c->heater->channel.empty()) {
      own.emplace_back(c->heater->channel, Key(p, "heater.channel"));
    }
    for (const auto& [name, path] : own) {
      for (const auto& [other, other_path] : written) {
        if (name == other) {
          return Invalid(path, absl::StrCat("\"", name, "\" is written by ", other_path,
                                            " too (a channel has one value per frame)"));
        }
      }
    }
    written.insert(written.end(), own.begin(), own.end());
  }
  for (size_t i = 0; i < s.gyros.size(); ++i) {
    const auto& sun = s.gyros[i].sun_face_drift;
    if (sun && sun->face_axis == estimator::kSunlitFaceAxis && !s.earth_shadow) {
      return Invalid(absl::StrCat("gyros[", i, "].sunFaceDrift.face"),
                     "sunlit needs \"earthShadow\": true (the orbit whose shadow it follows)");
    }
  }
  return s;
}

}  // namespace

absl::StatusOr<Scenario> ParseScenarioJson(std::string_view text) {
  try {
    const json root = json::parse(text.begin(), text.end());
    // nlohmann-json keeps the last value of a repeated key: refused with its path.
    if (absl::Status strict = proto_convert::CheckStrictJson(text); !strict.ok()) return strict;
    return ParseTop(root);
  } catch (const json::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("scenario: malformed JSON: ", e.what()));
  } catch (const std::exception& e) {
    return absl::InvalidArgumentError(absl::StrCat("scenario: ", e.what()));
  }
}

absl::StatusOr<Scenario> ReadScenarioFile(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return absl::NotFoundError(absl::StrCat(path, ": cannot open scenario file"));
  std::ostringstream text;
  text << in.rdbuf();
  if (in.bad()) return absl::UnavailableError(absl::StrCat(path, ": read failed"));
  absl::StatusOr<Scenario> s = ParseScenarioJson(text.str());
  if (!s.ok()) {
    return absl::InvalidArgumentError(absl::StrCat(path, ": ", s.status().message()));
  }
  return s;
}

absl::Status ApplyScenario(const Scenario& scenario, estimator::SimulationSpec* spec) {
  for (estimator::GyroTruth& g : spec->gyros) {
    if (scenario.readout_noise) g.readout_noise = scenario.readout_noise;
    if (scenario.random_walk) g.random_walk = scenario.random_walk;
  }
  for (size_t i = 0; i < scenario.gyros.size(); ++i) {
    const ScenarioGyro& s = scenario.gyros[i];
    const estimator::GyroConfig* config = spec->config.FindGyro(s.id);
    if (config == nullptr) {
      return Invalid(absl::StrCat("gyros[", i, "].id"),
                     absl::StrCat("gyro ", s.id, " is not in the configuration"));
    }
    estimator::GyroTruth& g = spec->gyros[s.id - 1];
    if (s.running) g.running = s.running;
    if (s.rotor_displacement_k) g.rotor_displacement_k = *s.rotor_displacement_k;
    if (s.c10_per_m) g.c10_per_m = *s.c10_per_m;
    if (s.c20_per_m) g.c20_per_m = *s.c20_per_m;
    const auto& drift = s.drift_coefficients;
    if (std::any_of(drift.begin(), drift.end(), [](const auto& x) { return x.has_value(); })) {
      estimator::DriftVector theta = g.drift.value_or(config->model).AsVector();
      for (int i = 0; i < estimator::kNumDriftCoefficients; ++i) {
        if (drift[i]) theta(i) = *drift[i];
      }
      g.drift = estimator::DriftCoefficients::FromVector(theta);
    }
    if (s.misalignment_b) g.misalignment_b = *s.misalignment_b;
    if (s.random_walk) g.random_walk = s.random_walk;
    if (s.readout_noise) g.readout_noise = s.readout_noise;
    if (s.voltage_noise) g.voltage_noise = *s.voltage_noise;
    if (s.initial_h_k) g.initial_h_k = s.initial_h_k;
    if (s.fault) g.fault = s.fault;
    if (s.switch_on_time) g.switch_on_time = s.switch_on_time;
    if (s.orbital_drift) g.orbital_drift = s.orbital_drift;
    if (s.rotor_displacement_rate_k_m_s) {
      g.rotor_displacement_rate_k_m_s = *s.rotor_displacement_rate_k_m_s;
    }
    if (s.rotor_displacement_turn) g.rotor_displacement_turn = s.rotor_displacement_turn;
    if (s.readout_distortion_k) g.readout_distortion_k = *s.readout_distortion_k;
    if (s.switching_drift) g.switching_drift = s.switching_drift;
    if (s.hidden_driver_drift) g.hidden_driver_drift = s.hidden_driver_drift;
    if (s.rate_drift) g.rate_drift = s.rate_drift;
    if (s.transient_drift) g.transient_drift = s.transient_drift;
    if (s.sun_face_drift) g.sun_face_drift = s.sun_face_drift;
    if (s.coefficient_step) g.coefficient_step = s.coefficient_step;
    if (s.channel_drift) {
      g.channel_drift = s.channel_drift;
      // A telemetered channel the configuration lacks is declared, so the recording's `ch:`
      // columns are valid for it and --write-config writes the declaration.
      const auto declare = [&](const estimator::ChannelConfig& c) {
        const bool declared =
            std::any_of(spec->config.channels.begin(), spec->config.channels.end(),
                        [&](const estimator::ChannelConfig& d) { return d.name == c.name; });
        if (!declared) spec->config.channels.push_back(c);
      };
      if (s.channel_drift->telemetered) {
        declare(ScenarioChannelConfig(*s.channel_drift, s.channel_unit));
        const auto& heater = s.channel_drift->heater;
        if (heater && !heater->channel.empty()) {
          estimator::ChannelConfig state;
          state.name = heater->channel;
          state.unit = "1";
          state.valid_min = 0.0;
          state.valid_max = 1.0;
          state.max_age = absl::Minutes(10);
          declare(state);
        }
      }
    }
  }
  estimator::StarTrackerTruth& st = spec->star_tracker;
  const estimator::StarTrackerTruth& from = scenario.star_tracker;
  if (from.noise) st.noise = from.noise;
  st.outlier_probability = from.outlier_probability;
  st.outlier_size = from.outlier_size;
  st.outages = from.outages;
  st.latency = from.latency;
  st.misalignment_b = from.misalignment_b;
  st.invalid_probability = from.invalid_probability;
  st.outlier_burst = from.outlier_burst;
  st.frozen = from.frozen;
  st.misalignment_jump = from.misalignment_jump;
  st.misalignment_cycle = from.misalignment_cycle;
  st.sun_mount = from.sun_mount;
  if (scenario.earth_shadow) spec->earth_shadow = scenario.profile_options.orbital;
  return absl::OkStatus();
}

estimator::ChannelConfig ScenarioChannelConfig(const estimator::ChannelDrift& drift,
                                               const std::string& unit) {
  const double half_range = 10.0 * drift.spread + 10.0 * drift.noise +
                            (drift.heater ? std::abs(drift.heater->step) : 0.0);
  estimator::ChannelConfig c;
  c.name = drift.channel;
  c.unit = unit;
  c.valid_min = std::floor(drift.mean - half_range);
  c.valid_max = std::ceil(drift.mean + half_range);
  c.max_age = absl::Minutes(10);
  return c;
}

absl::Status CheckScenarioAgainstProfile(const Scenario& scenario,
                                         const estimator::AttitudeProfile& profile) {
  for (size_t i = 0; i < scenario.gyros.size(); ++i) {
    const ScenarioGyro& g = scenario.gyros[i];
    if (g.orbital_drift && !g.orbital_drift->period_s && !profile.OrbitalPeriod()) {
      return Invalid(absl::StrCat("gyros[", i, "].orbitalDrift.periodMin"),
                     absl::StrCat("required: the attitude profile (", profile.Describe(),
                                  ") has no orbital period"));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<estimator::ProfilePtr> MakeScenarioProfile(const Scenario& scenario,
                                                          std::string_view name_override,
                                                          double duration) {
  std::string name = "calibration";
  if (!name_override.empty()) {
    name = std::string(name_override);
  } else if (scenario.profile) {
    name = *scenario.profile;
  }
  return estimator::MakeNamedProfile(name, duration, scenario.profile_seed,
                                     scenario.profile_options);
}

}  // namespace esg::client
