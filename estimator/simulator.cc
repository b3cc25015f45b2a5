#include "estimator/simulator.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "estimator/channels.h"
#include "estimator/eclipse.h"
#include "estimator/orbit.h"
#include "estimator/random.h"
#include "estimator/rotation.h"
#include "estimator/simulator_star_tracker.h"
#include "estimator/simulator_sun.h"
#include "estimator/simulator_truth.h"
#include "estimator/status_macros.h"
#include "estimator/sun_direction.h"

namespace esg::estimator {

using Eigen::Matrix3d;
using Eigen::Quaterniond;
using Eigen::Vector3d;
using simulator_internal::StarTrackerSampler;
using simulator_internal::SunNodes;

namespace {

// Random-stream ids (DeriveSeed). Gyro streams: kGyroStreamBase + 16 * id + offset.
// The star tracker's streams are 1-3 (simulator_star_tracker.h).
constexpr uint64_t kGyroStreamBase = 100;
constexpr uint64_t kReadoutOffset = 0;
constexpr uint64_t kVoltageOffset = 1;
constexpr uint64_t kRandomWalkOffset = 2;
constexpr uint64_t kSwitchingOffset = 3;
constexpr uint64_t kHiddenDriverOffset = 4;
constexpr uint64_t kChannelDriverOffset = 5;
constexpr uint64_t kChannelNoiseOffset = 6;

uint64_t GyroStream(int id, uint64_t offset) { return kGyroStreamBase + 16 * id + offset; }

int64_t NumFrames(const SimulationSpec& spec) {
  // Frames at m * telemetry_step <= duration (1e-9 relative slack for rounding).
  return static_cast<int64_t>(
             std::floor(spec.duration / spec.telemetry_step * (1.0 + 1e-12) + 1e-9)) +
         1;
}

// Everything the loop needs per running gyro, computed once.
struct GyroState {
  int id = 0;
  Matrix3d C_b_k;  // true mounting
  Matrix3d C_k_b;
  // True drift, the paper's printed formulas (estimator/simulator_truth.h), never the filter's
  // drift model.
  simulator_truth::PrintedDrift drift;
  Vector3d h_in;
  Vector3d dw_in_prev = Vector3d::Zero();  // last step's drift, for the midpoint predictor
  Vector3d dw_rw_in = Vector3d::Zero();    // random-walk drift, inertial axes
  double rw_intensity = 0.0;               // [rad/s/sqrt(s)]
  double readout_noise = 0.0;
  double voltage_noise = 0.0;
  Vector3d u_offset_k;  // eq. (3) inverse of the displacement [V]
  std::optional<GyroFault> fault;
  double switch_on_time = -std::numeric_limits<double>::infinity();  // [s]
  std::optional<GyroReading> held_reading;  // the frozen reading inside a kReadingFrozen window

  // Effects beyond the paper's models (GyroTruth). With a displacement rate or turn the printed
  // drift is rebuilt from Delta(t) (model coefficients, c10_per_m and c20_per_m kept for it).
  bool displacement_varies = false;  // a rate, a turn or both
  DriftCoefficients model;
  Vector3d displacement0_k = Vector3d::Zero();  // [m]
  Vector3d displacement_rate_k = Vector3d::Zero();  // [m/s]
  bool displacement_turns = false;
  Vector3d turn_axis_k = Vector3d::UnitZ();  // unit, case axes [1]
  double turn_period_s = 1.0;                // [s]
  double c10_per_m = 0.0, c20_per_m = 0.0;
  bool has_orbital = false;
  Vector3d orbital_amplitude_k = Vector3d::Zero();  // [rad/s]
  double orbital_omega = 0.0;                      // 2 pi / period [rad/s]
  double orbital_phase = 0.0;                      // [rad]
  bool has_distortion = false;
  Matrix3d I_plus_D = Matrix3d::Identity();
  bool has_switching = false;
  Vector3d switching_amplitude_k = Vector3d::Zero();  // [rad/s]
  double switching_initial_level = 0.0;
  std::vector<double> switch_times;  // [s], increasing
  bool has_hidden = false;
  Vector3d hidden_amplitude_k = Vector3d::Zero();  // [rad/s]
  double hidden_tau = 0.0;                         // [s]
  double hidden_x = 0.0;                           // x(t) at the current propagation time [1]
  bool has_rate = false;
  Matrix3d rate_gain_k = Matrix3d::Zero();  // [1]
  bool has_transient = false;
  Vector3d transient_amplitude_k = Vector3d::Zero();  // [rad/s]
  double transient_tau = 1.0;                         // [s]
  double transient_start = 0.0;                       // [s]
  bool has_sun = false;
  Vector3d sun_amplitude_k = Vector3d::Zero();  // [rad/s]
  int sun_face_axis = 0;
  double sun_face_sign = 1.0;
  double sun_tau = 1.0;  // [s]
  double sun_y = 0.0;    // lagged illumination y at the current propagation time [1]
  // The channel drift (ChannelDrift): x the driver at the current propagation time [1], y the
  // lagged temperature there [the channel's unit].
  std::optional<ChannelDrift> channel;
  double channel_x = 0.0;
  double channel_y = 0.0;
  bool has_extra_drift = false;  // any of orbital, switching, hidden, rate, transient, sun
  std::optional<CoefficientStep> coefficient_step;

  Rng readout_rng;
  Rng voltage_rng;
  Rng rw_rng;
  Rng switching_rng;
  Rng hidden_rng;
  Rng channel_rng;
  Rng channel_noise_rng;

  GyroState(int gyro_id, uint64_t seed)
      : id(gyro_id),
        readout_rng(DeriveSeed(seed, GyroStream(gyro_id, kReadoutOffset))),
        voltage_rng(DeriveSeed(seed, GyroStream(gyro_id, kVoltageOffset))),
        rw_rng(DeriveSeed(seed, GyroStream(gyro_id, kRandomWalkOffset))),
        switching_rng(DeriveSeed(seed, GyroStream(gyro_id, kSwitchingOffset))),
        hidden_rng(DeriveSeed(seed, GyroStream(gyro_id, kHiddenDriverOffset))),
        channel_rng(DeriveSeed(seed, GyroStream(gyro_id, kChannelDriverOffset))),
        channel_noise_rng(DeriveSeed(seed, GyroStream(gyro_id, kChannelNoiseOffset))) {}

  // Whether the channel drift's heater is on at t [s since the start].
  bool HeaterOn(double t) const {
    if (!channel || !channel->heater) return false;
    const ChannelHeater& h = *channel->heater;
    return std::fmod(t, h.period_s) < h.on_fraction * h.period_s;
  }
  // The channel's true temperature at t, T = mean + spread x (+ the heater's step while it is on)
  // [the channel's unit], x at the current propagation time.
  double ChannelValue(double t) const {
    return channel->mean + channel->spread * channel_x +
           (HeaterOn(t) ? channel->heater->step : 0.0);
  }
  // The drift's signal for y, the lag at the same time as T: y - mean, or dy/dt = (T - y) / tau
  // per hour for the derivative.
  double ChannelSignal(double T, double y) const {
    return channel->derivative ? (T - y) / channel->lag_s * kSecondsPerHour : y - channel->mean;
  }

  // Delta(t) [m], case axes: Delta0 + rate t, turned right-handed by 2 pi t / P about the turn's
  // axis a when it turns (Rodrigues: v cos phi + (a x v) sin phi + a (a . v) (1 - cos phi)).
  Vector3d Displacement_k(double t) const {
    const Vector3d grown_k = displacement0_k + displacement_rate_k * t;
    if (!displacement_turns) return grown_k;
    const double phi_rad = 2.0 * kPi * (t / turn_period_s);
    const double c = std::cos(phi_rad);
    return c * grown_k + std::sin(phi_rad) * turn_axis_k.cross(grown_k) +
           ((1.0 - c) * turn_axis_k.dot(grown_k)) * turn_axis_k;
  }

  // The printed drift of eq. (1), (10) and eq. (8) + (9) at time t: with a growing or turning
  // displacement, eq. (8), (9) are evaluated with Delta(t).
  simulator_truth::PrintedDrift PrintedDriftAt(double t) const {
    return simulator_truth::FromGyroTruth(model, Displacement_k(t), c10_per_m, c20_per_m);
  }

  Vector3d OrbitalDrift_k(double t) const {
    return has_orbital ? Vector3d(orbital_amplitude_k * std::cos(orbital_omega * t + orbital_phase))
                       : Vector3d::Zero();
  }

  // +1 or -1 at t (the level flips at each switch time <= t); 0 without a switching drift.
  double SwitchingLevel(double t) const {
    if (!has_switching) return 0.0;
    const auto flips = std::upper_bound(switch_times.begin(), switch_times.end(), t) -
                       switch_times.begin();
    return flips % 2 == 0 ? switching_initial_level : -switching_initial_level;
  }

  // The rate-dependent drift for the body rate w_b [rad/s] (body axes).
  Vector3d RateDrift_k(const Vector3d& w_b) const {
    return has_rate ? Vector3d(rate_gain_k * (C_k_b * w_b)) : Vector3d::Zero();
  }

  // The warm-up transient at time t.
  Vector3d TransientDrift_k(double t) const {
    if (!has_transient || t < transient_start) return Vector3d::Zero();
    return transient_amplitude_k * std::exp(-(t - transient_start) / transient_tau);
  }

  // The face's illumination max(0, +-s_b[axis]) for the sun s_b in body axes.
  double SunIllumination(const Vector3d& s_b) const {
    // s_b is scaled by the sunlit fraction when the spacecraft flies an orbit (SunNodes::At).
    return simulator_internal::FaceIllumination(s_b, sun_face_axis, sun_face_sign);
  }

  // The coefficient step's drift at time t for the spin axis h_k.
  Vector3d CoefficientStepDrift_k(double t, const Vector3d& h_k) const {
    if (!coefficient_step || t < coefficient_step->time_s) return Vector3d::Zero();
    simulator_truth::PrintedDrift step;
    step.coefficients = coefficient_step->delta;
    return simulator_truth::TrueDriftRate_k(step, h_k);  // eq. (1), (10) as printed
  }

  // Fault drift step in case axes at time t.
  Vector3d FaultDrift_k(double t) const {
    if (fault && fault->kind == GyroFault::Kind::kDriftStep && t >= fault->time) {
      return fault->value;
    }
    return Vector3d::Zero();
  }

  // Whether t lies in the [time, end) window of a fault of this kind.
  bool InFaultWindow(GyroFault::Kind kind, double t) const {
    return fault && fault->kind == kind && t >= fault->time && t < fault->end;
  }
};

// h_in turned by the rotation vector a = dw_in dt (dh/dt = dw x h), by Rodrigues' formula
// h + (sin t / t) a x h + ((1 - cos t) / t^2) a x (a x h), t = |a|. For the tiny angles of drift
// (|a| ~ 1e-6 rad) the two coefficients come from their series, without trigonometry per step;
// above 1e-3 rad, where the truncated series terms (t^6 / 5040) would start to matter, from
// sin and cos. Written here rather than taken from the filter's spin-axis propagation.
Vector3d FastStepSpinAxis(const Vector3d& h_in, const Vector3d& dw_in, double dt) {
  const Vector3d a = dw_in * dt;
  const double theta2 = a.squaredNorm();
  double sin_over, one_minus_cos_over;
  if (theta2 > 1e-6) {
    const double theta = std::sqrt(theta2);
    sin_over = std::sin(theta) / theta;
    one_minus_cos_over = (1.0 - std::cos(theta)) / theta2;
  } else {
    sin_over = 1.0 - theta2 / 6.0 * (1.0 - theta2 / 20.0);             // sin(t)/t
    one_minus_cos_over = 0.5 - theta2 / 24.0 * (1.0 - theta2 / 30.0);  // (1-cos t)/t^2
  }
  const Vector3d axh = a.cross(h_in);
  return (h_in + sin_over * axh + one_minus_cos_over * a.cross(axh)).normalized();
}

}  // namespace

Vector3d DefaultInitialSpinAxis(int id) {
  switch (id) {
    case 1:
      return Vector3d(0.2, 0.3, 0.93).normalized();
    case 2:
      return Vector3d(0.93, 0.2, 0.3).normalized();
    case 3:
      return Vector3d(0.3, 0.93, 0.2).normalized();
    default:
      return Vector3d(-0.5, 0.5, 0.7).normalized();
  }
}

bool GyroRuns(const SimulationSpec& spec, int id) {
  if (id < 1 || id > kMaxGyros) return false;
  const GyroTruth& truth = spec.gyros[id - 1];
  if (truth.running.has_value()) return *truth.running;
  if (truth.switch_on_time.has_value()) return true;
  if (spec.config.FindGyro(id) == nullptr) return false;
  const auto& w = spec.config.working_pair;
  const auto& r = spec.config.reserve_pair;
  return id == w[0] || id == w[1] || id == r[0] || id == r[1];
}

namespace {

// A result with the recording's metadata set and room for num_frames frames and truth samples.
SimulationResult StartResult(const SimulationSpec& spec, int64_t num_frames) {
  SimulationResult result;
  Recording& recording = result.recording;
  recording.metadata["spacecraft_id"] = spec.config.spacecraft_id;
  recording.metadata["seed"] = absl::StrCat(spec.seed);
  recording.metadata["profile"] = spec.profile->Describe();
  recording.metadata["source"] = "esg simulator";
  recording.metadata["telemetry_step_s"] = absl::StrFormat("%.17g", spec.telemetry_step);
  recording.metadata["integration_rate_hz"] = absl::StrFormat("%.17g", spec.integration_rate_hz);
  recording.frames.reserve(num_frames);
  result.truth.reserve(num_frames);
  return result;
}

// Gyro id's paper-model state: true mounting, printed drift, noise levels, offset voltages, fault,
// switch-on time and the spin axis at the start (C_in_b0 the attitude at 0).
GyroState MakePaperGyro(const SimulationSpec& spec, int id, const Matrix3d& C_in_b0) {
  const SpacecraftConfig& config = spec.config;
  const GyroTruth& truth = spec.gyros[id - 1];
  const GyroConfig& gc = *config.FindGyro(id);
  GyroState g(id, spec.seed);
  g.C_b_k = ExpMatrix(truth.misalignment_b) * gc.C_b_k;
  g.C_k_b = g.C_b_k.transpose();
  g.drift =
      simulator_truth::FromGyroTruth(truth.drift.value_or(gc.model), truth.rotor_displacement_k,
                                     truth.c10_per_m, truth.c20_per_m);
  g.rw_intensity = truth.random_walk.value_or(config.random_walk);
  g.readout_noise = truth.readout_noise.value_or(config.readout_noise);
  g.voltage_noise = truth.voltage_noise;
  const SuspensionConfig& s = config.suspension;
  for (int axis = 0; axis < 3; ++axis) {
    g.u_offset_k(axis) = OffsetVoltageFromDisplacement(
        truth.rotor_displacement_k(axis), s.amplifier_gain, s.reference_voltage, s.gap);
  }
  g.fault = truth.fault;
  if (truth.switch_on_time) g.switch_on_time = *truth.switch_on_time;
  const Vector3d h_k0 = truth.initial_h_k.value_or(DefaultInitialSpinAxis(id)).normalized();
  g.h_in = (C_in_b0 * g.C_b_k * h_k0).normalized();
  return g;
}

// Turns on g's effects beyond the paper's models as its truth asks, recording each in effects;
// each draws only from its own stream, and only when on. Makes sun_nodes at the first sun-face
// drift; fails only when the sun's direction cannot be computed.
absl::Status SetUpGyroEffects(const SimulationSpec& spec, const Matrix3d& C_in_b0, GyroState& g,
                              GyroEffectsTruth& effects, std::optional<SunNodes>& sun_nodes) {
  const GyroTruth& truth = spec.gyros[g.id - 1];
  const GyroConfig& gc = *spec.config.FindGyro(g.id);
  g.displacement0_k = truth.rotor_displacement_k;
  if (!truth.rotor_displacement_rate_k_m_s.isZero(0.0) || truth.rotor_displacement_turn) {
    g.displacement_varies = true;
    g.model = truth.drift.value_or(gc.model);
    g.displacement_rate_k = truth.rotor_displacement_rate_k_m_s;
    g.c10_per_m = truth.c10_per_m;
    g.c20_per_m = truth.c20_per_m;
    effects.rotor_displacement_rate_k_m_s = truth.rotor_displacement_rate_k_m_s;
  }
  if (truth.rotor_displacement_turn) {
    g.displacement_turns = true;
    g.turn_axis_k = truth.rotor_displacement_turn->axis_k.normalized();
    g.turn_period_s = truth.rotor_displacement_turn->period_s;
    effects.rotor_displacement_turn = DisplacementTurn{g.turn_axis_k, g.turn_period_s};
  }
  if (truth.orbital_drift) {
    OrbitalDrift o = *truth.orbital_drift;
    if (!o.period_s) o.period_s = spec.profile->OrbitalPeriod();
    g.has_orbital = true;
    g.orbital_amplitude_k = o.amplitude_k_rad_s;
    g.orbital_omega = 2.0 * kPi / *o.period_s;
    g.orbital_phase = o.phase_rad;
    effects.orbital_drift = o;
  }
  if (!truth.readout_distortion_k.isZero(0.0)) {
    g.has_distortion = true;
    g.I_plus_D = Matrix3d::Identity() + truth.readout_distortion_k;
    effects.readout_distortion_k = truth.readout_distortion_k;
  }
  if (truth.switching_drift) {
    // Random telegraph process: the level at 0 is +-1 with probability 1/2, then exponential
    // dwell times (inverse transform, 1 - U in (0, 1]), all drawn now for the whole run.
    g.has_switching = true;
    g.switching_amplitude_k = truth.switching_drift->amplitude_k_rad_s;
    g.switching_initial_level = g.switching_rng.Uniform() < 0.5 ? 1.0 : -1.0;
    const double tau = truth.switching_drift->mean_dwell_s;
    for (double t_switch = -tau * std::log(1.0 - g.switching_rng.Uniform());
         t_switch <= spec.duration;
         t_switch += -tau * std::log(1.0 - g.switching_rng.Uniform())) {
      g.switch_times.push_back(t_switch);
    }
    effects.switching_drift = truth.switching_drift;
    effects.switching_initial_level = g.switching_initial_level;
    effects.switch_times_s = g.switch_times;
  }
  if (truth.hidden_driver_drift) {
    g.has_hidden = true;
    g.hidden_amplitude_k = truth.hidden_driver_drift->amplitude_k_rad_s;
    g.hidden_tau = truth.hidden_driver_drift->correlation_time_s;
    g.hidden_x = g.hidden_rng.Normal();  // stationary start: x(0) ~ N(0, 1)
    effects.hidden_driver_drift = truth.hidden_driver_drift;
  }
  if (truth.rate_drift) {
    g.has_rate = true;
    g.rate_gain_k = truth.rate_drift->gain_k;
    effects.rate_drift = truth.rate_drift;
  }
  g.coefficient_step = truth.coefficient_step;
  if (truth.transient_drift) {
    g.has_transient = true;
    g.transient_amplitude_k = truth.transient_drift->amplitude_k_rad_s;
    g.transient_tau = truth.transient_drift->time_constant_s;
    g.transient_start = truth.transient_drift->start_s;
    effects.transient_drift = truth.transient_drift;
  }
  if (truth.sun_face_drift) {
    if (!sun_nodes) {
      ASSIGN_OR_RETURN(SunNodes nodes, SunNodes::Make(spec.start, spec.duration, spec.earth_shadow));
      sun_nodes = std::move(nodes);
    }
    g.has_sun = true;
    g.sun_amplitude_k = truth.sun_face_drift->amplitude_k_rad_s;
    g.sun_face_axis = truth.sun_face_drift->face_axis;
    g.sun_face_sign = truth.sun_face_drift->face_sign;
    g.sun_tau = truth.sun_face_drift->time_constant_s;
    // The face in equilibrium with its illumination at the start: y(0) = u(0).
    g.sun_y = g.SunIllumination(C_in_b0.transpose() * sun_nodes->At(0.0));
    effects.sun_face_drift = truth.sun_face_drift;
  }
  if (truth.channel_drift) {
    g.channel = truth.channel_drift;
    g.channel_x = g.channel_rng.Normal();  // stationary start: x(0) ~ N(0, 1)
    g.channel_y = g.ChannelValue(0.0);     // the lag in equilibrium at the start
    effects.channel_drift = truth.channel_drift;
  }
  g.has_extra_drift = g.has_orbital || g.has_switching || g.has_hidden || g.has_rate ||
                      g.has_transient || g.has_sun;
  return absl::OkStatus();
}

// The running gyros in id order, each set up with its effects; fills result's true coefficients
// and effects truth, and sun_nodes when a gyro has a sun-face drift.
absl::StatusOr<std::vector<GyroState>> SetUpGyros(const SimulationSpec& spec,
                                                  SimulationResult& result,
                                                  std::optional<SunNodes>& sun_nodes) {
  std::vector<GyroState> gyros;
  const Matrix3d C_in_b0 = spec.profile->Attitude(0.0).toRotationMatrix();
  for (int id = 1; id <= kMaxGyros; ++id) {
    if (!GyroRuns(spec, id)) continue;
    GyroState g = MakePaperGyro(spec, id, C_in_b0);
    result.true_coefficients[id - 1] = simulator_truth::EquivalentCoefficients(g.drift);
    RETURN_IF_ERROR(SetUpGyroEffects(spec, C_in_b0, g, result.effects[id - 1], sun_nodes));
    gyros.push_back(std::move(g));
  }
  return gyros;
}

// Truth integration: advances every gyro's spin axis and drift states over the step [t0, t0 + h].
class TruthIntegrator {
 public:
  TruthIntegrator(const AttitudeProfile& profile, const std::optional<SunNodes>& sun_nodes,
                  std::vector<GyroState>& gyros)
      : profile_(profile),
        sun_nodes_(sun_nodes),
        gyros_(gyros),
        any_rate_drift_(std::any_of(gyros.begin(), gyros.end(),
                                    [](const GyroState& g) { return g.has_rate; })) {}

  // One integration step [t0, t0 + h]: drift at the midpoint (attitude at t_mid, h_in
  // extrapolated half a step with the previous drift), then h_in turned by dw_in * h.
  void Step(double t0, double h) {
    const double t_mid = t0 + 0.5 * h;
    const Matrix3d C_in_b = profile_.Attitude(t_mid).toRotationMatrix();
    const double sqrt_h = std::sqrt(h);
    const Vector3d w_b = any_rate_drift_ ? profile_.Rate(t_mid) : Vector3d::Zero();
    const Vector3d s_b = sun_nodes_ ? Vector3d(C_in_b.transpose() * sun_nodes_->At(t_mid))
                                    : Vector3d::Zero();
    for (GyroState& g : gyros_) StepGyro(g, t_mid, h, sqrt_h, C_in_b, w_b, s_b);
  }

 private:
  // Gyro g over the step of length h with midpoint t_mid (attitude C_in_b, body rate w_b, sun
  // s_b in body axes there).
  static void StepGyro(GyroState& g, double t_mid, double h, double sqrt_h, const Matrix3d& C_in_b,
                       const Vector3d& w_b, const Vector3d& s_b) {
    const Vector3d h_mid = g.h_in + (0.5 * h) * g.dw_in_prev.cross(g.h_in);
    const Vector3d h_k = g.C_k_b * (C_in_b.transpose() * h_mid);
    Vector3d dw_k = g.displacement_varies
                        ? simulator_truth::TrueDriftRate_k(g.PrintedDriftAt(t_mid), h_k)
                        : simulator_truth::TrueDriftRate_k(g.drift, h_k);
    if (g.fault) dw_k += g.FaultDrift_k(t_mid);
    if (g.coefficient_step) dw_k += g.CoefficientStepDrift_k(t_mid, h_k);
    if (g.has_extra_drift) {
      dw_k += g.OrbitalDrift_k(t_mid) + g.SwitchingLevel(t_mid) * g.switching_amplitude_k +
              g.hidden_x * g.hidden_amplitude_k + g.RateDrift_k(w_b) + g.TransientDrift_k(t_mid);
    }
    if (g.has_sun) {
      // The lag stepped exactly for the illumination u at the midpoint: y at the midpoint for
      // the drift, y at the step end for the next step.
      const double u = g.SunIllumination(s_b);
      dw_k += (u + (g.sun_y - u) * std::exp(-0.5 * h / g.sun_tau)) * g.sun_amplitude_k;
      g.sun_y = u + (g.sun_y - u) * std::exp(-h / g.sun_tau);
    }
    if (g.channel) {
      // T held over the step at its start; y at the midpoint for the drift, at the end for the
      // next step (exact for T held); without a lag y is T.
      const ChannelDrift& c = *g.channel;
      const double T = g.ChannelValue(t_mid - 0.5 * h);
      const double y_mid =
          c.lag_s > 0.0 ? T + (g.channel_y - T) * std::exp(-0.5 * h / c.lag_s) : T;
      dw_k += g.ChannelSignal(T, y_mid) * c.gain_k_rad_s_per_unit;
      g.channel_y = c.lag_s > 0.0 ? T + (g.channel_y - T) * std::exp(-h / c.lag_s) : T;
      const double a = std::exp(-h / c.correlation_time_s);
      g.channel_x = a * g.channel_x + std::sqrt(-std::expm1(-2.0 * h / c.correlation_time_s)) *
                                          g.channel_rng.Normal();
      if (c.lag_s == 0.0) g.channel_y = g.ChannelValue(t_mid + 0.5 * h);
    }
    const Vector3d dw_in = C_in_b * (g.C_b_k * dw_k) + g.dw_rw_in;
    g.h_in = FastStepSpinAxis(g.h_in, dw_in, h);
    g.dw_in_prev = dw_in;
    if (g.rw_intensity > 0.0) g.dw_rw_in += (g.rw_intensity * sqrt_h) * g.rw_rng.Normal3();
    if (g.has_hidden) {
      // Exact OU step over h: a = exp(-h / tau), innovation variance 1 - a^2 = -expm1(-2h/tau).
      const double a = std::exp(-h / g.hidden_tau);
      g.hidden_x = a * g.hidden_x + std::sqrt(-std::expm1(-2.0 * h / g.hidden_tau)) *
                                        g.hidden_rng.Normal();
    }
  }

  const AttitudeProfile& profile_;
  const std::optional<SunNodes>& sun_nodes_;
  std::vector<GyroState>& gyros_;
  const bool any_rate_drift_;
};

// Gyro g's truth at t_m (C_b_in the true attitude's transpose there): spin axis, mounting,
// displacement and every drift term.
GyroTruthSample GyroTruthAt(const GyroState& g, double t_m, const Matrix3d& C_b_in,
                            const AttitudeProfile& profile,
                            const std::optional<SunNodes>& sun_nodes) {
  GyroTruthSample gt;
  gt.h_in = g.h_in;
  gt.h_k = (g.C_k_b * (C_b_in * g.h_in)).normalized();
  gt.C_b_k = g.C_b_k;
  gt.rotor_displacement_k_m = g.Displacement_k(t_m);
  const Vector3d dw_model_k = g.displacement_varies
                                  ? simulator_truth::TrueDriftRate_k(g.PrintedDriftAt(t_m), gt.h_k)
                                  : simulator_truth::TrueDriftRate_k(g.drift, gt.h_k);
  gt.dw_k = dw_model_k + g.FaultDrift_k(t_m) + g.CoefficientStepDrift_k(t_m, gt.h_k) +
            g.C_k_b * (C_b_in * g.dw_rw_in);
  if (g.has_extra_drift) {
    gt.dw_orbital_k_rad_s = g.OrbitalDrift_k(t_m);
    gt.switching_level = g.SwitchingLevel(t_m);
    gt.dw_switching_k_rad_s = gt.switching_level * g.switching_amplitude_k;
    gt.hidden_driver = g.has_hidden ? g.hidden_x : 0.0;
    gt.dw_hidden_k_rad_s = gt.hidden_driver * g.hidden_amplitude_k;
    gt.dw_rate_k_rad_s = g.RateDrift_k(g.has_rate ? profile.Rate(t_m) : Vector3d::Zero());
    gt.dw_transient_k_rad_s = g.TransientDrift_k(t_m);
    if (g.has_sun) {
      gt.sun_illumination = g.SunIllumination(C_b_in * sun_nodes->At(t_m));
      gt.sun_lagged_illumination = g.sun_y;
      gt.dw_sun_k_rad_s = g.sun_y * g.sun_amplitude_k;
    }
    gt.dw_k += gt.dw_orbital_k_rad_s + gt.dw_switching_k_rad_s + gt.dw_hidden_k_rad_s +
               gt.dw_rate_k_rad_s + gt.dw_transient_k_rad_s + gt.dw_sun_k_rad_s;
  }
  if (g.channel) {
    gt.channel_value = g.ChannelValue(t_m);
    gt.channel_lagged = g.channel_y;
    gt.dw_channel_k_rad_s =
        g.ChannelSignal(gt.channel_value, g.channel_y) * g.channel->gain_k_rad_s_per_unit;
    gt.dw_k += gt.dw_channel_k_rad_s;
  }
  return gt;
}

// What gyro g reads at t_m for its truth gt: distortion, readout noise (two draws, always), a
// readout jump, then the offset voltages with their noise (three draws, always).
GyroReading ReadGyro(GyroState& g, const GyroTruthSample& gt, double t_m,
                     const SuspensionConfig& s) {
  // The pick-off's distortion, then readout noise: a small rotation perpendicular to the
  // distorted axis (two draws, always).
  const Vector3d h_read = g.has_distortion ? Vector3d((g.I_plus_D * gt.h_k).normalized()) : gt.h_k;
  const Vector3d e1 = AnyPerpendicular(h_read);
  const Vector3d e2 = h_read.cross(e1);
  const double n1 = g.readout_rng.Normal();
  const double n2 = g.readout_rng.Normal();
  Vector3d h_meas = ExpMatrix(g.readout_noise * (n1 * e1 + n2 * e2)) * h_read;
  if (g.fault && g.fault->kind == GyroFault::Kind::kReadoutJump && t_m >= g.fault->time) {
    h_meas = ExpMatrix(g.fault->value) * h_meas;
  }
  GyroReading reading;
  reading.h_k = h_meas.normalized();
  Vector3d u_offset_k = g.u_offset_k;
  if (g.displacement_varies) {
    // eq. (3) inverse at Delta(t_m), per suspension axis.
    for (int axis = 0; axis < 3; ++axis) {
      u_offset_k(axis) = OffsetVoltageFromDisplacement(
          gt.rotor_displacement_k_m(axis), s.amplifier_gain, s.reference_voltage, s.gap);
    }
  }
  const Vector3d u_k = u_offset_k + g.voltage_noise * g.voltage_rng.Normal3();
  reading.u_k_mv = u_k / kVoltsPerMv;
  return reading;
}

// Every gyro's truth and reading at t_m into truth and frame. Switch-on, missing and frozen
// readings only decide what is telemetered, after the draws.
void SampleGyros(std::vector<GyroState>& gyros, double t_m, const SimulationSpec& spec,
                 const std::optional<SunNodes>& sun_nodes, TelemetryFrame& frame,
                 TruthSample& truth) {
  const Matrix3d C_b_in = truth.q_in_b.toRotationMatrix().transpose();
  for (GyroState& g : gyros) {
    const GyroTruthSample gt = GyroTruthAt(g, t_m, C_b_in, *spec.profile, sun_nodes);
    GyroReading reading = ReadGyro(g, gt, t_m, spec.config.suspension);
    if (g.channel) {
      // The channel's reading (one draw, always); carried whether the gyro's reading is.
      const double noise = g.channel->noise * g.channel_noise_rng.Normal();
      if (g.channel->telemetered) {
        frame.channels.Set(g.channel->channel, gt.channel_value + noise);
        if (g.channel->heater && !g.channel->heater->channel.empty()) {
          frame.channels.Set(g.channel->heater->channel, g.HeaterOn(t_m) ? 1.0 : 0.0);
        }
      }
    }
    if (t_m < g.switch_on_time) continue;
    truth.gyros[g.id - 1] = gt;
    if (g.InFaultWindow(GyroFault::Kind::kReadingsMissing, t_m)) continue;
    if (g.InFaultWindow(GyroFault::Kind::kReadingFrozen, t_m)) {
      if (!g.held_reading) g.held_reading = reading;
      reading = *g.held_reading;
    } else {
      g.held_reading.reset();
    }
    frame.gyros[g.id - 1] = reading;
  }
}

}  // namespace

absl::StatusOr<SimulationResult> Simulate(const SimulationSpec& spec,
                                          const std::function<void(double fraction)>& progress) {
  RETURN_IF_ERROR(ValidateSimulationSpec(spec));
  const AttitudeProfile& profile = *spec.profile;
  const double dt = 1.0 / spec.integration_rate_hz;
  const int64_t num_frames = NumFrames(spec);

  SimulationResult result = StartResult(spec, num_frames);
  // Made when a gyro has a SunFaceDrift or the star tracker's mount follows the sun.
  std::optional<SunNodes> sun_nodes;
  ASSIGN_OR_RETURN(std::vector<GyroState> gyros, SetUpGyros(spec, result, sun_nodes));
  if (spec.star_tracker.sun_mount && !sun_nodes) {
    ASSIGN_OR_RETURN(SunNodes nodes, SunNodes::Make(spec.start, spec.duration, spec.earth_shadow));
    sun_nodes = std::move(nodes);
  }
  StarTrackerSampler star_tracker(spec, sun_nodes ? &*sun_nodes : nullptr);
  TruthIntegrator integrator(profile, sun_nodes, gyros);

  const int64_t progress_every = std::max<int64_t>(1, num_frames / 100);
  double t = 0.0;
  int64_t grid_steps = 0;  // completed steps of the dt grid
  for (int64_t m = 0; m < num_frames; ++m) {
    const double t_m = static_cast<double>(m) * spec.telemetry_step;
    // Integrate to t_m on the dt grid (a partial step where t_m falls between grid points).
    while (t < t_m) {
      double next_grid = static_cast<double>(grid_steps + 1) * dt;
      if (std::abs(next_grid - t_m) <= 1e-9 * dt) next_grid = t_m;
      const double t_next = std::min(next_grid, t_m);
      integrator.Step(t, t_next - t);
      t = t_next;
      if (t_next == next_grid) ++grid_steps;
    }

    TelemetryFrame frame;
    TruthSample truth;
    frame.time = spec.start + absl::Seconds(t_m);
    truth.time = frame.time;
    truth.q_in_b = profile.Attitude(t_m);
    SampleGyros(gyros, t_m, spec, sun_nodes, frame, truth);
    star_tracker.Sample(t_m, frame, truth);

    result.recording.frames.push_back(std::move(frame));
    result.truth.push_back(std::move(truth));
    if (progress && m % progress_every == 0) {
      progress(static_cast<double>(m) / static_cast<double>(num_frames));
    }
  }
  if (progress) progress(1.0);
  return result;
}

}  // namespace esg::estimator
