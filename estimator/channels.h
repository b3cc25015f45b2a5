// Auxiliary housekeeping channels (docs/formats.md "Channels", docs/decisions.md D105): how the
// configuration declares them, which values a frame may carry, and the age rule by which a
// channel that is absent from a frame keeps its last value. Pure values and checks; the proto,
// CSV and column-mapping readers call the checks below so that every edge refuses the same input
// with the same field named.
#ifndef ESG_ESTIMATOR_CHANNELS_H_
#define ESG_ESTIMATOR_CHANNELS_H_

#include <map>
#include <optional>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/string_view.h"
#include "absl/time/time.h"
#include "estimator/telemetry.h"

namespace esg::estimator {

// At most this many channels are declared in a configuration and carried by one frame. With names
// of at most kMaxChannelNameLength characters a frame's channels serialize to at most about 2.9 kB
// (45 bytes each), so a frame with four gyros, the star tracker and every channel stays below the
// service's 8192-byte frame limit (docs/service.md "Ingest contract") with room to spare.
inline constexpr int kMaxChannels = 64;
inline constexpr int kMaxChannelNameLength = 32;
// A declared unit is 1..16 printable ASCII characters ("K", "degC", "1" for dimensionless).
inline constexpr int kMaxChannelUnitLength = 16;
// A channel's maxAgeS is at most the largest gap between frames the service accepts
// (estimator/frame_gap.h kMaxFrameGap, 7 days).
inline constexpr absl::Duration kMaxChannelAge = absl::Hours(24 * 7);

// One declared channel (spacecraft_config.proto ChannelConfig).
struct ChannelConfig {
  std::string name;
  std::string unit;
  // The valid range, inclusive, in `unit`: a value outside is refused, not clipped.
  double valid_min = 0.0;
  double valid_max = 0.0;
  // The channel has its own cadence: a frame without it keeps the channel's last value, with its
  // age, while the age is at most max_age; older, the channel has no value. Zero: a value holds
  // only at its own frame's time.
  absl::Duration max_age = absl::ZeroDuration();
  bool operator==(const ChannelConfig&) const = default;
};

// The field a channel's value is named by in messages: channels["T_gyro2"], the name escaped
// (absl::CHexEscape) and cut to kMaxChannelNameLength characters, so no control character or
// long value reaches a message.
std::string ChannelField(absl::string_view name);

// InvalidArgument "<field>: ..." unless `name` is 1..kMaxChannelNameLength characters from
// [A-Za-z0-9_.-] starting with a letter (so that it is a CSV column `ch:NAME` and a JSON key as
// it is).
absl::Status ValidateChannelName(absl::string_view name, absl::string_view field);

// The declarations of a configuration, "channels[i].<jsonField>: <reason>": at most kMaxChannels,
// each name valid and declared once, unit 1..kMaxChannelUnitLength printable ASCII characters,
// validMin and validMax finite with validMin <= validMax, maxAgeS in [0, kMaxChannelAge].
absl::Status ValidateChannelConfigs(const std::vector<ChannelConfig>& channels);

// What a frame's channels may be without a configuration (the proto and CSV readers):
// "channels: <n> channels, at most 64 in a frame", then per channel in name order
// `channels["x y"]: ...` for a bad name and `channels["T_gyro2"]: nan is not finite`.
absl::Status ValidateFrameChannels(const Channels& channels);

// Against the declarations (the ingest and the offline verbs): InvalidArgument
// `channels["T_gyro2"]: not declared in the configuration (declared: T_gyro1, heater_1)` or
// `channels["T_gyro2"]: 412 K is outside its valid range [250, 350] K`. The channels are a
// reader's (FrameFromProto, the recording CSV, a column mapping), which ValidateFrameChannels
// already accepted: a declared name is a valid one, and a value that is not finite is outside
// every range.
absl::Status CheckDeclaredChannels(const Channels& channels,
                                   const std::vector<ChannelConfig>& declared);

// The same over a recording, for the offline verbs: the first problem, prefixed with the frame,
// "frame 17 (2019-03-01T00:17:00.000Z): channels[\"T_gyro2\"]: ..." (frames counted from 1).
absl::Status CheckRecordingChannels(const std::vector<TelemetryFrame>& frames,
                                    const std::vector<ChannelConfig>& declared);

// A channel's value at an instant by the age rule of ChannelConfig::max_age.
struct ChannelSample {
  double value = 0.0;
  absl::Duration age;  // time since the frame that carried the value, >= 0
};

// The last value of each declared channel over frames fed in time order. Not thread-safe; a value.
class ChannelHold {
 public:
  explicit ChannelHold(std::vector<ChannelConfig> declared);

  // Takes the declared channels the frame carries (an undeclared one is ignored: the readers
  // refuse it before). Frames must come in increasing time; an older frame is ignored.
  void Update(const TelemetryFrame& frame);

  // The last value of `name` at `time` (not before the frame that carried it) and its age, or
  // nullopt when the channel is not declared, has no value yet, or its value is older than its
  // max_age.
  std::optional<ChannelSample> At(absl::string_view name, absl::Time time) const;

 private:
  struct Last {
    ChannelConfig config;
    std::optional<absl::Time> time;
    double value = 0.0;
  };
  std::map<std::string, Last, std::less<>> channels_;
  absl::Time latest_ = absl::InfinitePast();
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_CHANNELS_H_
