// Spacecraft configuration value types (DESIGN §7 JSON, proto esg.v1.SpacecraftConfig).
// Everything here is SI: drift coefficients in rad/s, noise in rad. proto/convert.cc converts
// from and to the deg/h and arcsec of the JSON form.
#ifndef ESG_ESTIMATOR_SPACECRAFT_CONFIG_H_
#define ESG_ESTIMATOR_SPACECRAFT_CONFIG_H_

#include <array>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "absl/status/status.h"
#include "estimator/drift_model.h"

namespace esg::estimator {

struct GyroConfig {
  int id = 0;  // 1..kMaxGyros.
  // C_b_k: case frame k to body b.
  Eigen::Matrix3d C_b_k = Eigen::Matrix3d::Identity();
  // A-priori (bench) drift model the user believes [rad/s].
  DriftCoefficients model;
  // 1-sigma prior uncertainty of each coefficient [rad/s]; > 0 means estimated (free),
  // 0 means held at its model value.
  DriftCoefficients model_sigma;
  // Prior 1-sigma of the gyro-to-star-tracker misalignment per body axis [rad]; 0 = not estimated.
  double misalignment_sigma = 0.0;
};

struct StarTrackerConfig {
  // 1-sigma noise about the body x, y, z axes [rad].
  Eigen::Vector3d noise = Eigen::Vector3d::Zero();
};

// Rotor-displacement readout of eq. (3): Delta = k * dU * d0 / U0.
struct SuspensionConfig {
  double amplifier_gain = 200.0;     // k [1]
  double reference_voltage = 200.0;  // U0 [V]
  double gap = 30e-6;                // d0 [m]
};

struct FilterConfig {
  double integration_rate_hz = 8.0;  // propagation rate [Hz]
  double measurement_step = 60.0;    // measurement update step [s]
  double innovation_kd = 5.0;        // k_d of eq. (14)
  double fault_threshold = 0.0;      // allowed mismatch angle of eq. (12) [rad]; 0 = derived
};

struct SpacecraftConfig {
  std::string spacecraft_id;
  std::vector<GyroConfig> gyros;
  std::array<int, 2> working_pair = {1, 2};  // gyro ids, reference first
  std::array<int, 2> reserve_pair = {1, 3};
  StarTrackerConfig star_tracker;
  double readout_noise = 0.0;  // 1-sigma readout noise of h_k, per axis [rad]
  // Intensity of each gyro's residual random-walk drift, model (11) [rad/s/sqrt(s)].
  double random_walk = 0.0;
  SuspensionConfig suspension;
  FilterConfig filter;

  // Gyro by id, or nullptr.
  const GyroConfig* FindGyro(int id) const;
};

// Checks ids, pairs, matrices (rotation to 1e-6), finite and non-negative values. The message of
// an InvalidArgument names the field, e.g. "gyros[1].caseToBody: not a rotation matrix".
absl::Status ValidateConfig(const SpacecraftConfig& config);

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_SPACECRAFT_CONFIG_H_
