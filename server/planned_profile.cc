// Slerp-interpolated planned attitude of a prediction request (docs/physics.md, "Prediction").
#include "server/planned_profile.h"

#include <algorithm>
#include <cmath>

#include "absl/strings/str_cat.h"
#include "estimator/utc_time.h"

namespace esg::server {

absl::StatusOr<SampledProfile> SampledProfile::Create(std::vector<PlannedSample> samples) {
  if (samples.empty()) {
    return absl::InvalidArgumentError("planned_attitude: at least one sample is needed");
  }
  SampledProfile p;
  p.start_ = samples.front().time;
  for (size_t i = 0; i < samples.size(); ++i) {
    const Eigen::Quaterniond& q = samples[i].q_in_b;
    const double n = q.norm();
    if (!std::isfinite(n) || std::abs(n - 1.0) > 1e-3) {
      return absl::InvalidArgumentError(
          absl::StrCat("planned_attitude[", i, "].q_in_b: norm ", n, " is not 1 (tolerance 0.001)"));
    }
    if (i > 0 && samples[i].time <= samples[i - 1].time) {
      return absl::InvalidArgumentError(absl::StrCat(
          "planned_attitude[", i, "].time: ", estimator::FormatUtc(samples[i].time),
          " is not after the previous sample ", estimator::FormatUtc(samples[i - 1].time)));
    }
    p.t_.push_back(absl::ToDoubleSeconds(samples[i].time - p.start_));
    p.q_in_b_.push_back(q.normalized());
  }
  return p;
}

Eigen::Quaterniond SampledProfile::Attitude(double t) const {
  if (t <= t_.front()) return q_in_b_.front();
  if (t >= t_.back()) return q_in_b_.back();
  const size_t j = std::upper_bound(t_.begin(), t_.end(), t) - t_.begin();  // t_[j-1] <= t < t_[j]
  const double s = (t - t_[j - 1]) / (t_[j] - t_[j - 1]);
  return q_in_b_[j - 1].slerp(s, q_in_b_[j]).normalized();  // Eigen's slerp takes the short arc
}

std::string SampledProfile::Describe() const {
  return absl::StrCat("planned attitude, ", t_.size(), " samples from ",
                      estimator::FormatUtc(start_));
}

}  // namespace esg::server
