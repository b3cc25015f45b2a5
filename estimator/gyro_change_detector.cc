// The per-gyro accumulated star-tracker test (gyro_change_detector.h).
#include "estimator/gyro_change_detector.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_format.h"
#include "estimator/statistics.h"

namespace esg::estimator {

namespace {
constexpr double kCapLevel = 1e-3;  // each step's NIS capped at chi2inv(1 - 1e-3, 2)
}  // namespace

GyroChangeDetector::GyroChangeDetector(GyroChangeDetectorOptions options) : options_(options) {
  const double dof = 2.0 * options_.window_steps;
  cap_ = ChiSquareQuantile(1.0 - kCapLevel, 2.0);
  fail_threshold_ = ChiSquareQuantile(1.0 - options_.alpha_fail, dof);
  pass_threshold_ = ChiSquareQuantile(1.0 - options_.alpha_pass, dof);
}

std::optional<GyroChangeDetector::Decision> GyroChangeDetector::Add(
    const std::array<int, 3>& gyro_ids, const std::array<double, 3>& nis,
    bool star_tracker_suspected) {
  if (gyro_ids != gyro_ids_) {
    steps_.clear();
    gyro_ids_ = gyro_ids;
  }
  // A NIS that is negative or NaN comes from a covariance that is not positive definite: it is no
  // chi-square value, and its step decides nothing (kept at 0, the step marked as undecided).
  std::array<double, 4> step;
  bool undecided = star_tracker_suspected;
  for (int k = 0; k < 3; ++k) {
    if (!(nis[k] >= 0.0)) {
      step[k] = 0.0;
      undecided = true;
    } else {
      step[k] = std::min(nis[k], cap_);  // +inf enters at the cap
    }
  }
  step[3] = undecided ? 1.0 : 0.0;
  steps_.push_back(step);
  while (static_cast<int>(steps_.size()) > options_.window_steps) steps_.pop_front();
  if (static_cast<int>(steps_.size()) < options_.window_steps) return std::nullopt;
  Decision d;
  d.gyro_ids = gyro_ids_;
  for (const auto& s : steps_) {
    if (s[3] != 0.0) return std::nullopt;
    for (int k = 0; k < 3; ++k) d.sums[k] += s[k];
  }
  d.fail_threshold = fail_threshold_;
  d.pass_threshold = pass_threshold_;
  d.steps = options_.window_steps;
  int failed = -1, failures = 0, passes = 0;
  for (int k = 0; k < 3; ++k) {
    if (d.sums[k] > fail_threshold_) {
      failed = k;
      ++failures;
    }
    passes += d.sums[k] < pass_threshold_ ? 1 : 0;
  }
  if (failures != 1 || passes != 2) return std::nullopt;
  d.gyro_id = gyro_ids_[failed];
  return d;
}

void GyroChangeDetector::Clear() {
  steps_.clear();
  gyro_ids_ = {0, 0, 0};
}

std::vector<double> GyroChangeDetector::ExportState() const {
  std::vector<double> v = {static_cast<double>(gyro_ids_[0]), static_cast<double>(gyro_ids_[1]),
                           static_cast<double>(gyro_ids_[2]), static_cast<double>(steps_.size())};
  for (const auto& s : steps_) v.insert(v.end(), s.begin(), s.end());
  return v;
}

absl::Status GyroChangeDetector::RestoreState(absl::Span<const double> state) {
  if (state.size() < 4) return absl::DataLossError("gyro change detector: state truncated");
  std::array<int, 3> ids;
  for (int k = 0; k < 3; ++k) {
    const double id = state[k];
    if (!(id >= 0.0 && id <= 1000.0 && id == std::floor(id))) {
      return absl::DataLossError(
          absl::StrFormat("gyro change detector: gyro id %g is not a small integer", id));
    }
    ids[k] = static_cast<int>(id);
  }
  const double n = state[3];
  if (!(n >= 0.0 && n <= options_.window_steps && n == std::floor(n))) {
    return absl::DataLossError(absl::StrFormat(
        "gyro change detector: step count %g outside [0, %d]", n, options_.window_steps));
  }
  if (state.size() != 4 + 4 * static_cast<size_t>(n)) {
    return absl::DataLossError("gyro change detector: state size does not match its step count");
  }
  std::deque<std::array<double, 4>> steps;
  for (size_t i = 0; i < static_cast<size_t>(n); ++i) {
    std::array<double, 4> s;
    for (int k = 0; k < 4; ++k) s[k] = state[4 + 4 * i + k];
    for (int k = 0; k < 3; ++k) {
      if (!(s[k] >= 0.0 && s[k] <= cap_)) {
        return absl::DataLossError(
            absl::StrFormat("gyro change detector: value %g outside [0, %g]", s[k], cap_));
      }
    }
    if (s[3] != 0.0 && s[3] != 1.0) {
      return absl::DataLossError(
          absl::StrFormat("gyro change detector: undecided flag %g is not 0 or 1", s[3]));
    }
    steps.push_back(s);
  }
  gyro_ids_ = ids;
  steps_ = std::move(steps);
  return absl::OkStatus();
}

}  // namespace esg::estimator
