#include "estimator/simulator_star_tracker.h"

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "estimator/rotation.h"
#include "estimator/units.h"

namespace esg::estimator::simulator_internal {

using Eigen::Quaterniond;
using Eigen::Vector3d;

namespace {

// Longest step of the mount's lag between two samples [s]: u is taken at each step's midpoint.
constexpr double kMountStepS = 10.0;

bool InAnyWindow(const std::vector<std::pair<double, double>>& windows, double t) {
  return std::any_of(windows.begin(), windows.end(),
                     [&](const auto& w) { return t >= w.first && t < w.second; });
}

}  // namespace

StarTrackerSampler::StarTrackerSampler(const SimulationSpec& spec, const SunNodes* sun_nodes)
    : st_(spec.star_tracker),
      profile_(*spec.profile),
      sun_nodes_(sun_nodes),
      noise_(st_.noise.value_or(spec.config.star_tracker.noise)),
      q_misalignment_(ExpQuaternion(st_.misalignment_b)),
      q_jump_(st_.misalignment_jump ? ExpQuaternion(st_.misalignment_jump->rotation_b)
                                    : Quaterniond::Identity()),
      burst_left_(st_.outlier_burst ? st_.outlier_burst->count : 0),
      noise_rng_(DeriveSeed(spec.seed, kStarTrackerNoiseStream)),
      outlier_rng_(DeriveSeed(spec.seed, kStarTrackerOutlierStream)),
      invalid_rng_(DeriveSeed(spec.seed, kStarTrackerInvalidStream)) {
  // The mount in equilibrium with its illumination at the start: y(0) = u(0).
  if (st_.sun_mount) mount_y_ = FaceIlluminationAt(0.0);
}

double StarTrackerSampler::FaceIlluminationAt(double t) const {
  const Vector3d s_b = profile_.Attitude(t).toRotationMatrix().transpose() * sun_nodes_->At(t);
  return FaceIllumination(s_b, st_.sun_mount->face_axis, st_.sun_mount->face_sign);
}

double StarTrackerSampler::MountIllumination(double t_m) {
  const double tau = st_.sun_mount->time_constant_s;
  while (mount_time_ < t_m) {
    const double h = std::min(kMountStepS, t_m - mount_time_);
    const double u = FaceIlluminationAt(mount_time_ + 0.5 * h);
    mount_y_ = u + (mount_y_ - u) * std::exp(-h / tau);
    mount_time_ += h;
  }
  return mount_y_;
}

void StarTrackerSampler::Sample(double t_m, TelemetryFrame& frame, TruthSample& truth) {
  const Vector3d n = noise_rng_.Normal3();
  const double outlier_draw = outlier_rng_.Uniform();
  const Vector3d outlier_axis = outlier_rng_.UnitVector();
  const double outlier_angle = st_.outlier_size * outlier_rng_.Uniform(1.0, 3.0);
  const double invalid_draw = invalid_rng_.Uniform();
  // The mount's temperature follows the sun in an outage too.
  const double mount_y = st_.sun_mount ? MountIllumination(t_m) : 0.0;
  const bool in_outage = InAnyWindow(st_.outages, t_m);
  const bool in_frozen = InAnyWindow(st_.frozen, t_m);
  if (!in_frozen) held_.reset();
  if (in_outage) return;
  const Quaterniond q_true_lagged =
      st_.latency == 0.0 ? truth.q_in_b : profile_.Attitude(t_m - st_.latency);
  Quaterniond q_meas = q_true_lagged * q_misalignment_;
  if (st_.misalignment_cycle) {
    const StarTrackerMisalignmentCycle& c = *st_.misalignment_cycle;
    q_meas = q_meas * ExpQuaternion(c.amplitude_b *
                                    std::sin(2.0 * kPi * t_m / c.period_s + c.phase_rad));
  }
  if (st_.sun_mount) q_meas = q_meas * ExpQuaternion(st_.sun_mount->rotation_b * mount_y);
  if (st_.misalignment_jump && t_m >= st_.misalignment_jump->time) q_meas = q_meas * q_jump_;
  q_meas = q_meas * ExpQuaternion(noise_.cwiseProduct(n));
  if (burst_left_ > 0 && t_m >= st_.outlier_burst->time) {
    // Cross-boresight: the frame's random axis without its body-z component.
    Vector3d axis(outlier_axis.x(), outlier_axis.y(), 0.0);
    axis = axis.norm() > 1e-12 ? Vector3d(axis.normalized()) : Vector3d::UnitX();
    q_meas = q_meas * ExpQuaternion(st_.outlier_burst->angle * axis);
    truth.star_tracker_outlier = true;
    truth.star_tracker_outlier_angle = st_.outlier_burst->angle;
    --burst_left_;
  } else if (outlier_draw < st_.outlier_probability) {
    q_meas = q_meas * ExpQuaternion(outlier_angle * outlier_axis);
    truth.star_tracker_outlier = true;
    truth.star_tracker_outlier_angle = outlier_angle;
  }
  StarTrackerReading reading;
  reading.q_in_b = Canonical(q_meas.normalized());
  reading.valid = !(invalid_draw < st_.invalid_probability);
  if (in_frozen) HoldOrRepeat(reading, truth);
  frame.star_tracker = reading;
}

void StarTrackerSampler::HoldOrRepeat(StarTrackerReading& reading, TruthSample& truth) {
  if (held_) {
    reading = *held_;
    truth.star_tracker_outlier = held_outlier_;
    truth.star_tracker_outlier_angle = held_outlier_angle_;
    truth.star_tracker_frozen = true;
  } else {
    held_ = reading;
    held_outlier_ = truth.star_tracker_outlier;
    held_outlier_angle_ = truth.star_tracker_outlier_angle;
  }
}

}  // namespace esg::estimator::simulator_internal
