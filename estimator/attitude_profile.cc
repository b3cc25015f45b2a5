#include "estimator/attitude_profile.h"

#include <algorithm>
#include <cmath>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "estimator/random.h"
#include "estimator/rotation.h"
#include "estimator/status_macros.h"

namespace esg::estimator {

using Eigen::Quaterniond;
using Eigen::Vector3d;

Vector3d AttitudeProfile::Rate(double t) const {
  // w_b = Log(conj(q(t - h)) (x) q(t + h)) / 2h, second order in h.
  const Quaterniond q_minus = Attitude(t - kRateStep);
  const Quaterniond q_plus = Attitude(t + kRateStep);
  return LogQuaternion(q_minus.conjugate() * q_plus) / (2.0 * kRateStep);
}

namespace {

// Random-stream id of the profile draws (see random.h DeriveSeed).
constexpr uint64_t kProfileStream = 0x5052'4F46;  // "PROF"

std::string FormatVector(const Vector3d& v) {
  return absl::StrFormat("[%.6g, %.6g, %.6g]", v.x(), v.y(), v.z());
}

class InertialHoldProfile final : public AttitudeProfile {
 public:
  explicit InertialHoldProfile(const Quaterniond& q_in_b) : q_in_b_(q_in_b.normalized()) {}
  Quaterniond Attitude(double) const override { return q_in_b_; }
  Vector3d Rate(double) const override { return Vector3d::Zero(); }
  std::string Describe() const override {
    return absl::StrFormat("inertial(q_in_b=[%.6f, %.6f, %.6f, %.6f])", q_in_b_.w(), q_in_b_.x(),
                           q_in_b_.y(), q_in_b_.z());
  }

 private:
  Quaterniond q_in_b_;
};

class ConstantSpinProfile final : public AttitudeProfile {
 public:
  ConstantSpinProfile(const Quaterniond& q_in_b0, const Vector3d& axis_b, double rate,
                      std::string description)
      : q_in_b0_(q_in_b0.normalized()),
        axis_b_(axis_b.normalized()),
        rate_(rate),
        description_(std::move(description)) {}

  Quaterniond Attitude(double t) const override {
    // q_in_b0 (x) Exp(axis_b * rate * t): one sincos per call.
    const double half_angle = 0.5 * rate_ * t;
    const double s = std::sin(half_angle);
    return q_in_b0_ *
           Quaterniond(std::cos(half_angle), s * axis_b_.x(), s * axis_b_.y(), s * axis_b_.z());
  }
  Vector3d Rate(double) const override { return rate_ * axis_b_; }
  std::string Describe() const override { return description_; }

 private:
  Quaterniond q_in_b0_;
  Vector3d axis_b_;
  double rate_;
  std::string description_;
};

class OrbitalProfile final : public AttitudeProfile {
 public:
  explicit OrbitalProfile(const OrbitalOptions& o) : options_(o), rate_(2.0 * kPi / o.period) {
    // C_in_b(u) = C_in_p * Rz(u) * C_p_b0 with p the orbit-plane frame (x to the ascending node,
    // z along the orbit normal): C_in_p = Rz(raan) Rx(inclination). At u = 0 the body axes in p
    // are x_b = (0,1,0) (velocity), y_b = (0,0,-1) (minus normal), z_b = (-1,0,0) (nadir).
    q_in_p_ = Quaterniond(Eigen::AngleAxisd(o.raan, Vector3d::UnitZ())) *
              Quaterniond(Eigen::AngleAxisd(o.inclination, Vector3d::UnitX()));
    Eigen::Matrix3d C_p_b0;
    C_p_b0.col(0) = Vector3d(0, 1, 0);
    C_p_b0.col(1) = Vector3d(0, 0, -1);
    C_p_b0.col(2) = Vector3d(-1, 0, 0);
    q_p_b0_ = Quaterniond(C_p_b0).normalized();
  }

  Quaterniond Attitude(double t) const override {
    const double half_u = 0.5 * (options_.arg_latitude0 + rate_ * t);
    return q_in_p_ * Quaterniond(std::cos(half_u), 0.0, 0.0, std::sin(half_u)) * q_p_b0_;
  }
  Vector3d Rate(double) const override { return Vector3d(0.0, -rate_, 0.0); }
  std::optional<double> OrbitalPeriod() const override { return options_.period; }
  std::string Describe() const override {
    return absl::StrFormat(
        "orbital(inclination %.4g deg, period %.6g min, raan %.4g deg, u0 %.4g deg)",
        RadToDeg(options_.inclination), options_.period / kSecondsPerMinute,
        RadToDeg(options_.raan), RadToDeg(options_.arg_latitude0));
  }

 private:
  OrbitalOptions options_;
  double rate_;
  Quaterniond q_in_p_;
  Quaterniond q_p_b0_;
};

class SequenceProfile final : public AttitudeProfile {
 public:
  SequenceProfile(std::vector<ProfileSegment> segments, double slew_duration,
                  std::string description)
      : segments_(std::move(segments)),
        slew_duration_(slew_duration),
        description_(std::move(description)) {
    double start = 0.0;
    for (const ProfileSegment& s : segments_) {
      starts_.push_back(start);
      start += s.duration;
    }
  }

  Quaterniond Attitude(double t) const override {
    const size_t i = SegmentIndex(t);
    const double local = t - starts_[i];
    const Quaterniond q_next = segments_[i].profile->Attitude(local);
    if (i == 0 || local >= slew_duration_) return q_next;
    // Slew from segment i-1 (continued past its end) to segment i.
    const Quaterniond q_prev = segments_[i - 1].profile->Attitude(t - starts_[i - 1]);
    const double tau = local / slew_duration_;
    const double s = tau * tau * tau * (10.0 + tau * (-15.0 + 6.0 * tau));  // quintic
    const Vector3d v = SlewRotation(i, local, q_prev.conjugate() * q_next);
    return (q_prev * ExpQuaternion(s * v)).normalized();
  }

  Vector3d Rate(double t) const override {
    const size_t i = SegmentIndex(t);
    const double local = t - starts_[i];
    // Away from slews (with a margin for the difference step) the segment's own rate.
    if (i == 0 || local >= slew_duration_ + kRateStep) {
      if (i + 1 >= segments_.size() || t + kRateStep < starts_[i + 1]) {
        return segments_[i].profile->Rate(local);
      }
    }
    return AttitudeProfile::Rate(t);
  }

  std::string Describe() const override { return description_; }

  std::optional<double> OrbitalPeriod() const override {
    for (const ProfileSegment& s : segments_) {
      if (std::optional<double> period = s.profile->OrbitalPeriod()) return period;
    }
    return std::nullopt;
  }

 private:
  // The relative rotation r = conj(q_prev) (x) q_next of the slew into segment i at local time
  // `local`, as a rotation vector on one branch for the whole slew. Both segments keep moving, so
  // r can pass through a rotation by pi; the shorter way (Log) would then flip its axis and the
  // attitude would jump. Instead r's sign is followed continuously from the slew's start, where
  // the shorter way is taken (the quaternions of r a few seconds apart are never near
  // orthogonal: each segment turns at most a few deg/s), and the angle 2 atan2(|r_xyz|, r_w)
  // runs over [0, 2 pi): a rotation through pi goes on the long way, continuously. While r stays
  // below pi this is exactly Log(r).
  Vector3d SlewRotation(size_t i, double local, const Quaterniond& r_now) const {
    const auto relative = [&](double u) {
      const double t = starts_[i] + u;
      const Quaterniond q_prev = segments_[i - 1].profile->Attitude(t - starts_[i - 1]);
      return Quaterniond(q_prev.conjugate() * segments_[i].profile->Attitude(u)).normalized();
    };
    Quaterniond branch = Canonical(relative(0.0));
    for (double u = kSlewUnwrapStep; u < local; u += kSlewUnwrapStep) {
      const Quaterniond r = relative(u);
      branch = r.dot(branch) < 0.0 ? Quaterniond(-r.w(), -r.x(), -r.y(), -r.z()) : r;
    }
    Quaterniond r = r_now;
    if (r.dot(branch) < 0.0) r = Quaterniond(-r.w(), -r.x(), -r.y(), -r.z());
    if (r.w() >= 0.0) return LogQuaternion(r);  // below pi: the shorter way, as Log gives it
    r.normalize();
    const Vector3d xyz(r.x(), r.y(), r.z());
    const double n = xyz.norm();
    return 2.0 * std::atan2(n, r.w()) * xyz / n;  // (pi, 2 pi): n > 0 there
  }

  static constexpr double kSlewUnwrapStep = 5.0;  // [s]

  size_t SegmentIndex(double t) const {
    const auto it = std::upper_bound(starts_.begin(), starts_.end(), t);
    return it == starts_.begin() ? 0 : static_cast<size_t>(it - starts_.begin()) - 1;
  }

  std::vector<ProfileSegment> segments_;
  std::vector<double> starts_;
  double slew_duration_;
  std::string description_;
};

absl::Status CheckFinite(double x, const char* field) {
  if (!std::isfinite(x)) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: must be finite, got %g", field, x));
  }
  return absl::OkStatus();
}

absl::Status CheckOrbital(const OrbitalOptions& o) {
  RETURN_IF_ERROR(CheckFinite(o.inclination, "orbital.inclination"));
  RETURN_IF_ERROR(CheckFinite(o.raan, "orbital.raan"));
  RETURN_IF_ERROR(CheckFinite(o.arg_latitude0, "orbital.arg_latitude0"));
  if (!(o.period > 0.0) || !std::isfinite(o.period)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("orbital.period: must be finite and > 0 s, got %g", o.period));
  }
  return absl::OkStatus();
}

absl::StatusOr<ProfilePtr> MakeSpin(const Quaterniond& q_in_b0, const Vector3d& axis_b, double rate,
                                    std::string description) {
  if (!q_in_b0.coeffs().allFinite() || q_in_b0.norm() < 1e-9) {
    return absl::InvalidArgumentError("spin.q_in_b0: must be a finite non-zero quaternion");
  }
  if (!axis_b.allFinite() || axis_b.norm() < 1e-9) {
    return absl::InvalidArgumentError("spin.axis_b: must be a finite non-zero vector");
  }
  RETURN_IF_ERROR(CheckFinite(rate, "spin.rate"));
  if (description.empty()) {
    description = absl::StrFormat("spin(axis_b %s, %.6g deg/s)", FormatVector(axis_b.normalized()),
                                  RadToDeg(rate));
  }
  return ProfilePtr(
      std::make_shared<ConstantSpinProfile>(q_in_b0, axis_b, rate, std::move(description)));
}

std::vector<Vector3d> DefaultSunAxes() {
  return {Vector3d::UnitZ(),
          Vector3d::UnitX(),
          Vector3d::UnitY(),
          Vector3d(1, 1, 1).normalized(),
          Vector3d(-1, 1, -1).normalized(),
          -Vector3d::UnitZ()};
}

// Calibration segments starting with axis/phase index `first`; phases drawn from rng if given.
absl::StatusOr<ProfilePtr> BuildCalibration(const CalibrationOptions& o, double duration, int first,
                                            Rng* rng) {
  if (!o.sun_in.allFinite() || o.sun_in.norm() < 1e-9) {
    return absl::InvalidArgumentError("calibration.sun_in: must be a finite non-zero vector");
  }
  if (!(o.spin_period > 0.0) || !std::isfinite(o.spin_period)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "calibration.spin_period: must be finite and > 0 s, got %g", o.spin_period));
  }
  if (!(o.segment_duration > 0.0) || !std::isfinite(o.segment_duration)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "calibration.segment_duration: must be finite and > 0 s, got %g", o.segment_duration));
  }
  if (!(o.slew_duration >= 0.0) || o.slew_duration > o.segment_duration) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "calibration.slew_duration: must be in [0, segment_duration], got %g s", o.slew_duration));
  }
  if (!(duration > 0.0) || !std::isfinite(duration)) {
    if (o.num_segments <= 0) {
      return absl::InvalidArgumentError(
          absl::StrFormat("duration: must be finite and > 0 s, got %g", duration));
    }
  }
  const std::vector<Vector3d> axes = o.sun_axes_b.empty() ? DefaultSunAxes() : o.sun_axes_b;
  for (size_t j = 0; j < axes.size(); ++j) {
    if (!axes[j].allFinite() || axes[j].norm() < 1e-9) {
      return absl::InvalidArgumentError(
          absl::StrFormat("calibration.sun_axes_b[%d]: must be a finite non-zero vector", j));
    }
  }
  for (size_t j = 0; j < o.phases.size(); ++j) {
    RETURN_IF_ERROR(CheckFinite(o.phases[j], "calibration.phases"));
  }
  int n = o.num_segments;
  if (n <= 0) n = static_cast<int>(std::ceil(duration / o.segment_duration));
  n = std::max(n, 1);
  if (n > 1000000) {
    return absl::InvalidArgumentError(
        absl::StrFormat("calibration: %d segments is too many (duration %g s)", n, duration));
  }
  const Vector3d sun_in = o.sun_in.normalized();
  const double rate = 2.0 * kPi / o.spin_period;
  std::vector<ProfileSegment> segments;
  segments.reserve(n);
  for (int i = 0; i < n; ++i) {
    const int k = first + i;
    const Vector3d a_b = axes[k % axes.size()].normalized();
    double phase = 2.1 * k;
    if (rng != nullptr) {
      phase = rng->Uniform(0.0, 2.0 * kPi);
    } else if (!o.phases.empty()) {
      phase = o.phases[k % o.phases.size()];
    }
    // Body axis a_b onto the Sun line, then the spin phase about the Sun line.
    const Quaterniond q_align = Quaterniond::FromTwoVectors(a_b, sun_in);
    const Quaterniond q_i = ExpQuaternion(phase * sun_in) * q_align;
    ASSIGN_OR_RETURN(
        ProfilePtr spin,
        MakeSpin(q_i, a_b, rate, absl::StrCat("sun-pointing spin about body ", FormatVector(a_b))));
    segments.push_back({std::move(spin), o.segment_duration});
  }
  return Sequence(
      std::move(segments), o.slew_duration,
      absl::StrFormat("calibration(sun_in %s, spin period %.6g min, orientation "
                      "every %.6g h, slew %.6g min, %d segments)",
                      FormatVector(sun_in), o.spin_period / kSecondsPerMinute,
                      SecondsToHours(o.segment_duration), o.slew_duration / kSecondsPerMinute, n));
}

Quaterniond RandomAttitude(Rng& rng) {
  // Uniform on SO(3): a normalised 4-D Gaussian.
  const double w = rng.Normal();
  const Vector3d v = rng.Normal3();
  return Quaterniond(w, v.x(), v.y(), v.z()).normalized();
}

}  // namespace

ProfilePtr InertialHold(const Quaterniond& q_in_b) {
  return std::make_shared<InertialHoldProfile>(q_in_b);
}

absl::StatusOr<ProfilePtr> ConstantSpin(const Quaterniond& q_in_b0, const Vector3d& axis_b,
                                        double rate) {
  return MakeSpin(q_in_b0, axis_b, rate, "");
}

absl::StatusOr<ProfilePtr> Orbital(const OrbitalOptions& options) {
  RETURN_IF_ERROR(CheckOrbital(options));
  return ProfilePtr(std::make_shared<OrbitalProfile>(options));
}

absl::StatusOr<ProfilePtr> Orbital(double inclination, double period, double raan,
                                   double arg_latitude0) {
  return Orbital(OrbitalOptions{inclination, period, raan, arg_latitude0});
}

absl::StatusOr<ProfilePtr> Sequence(std::vector<ProfileSegment> segments, double slew_duration,
                                    std::string description) {
  if (segments.empty()) return absl::InvalidArgumentError("sequence: no segments");
  if (!(slew_duration >= 0.0) || !std::isfinite(slew_duration)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "sequence.slew_duration: must be finite and >= 0 s, got %g", slew_duration));
  }
  for (size_t i = 0; i < segments.size(); ++i) {
    if (segments[i].profile == nullptr) {
      return absl::InvalidArgumentError(absl::StrFormat("sequence.segments[%d]: no profile", i));
    }
    if (!(segments[i].duration > 0.0) || !std::isfinite(segments[i].duration)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("sequence.segments[%d].duration: must be finite and > 0 s, got %g", i,
                          segments[i].duration));
    }
    if (i > 0 && slew_duration > segments[i].duration) {
      return absl::InvalidArgumentError(
          absl::StrFormat("sequence.slew_duration: %g s is longer than segment %d (%g s)",
                          slew_duration, i, segments[i].duration));
    }
  }
  return ProfilePtr(std::make_shared<SequenceProfile>(std::move(segments), slew_duration,
                                                      std::move(description)));
}

absl::StatusOr<ProfilePtr> Calibration(const CalibrationOptions& options, double duration) {
  return BuildCalibration(options, duration, 0, nullptr);
}

std::vector<std::string> NamedProfileNames() {
  return {"inertial", "orbital", "calibration", "mixed"};
}

absl::StatusOr<ProfilePtr> MakeNamedProfile(std::string_view name, double duration,
                                            std::optional<uint64_t> seed,
                                            const ProfileOptions& options) {
  const std::vector<std::string> names = NamedProfileNames();
  if (std::find(names.begin(), names.end(), name) == names.end()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "profile: unknown name '%s'; valid names are %s", name, absl::StrJoin(names, ", ")));
  }
  if (!(duration > 0.0) || !std::isfinite(duration)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("profile duration: must be finite and > 0 s, got %g", duration));
  }
  std::optional<Rng> rng;
  if (seed.has_value()) rng.emplace(DeriveSeed(*seed, kProfileStream));
  Rng* rng_ptr = rng.has_value() ? &*rng : nullptr;

  if (name == "inertial") {
    if (!options.inertial_q_in_b.coeffs().allFinite() || options.inertial_q_in_b.norm() < 1e-9) {
      return absl::InvalidArgumentError("inertial_q_in_b: must be a finite non-zero quaternion");
    }
    return InertialHold(rng_ptr ? RandomAttitude(*rng_ptr) : options.inertial_q_in_b);
  }
  if (name == "orbital") {
    OrbitalOptions o = options.orbital;
    if (rng_ptr) o.arg_latitude0 = rng_ptr->Uniform(0.0, 2.0 * kPi);
    return Orbital(o);
  }
  if (name == "calibration") {
    return BuildCalibration(options.calibration, duration, 0, rng_ptr);
  }
  // mixed: orbital, calibration, inertial, repeating.
  RETURN_IF_ERROR(CheckOrbital(options.orbital));
  const double parts[3] = {options.mixed_orbital_duration, options.mixed_calibration_duration,
                           options.mixed_inertial_duration};
  for (double d : parts) {
    if (!(d > 0.0) || !std::isfinite(d)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("mixed: part durations must be finite and > 0 s, got %g", d));
    }
  }
  const double slew = options.calibration.slew_duration;
  const double u0 = rng_ptr ? rng_ptr->Uniform(0.0, 2.0 * kPi) : options.orbital.arg_latitude0;
  const double orbit_rate = 2.0 * kPi / options.orbital.period;
  std::vector<ProfileSegment> segments;
  double covered = 0.0;
  int calibration_first = 0;
  for (int k = 0; covered < duration; k = (k + 1) % 3) {
    const double d = parts[k];
    ProfilePtr p;
    if (k == 0) {
      // The orbit runs on through the other parts: u at the segment start follows the clock.
      OrbitalOptions o = options.orbital;
      o.arg_latitude0 = std::fmod(u0 + orbit_rate * covered, 2.0 * kPi);
      ASSIGN_OR_RETURN(p, Orbital(o));
    } else if (k == 1) {
      CalibrationOptions c = options.calibration;
      c.num_segments = 0;
      ASSIGN_OR_RETURN(p, BuildCalibration(c, d, calibration_first, rng_ptr));
      calibration_first += static_cast<int>(std::ceil(d / c.segment_duration));
    } else {
      p = InertialHold(rng_ptr ? RandomAttitude(*rng_ptr) : options.inertial_q_in_b);
    }
    segments.push_back({std::move(p), d});
    covered += d;
  }
  return Sequence(std::move(segments), slew,
                  absl::StrFormat("mixed(orbital %.6g h, calibration %.6g h, inertial %.6g h, "
                                  "repeating; slew %.6g min)",
                                  SecondsToHours(parts[0]), SecondsToHours(parts[1]),
                                  SecondsToHours(parts[2]), slew / kSecondsPerMinute));
}

}  // namespace esg::estimator
