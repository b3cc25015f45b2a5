// The regressors of basis terms of kind `channel` (basis_term.h; docs/formats.md "BasisTerm",
// docs/physics.md "A drift that follows a housekeeping channel"): a declared channel's held value,
// its first-order lag and the lag's derivative, as deterministic functions of the channel's held
// series (channels.h ChannelHold's rule: the last value carried up to the channel's maxAgeS).
//
// Over the interval between frames (t_{k-1}, t_k] the value x is the one frames up to t_{k-1}
// carried, held; the frame at t_k takes effect after it (Advance). When the frame at t_k is known
// while the interval is integrated (Ahead: a session propagating to the frame it is adding), x
// is instead the straight line from the last value x_0 (at t_0) to the frame's x_1 (at t_1), as
// long as t_1 - t_0 is within maxAgeS: a sample is the channel at its time, and a value held for
// a frame lags the channel by half a frame on average (a 30 s delay against a 10 min lag makes the
// derivative's regression slope e^(-30/600) = 0.95 of the truth's). The lag y of time constant
// tau solves tau dy/dt = x - y exactly, for x held:
//
//     y(t) = x + (y(t_a) - x) exp(-(t_a' - t_a) / tau),   t_a' = min(t, time x expires)
//
// and for x(t) = x(t_a) + m (t - t_a) on the line (m its slope):
//
//     y(t) = x(t) - m tau + (y(t_a) - x(t_a) + m tau) exp(-(t - t_a) / tau)
//
// so y holds where the channel has no value (none yet, or older than its maxAgeS); y starts at the
// channel's first value (in equilibrium with it). The regressors, in the channel's unit u:
//
//   value        x - reference (0 without a value)                  u
//   lag          y - reference (0 before the first value)           u
//   derivative   dy/dt = (x - y) / tau, per hour (0 without a value) u/h
//
// The derivative is the lag's: a smoothed dx/dt whose smoothing is tau (a raw difference of a
// noisy channel over a 60 s frame would be mostly its noise). A value; not thread-safe.
#ifndef ESG_ESTIMATOR_CHANNEL_SIGNAL_H_
#define ESG_ESTIMATOR_CHANNEL_SIGNAL_H_

#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/time/time.h"
#include "absl/types/span.h"
#include "estimator/basis_term.h"
#include "estimator/channels.h"
#include "estimator/telemetry.h"

namespace esg::estimator {

class ChannelSignals {
 public:
  ChannelSignals() = default;
  // Tracks the channels the `terms` of kind channel name (each declared in `declared`: the
  // configuration's validation refuses any other) and a lag per (channel, time constant) of their
  // lag and derivative terms. Terms of other kinds are ignored.
  ChannelSignals(const std::vector<ChannelConfig>& declared,
                 const std::vector<BasisTerm>& terms);

  // Whether any channel is tracked (a configuration without channel terms tracks none).
  bool empty() const { return channels_.empty(); }

  // s of a channel term (the table above) at `time` in the interval after the last Advance, up
  // to the next frame's time. 0 for a channel not tracked.
  double Scalar(const BasisTerm& term, absl::Time time) const;

  // The frame that will close the interval (before Advance of it): its values of the tracked
  // channels are the ends of the lines the interval interpolates on (the file comment). A frame
  // not after the last one, and a channel it does not carry or whose line would span more than
  // the channel's maxAgeS, leave that channel held. Advance clears what Ahead set; without Ahead
  // (a prediction past the last frame) values are held.
  void Ahead(const TelemetryFrame& next);

  // Closes the interval at frame.time: each lag stepped to it (on the line Ahead set, else with
  // the held value), then the frame's values of the tracked channels taken. Frames in increasing
  // time; an older one is ignored.
  void Advance(const TelemetryFrame& frame);

  // The state as doubles (for the session's checkpoint) and back: per tracked channel in name
  // order has_value, time (unix seconds, nanoseconds), value; per lag in (name, tau) order
  // has_value, time (seconds, nanoseconds), y. RestoreState: DataLoss when the values do not
  // match this object's channels and lags or are not finite.
  std::vector<double> ExportState() const;
  absl::Status RestoreState(absl::Span<const double> state);

 private:
  struct Held {
    absl::Duration max_age;
    std::optional<absl::Time> time;  // of the frame that carried `value`
    double value = 0.0;
    // The next frame's value and time (Ahead), the line's far end; not part of the state.
    std::optional<std::pair<absl::Time, double>> next;
  };
  struct Lag {
    std::optional<absl::Time> time;  // y is y(time)
    double y = 0.0;
  };
  // The value of `h` at `t` (on the line to `next` when set, else held), nullopt when none or
  // expired.
  static std::optional<double> HeldAt(const Held& h, absl::Time t);
  // The lag of `held` advanced from lag.time to `t` (not stored).
  static std::optional<double> LagAt(const Held& held, const Lag& lag, double tau_s, absl::Time t);

  std::map<std::string, Held, std::less<>> channels_;
  std::map<std::pair<std::string, double>, Lag> lags_;
  absl::Time latest_ = absl::InfinitePast();
};

}  // namespace esg::estimator

#endif  // ESG_ESTIMATOR_CHANNEL_SIGNAL_H_
