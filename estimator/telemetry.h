// Telemetry value types (the recording columns of docs/formats.md): what one frame carries. Pure
// values; CSV and protobuf conversions live in storage/ and proto/.
#ifndef ESG_ESTIMATOR_TELEMETRY_H_
#define ESG_ESTIMATOR_TELEMETRY_H_

#include <array>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/time/time.h"
#include "estimator/conventions.h"

namespace esg::estimator {

struct GyroReading {
  // Spin-axis direction cosines in the gyro case frame k [1], unit norm.
  Eigen::Vector3d h_k = Eigen::Vector3d::UnitZ();
  // Suspension offset voltages along the case axes [mV]; absent when not telemetered.
  std::optional<Eigen::Vector3d> u_k_mv;
};

struct StarTrackerReading {
  // Attitude from the star tracker, q_in_b (body to inertial), unit norm.
  Eigen::Quaterniond q_in_b = Eigen::Quaterniond::Identity();
  bool valid = false;
};

struct TelemetryFrame {
  absl::Time time;  // Measurement epoch, UTC.
  // Index gyro id - 1; empty when the gyro is off or its reading is missing.
  std::array<std::optional<GyroReading>, kMaxGyros> gyros;
  // Empty during a star-tracker outage.
  std::optional<StarTrackerReading> star_tracker;
};

struct Recording {
  // `# key: value` metadata lines, e.g. "spacecraft_id" -> "RDK-1".
  std::map<std::string, std::string> metadata;
  std::vector<TelemetryFrame> frames;
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_TELEMETRY_H_
