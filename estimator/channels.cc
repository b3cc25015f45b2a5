#include "estimator/channels.h"

#include <cmath>
#include <set>
#include <utility>

#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/status_macros.h"
#include "estimator/utc_time.h"

namespace esg::estimator {

std::string ChannelField(absl::string_view name) {
  const bool cut = name.size() > static_cast<size_t>(kMaxChannelNameLength);
  return absl::StrCat("channels[\"", absl::CHexEscape(name.substr(0, kMaxChannelNameLength)),
                      cut ? "\"...]" : "\"]");
}

absl::Status ValidateChannelName(absl::string_view name, absl::string_view field) {
  static_assert(kMaxChannelNameLength == 32, "kRule states the length");
  constexpr absl::string_view kRule =
      "a channel name is 1..32 characters from [A-Za-z0-9_.-], starting with a letter";
  if (name.empty()) return absl::InvalidArgumentError(absl::StrCat(field, ": empty name: ", kRule));
  if (name.size() > static_cast<size_t>(kMaxChannelNameLength)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: %d characters is too long: %s", field, name.size(), kRule));
  }
  for (size_t i = 0; i < name.size(); ++i) {
    const unsigned char c = static_cast<unsigned char>(name[i]);
    if (absl::ascii_isalpha(c) ||
        (i > 0 && (absl::ascii_isdigit(c) || c == '_' || c == '.' || c == '-'))) {
      continue;
    }
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: character '%s' at index %d is not allowed: %s", field,
                        absl::CHexEscape(name.substr(i, 1)), i, kRule));
  }
  return absl::OkStatus();
}

absl::Status ValidateChannelConfigs(const std::vector<ChannelConfig>& channels) {
  if (channels.size() > static_cast<size_t>(kMaxChannels)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "channels: %d channels declared, at most %d (a frame carrying all of them must stay "
        "within the 8192-byte frame limit)",
        channels.size(), kMaxChannels));
  }
  std::set<absl::string_view> names;
  for (size_t i = 0; i < channels.size(); ++i) {
    const ChannelConfig& c = channels[i];
    const std::string at = absl::StrCat("channels[", i, "].");
    RETURN_IF_ERROR(ValidateChannelName(c.name, absl::StrCat(at, "name")));
    if (!names.insert(c.name).second) {
      return absl::InvalidArgumentError(
          absl::StrCat(at, "name: channel '", c.name, "' is declared twice"));
    }
    bool printable = !c.unit.empty() && c.unit.size() <= static_cast<size_t>(kMaxChannelUnitLength);
    for (char ch : c.unit) printable = printable && absl::ascii_isprint(ch);
    if (!printable) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%sunit: \"%s\" is not 1..%d printable ASCII characters (\"1\" for a dimensionless "
          "channel)",
          at, absl::CHexEscape(c.unit.substr(0, kMaxChannelUnitLength)), kMaxChannelUnitLength));
    }
    if (!std::isfinite(c.valid_min) || !std::isfinite(c.valid_max) || c.valid_min > c.valid_max) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%svalidMin: the valid range [%g, %g] %s must be finite with validMin <= validMax", at,
          c.valid_min, c.valid_max, c.unit));
    }
    if (c.max_age < absl::ZeroDuration() || c.max_age > kMaxChannelAge) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%smaxAgeS: %g s is outside [0, %g] s (a value is held at most as long as the longest "
          "gap between frames, 7 days)",
          at, absl::ToDoubleSeconds(c.max_age), absl::ToDoubleSeconds(kMaxChannelAge)));
    }
  }
  return absl::OkStatus();
}

absl::Status ValidateFrameChannels(const Channels& channels) {
  if (channels.size() > kMaxChannels) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "channels: %d channels, at most %d in a frame", channels.size(), kMaxChannels));
  }
  for (const ChannelValue& c : channels) {
    const std::string field = ChannelField(c.name);
    RETURN_IF_ERROR(ValidateChannelName(c.name, field));
    if (!std::isfinite(c.value)) {
      return absl::InvalidArgumentError(absl::StrFormat("%s: %g is not finite", field, c.value));
    }
  }
  return absl::OkStatus();
}

absl::Status CheckDeclaredChannels(const Channels& channels,
                                   const std::vector<ChannelConfig>& declared) {
  for (const ChannelValue& c : channels) {
    const ChannelConfig* config = nullptr;
    for (const ChannelConfig& d : declared) {
      if (d.name == c.name) config = &d;
    }
    if (config == nullptr) {
      std::vector<absl::string_view> names;
      for (const ChannelConfig& d : declared) names.push_back(d.name);
      return absl::InvalidArgumentError(absl::StrCat(
          ChannelField(c.name), ": not declared in the configuration (declared: ",
          names.empty() ? "none" : absl::StrJoin(names, ", "), ")"));
    }
    if (!(c.value >= config->valid_min && c.value <= config->valid_max)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: %g %s is outside its valid range [%g, %g] %s", ChannelField(c.name), c.value,
          config->unit, config->valid_min, config->valid_max, config->unit));
    }
  }
  return absl::OkStatus();
}

absl::Status CheckRecordingChannels(const std::vector<TelemetryFrame>& frames,
                                    const std::vector<ChannelConfig>& declared) {
  for (size_t i = 0; i < frames.size(); ++i) {
    if (frames[i].channels.empty()) continue;
    absl::Status s = CheckDeclaredChannels(frames[i].channels, declared);
    if (!s.ok()) {
      return absl::InvalidArgumentError(
          absl::StrCat("frame ", i + 1, " (", FormatUtc(frames[i].time), "): ", s.message()));
    }
  }
  return absl::OkStatus();
}

ChannelHold::ChannelHold(std::vector<ChannelConfig> declared) {
  for (ChannelConfig& c : declared) {
    std::string name = c.name;
    channels_[std::move(name)] = Last{std::move(c), std::nullopt, 0.0};
  }
}

void ChannelHold::Update(const TelemetryFrame& frame) {
  if (frame.time < latest_) return;
  latest_ = frame.time;
  for (const ChannelValue& c : frame.channels) {
    auto it = channels_.find(c.name);
    if (it == channels_.end()) continue;
    it->second.time = frame.time;
    it->second.value = c.value;
  }
}

std::optional<ChannelSample> ChannelHold::At(absl::string_view name, absl::Time time) const {
  auto it = channels_.find(name);
  if (it == channels_.end() || !it->second.time.has_value()) return std::nullopt;
  const absl::Duration age = time - *it->second.time;
  if (age < absl::ZeroDuration() || age > it->second.config.max_age) return std::nullopt;
  return ChannelSample{it->second.value, age};
}

}  // namespace esg::estimator
