// Seeded ESG / star-tracker telemetry simulator (the paper's flight-test setting, section 3:
// telemetry every 60 s, 8 Hz integration). It propagates each running gyro's true inertial spin
// axis h_in with the drift of eq. (1), (8)-(10) plus a random walk (model (11) style) and optional
// faults, and samples what the spacecraft telemeters: h_k with readout noise, the suspension
// offset voltages of eq. (3) and the star-tracker quaternion.
//
// Truth model (all SI):
// - Mounting: C_b_k_true = ExpMatrix(misalignment_b) * C_b_k(config), i.e. the case frame turned
//   by the small rotation vector misalignment_b expressed in body axes.
// - Drift: dw_k = the paper's printed component formulas (estimator/simulator_truth.h, which
//   never calls the filter's drift model estimator/drift_model.h): eq. (1) and (10) with the
//   coefficients `drift` (default the config model), plus eq. (8) + (9) for the rotor
//   displacement (lambda = Delta / |Delta|, C10 = c10_per_m |Delta|, C20 = c20_per_m |Delta|);
//   plus a fault drift step (case axes) after its time; plus a step of the coefficients
//   (CoefficientStep) after its time; plus the random-walk drift vector dw_rw_in
//   (inertial axes), which starts at zero and takes an independent N(0, q h I) step after every
//   integration step of length h (q = random_walk^2), so its increment over any interval T
//   between telemetry frames is N(0, q T I), independent of other intervals.
// - Effects beyond the paper's models (GyroTruth, each off by default), added to dw_k in case
//   axes: an orbital drift A cos(2 pi t / P + phase); a rotor displacement growing as
//   Delta(t) = Delta0 + rate t, and/or turning about a case axis a as Delta(t) = R(a, 2 pi t / P)
//   (Delta0 + rate t), with eq. (8) + (9) evaluated at Delta(t) (lambda = Delta(t) /
//   |Delta(t)|, C10 = c10_per_m |Delta(t)|, C20 = c20_per_m |Delta(t)|) and the voltages of
//   eq. (3) at Delta(t); a switching drift +-A (random telegraph process, switch times drawn for
//   the whole run at the start); a hidden-driver drift B x(t), x an Ornstein-Uhlenbeck process
//   of unit variance; a rate-dependent drift G w_k (w_k the body rate in case axes); a warm-up
//   transient A exp(-(t - t0) / tau) from t0; a sun-driven thermal drift A y(t), y the
//   first-order lag of the sun's illumination of one body face (SunFaceDrift). In a step the
//   switching level, the orbital drift, the body rate, the transient and the lagged illumination
//   are taken at the step midpoint, x(t) at the step start (then x is stepped exactly over the
//   step).
// - Propagation: h_in stepped at integration_rate_hz as StepSpinAxis(h_in, dw_in, dt) (a
//   rotation by dw_in dt, evaluated by its Rodrigues series for the tiny drift angles),
//   dw_in = C_in_b(t_mid) C_b_k_true dw_k evaluated at the step midpoint (attitude at t_mid, h_in
//   extrapolated half a step with the previous step's drift).
// - Gyro reading at each telemetry time: h_k_meas = Exp(jump_k) Exp(n) h_k_read, with
//   h_k_read = normalise((I + D) h_k_true) (D the readout distortion; h_k_read = h_k_true when D
//   is zero), n perpendicular to h_k_read with independent N(0, readout_noise^2) components on
//   two perpendicular axes; jump_k is the readout_jump fault (zero before its time). Voltages u_k = eq. (3) inverse of the rotor
//   displacement per case axis plus N(0, voltage_noise^2) each, written in mV. A reading_frozen
//   fault repeats the whole reading (h_k and voltages) of the first frame of its window in every
//   frame of the window; a readings_missing fault leaves the gyro's field empty in its window; a
//   gyro with a switch-on time has no field (and no truth sample) before it.
// - Star tracker: q_meas = q_in_b_true(t - latency) (x) Exp(misalignment_b) (x) Exp(cycle_b(t))
//   (x) Exp(mount_b(t)) (x) Exp(jump_b) (x) Exp(n) [(x) Exp(o)], cycle_b(t) the misalignment
//   cycling with the orbit (StarTrackerMisalignmentCycle, zero without one), mount_b(t) the
//   mount's turn following the sun (StarTrackerSunMount, zero without one),
//   n = (noise_x N, noise_y N, noise_z N) about body axes, jump_b the
//   misalignment jump (zero before its time), o an outlier with probability
//   outlier_probability: uniformly random axis, angle uniform in [outlier_size, 3 outlier_size].
//   The samples of an outlier burst carry instead o = angle * a_perp, a_perp the same per-frame
//   random axis with its boresight (body z) component removed, renormalised: a cross-boresight
//   outlier of exactly the burst's angle.
//   Inside an outage no star-tracker field; with probability invalid_probability valid = false.
//   Inside a frozen window every sample repeats the first sample of the window (quaternion, valid
//   flag and outlier truth), with the frame's own time stamp.
// Every random source has its own stream (DeriveSeed(seed, stream)), and every stream draws the
// same numbers per frame whether or not a sample is used, so turning on outliers, bursts,
// outages, frozen windows, misalignment jumps, invalid flags, missing or frozen gyro readings or a
// late switch-on never changes the gyro noise or the star-tracker noise of the other samples.
// The switching drift and the hidden driver draw from streams of their own too, so switching
// them on changes no other random number (only the spin axes they turn).
#ifndef ESG_ESTIMATOR_SIMULATOR_H_
#define ESG_ESTIMATOR_SIMULATOR_H_

#include <array>
#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/attitude_profile.h"
#include "estimator/conventions.h"
#include "estimator/drift_model.h"
#include "estimator/spacecraft_config.h"
#include "estimator/telemetry.h"
#include "estimator/units.h"

namespace esg::estimator {

// Paper sizes (section 1.1): C10 ~ 0.05 deg/h and C20 ~ 0.015 deg/h per um of rotor
// displacement, so 3 um gives C ~ 0.2 deg/h.
inline constexpr double kDefaultC10PerM = DegPerHourToRadPerSec(0.05) / kMetresPerUm;  // [rad/s/m]
inline constexpr double kDefaultC20PerM = DegPerHourToRadPerSec(0.015) / kMetresPerUm;

struct GyroFault {
  enum class Kind {
    kReadoutJump,  // value: rotation vector [rad] in case axes added to every reading from time on
    kDriftStep,    // value: extra constant drift [rad/s] in case axes from time on
    kReadingFrozen,    // the telemetered reading (h_k and voltages) of the first frame at or after
                       // time is repeated in every frame of [time, end); value unused. The truth
                       // keeps moving.
    kReadingsMissing,  // no reading of this gyro (field absent) in the frames of [time, end);
                       // value unused
  };
  double time = 0.0;  // [s since the simulation start]
  Kind kind = Kind::kReadoutJump;
  Eigen::Vector3d value = Eigen::Vector3d::Zero();
  // [s since the simulation start]; exclusive end of the window of kReadingFrozen and
  // kReadingsMissing, > time (infinity: to the end). Unused by the other kinds.
  double end = std::numeric_limits<double>::infinity();
};

// A drift fixed in the case that cycles with the orbit, as the thermal cycle of a spacecraft in
// and out of the Earth's shadow does: dw_k = amplitude_k_rad_s cos(2 pi t / period_s + phase_rad),
// t in seconds since the simulation start (the cycle's epoch t0 is the start; phase_rad shifts it).
struct OrbitalDrift {
  Eigen::Vector3d amplitude_k_rad_s = Eigen::Vector3d::Zero();  // case axes [rad/s]
  // [s], > 0; default (nullopt): the attitude profile's AttitudeProfile::OrbitalPeriod(), which
  // must then exist.
  std::optional<double> period_s;
  double phase_rad = 0.0;  // [rad]
};

// A drift that switches at random between +amplitude_k_rad_s and -amplitude_k_rad_s (a random
// telegraph process, e.g. a bistable contact or a mode of the suspension electronics): the level
// at the start is +1 or -1 with probability 1/2 each, and the dwell times between switches are
// independent and exponential with mean mean_dwell_s, so the switches form a Poisson process of
// rate 1 / mean_dwell_s.
struct SwitchingDrift {
  Eigen::Vector3d amplitude_k_rad_s = Eigen::Vector3d::Zero();  // case axes [rad/s]
  double mean_dwell_s = 3600.0;                                 // [s], > 0
};

// A drift driven by a quantity that is not telemetered (e.g. a temperature nobody measures):
// dw_k = amplitude_k_rad_s x(t), x a stationary Ornstein-Uhlenbeck process of unit variance and
// correlation time correlation_time_s: E[x(t) x(t + s)] = exp(-|s| / correlation_time_s),
// x(0) ~ N(0, 1). Stepped exactly: x(t + h) = a x(t) + sqrt(1 - a^2) N(0, 1), a = exp(-h / tau).
struct HiddenDriverDrift {
  Eigen::Vector3d amplitude_k_rad_s = Eigen::Vector3d::Zero();  // case axes [rad/s]
  double correlation_time_s = 3600.0;                           // [s], > 0
};

// A drift proportional to the body rate (a rate-dependent drift of the suspension or the
// pick-off): dw_k = gain_k w_k, w_k the body rate w_b_in_b in case axes. gain_k [rad/s of drift
// per rad/s of rate, 1]; 1 deg/h per deg/s is 1/3600.
struct RateDrift {
  Eigen::Matrix3d gain_k = Eigen::Matrix3d::Zero();
};

// A warm-up transient: a case-fixed drift that decays from its start,
// dw_k = amplitude_k_rad_s exp(-(t - start_s) / time_constant_s) for t >= start_s, 0 before.
struct TransientDrift {
  Eigen::Vector3d amplitude_k_rad_s = Eigen::Vector3d::Zero();  // case axes [rad/s]
  double time_constant_s = 3600.0;                              // [s], > 0
  double start_s = 0.0;  // [s since the simulation start], >= 0
};

// A step of the drift coefficients of eq. (1), (10) at a time (docs/discovery.md, "Time
// behaviour"): from time_s on, dw_k gains the printed eq. (1), (10) drift of the coefficients
// `delta` (simulator_truth.h TrueDriftRate_k), 0 before.
struct CoefficientStep {
  double time_s = 0.0;      // [s since the simulation start], >= 0
  DriftCoefficients delta;  // [rad/s]
};

// A thermal drift driven by the sun on one face of the body (a gyro heated through the panel the
// sun shines on): the face's illumination u(t) = max(0, face_sign s_b(t)[face_axis]), s_b the
// unit vector to the sun (estimator/sun_direction.h) in body axes of the true attitude, drives
// the face's temperature y through a first-order lag tau dy/dt = u - y with y(0) = u(0) (the face
// in equilibrium at the start), and dw_k = amplitude_k_rad_s y(t). Over an integration step of
// length h, u is taken at the step midpoint and y stepped exactly for it:
// y(t + h) = u + (y(t) - u) exp(-h / tau). The sun's direction is computed every 600 s from the
// simulated UTC and interpolated linearly between (normalised; the sun moves 0.007 deg in 600 s,
// the interpolation is off by under 1e-8 rad). With SimulationSpec::earth_shadow the illumination
// is u(t) times the fraction of the sun's disc seen from that orbit (estimator/eclipse.h: 0 in
// the Earth's umbra).
inline constexpr int kSunlitFaceAxis = 3;
struct SunFaceDrift {
  Eigen::Vector3d amplitude_k_rad_s = Eigen::Vector3d::Zero();  // case axes, at y = 1 [rad/s]
  // Body axis of the face's outward normal: 0 x, 1 y, 2 z; or kSunlitFaceAxis: no face, u(t) the
  // fraction of the sun's disc seen from the SimulationSpec::earth_shadow orbit (required then),
  // a drift that follows the eclipses whatever the attitude.
  int face_axis = 0;
  int face_sign = 1;                // +1: the face towards +axis, -1: towards -axis
  double time_constant_s = 3600.0;  // [s], > 0
};

// A drift that follows a housekeeping temperature the frames carry (issue 38; docs/physics.md "A
// drift that follows a housekeeping channel"): the temperature T(t) = mean + spread x(t), x a
// stationary Ornstein-Uhlenbeck process of unit variance and correlation time correlation_time_s
// (stepped exactly as HiddenDriverDrift's, its own random stream), drives the drift
//
//     dw_k = gain_k (y(t) - mean),   y = T (lag_s = 0) or tau dy/dt = T - y (lag_s = tau > 0),
//
// y(0) = T(0), stepped exactly for T held over an integration step. With `derivative` the drift
// follows the lag's rate of change instead, dw_k = gain_k dy/dt = gain_k (T - y) / tau [per hour]
// (the basis term's derivative form, estimator/channel_signal.h; lag_s = tau > 0 required, gain
// per unit per hour). A heater adds `step` to T while it is on, the first on_fraction of each
// period from the start (no random draw). Each frame carries T with white noise of 1-sigma
// `noise` as channel `channel` (SimulationSpec::config must declare it), and the heater's state
// (1 on, 0 off) as its channel when it names one, unless `telemetered` is false: the same drift
// with its cause absent from the recording (noise drawn all the same).
struct ChannelHeater {
  double period_s = 4.0 * 3600.0;  // [s], > 0
  double on_fraction = 0.5;        // (0, 1)
  double step = 1.0;               // T's rise while on [the channel's unit], finite
  std::string channel;             // the heater state's channel; empty: not telemetered
};
struct ChannelDrift {
  std::string channel = "T_gyro";
  double mean = 293.15;                // [the channel's unit, K]
  double spread = 2.0;                 // 1-sigma of T about the mean, > 0
  double correlation_time_s = 3.0 * 3600.0;  // [s], > 0
  double noise = 0.02;                 // per frame, 1-sigma, >= 0
  Eigen::Vector3d gain_k_rad_s_per_unit = Eigen::Vector3d::Zero();  // case axes [rad/s per K]
  double lag_s = 0.0;                  // [s], >= 0; 0: the drift follows T itself
  bool derivative = false;             // the drift follows dy/dt (lag_s > 0)
  std::optional<ChannelHeater> heater;
  bool telemetered = true;
};

// A rotor displacement turning about a case axis (e.g. a suspension bias following a rotating
// thermal gradient): Delta(t) = R(axis_k, 2 pi t / period_s) (rotor_displacement_k + rate t),
// R(a, phi) the right-handed rotation by phi about the unit axis a (case axes), t since the start.
struct DisplacementTurn {
  Eigen::Vector3d axis_k = Eigen::Vector3d::UnitZ();  // [1], unit, case axes
  double period_s = 86400.0;                          // one full turn [s], > 0
};

struct GyroTruth {
  // Whether the gyro runs. Default (nullopt): it runs when it is configured and belongs to the
  // working or the reserve pair; so with the usual pairs {1,2}, {1,3} gyros 1-3 run and gyro 4,
  // the cold spare, is off. A running gyro must be configured.
  std::optional<bool> running;
  // True drift coefficients [rad/s]; default the configuration's model.
  std::optional<DriftCoefficients> drift;
  // Rotor displacement from the suspension centre [m], case axes. Adds the drift of eq. (8) + (9)
  // and offsets the suspension voltages through eq. (3).
  Eigen::Vector3d rotor_displacement_k = Eigen::Vector3d::Zero();
  double c10_per_m = kDefaultC10PerM;  // [rad/s per m]
  double c20_per_m = kDefaultC20PerM;  // [rad/s per m]
  double voltage_noise = 1e-3;         // 1-sigma per axis [V]
  // Mounting misalignment, small rotation vector in body axes [rad] (see file comment).
  Eigen::Vector3d misalignment_b = Eigen::Vector3d::Zero();
  // Random-walk intensity [rad/s/sqrt(s)]; default config.random_walk.
  std::optional<double> random_walk;
  // Readout noise 1-sigma per perpendicular axis [rad]; default config.readout_noise.
  std::optional<double> readout_noise;
  std::optional<GyroFault> fault;
  // [s since the simulation start]; the gyro's readings appear from this time on (the cold spare
  // switched on by the spacecraft): frames before it carry no reading and no truth sample of the
  // gyro. Setting it makes the gyro run (`running` must not be false). The spin axis is
  // propagated from the start all the same (initial_h_k is its value at the start), so the random
  // streams draw the same numbers whatever the switch-on time.
  std::optional<double> switch_on_time;
  // Spin axis in case axes at the start [1] (normalised). Default per gyro id (well separated
  // even with identical mountings): 1: (0.2, 0.3, 0.93), 2: (0.93, 0.2, 0.3), 3: (0.3, 0.93, 0.2),
  // 4: (-0.5, 0.5, 0.7), each normalised.
  std::optional<Eigen::Vector3d> initial_h_k;

  // Drift effects beyond the paper's models, each off by default (see the file comment). With all
  // of them off the simulation draws and computes exactly what it did without them.
  std::optional<OrbitalDrift> orbital_drift;
  // Growth of the rotor displacement [m/s], case axes: Delta(t) = rotor_displacement_k +
  // rotor_displacement_rate_k_m_s t. The drift of eq. (8) + (9) and the voltages of eq. (3)
  // follow Delta(t). Delta(t) must stay inside the suspension gap over the run.
  Eigen::Vector3d rotor_displacement_rate_k_m_s = Eigen::Vector3d::Zero();
  // The displacement turning about a case axis (DisplacementTurn; with a rate, the growing
  // displacement turns). Needs a non-zero rotor_displacement_k; the axis is normalised. Since the
  // turn moves the displacement's components, |rotor_displacement_k + rate t| (the length, which
  // the turn keeps) must stay below the suspension gap over the run.
  std::optional<DisplacementTurn> rotor_displacement_turn;
  // Symmetric distortion D of the spin-axis readout [1] (scale-factor errors on the diagonal,
  // non-orthogonality of the direction-cosine pick-off off it): the reading, before readout
  // noise, is normalise((I + D) h_k). |D_ij| < 0.1.
  Eigen::Matrix3d readout_distortion_k = Eigen::Matrix3d::Zero();
  std::optional<SwitchingDrift> switching_drift;
  std::optional<HiddenDriverDrift> hidden_driver_drift;
  std::optional<RateDrift> rate_drift;
  std::optional<CoefficientStep> coefficient_step;
  std::optional<TransientDrift> transient_drift;
  std::optional<SunFaceDrift> sun_face_drift;
  std::optional<ChannelDrift> channel_drift;
};

// n consecutive star-tracker outliers (see the file comment for their axis).
struct StarTrackerOutlierBurst {
  double time = 0.0;   // [s since the simulation start]; the burst starts at the first sample
                       // emitted at or after it (frames in an outage do not count)
  int count = 0;       // samples, >= 1
  double angle = 0.0;  // [rad], > 0; the angle of each outlier
};

// The star tracker's mount turning with the orbit (a thermo-elastic misalignment): an extra
// rotation amplitude_b sin(2 pi t / period_s + phase_rad), body axes, t since the simulation start.
struct StarTrackerMisalignmentCycle {
  Eigen::Vector3d amplitude_b = Eigen::Vector3d::Zero();  // rotation vector amplitude [rad]
  double period_s = 5400.0;                               // [s], > 0
  double phase_rad = 0.0;
};

// The star tracker's mount heated by the sun on one body face (a thermo-elastic misalignment that
// follows the illumination, not the orbital phase): an extra rotation rotation_b y(t), body axes,
// y the face's lagged illumination as SunFaceDrift's (u(t) = max(0, face_sign s_b(t)[face_axis])
// of the true attitude, scaled by the sunlit fraction with SimulationSpec::earth_shadow;
// tau dy/dt = u - y, y(0) = u(0)), stepped exactly for u taken at the midpoint of steps of at
// most 10 s between the star tracker's samples. face_axis kSunlitFaceAxis: no face, the sunlit
// fraction of the earth_shadow orbit (required then).
struct StarTrackerSunMount {
  Eigen::Vector3d rotation_b = Eigen::Vector3d::Zero();  // at full illumination (y = 1) [rad]
  int face_axis = 0;                                     // 0 x, 1 y, 2 z, or kSunlitFaceAxis
  int face_sign = 1;                                     // +1 or -1
  double time_constant_s = 3600.0;                       // [s], > 0
};

// A star-tracker mounting change: an extra rotation from time on (see the file comment).
struct StarTrackerMisalignmentJump {
  double time = 0.0;                                     // [s since the simulation start]
  Eigen::Vector3d rotation_b = Eigen::Vector3d::Zero();  // rotation vector, body axes [rad]
};

struct StarTrackerTruth {
  // 1-sigma noise about body x, y, z [rad]; default config.star_tracker.noise.
  std::optional<Eigen::Vector3d> noise;
  double outlier_probability = 0.0;  // per sample, [0, 1]
  double outlier_size = 0.0;         // [rad]; outlier angle uniform in [size, 3 size]
  // Outages [start, end) in seconds since the simulation start: no star-tracker field.
  std::vector<std::pair<double, double>> outages;
  // [s]; positive: the quaternion stamped t is the attitude at t - latency.
  double latency = 0.0;
  // Star-tracker misalignment, rotation vector [rad] (see file comment).
  Eigen::Vector3d misalignment_b = Eigen::Vector3d::Zero();
  double invalid_probability = 0.0;  // per sample, [0, 1]
  std::optional<StarTrackerOutlierBurst> outlier_burst;
  // Frozen output [start, end) in seconds since the simulation start (see the file comment).
  std::vector<std::pair<double, double>> frozen;
  std::optional<StarTrackerMisalignmentJump> misalignment_jump;
  std::optional<StarTrackerMisalignmentCycle> misalignment_cycle;
  std::optional<StarTrackerSunMount> sun_mount;
};

struct SimulationSpec {
  SpacecraftConfig config;
  std::array<GyroTruth, kMaxGyros> gyros;  // index id - 1
  StarTrackerTruth star_tracker;
  ProfilePtr profile;                                    // required
  absl::Time start = absl::FromUnixSeconds(1551398400);  // 2019-03-01T00:00:00Z
  double duration = 86400.0;     // [s], > 0; frames at 0, step, 2 step ... <= duration
  double telemetry_step = 60.0;  // [s]
  double integration_rate_hz = 8.0;
  uint64_t seed = 1;
  // The circular orbit the spacecraft flies (attitude_profile.h OrbitalOptions, orbit.h
  // CircularOrbitState, epoch `start`) when the sun-face drifts see the Earth's shadow from it;
  // nullopt: the sun always shines.
  std::optional<OrbitalOptions> earth_shadow;
};

struct GyroTruthSample {
  Eigen::Vector3d h_in;   // true spin axis, inertial axes
  Eigen::Vector3d h_k;    // true spin axis, case axes (noise-free)
  Eigen::Vector3d dw_k;   // true total drift [rad/s], case axes (model + displacement +
                          // random walk + fault step + the effects below)
  Eigen::Matrix3d C_b_k;  // true mounting
  // The parts of dw_k from the effects of GyroTruth beyond the paper's models (zero when off):
  Eigen::Vector3d rotor_displacement_k_m = Eigen::Vector3d::Zero();  // Delta(t) [m], case axes
  Eigen::Vector3d dw_orbital_k_rad_s = Eigen::Vector3d::Zero();      // orbital drift [rad/s]
  double switching_level = 0.0;  // +1 or -1 with a switching drift, else 0 [1]
  Eigen::Vector3d dw_switching_k_rad_s = Eigen::Vector3d::Zero();  // level * amplitude [rad/s]
  double hidden_driver = 0.0;  // x(t) of the hidden-driver drift, else 0 [1]
  Eigen::Vector3d dw_hidden_k_rad_s = Eigen::Vector3d::Zero();  // x(t) * amplitude [rad/s]
  Eigen::Vector3d dw_rate_k_rad_s = Eigen::Vector3d::Zero();       // gain * w_k [rad/s]
  Eigen::Vector3d dw_transient_k_rad_s = Eigen::Vector3d::Zero();  // the transient [rad/s]
  // The sun-driven drift: the face's illumination u(t) and its lag y(t) [1] (0 without it).
  double sun_illumination = 0.0;
  double sun_lagged_illumination = 0.0;
  Eigen::Vector3d dw_sun_k_rad_s = Eigen::Vector3d::Zero();  // y * amplitude [rad/s]
  // The channel drift: the true temperature T(t), its lag y(t) [the channel's unit] (0 without
  // it) and gain (y - mean), or gain dy/dt for the derivative [rad/s].
  double channel_value = 0.0;
  double channel_lagged = 0.0;
  Eigen::Vector3d dw_channel_k_rad_s = Eigen::Vector3d::Zero();
};

// One gyro's effects beyond the paper's models as simulated: the settings in effect (the orbital
// period resolved from the profile) and the drawn history of the switching drift.
struct GyroEffectsTruth {
  std::optional<OrbitalDrift> orbital_drift;  // period_s always set
  Eigen::Vector3d rotor_displacement_rate_k_m_s = Eigen::Vector3d::Zero();
  std::optional<DisplacementTurn> rotor_displacement_turn;  // axis_k normalised
  Eigen::Matrix3d readout_distortion_k = Eigen::Matrix3d::Zero();
  std::optional<SwitchingDrift> switching_drift;
  double switching_initial_level = 0.0;  // +1 or -1 at t = 0 (0 without a switching drift)
  // [s since the simulation start], increasing, all <= duration: the level flips sign at each.
  std::vector<double> switch_times_s;
  std::optional<HiddenDriverDrift> hidden_driver_drift;
  std::optional<RateDrift> rate_drift;
  std::optional<TransientDrift> transient_drift;
  std::optional<SunFaceDrift> sun_face_drift;
  std::optional<ChannelDrift> channel_drift;
};

struct TruthSample {
  absl::Time time;
  Eigen::Quaterniond q_in_b;                                    // true attitude at time
  std::array<std::optional<GyroTruthSample>, kMaxGyros> gyros;  // empty: gyro off
  bool star_tracker_outlier = false;        // the emitted sample carries an outlier
  double star_tracker_outlier_angle = 0.0;  // [rad]
  bool star_tracker_frozen = false;         // the emitted sample repeats an earlier one
};

struct SimulationResult {
  // Metadata: spacecraft_id, seed, profile, source.
  Recording recording;
  std::vector<TruthSample> truth;  // one per frame
  // Effective true drift coefficients per gyro [rad/s]; empty: off. The model coefficients with
  // the displacement folded in as eq. (10) terms: C1 += (C10 + C20) lambda, C2 += -5 C20 lambda
  // (simulator_truth::EquivalentCoefficients), so DriftRate_k(true_coefficients, h_k) is the
  // simulated deterministic drift.
  // With a rotor displacement rate or turn, the coefficients of the displacement at the start.
  std::array<std::optional<DriftCoefficients>, kMaxGyros> true_coefficients;
  // Per gyro (index id - 1; default-constructed when the gyro is off).
  std::array<GyroEffectsTruth, kMaxGyros> effects;
};

// Default starting spin axis in case axes for gyro `id` (see GyroTruth::initial_h_k).
Eigen::Vector3d DefaultInitialSpinAxis(int id);

// Whether gyro `id` runs under spec (GyroTruth::running rule; a switch-on time makes it run).
bool GyroRuns(const SimulationSpec& spec, int id);

// Checks the spec; InvalidArgument naming the field (e.g. "duration: must be > 0 s, got -1").
absl::Status ValidateSimulationSpec(const SimulationSpec& spec);

// Runs the simulation. progress, when set, is called with the fraction done in [0, 1] about 100
// times and once with 1. Errors: InvalidArgument from ValidateSimulationSpec.
absl::StatusOr<SimulationResult> Simulate(
    const SimulationSpec& spec, const std::function<void(double fraction)>& progress = {});

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_SIMULATOR_H_
