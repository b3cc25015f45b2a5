// The planned attitude of a prediction request (long-gap prediction, docs/physics.md) as an
// estimator::AttitudeProfile: a time-ordered list of q_in_b samples, interpolated by slerp between
// neighbours and held constant before the first and after the last sample.
#ifndef ESG_SERVER_PLANNED_PROFILE_H_
#define ESG_SERVER_PLANNED_PROFILE_H_

#include <string>
#include <vector>

#include "Eigen/Geometry"
#include "absl/status/statusor.h"
#include "absl/time/time.h"
#include "estimator/attitude_profile.h"

namespace esg::server {

struct PlannedSample {
  absl::Time time;
  Eigen::Quaterniond q_in_b;  // unit
};

class SampledProfile : public estimator::AttitudeProfile {
 public:
  // Profile time t = 0 is samples[0].time. InvalidArgument naming "planned_attitude[i].time"
  // unless times strictly increase, or "planned_attitude[i].q_in_b" for a non-unit quaternion
  // (|norm - 1| > 1e-3) or non-finite values; at least one sample.
  static absl::StatusOr<SampledProfile> Create(std::vector<PlannedSample> samples);

  absl::Time start() const { return start_; }
  Eigen::Quaterniond Attitude(double t) const override;
  std::string Describe() const override;

 private:
  absl::Time start_;
  std::vector<double> t_;                 // [s] since start_
  std::vector<Eigen::Quaterniond> q_in_b_;
};

}  // namespace esg::server

#endif  // ESG_SERVER_PLANNED_PROFILE_H_
