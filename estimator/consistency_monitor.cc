// The running chi-square test of consistency_monitor.h.
#include "estimator/consistency_monitor.h"

#include <algorithm>
#include <cmath>

#include "estimator/discovery/statistics.h"

namespace esg::estimator {

namespace {
// Per-step cap level: a step's NIS enters at most at its 1 - 1e-3 quantile.
constexpr double kCapLevel = 1e-3;
}  // namespace

double PerTestLevel(double measurement_step_s, int test_every_steps, int channels,
                    double span_s, double expected_false_alarms) {
  const double tests = span_s / (measurement_step_s * test_every_steps) * channels;
  return expected_false_alarms / tests;
}

const char* ConsistencyChannelName(ConsistencyMonitor::Channel channel) {
  switch (channel) {
    case ConsistencyMonitor::Channel::kStarTracker:
      return "star-tracker NIS";
    case ConsistencyMonitor::Channel::kAutonomous:
      return "z_avt NIS";
  }
  return "?";
}

ConsistencyMonitor::ConsistencyMonitor(const ConsistencyMonitorOptions& options)
    : options_(options) {
  options_.window_steps = std::max(options_.window_steps, 1);
  options_.test_every_steps = std::clamp(options_.test_every_steps, 1, options_.window_steps);
  options_.warmup_steps = std::max(options_.warmup_steps, 0);
}

double ConsistencyMonitor::Threshold(ChannelState& c, int dof, double level) {
  auto& cache = c.thresholds;
  for (const auto& [d, q] : cache) {
    if (d == dof) return q;
  }
  const double q = discovery::ChiSquareQuantile(1.0 - level, dof);
  if (cache.size() >= 8) cache.erase(cache.begin());
  cache.emplace_back(dof, q);
  return q;
}

double ConsistencyMonitor::Cap(int dof) {
  if (dof < static_cast<int>(cap_cache_.size())) {
    double& c = cap_cache_[dof];
    if (c == 0.0) c = discovery::ChiSquareQuantile(1.0 - kCapLevel, dof);
    return c;
  }
  return discovery::ChiSquareQuantile(1.0 - kCapLevel, dof);
}

std::optional<ConsistencyMonitor::TestResult> ConsistencyMonitor::Add(Channel channel,
                                                                      absl::Time time, double nis,
                                                                      int dof) {
  if (dof <= 0 || !std::isfinite(nis)) return std::nullopt;
  ChannelState& c = channels_[static_cast<int>(channel)];
  ++c.steps_seen;
  if (c.steps_seen <= options_.warmup_steps) return std::nullopt;
  c.window.push_back(Step{std::min(std::max(nis, 0.0), Cap(dof)), dof});
  const int n = options_.window_steps;
  if (static_cast<int>(c.window.size()) > 2 * n) c.window.pop_front();
  const long tested = c.steps_seen - options_.warmup_steps - 2L * n;
  if (tested < 0 || tested % options_.test_every_steps != 0) return std::nullopt;
  TestResult r;
  r.channel = channel;
  r.time = time;
  r.steps = n;
  int previous_dof = 0;
  for (int k = 0; k < 2 * n; ++k) {
    const Step& s = c.window[k];
    if (k < n) {
      r.previous_nis_sum += s.nis;
      previous_dof += s.dof;
    } else {
      r.nis_sum += s.nis;
      r.dof += s.dof;
    }
  }
  const double window_level = std::sqrt(options_.false_alarm_per_test);
  r.threshold = Threshold(c, r.dof, window_level);
  r.window_exceeded = r.nis_sum > r.threshold;
  r.inconsistent =
      r.window_exceeded && r.previous_nis_sum > Threshold(c, previous_dof, window_level);
  ++tests_;
  if (r.inconsistent) {
    ++inconsistent_tests_;
    if (first_inconsistent_time_ == absl::InfinitePast()) first_inconsistent_time_ = time;
  }
  c.last = r;
  return r;
}

void ConsistencyMonitor::Reset() {
  for (ChannelState& c : channels_) {
    c.window.clear();
    c.steps_seen = 0;
  }
}

bool ConsistencyMonitor::inconsistent() const {
  for (const ChannelState& c : channels_) {
    if (c.last.has_value() && c.last->inconsistent) return true;
  }
  return false;
}

}  // namespace esg::estimator
