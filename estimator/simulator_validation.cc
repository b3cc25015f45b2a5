// ValidateSimulationSpec (simulator.h): every field of a SimulationSpec checked, each error an
// InvalidArgument naming the field.
#include <algorithm>
#include <cmath>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/channels.h"
#include "estimator/eclipse.h"
#include "estimator/orbit.h"
#include "estimator/simulator.h"
#include "estimator/status_macros.h"
#include "estimator/sun_direction.h"

namespace esg::estimator {

using Eigen::Matrix3d;
using Eigen::Vector3d;

namespace {

// Largest |D_ij| of a readout distortion (keeps I + D far from singular).
constexpr double kMaxReadoutDistortion = 0.1;
// Most switches a switching drift may expect over a run (duration / mean dwell).
constexpr double kMaxExpectedSwitches = 1e7;
// Most frames and integration steps a run may have.
constexpr double kMaxFrames = 1e7;
constexpr double kMaxSteps = 1e10;

absl::Status FiniteAtLeast(double x, double min, const std::string& field) {
  if (!std::isfinite(x) || x < min) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: must be finite and >= %g, got %g", field, min, x));
  }
  return absl::OkStatus();
}

absl::Status Positive(double x, const std::string& field) {
  if (!std::isfinite(x) || !(x > 0.0)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: must be finite and > 0, got %g", field, x));
  }
  return absl::OkStatus();
}

absl::Status FiniteVector(const Vector3d& v, const std::string& field) {
  if (!v.allFinite()) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: values must be finite", field));
  }
  return absl::OkStatus();
}

absl::Status Probability(double p, const std::string& field) {
  if (!(p >= 0.0 && p <= 1.0)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: must be a probability in [0, 1], got %g", field, p));
  }
  return absl::OkStatus();
}

absl::Status CheckWindows(const std::vector<std::pair<double, double>>& windows,
                          const std::string& field) {
  for (size_t i = 0; i < windows.size(); ++i) {
    const auto& [a, b] = windows[i];
    if (!std::isfinite(a) || !std::isfinite(b) || !(a < b)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s[%d]: need finite start < end, got [%g, %g] s", field, i, a, b));
    }
  }
  return absl::OkStatus();
}

// The orbital drift: finite, with a period of its own or the profile's.
absl::Status ValidateOrbitalDrift(const SimulationSpec& spec, const GyroTruth& g,
                                  const std::string& f) {
  if (g.orbital_drift) {
    const OrbitalDrift& o = *g.orbital_drift;
    RETURN_IF_ERROR(FiniteVector(o.amplitude_k_rad_s, f + ".orbital_drift.amplitude_k_rad_s"));
    if (!std::isfinite(o.phase_rad)) {
      return absl::InvalidArgumentError(
          absl::StrCat(f, ".orbital_drift.phase_rad: must be finite"));
    }
    if (o.period_s) {
      RETURN_IF_ERROR(Positive(*o.period_s, f + ".orbital_drift.period_s"));
    } else if (!spec.profile->OrbitalPeriod()) {
      return absl::InvalidArgumentError(
          absl::StrCat(f, ".orbital_drift.period_s: required: the attitude profile (",
                       spec.profile->Describe(), ") has no orbital period"));
    }
  }
  return absl::OkStatus();
}

// The growing and the turning rotor displacement: inside the suspension gap over the run.
absl::Status ValidateMovingDisplacement(const SimulationSpec& spec, const GyroTruth& g,
                                        const std::string& f) {
  RETURN_IF_ERROR(
      FiniteVector(g.rotor_displacement_rate_k_m_s, f + ".rotor_displacement_rate_k_m_s"));
  // Delta(t) is linear in t: inside the gap at both ends means inside throughout.
  const Vector3d end_k = g.rotor_displacement_k + g.rotor_displacement_rate_k_m_s * spec.duration;
  if ((end_k.array().abs() >= spec.config.suspension.gap).any()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s.rotor_displacement_rate_k_m_s: the displacement reaches the suspension gap %g m "
        "within the run (at its end (%g, %g, %g) m)",
        f, spec.config.suspension.gap, end_k.x(), end_k.y(), end_k.z()));
  }
  if (g.rotor_displacement_turn) {
    const DisplacementTurn& turn = *g.rotor_displacement_turn;
    const std::string ft = f + ".rotor_displacement_turn";
    if (!turn.axis_k.allFinite() || turn.axis_k.norm() < 1e-12) {
      return absl::InvalidArgumentError(
          absl::StrCat(ft, ".axis_k: must be a finite non-zero vector"));
    }
    RETURN_IF_ERROR(Positive(turn.period_s, ft + ".period_s"));
    if (g.rotor_displacement_k.isZero(0.0)) {
      return absl::InvalidArgumentError(
          absl::StrCat(ft, ": needs a non-zero rotor_displacement_k (a turn of no displacement)"));
    }
    // The turn keeps |Delta0 + rate t|, which is convex in t: below the gap at both ends means
    // below it throughout, and then every component of the turned displacement is too.
    const double longest_m = std::max(g.rotor_displacement_k.norm(), end_k.norm());
    if (longest_m >= spec.config.suspension.gap) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: the turning displacement's length %g m reaches the suspension gap %g m", ft,
          longest_m, spec.config.suspension.gap));
    }
  }
  return absl::OkStatus();
}

// The readout distortion, the switching and hidden-driver drifts and the rate drift.
absl::Status ValidateReadoutAndRandomDrifts(const SimulationSpec& spec, const GyroTruth& g,
                                            const std::string& f) {
  const Matrix3d& D = g.readout_distortion_k;
  if (!D.allFinite() || (D - D.transpose()).cwiseAbs().maxCoeff() != 0.0 ||
      D.cwiseAbs().maxCoeff() >= kMaxReadoutDistortion) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s.readout_distortion_k: must be finite, symmetric and every |D_ij| < %g",
                        f, kMaxReadoutDistortion));
  }
  if (g.switching_drift) {
    RETURN_IF_ERROR(FiniteVector(g.switching_drift->amplitude_k_rad_s,
                                 f + ".switching_drift.amplitude_k_rad_s"));
    RETURN_IF_ERROR(Positive(g.switching_drift->mean_dwell_s, f + ".switching_drift.mean_dwell_s"));
    if (spec.duration / g.switching_drift->mean_dwell_s > kMaxExpectedSwitches) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s.switching_drift.mean_dwell_s: %g s over %g s gives more than %g expected switches", f,
          g.switching_drift->mean_dwell_s, spec.duration, kMaxExpectedSwitches));
    }
  }
  if (g.hidden_driver_drift) {
    RETURN_IF_ERROR(FiniteVector(g.hidden_driver_drift->amplitude_k_rad_s,
                                 f + ".hidden_driver_drift.amplitude_k_rad_s"));
    RETURN_IF_ERROR(Positive(g.hidden_driver_drift->correlation_time_s,
                             f + ".hidden_driver_drift.correlation_time_s"));
  }
  if (g.rate_drift && !g.rate_drift->gain_k.allFinite()) {
    return absl::InvalidArgumentError(absl::StrCat(f, ".rate_drift.gain_k: must be finite"));
  }
  return absl::OkStatus();
}

// The transient drift and the coefficient step: finite, from a time >= 0.
absl::Status ValidateTransientAndStep(const GyroTruth& g, const std::string& f) {
  if (g.transient_drift) {
    RETURN_IF_ERROR(FiniteVector(g.transient_drift->amplitude_k_rad_s,
                                 f + ".transient_drift.amplitude_k_rad_s"));
    RETURN_IF_ERROR(
        Positive(g.transient_drift->time_constant_s, f + ".transient_drift.time_constant_s"));
    if (!(g.transient_drift->start_s >= 0.0) || !std::isfinite(g.transient_drift->start_s)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s.transient_drift.start_s: must be finite and >= 0, got %g", f,
                          g.transient_drift->start_s));
    }
  }
  if (g.coefficient_step) {
    const CoefficientStep& c = *g.coefficient_step;
    if (!(c.time_s >= 0.0) || !std::isfinite(c.time_s)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s.coefficient_step.time_s: must be finite and >= 0, got %g", f, c.time_s));
    }
    if (!c.delta.AsVector().allFinite()) {
      return absl::InvalidArgumentError(absl::StrCat(f, ".coefficient_step.delta: must be finite"));
    }
  }
  return absl::OkStatus();
}

// The drift following a channel: its parameters, its heater, and a telemetered channel (and
// heater state) declared in the configuration.
absl::Status ValidateChannelDrift(const SimulationSpec& spec, const GyroTruth& g,
                                  const std::string& f) {
  if (g.channel_drift) {
    const ChannelDrift& c = *g.channel_drift;
    const std::string p = f + ".channel_drift";
    RETURN_IF_ERROR(ValidateChannelName(c.channel, p + ".channel"));
    RETURN_IF_ERROR(FiniteVector(c.gain_k_rad_s_per_unit, p + ".gain_k_rad_s_per_unit"));
    RETURN_IF_ERROR(Positive(c.spread, p + ".spread"));
    RETURN_IF_ERROR(Positive(c.correlation_time_s, p + ".correlation_time_s"));
    if (!std::isfinite(c.mean)) return absl::InvalidArgumentError(p + ".mean: must be finite");
    if (!(c.noise >= 0.0) || !std::isfinite(c.noise)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s.noise: must be finite and >= 0, got %g", p, c.noise));
    }
    if (!(c.lag_s >= 0.0) || !std::isfinite(c.lag_s)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s.lag_s: must be finite and >= 0, got %g", p, c.lag_s));
    }
    if (c.derivative && !(c.lag_s > 0.0)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s.lag_s: the derivative is the lag's, so it must be > 0, got %g", p, c.lag_s));
    }
    const auto declared = [&](const std::string& name) {
      return std::any_of(spec.config.channels.begin(), spec.config.channels.end(),
                         [&](const ChannelConfig& d) { return d.name == name; });
    };
    if (c.telemetered && !declared(c.channel)) {
      return absl::InvalidArgumentError(absl::StrCat(
          p, ".channel: \"", c.channel,
          "\" is not declared in the configuration's channels (a telemetered channel must be)"));
    }
    if (c.heater) {
      const ChannelHeater& h = *c.heater;
      const std::string hp = p + ".heater";
      RETURN_IF_ERROR(Positive(h.period_s, hp + ".period_s"));
      if (!(h.on_fraction > 0.0 && h.on_fraction < 1.0)) {
        return absl::InvalidArgumentError(
            absl::StrFormat("%s.on_fraction: must be in (0, 1), got %g", hp, h.on_fraction));
      }
      if (!std::isfinite(h.step)) {
        return absl::InvalidArgumentError(hp + ".step: must be finite");
      }
      if (!h.channel.empty()) {
        RETURN_IF_ERROR(ValidateChannelName(h.channel, hp + ".channel"));
        if (h.channel == c.channel) {
          return absl::InvalidArgumentError(
              absl::StrCat(hp, ".channel: \"", h.channel, "\" is the temperature's channel too"));
        }
        if (c.telemetered && !declared(h.channel)) {
          return absl::InvalidArgumentError(
              absl::StrCat(hp, ".channel: \"", h.channel,
                           "\" is not declared in the configuration's channels (a telemetered "
                           "channel must be)"));
        }
      }
    }
  }
  return absl::OkStatus();
}

// A sun-driven effect's face (or the sunlit fraction, which needs the orbit), sign and time
// constant, over a run where the sun is known; f names the effect ("gyros[1].sun_face_drift").
absl::Status ValidateSunFace(const SimulationSpec& spec, int face_axis, int face_sign,
                             double time_constant_s, const std::string& f) {
  if (face_axis < 0 || face_axis > kSunlitFaceAxis) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s.face_axis: must be 0 (x), 1 (y), 2 (z) or %d (sunlit), got %d", f,
                        kSunlitFaceAxis, face_axis));
  }
  if (face_axis == kSunlitFaceAxis && !spec.earth_shadow) {
    return absl::InvalidArgumentError(
        absl::StrCat(f, ".face_axis: the sunlit fraction needs the orbit (earth_shadow)"));
  }
  if (face_sign != 1 && face_sign != -1) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s.face_sign: must be +1 or -1, got %d", f, face_sign));
  }
  RETURN_IF_ERROR(Positive(time_constant_s, f + ".time_constant_s"));
  for (const double t : {0.0, spec.duration}) {
    const auto s_in = SunDirection_in(spec.start + absl::Seconds(t));
    if (!s_in.ok()) {
      return absl::InvalidArgumentError(
          absl::StrCat(f, ": the run (start and duration) must lie where the sun is known: ",
                       s_in.status().message()));
    }
  }
  return absl::OkStatus();
}

// The drift following the sun on a face.
absl::Status ValidateSunFaceDrift(const SimulationSpec& spec, const GyroTruth& g,
                                  const std::string& f) {
  if (!g.sun_face_drift) return absl::OkStatus();
  const SunFaceDrift& d = *g.sun_face_drift;
  RETURN_IF_ERROR(FiniteVector(d.amplitude_k_rad_s, f + ".sun_face_drift.amplitude_k_rad_s"));
  return ValidateSunFace(spec, d.face_axis, d.face_sign, d.time_constant_s,
                         f + ".sun_face_drift");
}

// The effects of GyroTruth beyond the paper's models; f names the gyro.
absl::Status ValidateGyroEffects(const SimulationSpec& spec, const GyroTruth& g,
                                 const std::string& f) {
  RETURN_IF_ERROR(ValidateOrbitalDrift(spec, g, f));
  RETURN_IF_ERROR(ValidateMovingDisplacement(spec, g, f));
  RETURN_IF_ERROR(ValidateReadoutAndRandomDrifts(spec, g, f));
  RETURN_IF_ERROR(ValidateTransientAndStep(g, f));
  RETURN_IF_ERROR(ValidateChannelDrift(spec, g, f));
  return ValidateSunFaceDrift(spec, g, f);
}

// The Earth-shadow orbit: a positive period, finite angles, and a radius (Kepler's third law)
// at least 100 km above the equator.
absl::Status ValidateEarthShadow(const OrbitalOptions& o, absl::Time start) {
  if (!std::isfinite(o.inclination) || !std::isfinite(o.raan) || !std::isfinite(o.arg_latitude0) ||
      !std::isfinite(o.period) || !(o.period > 0.0)) {
    return absl::InvalidArgumentError(
        "earth_shadow: the orbit's period must be positive and its angles finite");
  }
  const double r_km =
      CircularOrbitState(o.inclination, o.raan, o.period, o.arg_latitude0, start, 0.0)
          .r_in_km.norm();
  if (r_km < kEarthEquatorialRadiusKm + 100.0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "earth_shadow: a period of %.1f min gives an orbit %.0f km from the Earth's centre, less "
        "than 100 km above its equator",
        o.period / 60.0, r_km));
  }
  return absl::OkStatus();
}

// Gyro id's truth (f names it): running and switched on only if configured, finite values, a
// displacement inside the suspension gap, a fault with its window, and the effects beyond the
// paper's models.
absl::Status ValidateGyroTruth(const SimulationSpec& spec, int id, const std::string& f) {
  const GyroTruth& g = spec.gyros[id - 1];
  if (g.running.value_or(false) && spec.config.FindGyro(id) == nullptr) {
    return absl::InvalidArgumentError(
        absl::StrCat(f, ".running: gyro ", id, " is not in the configuration"));
  }
  if (g.switch_on_time) {
    if (!std::isfinite(*g.switch_on_time)) {
      return absl::InvalidArgumentError(absl::StrCat(f, ".switch_on_time: must be finite"));
    }
    if (g.running == false) {
      return absl::InvalidArgumentError(
          absl::StrCat(f, ".switch_on_time: set for a gyro with running = false"));
    }
    if (spec.config.FindGyro(id) == nullptr) {
      return absl::InvalidArgumentError(
          absl::StrCat(f, ".switch_on_time: gyro ", id, " is not in the configuration"));
    }
  }
  if (g.drift && !g.drift->AsVector().allFinite()) {
    return absl::InvalidArgumentError(absl::StrCat(f, ".drift: values must be finite"));
  }
  RETURN_IF_ERROR(FiniteVector(g.rotor_displacement_k, f + ".rotor_displacement_k"));
  if ((g.rotor_displacement_k.array().abs() >= spec.config.suspension.gap).any()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s.rotor_displacement_k: a component reaches the suspension gap %g m", f,
                        spec.config.suspension.gap));
  }
  if (!std::isfinite(g.c10_per_m) || !std::isfinite(g.c20_per_m)) {
    return absl::InvalidArgumentError(absl::StrCat(f, ".c10_per_m/c20_per_m: must be finite"));
  }
  RETURN_IF_ERROR(FiniteAtLeast(g.voltage_noise, 0.0, f + ".voltage_noise"));
  RETURN_IF_ERROR(FiniteVector(g.misalignment_b, f + ".misalignment_b"));
  if (g.random_walk) RETURN_IF_ERROR(FiniteAtLeast(*g.random_walk, 0.0, f + ".random_walk"));
  if (g.readout_noise) {
    RETURN_IF_ERROR(FiniteAtLeast(*g.readout_noise, 0.0, f + ".readout_noise"));
  }
  if (g.fault) {
    if (!std::isfinite(g.fault->time)) {
      return absl::InvalidArgumentError(absl::StrCat(f, ".fault.time: must be finite"));
    }
    RETURN_IF_ERROR(FiniteVector(g.fault->value, f + ".fault.value"));
    const bool windowed = g.fault->kind == GyroFault::Kind::kReadingFrozen ||
                          g.fault->kind == GyroFault::Kind::kReadingsMissing;
    if (windowed && (std::isnan(g.fault->end) || !(g.fault->end > g.fault->time))) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s.fault.end: must be after fault.time %g s, got %g s", f, g.fault->time, g.fault->end));
    }
  }
  if (g.initial_h_k && (!g.initial_h_k->allFinite() || g.initial_h_k->norm() < 1e-9)) {
    return absl::InvalidArgumentError(
        absl::StrCat(f, ".initial_h_k: must be a finite non-zero vector"));
  }
  return ValidateGyroEffects(spec, g, f);
}

// The star tracker's truth: noise, outliers, invalid frames, outages, frozen spans, a burst, a
// misalignment that jumps, cycles or follows the sun, the latency and the misalignment.
absl::Status ValidateStarTrackerTruth(const SimulationSpec& spec) {
  const StarTrackerTruth& st = spec.star_tracker;
  if (st.noise) {
    if (!st.noise->allFinite() || (st.noise->array() < 0.0).any()) {
      return absl::InvalidArgumentError("star_tracker.noise: values must be finite and >= 0");
    }
  }
  RETURN_IF_ERROR(Probability(st.outlier_probability, "star_tracker.outlier_probability"));
  RETURN_IF_ERROR(FiniteAtLeast(st.outlier_size, 0.0, "star_tracker.outlier_size"));
  RETURN_IF_ERROR(Probability(st.invalid_probability, "star_tracker.invalid_probability"));
  RETURN_IF_ERROR(CheckWindows(st.outages, "star_tracker.outages"));
  RETURN_IF_ERROR(CheckWindows(st.frozen, "star_tracker.frozen"));
  if (st.outlier_burst) {
    if (!std::isfinite(st.outlier_burst->time)) {
      return absl::InvalidArgumentError("star_tracker.outlier_burst.time: must be finite");
    }
    if (st.outlier_burst->count < 1) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "star_tracker.outlier_burst.count: must be >= 1, got %d", st.outlier_burst->count));
    }
    RETURN_IF_ERROR(Positive(st.outlier_burst->angle, "star_tracker.outlier_burst.angle"));
  }
  if (st.misalignment_jump) {
    if (!std::isfinite(st.misalignment_jump->time)) {
      return absl::InvalidArgumentError("star_tracker.misalignment_jump.time: must be finite");
    }
    RETURN_IF_ERROR(FiniteVector(st.misalignment_jump->rotation_b,
                                 "star_tracker.misalignment_jump.rotation_b"));
  }
  if (st.sun_mount) {
    RETURN_IF_ERROR(FiniteVector(st.sun_mount->rotation_b, "star_tracker.sun_mount.rotation_b"));
    RETURN_IF_ERROR(ValidateSunFace(spec, st.sun_mount->face_axis, st.sun_mount->face_sign,
                                    st.sun_mount->time_constant_s, "star_tracker.sun_mount"));
  }
  if (st.misalignment_cycle) {
    RETURN_IF_ERROR(FiniteVector(st.misalignment_cycle->amplitude_b,
                                 "star_tracker.misalignment_cycle.amplitude_b"));
    RETURN_IF_ERROR(
        Positive(st.misalignment_cycle->period_s, "star_tracker.misalignment_cycle.period_s"));
    if (!std::isfinite(st.misalignment_cycle->phase_rad)) {
      return absl::InvalidArgumentError(
          "star_tracker.misalignment_cycle.phase_rad: must be finite");
    }
  }
  if (!std::isfinite(st.latency)) {
    return absl::InvalidArgumentError("star_tracker.latency: must be finite");
  }
  RETURN_IF_ERROR(FiniteVector(st.misalignment_b, "star_tracker.misalignment_b"));
  return absl::OkStatus();
}

}  // namespace

absl::Status ValidateSimulationSpec(const SimulationSpec& spec) {
  RETURN_IF_ERROR(ValidateConfig(spec.config));
  if (spec.profile == nullptr) {
    return absl::InvalidArgumentError("profile: an attitude profile is required");
  }
  RETURN_IF_ERROR(Positive(spec.duration, "duration"));
  RETURN_IF_ERROR(Positive(spec.telemetry_step, "telemetry_step"));
  RETURN_IF_ERROR(Positive(spec.integration_rate_hz, "integration_rate_hz"));
  if (spec.duration / spec.telemetry_step > kMaxFrames) {
    return absl::InvalidArgumentError(
        absl::StrFormat("telemetry_step: %g s over %g s gives more than %g frames",
                        spec.telemetry_step, spec.duration, kMaxFrames));
  }
  if (spec.duration * spec.integration_rate_hz > kMaxSteps) {
    return absl::InvalidArgumentError(
        absl::StrFormat("integration_rate_hz: %g Hz over %g s gives more than %g steps",
                        spec.integration_rate_hz, spec.duration, kMaxSteps));
  }
  if (spec.earth_shadow) RETURN_IF_ERROR(ValidateEarthShadow(*spec.earth_shadow, spec.start));
  for (int id = 1; id <= kMaxGyros; ++id) {
    const std::string f = absl::StrFormat("gyros[%d] (gyro %d)", id - 1, id);
    RETURN_IF_ERROR(ValidateGyroTruth(spec, id, f));
  }
  return ValidateStarTrackerTruth(spec);
}

}  // namespace esg::estimator
