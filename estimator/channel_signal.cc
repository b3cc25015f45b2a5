#include "estimator/channel_signal.h"

#include <algorithm>
#include <cmath>
#include <cstdint>

#include "absl/strings/str_cat.h"
#include "estimator/units.h"

namespace esg::estimator {

namespace {

void PutTime(std::vector<double>& v, const std::optional<absl::Time>& t) {
  const int64_t ns = t.has_value() ? absl::ToUnixNanos(*t) : 0;
  v.push_back(t.has_value() ? 1.0 : 0.0);
  v.push_back(static_cast<double>(ns / 1000000000));
  v.push_back(static_cast<double>(ns % 1000000000));
}

}  // namespace

ChannelSignals::ChannelSignals(const std::vector<ChannelConfig>& declared,
                               const std::vector<BasisTerm>& terms) {
  for (const BasisTerm& t : terms) {
    if (t.kind != BasisKind::kChannel) continue;
    const auto c = std::find_if(declared.begin(), declared.end(),
                                [&](const ChannelConfig& d) { return d.name == t.channel; });
    if (c == declared.end()) continue;
    channels_[t.channel].max_age = c->max_age;
    if (t.form != ChannelForm::kValue) lags_[{t.channel, t.time_constant}];
  }
}

namespace {

// The slope of the line from the held value to the next one [unit/s] (Ahead).
double LineSlope(absl::Time t0, double x0, const std::pair<absl::Time, double>& next) {
  return (next.second - x0) / absl::ToDoubleSeconds(next.first - t0);
}

}  // namespace

std::optional<double> ChannelSignals::HeldAt(const Held& h, absl::Time t) {
  if (!h.time.has_value()) return std::nullopt;
  const absl::Duration age = t - *h.time;
  if (h.next.has_value() && age >= absl::ZeroDuration() && t <= h.next->first) {
    return h.value + LineSlope(*h.time, h.value, *h.next) * absl::ToDoubleSeconds(age);
  }
  if (age < absl::ZeroDuration() || age > h.max_age) return std::nullopt;
  return h.value;
}

std::optional<double> ChannelSignals::LagAt(const Held& held, const Lag& lag, double tau_s,
                                            absl::Time t) {
  if (!lag.time.has_value()) return std::nullopt;
  if (!held.time.has_value() || t <= *lag.time) return lag.y;
  if (held.next.has_value() && *lag.time >= *held.time && t <= held.next->first) {
    // On the line to the next value (the file comment's second solution).
    const double m = LineSlope(*held.time, held.value, *held.next);
    const double x_a = held.value + m * absl::ToDoubleSeconds(*lag.time - *held.time);
    const double x_t = held.value + m * absl::ToDoubleSeconds(t - *held.time);
    const double dt = absl::ToDoubleSeconds(t - *lag.time);
    return x_t - m * tau_s + (lag.y - x_a + m * tau_s) * std::exp(-dt / tau_s);
  }
  // The input holds held.value until it expires; the lag is held after.
  const absl::Time until = std::min(t, *held.time + held.max_age);
  if (until <= *lag.time) return lag.y;
  const double dt = absl::ToDoubleSeconds(until - *lag.time);
  return held.value + (lag.y - held.value) * std::exp(-dt / tau_s);
}

double ChannelSignals::Scalar(const BasisTerm& term, absl::Time time) const {
  const auto c = channels_.find(term.channel);
  if (c == channels_.end()) return 0.0;
  if (term.form == ChannelForm::kValue) {
    const std::optional<double> x = HeldAt(c->second, time);
    return x.has_value() ? *x - term.reference : 0.0;
  }
  const auto l = lags_.find({term.channel, term.time_constant});
  if (l == lags_.end()) return 0.0;
  const std::optional<double> y = LagAt(c->second, l->second, term.time_constant, time);
  if (!y.has_value()) return 0.0;
  if (term.form == ChannelForm::kLag) return *y - term.reference;
  const std::optional<double> x = HeldAt(c->second, time);
  if (!x.has_value()) return 0.0;
  return (*x - *y) / term.time_constant * kSecondsPerHour;  // per hour
}

void ChannelSignals::Ahead(const TelemetryFrame& next) {
  for (auto& [name, held] : channels_) {
    held.next.reset();
    const double* x = next.channels.Find(name);
    if (x == nullptr || !held.time.has_value() || next.time <= *held.time ||
        next.time < latest_ || next.time - *held.time > held.max_age) {
      continue;
    }
    held.next = std::make_pair(next.time, *x);
  }
}

void ChannelSignals::Advance(const TelemetryFrame& frame) {
  if (frame.time < latest_) {
    for (auto& [name, held] : channels_) held.next.reset();
    return;
  }
  latest_ = frame.time;
  for (auto& [key, lag] : lags_) {
    const Held& held = channels_.at(key.first);
    if (lag.time.has_value()) {
      lag.y = *LagAt(held, lag, key.second, frame.time);
      lag.time = frame.time;
    }
  }
  for (auto& [name, held] : channels_) {
    held.next.reset();
    const double* x = frame.channels.Find(name);
    if (x == nullptr) continue;
    held.time = frame.time;
    held.value = *x;
  }
  for (auto& [key, lag] : lags_) {
    if (lag.time.has_value()) continue;
    const Held& held = channels_.at(key.first);
    if (!held.time.has_value()) continue;
    lag.time = frame.time;  // in equilibrium with the first value
    lag.y = held.value;
  }
}

std::vector<double> ChannelSignals::ExportState() const {
  std::vector<double> v;
  for (const auto& [name, held] : channels_) {
    PutTime(v, held.time);
    v.push_back(held.value);
  }
  for (const auto& [key, lag] : lags_) {
    PutTime(v, lag.time);
    v.push_back(lag.y);
  }
  return v;
}

absl::Status ChannelSignals::RestoreState(absl::Span<const double> state) {
  const size_t expected = 4 * (channels_.size() + lags_.size());
  if (state.size() != expected) {
    return absl::DataLossError(absl::StrCat("channel state of ", state.size(),
                                            " values, the configuration's channel terms need ",
                                            expected));
  }
  size_t at = 0;
  auto read = [&](std::optional<absl::Time>& time, double& value) -> absl::Status {
    const double flag = state[at], sec = state[at + 1], nsec = state[at + 2], x = state[at + 3];
    at += 4;
    if ((flag != 0.0 && flag != 1.0) || !(std::abs(sec) <= 1e12) || sec != std::floor(sec) ||
        !(std::abs(nsec) < 1e9) || nsec != std::floor(nsec) || !std::isfinite(x)) {
      return absl::DataLossError(
          absl::StrCat("channel state value ", at - 4, ": not a time and a value"));
    }
    time.reset();
    if (flag == 1.0) {
      time = absl::FromUnixSeconds(static_cast<int64_t>(sec)) +
             absl::Nanoseconds(static_cast<int64_t>(nsec));
    }
    value = x;
    return absl::OkStatus();
  };
  for (auto& [name, held] : channels_) {
    if (absl::Status s = read(held.time, held.value); !s.ok()) return s;
    if (held.time.has_value()) latest_ = std::max(latest_, *held.time);
  }
  for (auto& [key, lag] : lags_) {
    if (absl::Status s = read(lag.time, lag.y); !s.ok()) return s;
    if (lag.time.has_value()) latest_ = std::max(latest_, *lag.time);
  }
  return absl::OkStatus();
}

}  // namespace esg::estimator
