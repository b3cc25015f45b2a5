// Simulation scenarios: a JSON file that changes the simulated truth away from the
// configuration's model (true drift coefficients, rotor displacement, misalignments, faults,
// star-tracker defects, drift behaviours beyond the paper's models) and chooses the attitude
// profile. Format and example: docs/scenario.md.
// Values are in the units their key names (deg/h, arcsec, um, ...), converted to SI here with
// estimator/units.h; unknown keys and out-of-range values are InvalidArgument naming the key path,
// e.g. "gyros[0].rotorDisplacementUm[1]: 50 is outside [-20, 20]".
#ifndef ESG_CLIENT_SCENARIO_H_
#define ESG_CLIENT_SCENARIO_H_

#include <array>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "estimator/attitude_profile.h"
#include "estimator/drift_model.h"
#include "estimator/simulator.h"

namespace esg::client {

// Changes to one gyro's truth. Unset fields keep the simulator's defaults (the configuration's
// model and noise settings). SI units.
struct ScenarioGyro {
  int id = 0;
  std::optional<bool> running;
  std::optional<Eigen::Vector3d> rotor_displacement_k;  // [m]
  std::optional<double> c10_per_m;                      // [rad/s per m]
  std::optional<double> c20_per_m;
  // True coefficient values replacing the configuration's model, one by one, in theta layout
  // (estimator/drift_model.h; keys "k0DegH", "c1DegH", ... of estimator/model_terms.h) [rad/s].
  std::array<std::optional<double>, estimator::kNumDriftCoefficients> drift_coefficients;
  std::optional<Eigen::Vector3d> misalignment_b;  // [rad]
  std::optional<double> random_walk;              // [rad/s/sqrt(s)]
  std::optional<double> readout_noise;            // [rad]
  std::optional<double> voltage_noise;            // [V]
  std::optional<Eigen::Vector3d> initial_h_k;     // [1]
  std::optional<estimator::GyroFault> fault;
  std::optional<double> switch_on_time;  // [s since the simulation start]
  // Effects beyond the paper's models (estimator/simulator.h), SI.
  std::optional<estimator::OrbitalDrift> orbital_drift;
  std::optional<Eigen::Vector3d> rotor_displacement_rate_k_m_s;  // [m/s]
  std::optional<estimator::DisplacementTurn> rotor_displacement_turn;  // axis normalised
  std::optional<Eigen::Matrix3d> readout_distortion_k;           // [1], symmetric
  std::optional<estimator::SwitchingDrift> switching_drift;
  std::optional<estimator::HiddenDriverDrift> hidden_driver_drift;
  std::optional<estimator::RateDrift> rate_drift;
  std::optional<estimator::TransientDrift> transient_drift;
  std::optional<estimator::SunFaceDrift> sun_face_drift;
  std::optional<estimator::CoefficientStep> coefficient_step;
  std::optional<estimator::ChannelDrift> channel_drift;
  std::string channel_unit = "K";  // the channel's unit when the scenario declares it
};

struct Scenario {
  std::string description;
  std::optional<std::string> profile;  // a NamedProfileNames() entry
  estimator::ProfileOptions profile_options;
  std::optional<uint64_t> profile_seed;
  std::vector<ScenarioGyro> gyros;
  estimator::StarTrackerTruth star_tracker;  // noise unset = configuration's
  std::optional<double> readout_noise;       // all gyros [rad]
  std::optional<double> random_walk;         // all gyros [rad/s/sqrt(s)]
  // "earthShadow": the sun-face drifts see the Earth's shadow from the circular orbit of the
  // scenario's orbital elements (profile_options.orbital: inclinationDeg, orbitPeriodMin, raanDeg,
  // argLatitudeDeg, the orbital profile's), which `esg simulate --orbit-out` writes.
  bool earth_shadow = false;
};

// Parses scenario JSON (docs/scenario.md). InvalidArgument "scenario: ..." for malformed JSON,
// "<key path>: <reason>" for unknown keys, wrong types and out-of-range values.
absl::StatusOr<Scenario> ParseScenarioJson(std::string_view json);

// Reads and parses a file: NotFound when it cannot be opened, InvalidArgument "<path>: ..." for
// bad content.
absl::StatusOr<Scenario> ReadScenarioFile(const std::string& path);

// Applies the gyro and star-tracker changes to spec (its config must be set): the top-level
// readout noise and random walk go to every gyro first, then each gyro entry; coefficient values
// replace the configuration model's one by one. A telemetered channel drift's channel (and its
// heater's) the configuration does not declare is declared in spec->config (ScenarioChannelConfig),
// so that --write-config writes it. InvalidArgument when an entry names a gyro that
// is not in the configuration. The profile fields are not applied here (see MakeScenarioProfile).
absl::Status ApplyScenario(const Scenario& scenario, estimator::SimulationSpec* spec);

// The declaration a scenario adds for a channel drift's temperature the configuration lacks: the
// scenario's unit, valid range mean +- (10 spread + |heater step| + 10 noise) rounded outwards to
// whole units, values held for 10 min.
estimator::ChannelConfig ScenarioChannelConfig(const estimator::ChannelDrift& drift,
                                               const std::string& unit);

// Checks what needs the attitude profile: a gyro's orbitalDrift without periodMin needs a profile
// with an orbital period. InvalidArgument "gyros[i].orbitalDrift.periodMin: ..." otherwise.
absl::Status CheckScenarioAgainstProfile(const Scenario& scenario,
                                         const estimator::AttitudeProfile& profile);

// The scenario's profile: `name_override` if not empty, else scenario.profile, else
// "calibration"; built with MakeNamedProfile over `duration` [s] with the scenario's options and
// profile seed.
absl::StatusOr<estimator::ProfilePtr> MakeScenarioProfile(const Scenario& scenario,
                                                          std::string_view name_override,
                                                          double duration);

}  // namespace esg::client

#endif  // ESG_CLIENT_SCENARIO_H_
