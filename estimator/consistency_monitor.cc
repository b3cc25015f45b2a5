// The running chi-square test of consistency_monitor.h.
#include "estimator/consistency_monitor.h"

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <string>

#include "absl/strings/str_format.h"

#include "estimator/statistics.h"

namespace esg::estimator {

namespace {
// Per-step cap level: a step's NIS enters at most at its 1 - 1e-3 quantile.
constexpr double kCapLevel = 1e-3;
// Largest degrees of freedom of one step a restored state may carry (2 per gyro, or 1).
constexpr int kMaxStepDof = 64;

void PutTime(absl::Time t, std::vector<double>& v) {
  if (t == absl::InfinitePast()) {
    v.insert(v.end(), {-1.0, 0.0, 0.0});
    return;
  }
  const int64_t ns = absl::ToUnixNanos(t);
  v.insert(v.end(),
           {1.0, static_cast<double>(ns / 1000000000), static_cast<double>(ns % 1000000000)});
}

// Reads ExportState's values in order; the first problem is kept and later reads return 0.
class StateReader {
 public:
  explicit StateReader(absl::Span<const double> v) : v_(v) {}

  double Real(const std::string& field, double lo, double hi) {
    const double x = Next(field);
    if (error_.empty() && !(x >= lo && x <= hi)) {
      Fail(field, x, absl::StrFormat("must be finite, in [%g, %g]", lo, hi));
      return 0.0;
    }
    return x;
  }
  int64_t Int(const std::string& field, int64_t lo, int64_t hi) {
    const double x = Next(field);
    if (!error_.empty()) return 0;
    if (!(x >= static_cast<double>(lo) && x <= static_cast<double>(hi)) || x != std::floor(x)) {
      Fail(field, x, absl::StrFormat("must be an integer in [%d, %d]", lo, hi));
      return 0;
    }
    return static_cast<int64_t>(x);
  }
  bool Flag(const std::string& field) { return Int(field, 0, 1) != 0; }
  absl::Time Time(const std::string& field) {
    const int64_t flag = Int(field + ".flag", -1, 1);
    const int64_t sec = Int(field + ".unix_seconds", -1000000000000, 1000000000000);
    const int64_t nsec = Int(field + ".nanoseconds", -999999999, 999999999);
    if (flag == 1) return absl::FromUnixSeconds(sec) + absl::Nanoseconds(nsec);
    if (error_.empty() && (flag != -1 || sec != 0 || nsec != 0)) {
      Fail(field + ".flag", static_cast<double>(flag), "must be 1, or -1 with zero seconds");
    }
    return absl::InfinitePast();
  }
  void Fail(const std::string& field, double value, const std::string& why) {
    if (error_.empty()) error_ = absl::StrFormat("%s = %g: %s", field, value, why);
  }
  absl::Status Finish() {
    if (error_.empty() && pos_ != v_.size()) {
      error_ =
          absl::StrFormat("consistency monitor state: %d values, %d expected", v_.size(), pos_);
    }
    if (error_.empty()) return absl::OkStatus();
    return absl::DataLossError(error_);
  }

 private:
  double Next(const std::string& field) {
    if (!error_.empty()) return 0.0;
    if (pos_ >= v_.size()) {
      error_ = absl::StrFormat("%s: consistency monitor state truncated at value %d", field, pos_);
      return 0.0;
    }
    return v_[pos_++];
  }

  absl::Span<const double> v_;
  size_t pos_ = 0;
  std::string error_;
};
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
  const double q = ChiSquareQuantile(1.0 - level, dof);
  if (cache.size() >= 8) cache.erase(cache.begin());
  cache.emplace_back(dof, q);
  return q;
}

double ConsistencyMonitor::Cap(int dof) {
  if (dof < static_cast<int>(cap_cache_.size())) {
    double& c = cap_cache_[dof];
    if (c == 0.0) c = ChiSquareQuantile(1.0 - kCapLevel, dof);
    return c;
  }
  return ChiSquareQuantile(1.0 - kCapLevel, dof);
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

std::vector<double> ConsistencyMonitor::ExportState() const {
  std::vector<double> v;
  v.push_back(tests_);
  v.push_back(inconsistent_tests_);
  PutTime(first_inconsistent_time_, v);
  for (const ChannelState& c : channels_) {
    v.push_back(static_cast<double>(c.steps_seen));
    v.push_back(c.last.has_value() ? 1 : 0);
    const TestResult r = c.last.value_or(TestResult{});
    PutTime(c.last.has_value() ? r.time : absl::InfinitePast(), v);
    v.insert(v.end(), {static_cast<double>(r.steps), static_cast<double>(r.dof), r.nis_sum,
                       r.previous_nis_sum, r.threshold, r.window_exceeded ? 1.0 : 0.0,
                       r.inconsistent ? 1.0 : 0.0});
    v.push_back(static_cast<double>(c.window.size()));
    for (const Step& step : c.window) v.insert(v.end(), {step.nis, static_cast<double>(step.dof)});
  }
  return v;
}

absl::Status ConsistencyMonitor::RestoreState(absl::Span<const double> state) {
  constexpr int64_t kMaxCount = int64_t{1} << 50;  // exact in a double, beyond any real count
  constexpr double kMaxSum = 1e15;
  StateReader in(state);
  const int64_t tests = in.Int("tests", 0, 1 << 30);
  const int64_t inconsistent_tests = in.Int("inconsistent_tests", 0, tests);
  const absl::Time first_inconsistent_time = in.Time("first_inconsistent_time");
  if (inconsistent_tests > 0 && first_inconsistent_time == absl::InfinitePast()) {
    in.Fail("first_inconsistent_time.flag", -1, "must be set when a test failed");
  }
  std::array<ChannelState, kChannels> channels;
  const int n = options_.window_steps;
  for (int k = 0; k < kChannels; ++k) {
    const std::string name =
        k == static_cast<int>(Channel::kStarTracker) ? "star_tracker" : "autonomous";
    ChannelState& c = channels[k];
    c.steps_seen = in.Int(name + ".steps_seen", 0, kMaxCount);
    const bool has_last = in.Flag(name + ".has_last");
    TestResult r;
    r.channel = static_cast<Channel>(k);
    r.time = in.Time(name + ".last.time");
    r.steps = static_cast<int>(in.Int(name + ".last.steps", 0, n));
    r.dof = static_cast<int>(in.Int(name + ".last.dof", 0, int64_t{kMaxStepDof} * n));
    r.nis_sum = in.Real(name + ".last.nis_sum", 0.0, kMaxSum);
    r.previous_nis_sum = in.Real(name + ".last.previous_nis_sum", 0.0, kMaxSum);
    r.threshold = in.Real(name + ".last.threshold", 0.0, kMaxSum);
    r.window_exceeded = in.Flag(name + ".last.window_exceeded");
    r.inconsistent = in.Flag(name + ".last.inconsistent");
    if (has_last) c.last = r;
    // Add keeps the last 2 N steps after the warm-up: the length follows from steps_seen.
    const int64_t expected =
        std::clamp<int64_t>(c.steps_seen - options_.warmup_steps, 0, int64_t{2} * n);
    const int64_t w = in.Int(name + ".window_length", 0, int64_t{2} * n);
    if (w != expected) {
      in.Fail(name + ".window_length", static_cast<double>(w),
              absl::StrFormat("must be %d (steps_seen after the warm-up of %d, at most 2 x %d)",
                              expected, options_.warmup_steps, n));
    }
    for (int64_t j = 0; j < w; ++j) {
      const double nis = in.Real(name + ".window.nis", 0.0, kMaxSum);
      const int dof = static_cast<int>(in.Int(name + ".window.dof", 1, kMaxStepDof));
      // Add stores each NIS capped; a larger one was not written by it.
      if (dof >= 1 && nis > Cap(dof)) {
        in.Fail(name + ".window.nis", nis, "exceeds the per-step cap");
      }
      c.window.push_back(Step{nis, dof});
    }
  }
  if (absl::Status s = in.Finish(); !s.ok()) return s;
  for (int k = 0; k < kChannels; ++k) {
    // The cached quantiles are a pure function of the degrees of freedom: kept.
    channels[k].thresholds = std::move(channels_[k].thresholds);
  }
  channels_ = std::move(channels);
  tests_ = static_cast<int>(tests);
  inconsistent_tests_ = static_cast<int>(inconsistent_tests);
  first_inconsistent_time_ = first_inconsistent_time;
  return absl::OkStatus();
}

bool ConsistencyMonitor::inconsistent() const {
  for (const ChannelState& c : channels_) {
    if (c.last.has_value() && c.last->inconsistent) return true;
  }
  return false;
}

}  // namespace esg::estimator
