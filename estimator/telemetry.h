// Telemetry value types (the recording columns of docs/formats.md): what one frame carries. Pure
// values; CSV and protobuf conversions live in storage/ and proto/.
#ifndef ESG_ESTIMATOR_TELEMETRY_H_
#define ESG_ESTIMATOR_TELEMETRY_H_

#include <algorithm>
#include <array>
#include <map>
#include <optional>
#include <string>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "absl/strings/string_view.h"
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

// One auxiliary housekeeping channel's value in a frame, in the unit its declaration states
// (channels.h ChannelConfig; docs/formats.md "Channels").
struct ChannelValue {
  std::string name;
  double value = 0.0;
  bool operator==(const ChannelValue&) const = default;
};

// The named housekeeping channels of one frame (temperatures, heater states, ...): name -> value,
// kept sorted by name with each name once. A frame without channels holds one empty vector (no
// allocation), so the gyro-only hot path does not grow. What a name and a value may be is
// estimator/channels.h's (ValidateFrameChannels); this container only keeps the order.
class Channels {
 public:
  bool empty() const { return values_.empty(); }
  int size() const { return static_cast<int>(values_.size()); }
  // Sets the value of `name`, replacing an earlier one.
  void Set(absl::string_view name, double value) {
    auto it = std::lower_bound(values_.begin(), values_.end(), name, ByName);
    if (it != values_.end() && it->name == name) {
      it->value = value;
    } else {
      values_.insert(it, ChannelValue{std::string(name), value});
    }
  }
  // The value of `name`, or nullptr when the frame does not carry it.
  const double* Find(absl::string_view name) const {
    auto it = std::lower_bound(values_.begin(), values_.end(), name, ByName);
    return it != values_.end() && it->name == name ? &it->value : nullptr;
  }
  std::vector<ChannelValue>::const_iterator begin() const { return values_.begin(); }
  std::vector<ChannelValue>::const_iterator end() const { return values_.end(); }
  bool operator==(const Channels&) const = default;

 private:
  static bool ByName(const ChannelValue& v, absl::string_view name) { return v.name < name; }
  std::vector<ChannelValue> values_;
};

struct TelemetryFrame {
  absl::Time time;  // Measurement epoch, UTC.
  // Index gyro id - 1; empty when the gyro is off or its reading is missing.
  std::array<std::optional<GyroReading>, kMaxGyros> gyros;
  // Empty during a star-tracker outage.
  std::optional<StarTrackerReading> star_tracker;
  // Auxiliary housekeeping channels carried by this frame; a channel absent here keeps its last
  // value up to its declared age (estimator/channels.h ChannelHold).
  Channels channels;
};

struct Recording {
  // `# key: value` metadata lines, e.g. "spacecraft_id" -> "RDK-1".
  std::map<std::string, std::string> metadata;
  std::vector<TelemetryFrame> frames;
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_TELEMETRY_H_
